"""Bounded curve points: bins of episodes by index, means over the bin, whatever the chunking."""

import pytest

from ablate.agent.records import EpisodeMetrics
from ablate.launch.curve import CURVE_POINTS, CurveReducer


def rows(episodes: int, per_update: int) -> list[EpisodeMetrics]:
    out = []
    for i in range(episodes):
        update = i // per_update + 1
        out.append(
            EpisodeMetrics(
                episode=i + 1,
                episode_return=float(10 + i),
                length=10 + i,
                loss=float(update),  # every row of an update carries that update's loss and entropy
                entropy=0.5 + update,
                rolling_mean=float(i),
                env_steps=100 * i,
                wall_s=0.1 * (i + 1),
                update=update,
            )
        )
    return out


def reduce(episodes, per_update, chunk, max_episodes, points=CURVE_POINTS):
    reducer = CurveReducer(max_episodes, points)
    data = rows(episodes, per_update)
    out = []
    for start in range(0, len(data), chunk):
        out += reducer.add(data[start : start + chunk])
    return out + reducer.flush()


def test_bin_size_bounds_the_points_whatever_the_budget():
    sizes = {budget: CurveReducer(budget).size for budget in (20, 100, 101, 1500, 10**6)}
    assert sizes == {20: 1, 100: 1, 101: 2, 1500: 15, 10**6: 10**4}
    for budget in (1, 99, 1500, 123_457):
        assert len(reduce(budget, 32, 32, budget)) <= CURVE_POINTS + 1


def test_points_are_means_over_fixed_bins_and_the_last_bin_is_partial():
    points = reduce(20, per_update=1, chunk=5, max_episodes=64, points=8)  # 8 episodes per point
    assert [p.episode for p in points] == [8, 16, 20]
    assert points[0].episode_return == pytest.approx(sum(range(10, 18)) / 8)
    assert points[2].length == pytest.approx(sum(range(26, 30)) / 4)
    assert [p.loss for p in points] == pytest.approx([4.5, 12.5, 18.5])  # mean over the bin's updates
    assert points[2].entropy == pytest.approx(19.0)
    assert points[1].rolling_mean == 15.0 and points[2].wall_s == pytest.approx(2.0)
    assert points[2].env_steps == 1900


@pytest.mark.parametrize("chunk", [1, 3, 10, 20])
def test_chunking_does_not_change_the_points(chunk):
    """A resumed trial replays its history in one call: it must give the same points as the live run."""
    assert reduce(20, per_update=4, chunk=chunk, max_episodes=60, points=10) == reduce(20, 4, 20, 60, 10)
