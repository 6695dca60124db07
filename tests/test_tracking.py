"""The tracker's metric layout and checkpoints, against a real SQLite MLflow store in a temp folder."""

import pytest
from test_curve import rows

from ablate.curve import CurveReducer
from ablate.tracking import POINT_METRICS, Tracker


def _track(tracking_uri, points, status="FINISHED"):
    tracker = Tracker(tracking_uri, "layout")
    launch = tracker.start_launch("g", "launch", {}, {})
    run_id = tracker.start_trial(launch, "g", "t-s0-abc", "t", 0, {"seed": 0}, "commit")
    for start in range(0, len(points), 2):  # the scheduler sends a few points at a time
        tracker.log_points("t-s0-abc", points[start : start + 2])
    if status == "FINISHED":
        tracker.finish_trial("t-s0-abc", {"episodes_run": 20}, None, tags={"ablate.node": "n1"})
    return tracker, run_id


def test_each_point_logs_every_curve_metric_at_its_last_episode(tracking_uri):
    reducer = CurveReducer(max_episodes=64, points=8)
    points = reducer.add(rows(20, per_update=1)) + reducer.flush()
    tracker, run_id = _track(tracking_uri, points)
    for metric, attr in POINT_METRICS.items():
        history = tracker.metric_history(run_id, metric)
        assert history == [(p.episode, pytest.approx(float(getattr(p, attr)))) for p in points], metric
    assert tracker.client.get_run(run_id).data.tags["ablate.node"] == "n1"


def test_a_killed_run_keeps_its_latest_checkpoint_for_the_next_launch(tracking_uri):
    tracker, run_id = _track(tracking_uri, [], status="RUNNING")
    tracker.log_checkpoint("t-s0-abc", b"first")
    tracker.log_checkpoint("t-s0-abc", b"second")  # replaces the first
    assert tracker.latest_checkpoint("g", "t-s0-abc") is None  # still running: not a checkpoint to resume
    tracker.kill_open_trials()
    assert Tracker(tracking_uri, "layout").latest_checkpoint("g", "t-s0-abc") == b"second"
    assert tracker.latest_checkpoint("other-generation", "t-s0-abc") is None
