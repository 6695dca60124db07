"""A tiny real ablation through real Ray and a real MLflow store: runs, params, metrics, artifacts,
resume, faults."""

import os
import signal
import subprocess
import sys
import tempfile
import time

import pandas as pd
import pytest

from ablate.config import load_experiment
from ablate.grid import expand
from ablate.tracking import POINT_METRICS, Tracker

TINY = """
name = "tiny"
seeds = 2
[base]
env_id = "CartPole-v1"
max_episodes = 20
episodes_per_update = 10
video_max_frames = 30
[[variants]]
name = "narrow"
hidden_sizes = [8]
[[variants]]
name = "deep"
hidden_sizes = [16, 16]
dropout = 0.1
"""


def _experiment(tmp_path, text=TINY, name="exp.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_experiment(path)


def _launches(tracker):
    return tracker.client.search_runs([tracker.experiment_id()], "tags.`ablate.role` = 'launch'")


def test_tiny_ablation_is_tracked_exactly(run_quiet, tmp_path, tracking_uri):
    experiment = _experiment(tmp_path)
    outcome = run_quiet(experiment, tmp_path, tracking_uri)
    assert outcome.exit_code == 0 and len(outcome.finished) == 4 and not outcome.failed

    tracker = Tracker(tracking_uri, "tiny")
    launches = _launches(tracker)
    assert len(launches) == 1
    launch_id = launches[0].info.run_id
    runs = tracker.trial_runs(with_artifacts=True)
    assert len(runs) == 4
    assert {r.key for r in runs} == {t.key for t in expand(experiment)}
    for run in runs:
        assert run.status == "FINISHED"
        assert run.tags["mlflow.parentRunId"] == launch_id
        assert run.params["variant"] == run.variant
        assert run.params["seed"] == str(run.seed)
        assert run.params["max_episodes"] == "20"
        expected_sizes = "[8]" if run.variant == "narrow" else "[16, 16]"
        assert run.params["model.hidden_sizes"] == expected_sizes
        assert run.params["model.dropout"] == ("0.0" if run.variant == "narrow" else "0.1")
        # 20 episodes of a 20-episode budget: one point per episode (bounded at CURVE_POINTS per curve)
        for metric in POINT_METRICS:
            assert [step for step, _ in tracker.metric_history(run.run_id, metric)] == list(range(1, 21)), metric
        returns = [v for _, v in tracker.metric_history(run.run_id, "episode/return")]
        assert run.metrics["env_steps"] == sum(returns)  # CartPole: one reward per step
        assert run.metrics["episode/rolling_mean"] == pytest.approx(sum(returns) / 20)  # solve_window 100 > 20
        assert run.metrics["episodes_run"] == 20 and run.metrics["solved"] == 0
        assert set(run.artifacts) == {"episodes.csv", "weights.pt", "video.mp4", "learning_curve.png"}
        assert run.tags["ablate.node"]  # the Ray node that ran it
        with tempfile.TemporaryDirectory() as folder:
            table = pd.read_csv(tracker.download(run.run_id, "episodes.csv", folder))
        assert list(table["episode"]) == list(range(1, 21)) and list(table["episode_return"]) == returns
    launch_files = {a.path for a in tracker.client.list_artifacts(launch_id)}
    assert launch_files == {"experiment.toml", "grid.json", "environment.json"}

    # Running the same experiment again runs nothing and creates no run.
    again = run_quiet(experiment, tmp_path, tracking_uri)
    assert again.launch_run_id is None and again.skipped == 4
    assert len(tracker.trial_runs()) == 4 and len(_launches(tracker)) == 1

    # --fresh starts a new generation under a new parent run.
    fresh = run_quiet(experiment, tmp_path, tracking_uri, fresh=True)
    assert len(fresh.finished) == 4 and fresh.generation != outcome.generation
    assert len(tracker.trial_runs(fresh.generation)) == 4 and len(_launches(tracker)) == 2


def test_rerun_after_adding_a_variant_runs_only_the_new_trials(run_quiet, tmp_path, tracking_uri):
    run_quiet(_experiment(tmp_path), tmp_path, tracking_uri)
    bigger = _experiment(tmp_path, TINY + '[[variants]]\nname = "wide"\nhidden_sizes = [64]\n')
    outcome = run_quiet(bigger, tmp_path, tracking_uri)
    assert outcome.skipped == 4 and len(outcome.finished) == 2
    runs = Tracker(tracking_uri, "tiny").trial_runs()
    assert len(runs) == 6 and len({r.key for r in runs}) == 6


def test_crash_is_retried_raise_is_recorded_failed(run_quiet, tmp_path, tracking_uri):
    marker = tmp_path / "crashed-once"
    text = f"""
name = "faults"
seeds = [0]
[base]
env_id = "CartPole-v1"
max_episodes = 10
episodes_per_update = 10
record_video = false
[[variants]]
name = "ok"
[[variants]]
name = "crash"
fault = "crash_once"
fault_marker = "{marker}"
[[variants]]
name = "boom"
fault = "raise"
"""
    outcome = run_quiet(_experiment(tmp_path, text), tmp_path, tracking_uri)
    assert marker.exists()  # the crash really happened
    assert sorted(k.split("-")[0] for k in outcome.finished) == ["crash", "ok"]
    assert list(outcome.failed) == [k for k in outcome.failed if k.startswith("boom")] and len(outcome.failed) == 1
    assert "injected fault" in next(iter(outcome.failed.values()))
    assert outcome.exit_code == 1

    runs = {r.variant: r for r in Tracker(tracking_uri, "faults").trial_runs()}
    assert set(runs) == {"ok", "crash", "boom"}  # the crashed attempt's partial run is not counted
    assert runs["crash"].status == "FINISHED" and runs["crash"].tags["ablate.attempt"] == "2"
    assert runs["boom"].status == "FAILED" and "injected fault" in runs["boom"].tags["ablate.error"]
    assert runs["ok"].status == "FINISHED"


def _restore_sigint() -> None:
    # A child started from a background job (``nohup ... &``) inherits SIGINT ignored and would never see Ctrl-C.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_kills_running_trials_and_a_rerun_finishes_the_rest(tmp_path, tracking_uri):
    # Deterministic by construction: two quick trials finish while a third blocks until a file exists, so
    # at the signal (sent once both are seen FINISHED and the third RUNNING) exactly one trial is running.
    release = tmp_path / "release"
    text = f"""
name = "interrupt"
seeds = 1
[base]
env_id = "CartPole-v1"
max_episodes = 20
episodes_per_update = 10
record_video = false
[[variants]]
name = "quick"
[[variants]]
name = "other"
hidden_sizes = [8]
[[variants]]
name = "blocked"
fault = "block"
fault_marker = "{release}"
"""
    path = tmp_path / "interrupt.toml"
    path.write_text(text)
    command = [sys.executable, "-m", "ablate.cli", "run", str(path), "--tracking-uri", tracking_uri, "--no-report"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        command,
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=env,
        text=True,
        preexec_fn=_restore_sigint,
    )
    tracker = Tracker(tracking_uri, "interrupt")
    try:

        def statuses() -> dict[str, str]:
            if proc.poll() is not None or not tracker.experiment_id(create=False):
                return {}
            return {r.variant: r.status for r in tracker.trial_runs()}

        deadline = time.monotonic() + 240
        seen: dict[str, str] = {}
        while time.monotonic() < deadline and proc.poll() is None:
            seen = statuses()
            if seen == {"quick": "FINISHED", "other": "FINISHED", "blocked": "RUNNING"}:
                break
            time.sleep(0.5)
        assert proc.poll() is None, "the run ended before it could be interrupted: " + proc.stdout.read()
        assert seen == {"quick": "FINISHED", "other": "FINISHED", "blocked": "RUNNING"}, seen
        proc.send_signal(signal.SIGINT)
        output, _ = proc.communicate(timeout=120)
        assert proc.returncode == 130, output
        assert "interrupted: 1 running trial(s) marked killed" in output and "Traceback" not in output
    finally:  # never leave a blocked child (and its Ray) behind when an assertion fails
        release.write_text("go\n")
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)  # lets the driver stop the Ray it started
            try:
                proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()

    runs = {r.variant: r for r in tracker.trial_runs()}
    assert {v: r.status for v, r in runs.items()} == {"quick": "FINISHED", "other": "FINISHED", "blocked": "KILLED"}
    finished_first = {r.key for r in runs.values() if r.status == "FINISHED"}

    rerun = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, env=env, timeout=300)
    assert rerun.returncode == 0, rerun.stdout + rerun.stderr
    finished = [r.key for r in tracker.trial_runs() if r.status == "FINISHED"]
    assert len(finished) == 3 and len(set(finished)) == 3  # no finished trial ran twice
    assert finished_first <= set(finished)
