"""The tracker's metric layout and checkpoints, against a real SQLite MLflow store in a temp folder."""

import pytest
from test_curve import rows

from ablate.launch.curve import CurveReducer
from ablate.launch.tracking import POINT_METRICS, Tracker
from ablate.launch.variant_runs import VariantRecord, log_variant_runs, variant_runs
from ablate.reporting.reader import RunReader


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
        history = sorted(
            (m.step, m.value) for m in RunReader(tracking_uri, "layout").client.get_metric_history(run_id, metric)
        )
        assert history == [(p.episode, pytest.approx(float(getattr(p, attr)))) for p in points], metric
    assert tracker.client.get_run(run_id).data.tags["ablate.node"] == "n1"
    start_ms = tracker.client.get_run(run_id).info.start_time
    stamps = [m.timestamp for m in tracker.client.get_metric_history(run_id, "episode/return")]
    assert stamps == [start_ms + int(1000 * p.wall_s) for p in points]  # each point at its moment in the trial


def test_a_killed_run_keeps_its_latest_checkpoint_for_the_next_launch(tracking_uri):
    tracker, run_id = _track(tracking_uri, [], status="RUNNING")
    tracker.log_checkpoint("t-s0-abc", b"first")
    tracker.log_checkpoint("t-s0-abc", b"second")  # replaces the first
    assert tracker.latest_checkpoints("g", ["t-s0-abc"]) == {}  # still running: not a checkpoint to resume
    launch = tracker.client.get_run(run_id).data.tags["mlflow.parentRunId"]
    tracker.kill_running_trials(launch, "interrupted")
    assert Tracker(tracking_uri, "layout").latest_checkpoints("g", ["t-s0-abc", "x"]) == {"t-s0-abc": b"second"}
    assert tracker.latest_checkpoints("other-generation", ["t-s0-abc"]) == {}


def test_metric_points_carry_their_own_time_not_the_batch_write(tracking_uri):
    reducer = CurveReducer(max_episodes=64, points=8)
    points = reducer.add(rows(20, per_update=1)) + reducer.flush()
    tracker, run_id = _track(tracking_uri, points)
    start_ms = tracker.client.get_run(run_id).info.start_time
    for metric in POINT_METRICS:
        stamps = {m.step: m.timestamp for m in tracker.client.get_metric_history(run_id, metric)}
        assert stamps == {p.episode: start_ms + int(p.wall_s * 1000) for p in points}, metric
        assert len(set(stamps.values())) == len(stamps)


def test_the_mlflow_link_opens_the_variant_comparison_in_the_machine_learning_view_on_the_given_port(tracking_uri):
    from urllib.parse import parse_qs, urlsplit

    tracker = Tracker(tracking_uri, "link")
    link = tracker.ui_link(5123)
    assert link.startswith(f"http://127.0.0.1:5123/#/experiments/{tracker.experiment_id()}/runs?")
    query = parse_qs(urlsplit(link.split("#", 1)[1]).query)
    assert query == {
        "workflowType": ["machine_learning"],
        "searchFilter": ['tags.`ablate.role` = "variant"'],
        "compareRunsMode": ["CHART"],
    }


def test_first_launches_racing_on_a_fresh_folder_all_open_the_store(tmp_path):
    """Two launches in a fresh folder both ran MLflow's schema migrations and one died in them; now the first
    use of a store is serialised. Children import MLflow, then start together when a file appears."""
    import subprocess
    import sys

    go = tmp_path / "go"
    script = (
        "import os, sys, time\n"
        "from ablate.launch.tracking import Tracker\n"
        "import mlflow.tracking, mlflow.store.tracking.sqlalchemy_store\n"
        "print('ready', flush=True)\n"
        f"while not os.path.exists({str(go)!r}): time.sleep(0.005)\n"
        f"Tracker('sqlite:///{tmp_path}/mlflow.db', 'race').experiment_id(create=False)\n"
        "print('ok')\n"
    )
    children = [
        subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    assert [c.stdout.readline() for c in children] == ["ready\n"] * 2  # all imported, none opened the store
    go.write_text("go")
    results = [c.communicate(timeout=120) for c in children]
    assert [c.returncode for c in children] == [0, 0], [err[-2000:] for _, err in results]
    assert Tracker(f"sqlite:///{tmp_path}/mlflow.db", "race").experiment_id(create=False) is None


def test_only_the_writer_and_the_reader_import_mlflow_and_run_never_imports_report():
    import ast
    from pathlib import Path

    package = Path(__file__).resolve().parents[1] / "ablate"
    importers, upward = set(), set()
    for path in package.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names += [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            relative = path.relative_to(package).as_posix()
            if any(n == "mlflow" or n.startswith("mlflow.") for n in names):
                importers.add(relative)
            if relative.startswith("launch/") and any(n.startswith("ablate.reporting") for n in names):
                upward.add(relative)
    # launch/patches.py: MLflow's one private name changed, for the writer's process (test_patches).
    writers = {"launch/tracking.py", "launch/mlflow_store.py", "launch/patches.py"}
    # reporting/reader.py: the report's reader (it reads through mlflow_store.Store's client, importing none).
    assert importers <= writers | {"reporting/reader.py"} and writers <= importers
    assert not upward  # the report after a launch is written by ablate/commands.py, above both layers


def test_variant_runs_are_replaced_whole_and_a_failed_write_keeps_the_earlier_ones(tracking_uri):
    tracker = Tracker(tracking_uri, "variants")
    launch = tracker.start_launch("g", "launch", {}, {})
    trial = tracker.start_trial(launch, "g", "a-s0-abc", "a", 0, {"seed": 0}, "commit")
    records = [
        VariantRecord("a", {"learning_rate": "0.03"}, {"ablate.verdict": "better"}, {"claim/change": -12.5}),
        VariantRecord("b", series={"curve/iqm": [(1, 9.0), (2, 11.0)]}),
    ]
    first = log_variant_runs(tracker, launch, records)
    run = tracker.client.get_run(first[0])
    assert (run.info.run_name, run.data.params, run.data.metrics) == (
        "a",
        {"learning_rate": "0.03"},
        {"claim/change": -12.5},
    )
    assert run.data.tags["ablate.role"] == "variant" and run.data.tags["mlflow.parentRunId"] == launch
    assert [(m.step, m.value) for m in tracker.client.get_metric_history(first[1], "curve/iqm")] == [
        (1, 9.0),
        (2, 11.0),
    ]
    second = log_variant_runs(tracker, launch, records)
    assert [r.info.run_id for r in variant_runs(tracker, launch)] == second and not set(first) & set(second)
    refused = VariantRecord("c", metrics={"claim!": 1.0})  # a name MLflow refuses: the third write fails
    with pytest.raises(Exception, match="claim!"):
        log_variant_runs(tracker, launch, [*records, refused])
    assert [r.info.run_id for r in variant_runs(tracker, launch)] == second  # the earlier runs, nothing added
    assert tracker.client.get_run(trial).data.tags["ablate.role"] == "trial"


def test_a_launch_whose_files_the_store_refuses_is_left_failed_not_running(tracking_uri, monkeypatch):
    tracker = Tracker(tracking_uri, "refused")
    monkeypatch.setattr(tracker.client._client, "log_text", lambda *a: (_ for _ in ()).throw(ValueError("no room")))
    with pytest.raises(ValueError, match="no room"):
        tracker.start_launch("g", "launch", {}, {"grid.json": "{}"})
    (run,) = tracker.client.search_runs([tracker.experiment_id()], "")
    assert run.info.status == "FAILED" and run.data.tags["ablate.error"] == "no room"
