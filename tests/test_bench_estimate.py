"""`benchmarks/bench_estimate.py`'s scoring of the time-left estimate: each estimate against the end of the
trials the view knew of when it made it (its phase), not against the end of a round it could not foresee."""

from pathlib import Path

import pytest
from views import Watched, grid_trials, row


@pytest.fixture
def bench_estimate(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).parent.parent / "benchmarks"))
    import bench_estimate

    return bench_estimate


def _run(view, clock, keys, seconds=100.0):
    """Each trial alone on the one slot, 100 episodes in ``seconds``, reported halfway."""
    for key in keys:
        view.started(key)
        clock.now += seconds / 2
        view.episodes(key, [row(50, 1.0)])
        clock.now += seconds / 2
        view.finished(key, solved=False, summary={"episodes_run": 100})


def test_each_estimate_is_held_to_the_end_of_its_phase_not_of_a_later_round(bench_estimate, clock):
    view = Watched("x", grid_trials(variants=("a",), seeds=(0, 1, 2, 3)), 0, enabled=False, slots=1,
                        start=clock.now, log_estimates=True)  # fmt: skip
    _run(view, clock, ["a-s0", "a-s1", "a-s2", "a-s3"])  # 400 s; every estimate after the first end is exact
    view.add_trials(grid_trials(variants=("a",), seeds=(4, 5)))  # a round of seeds, 200 s more
    _run(view, clock, ["a-s4", "a-s5"])
    view.state.trials_end = clock.now
    errors = bench_estimate._eta_errors(view)
    assert [(p["trials"], p["within_bound"] == p["points"]) for p in errors["phases"]] == [(4, True), (2, True)]
    assert errors["within_bound"] == errors["points"] > 0 and errors["worst_over_bound"] == pytest.approx(0.0)
    # Held to the launch's end instead, round 1's last estimates (100 s said, 300 s left) would be far outside.
    first_phase = [e for e in view.estimates if e[4] == 0 and e[2] is not None and e[1] >= 1]
    assert any(abs(est - (600 - t)) > max(0.3 * (600 - t), 20) for t, _, est, *_ in first_phase)
