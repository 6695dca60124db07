"""The tracker's metric layout, against a real SQLite MLflow store in a temp folder."""

import pytest

from ablate.tracking import EPISODES_PER_POINT, Tracker
from ablate.trial import EpisodeMetrics

UPDATE_KEYS = ("episode/rolling_mean", "episode/loss", "episode/entropy", "episode/wall_s", "episode/length")


def _rows(episodes: int, per_update: int) -> list[EpisodeMetrics]:
    rows = []
    for i in range(episodes):
        update = i // per_update + 1
        rows.append(
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
    return rows


def _track(tracking_uri, rows, chunk):
    tracker = Tracker(tracking_uri, "layout")
    launch = tracker.start_launch("g", "launch", {}, {})
    run_id = tracker.start_trial(launch, "g", "t-s0-abc", "t", 0, {"seed": 0}, "commit")
    for start in range(0, len(rows), chunk):  # the scheduler sends whole updates, a few at a time
        tracker.log_episodes("t-s0-abc", rows[start : start + chunk])
    tracker.finish_trial("t-s0-abc", {"episodes_run": len(rows)}, None)
    return tracker, run_id


def test_one_episode_updates_get_a_point_every_eight_episodes_and_the_rest_at_the_end(tracking_uri):
    assert EPISODES_PER_POINT == 8
    tracker, run_id = _track(tracking_uri, _rows(20, per_update=1), chunk=5)
    assert [step for step, _ in tracker.metric_history(run_id, "episode/return")] == list(range(1, 21))
    for key in UPDATE_KEYS:
        assert [step for step, _ in tracker.metric_history(run_id, key)] == [8, 16, 20], key
    loss = dict(tracker.metric_history(run_id, "episode/loss"))
    assert loss == {8: pytest.approx(4.5), 16: pytest.approx(12.5), 20: pytest.approx(18.5)}  # mean of updates
    entropy = dict(tracker.metric_history(run_id, "episode/entropy"))
    assert entropy[20] == pytest.approx(19.0)
    length = dict(tracker.metric_history(run_id, "episode/length"))
    assert length[8] == pytest.approx(sum(range(10, 18)) / 8) and length[20] == pytest.approx(sum(range(26, 30)) / 4)
    assert dict(tracker.metric_history(run_id, "episode/rolling_mean"))[16] == 15.0  # the value at that episode
    assert dict(tracker.metric_history(run_id, "episode/wall_s"))[20] == pytest.approx(2.0)


@pytest.mark.parametrize(("per_update", "steps"), [(10, [10, 20]), (4, [8, 16, 20]), (32, [20])])
def test_points_fall_on_update_ends(tracking_uri, per_update, steps):
    tracker, run_id = _track(tracking_uri, _rows(20, per_update), chunk=per_update)
    for key in UPDATE_KEYS:
        assert [step for step, _ in tracker.metric_history(run_id, key)] == steps, key


def test_metric_points_carry_the_episodes_own_time_not_the_batch_write(tracking_uri):
    tracker, run_id = _track(tracking_uri, _rows(20, per_update=1), chunk=20)  # one batch: one write time
    start_ms = tracker.client.get_run(run_id).info.start_time
    for key in ("episode/return", *UPDATE_KEYS):
        stamps = {m.step: m.timestamp for m in tracker.client.get_metric_history(run_id, key)}
        assert stamps == {step: start_ms + int(0.1 * step * 1000) for step in stamps}, key  # wall_s = 0.1 x episode
        assert len(set(stamps.values())) == len(stamps)


def test_the_mlflow_link_opens_the_machine_learning_view_on_the_given_port(tracking_uri):
    tracker = Tracker(tracking_uri, "link")
    assert tracker.ui_link(5123) == (
        f"http://127.0.0.1:5123/#/experiments/{tracker.experiment_id()}/runs?workflowType=machine_learning"
    )


def test_first_launches_racing_on_a_fresh_folder_all_open_the_store(tmp_path):
    """Two launches in a fresh folder both ran MLflow's schema migrations and one died in them; now the first
    use of a store is serialised. Children import MLflow, then start together when a file appears."""
    import subprocess
    import sys

    go = tmp_path / "go"
    script = (
        "import os, sys, time\n"
        "from ablate.tracking import Tracker\n"
        "import mlflow.tracking, mlflow.store.tracking.sqlalchemy_store\n"
        "print('ready', flush=True)\n"
        f"while not os.path.exists({str(go)!r}): time.sleep(0.005)\n"
        f"Tracker('sqlite:///{tmp_path}/mlflow.db', 'race').experiment_id(create=False)\n"
        "print('ok')\n"
    )
    children = [
        subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(3)
    ]
    assert [c.stdout.readline() for c in children] == ["ready\n"] * 3  # all imported, none opened the store
    go.write_text("go")
    results = [c.communicate(timeout=120) for c in children]
    assert [c.returncode for c in children] == [0, 0, 0], [err[-2000:] for _, err in results]
    assert Tracker(f"sqlite:///{tmp_path}/mlflow.db", "race").experiment_id(create=False) is None
