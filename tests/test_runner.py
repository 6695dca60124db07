"""A tiny real ablation through real Ray and a real MLflow store: runs, params, metrics, artifacts,
resume, faults."""

import contextlib
import io
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import pandas as pd
import pytest
import torch
from mlflow.entities import ViewType
from stores import fresh_store

from ablate.experiment import load_experiment
from ablate.launch.grid import expand
from ablate.launch.store import lock_file
from ablate.launch.tracking import POINT_METRICS, Tracker
from ablate.reporting.reader import RunReader

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


HANG_S = 1800
"""How long a child process may take before a test calls it hung: a guard against a hang, never a bound on speed
(a loaded machine once took past the 240 s a wait here allowed). The tests wait on the states they observe."""


def _experiment(tmp_path, text=TINY, name="exp.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_experiment(path)


@pytest.fixture(scope="module")
def tiny_launch(run_quiet, tmp_path_factory):
    """TINY launched once (per test process): the tests that start from a store holding it take a copy."""
    folder = tmp_path_factory.mktemp("tiny")
    uri = fresh_store(folder / "mlflow.db")
    experiment = _experiment(folder)
    outcome = run_quiet(experiment, folder, uri)
    return folder / "mlflow.db", experiment, outcome


@pytest.fixture
def tiny_store(tiny_launch, tmp_path):
    """A copy of the store ``tiny_launch`` wrote (its runs' artifacts stay where they were written): its URI,
    the experiment and the launch's outcome."""
    db, experiment, outcome = tiny_launch
    shutil.copyfile(db, tmp_path / "mlflow.db")
    return f"sqlite:///{tmp_path / 'mlflow.db'}", experiment, outcome


def _launches(tracker):
    return tracker.client.search_runs([tracker.experiment_id()], "tags.`ablate.role` = 'launch'")


def test_tiny_ablation_is_tracked_exactly(run_quiet, tmp_path, tiny_store):
    tracking_uri, experiment, outcome = tiny_store
    assert outcome.exit_code == 0 and len(outcome.finished) == 4 and not outcome.failed

    tracker = RunReader(tracking_uri, "tiny")
    launches = _launches(tracker)
    assert len(launches) == 1
    launch_id = launches[0].info.run_id
    runs = tracker.trial_runs()
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
            assert [
                step
                for step, _ in sorted((m.step, m.value) for m in tracker.client.get_metric_history(run.run_id, metric))
            ] == list(range(1, 21)), metric
        returns = [
            v
            for _, v in sorted(
                (m.step, m.value) for m in tracker.client.get_metric_history(run.run_id, "episode/return")
            )
        ]
        assert run.metrics["env_steps"] == sum(returns)  # CartPole: one reward per step
        assert run.metrics["episode/rolling_mean"] == pytest.approx(sum(returns) / 20)  # solve_window 100 > 20
        assert run.metrics["episodes_run"] == 20 and run.metrics["solved"] == 0
        # No video: a launch leaves it to the report, which records the seeds it shows from weights and config.
        artifacts = {a.path for a in tracker.client.list_artifacts(run.run_id)}
        assert artifacts == {"episodes.csv", "weights.pt", "config.json", "learning_curve.png"}
        assert run.tags["ablate.node"]  # the Ray node that ran it
        assert run.tags["ablate.stage"] == "eval"  # no [tune]: every trial is an evaluation trial
        with tempfile.TemporaryDirectory() as folder:
            table = pd.read_csv(tracker.download(run.run_id, "episodes.csv", folder))
        assert list(table["episode"]) == list(range(1, 21)) and list(table["episode_return"]) == returns
    launch_files = {a.path for a in tracker.client.list_artifacts(launch_id)}
    assert launch_files == {"experiment.toml", "grid.json", "environment.json"}

    # Running the same experiment again runs nothing and creates no run.
    again = run_quiet(experiment, tmp_path, tracking_uri)
    assert again.launch_run_id is None and again.skipped == 4
    assert len(tracker.trial_runs()) == 4 and len(_launches(tracker)) == 1
    # (--fresh, a new generation under a new parent run: tests/test_status.py's real store.)


def test_rerun_after_adding_a_variant_runs_only_the_new_trials(run_quiet, tmp_path, tiny_store):
    tracking_uri, _, _ = tiny_store
    bigger = _experiment(tmp_path, TINY + '[[variants]]\nname = "wide"\nhidden_sizes = [64]\n')
    outcome = run_quiet(bigger, tmp_path, tracking_uri)
    assert outcome.skipped == 4 and len(outcome.finished) == 2
    runs = Tracker(tracking_uri, "tiny").trial_runs()
    assert len(runs) == 6 and len({r.key for r in runs}) == 6


def test_the_progress_line_and_the_summary_count_the_same_trials_finished_before(tmp_path, tiny_store, monkeypatch):
    """The store holds seeds this launch does not run (2 of each variant, the launch asks for 1): the progress line
    said "4 finished before" beside the summary's "2 finished before" (3e01923). Both count this launch's own."""
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    tracking_uri, _, _ = tiny_store
    _fake_scheduler(monkeypatch, lambda trials, events: None)
    fewer = TINY.replace("seeds = 2", "seeds = 1") + '[[variants]]\nname = "wide"\nhidden_sizes = [64]\n'
    outcome = run_plan(LaunchPlan(_experiment(tmp_path, fewer), tracking_uri=tracking_uri, show_progress=False))
    assert outcome.skipped == 2 and outcome.view.state.already_done == 2


def test_a_launch_records_the_seconds_until_its_first_trial_started(tmp_path, tracking_uri, monkeypatch):
    """What the next ``--dry-run`` says a start costs (``start_s`` on the launch's run)."""
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    _fake_scheduler(monkeypatch, lambda trials, events: events.started(trials[0].key))
    run_plan(LaunchPlan(_experiment(tmp_path), tracking_uri=tracking_uri, show_progress=False))
    start_s = _launches(Tracker(tracking_uri, "tiny"))[0].data.metrics["start_s"]
    assert 0 <= start_s < HANG_S


FAULTS = """
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
fault_marker = "{crashed}"
[[variants]]
name = "boom"
fault = "raise"
[[variants]]
name = "resumable"
hidden_sizes = [8]
max_episodes = 48
episodes_per_update = 8
checkpoint_every = 16
fault = "crash_after_checkpoint"
fault_marker = "{died}"
"""


@pytest.fixture(scope="module")
def faults_launch(run_quiet, tmp_path_factory):
    """One launch of trials that fail in each way (a process that dies once, once after a checkpoint, a trial
    that raises) beside one that does not: the tests below read it."""
    folder = tmp_path_factory.mktemp("faults")
    uri = fresh_store(folder / "mlflow.db")
    markers = {"crashed": folder / "crashed-once", "died": folder / "died-after-checkpoint"}
    terminal = io.StringIO()  # what this process printed: Ray's driver prints from a thread of its own
    with contextlib.redirect_stdout(terminal), contextlib.redirect_stderr(terminal):
        outcome = run_quiet(_experiment(folder, FAULTS.format(**markers)), folder, uri)
        # Ray publishes a worker's death after the fact (in ms: long before the launch ends); wait until it
        # reached the launch's log, with room for a loaded machine
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and "A worker died" not in _logs(folder / "ray"):
            time.sleep(0.2)
    return uri, outcome, markers, (terminal.getvalue(), _logs(folder / "ray"), folder / "ray")


def _logs(folder) -> str:
    return "".join(path.read_text() for path in sorted(folder.glob("*.log")))


@pytest.mark.e2e  # Ray worker processes that die mid-trial, and Tune's retries
def test_crash_is_retried_raise_is_recorded_failed(faults_launch):
    tracking_uri, outcome, markers, _ = faults_launch
    assert markers["crashed"].exists()  # the crash really happened
    assert sorted(k.split("-")[0] for k in outcome.finished) == ["crash", "ok", "resumable"]
    assert list(outcome.failed) == [k for k in outcome.failed if k.startswith("boom")] and len(outcome.failed) == 1
    assert "injected fault" in next(iter(outcome.failed.values()))
    assert outcome.exit_code == 1

    runs = {r.variant: r for r in Tracker(tracking_uri, "faults").trial_runs()}
    assert set(runs) == {"ok", "crash", "boom", "resumable"}  # the crashed attempts' partial runs are not counted
    assert runs["crash"].status == "FINISHED" and runs["crash"].tags["ablate.attempt"] == "2"
    assert runs["boom"].status == "FAILED" and "injected fault" in runs["boom"].tags["ablate.error"]
    assert runs["ok"].status == "FINISHED"


@pytest.mark.e2e  # Ray worker processes that die mid-trial: Ray's message about it
def test_a_dead_workers_raylet_error_goes_to_the_launchs_log_and_one_line_to_the_terminal(faults_launch):
    _, _, markers, (terminal, log, folder) = faults_launch
    assert markers["crashed"].exists() and "A worker died" in log  # Ray told of a death, and the log has it
    # Ray's own line (~1,000 characters: ids, ports, OOM advice) printed to stdout from its error thread
    assert "(raylet)" not in terminal and "Lease ID" not in terminal and "Worker exit detail" not in terminal
    told = [line for line in terminal.splitlines() if line.startswith("Ray: a worker died")]
    (path,) = folder.glob("*.log")
    assert told and all(line.endswith(f"Ray's message in full: {path}") for line in told), terminal
    assert all(len(line) < 300 for line in told)


def _restore_sigint() -> None:
    # A child started from a background job (``nohup ... &``) inherits SIGINT ignored and would never see Ctrl-C.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.e2e  # a child `ablate run` that starts its own Ray (the default path), twice
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

        deadline = time.monotonic() + HANG_S  # a hang guard: the loop waits on what it observes
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


@pytest.mark.e2e  # a Ray worker process that dies after a checkpoint
def test_a_trial_whose_process_died_resumes_from_its_checkpoint_in_one_continuous_run(faults_launch):
    tracking_uri, _, markers, _ = faults_launch
    assert markers["died"].exists()  # the process really died
    tracker = RunReader(tracking_uri, "faults")
    (run,) = [r for r in tracker.trial_runs() if r.variant == "resumable"]
    assert run.status == "FINISHED" and run.tags["ablate.attempt"] == "2"  # the process died once
    wall = sorted((m.step, m.value) for m in tracker.client.get_metric_history(run.run_id, "episode/wall_s"))
    assert [step for step, _ in wall] == list(range(1, 49))  # one curve, every episode once
    # The retry resumed: its episodes 1-16 carry the dead attempt's own clock, as in the checkpoint the dead
    # attempt left on its (deleted) run, which a restart from scratch could not reproduce.
    dead = tracker.client.search_runs(
        [tracker.experiment_id()], "tags.`ablate.attempt` = '1'", run_view_type=ViewType.DELETED_ONLY
    )
    (dead,) = [d for d in dead if d.data.tags.get("ablate.trial_key") == run.key]
    saved = torch.load(tracker.download(dead.info.run_id, "checkpoint.pt"), weights_only=False)
    assert len(saved["history"]) == 16
    with tempfile.TemporaryDirectory() as folder:
        table = pd.read_csv(tracker.download(run.run_id, "episodes.csv", folder))
    assert list(table["wall_s"][:16]) == [row[7] for row in saved["history"]]
    artifacts = {a.path for a in tracker.client.list_artifacts(run.run_id)}
    assert "checkpoint.pt" in artifacts  # the latest checkpoint stays with the run


BLOCKED = """
name = "{name}"
seeds = 1
[base]
env_id = "CartPole-v1"
max_episodes = 20
episodes_per_update = 10
record_video = false
[[variants]]
name = "quick"
[[variants]]
name = "blocked"
fault = "block"
fault_marker = "{release}"
"""


class _Launch:
    """``ablate run`` in a child process of its own session (so a failed test can kill it and its Ray at once),
    with the test waiting on states it observes in the store."""

    def __init__(self, tmp_path, path, tracking_uri, release):
        self.release = release
        self.command = [sys.executable, "-m", "ablate.cli", "run", str(path), "--tracking-uri", tracking_uri]
        self.command.append("--no-report")
        self.proc = subprocess.Popen(
            self.command,
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
            text=True,
            start_new_session=True,
        )

    def wait_for(self, tracker, wanted: dict[str, str], timeout_s: float = HANG_S) -> None:
        deadline = time.monotonic() + timeout_s
        seen: dict[str, str] = {}
        while time.monotonic() < deadline and self.proc.poll() is None:
            if tracker.experiment_id(create=False):
                seen = {r.variant: r.status for r in tracker.trial_runs()}  # the newest run of each wins
                if all(seen.get(v) == s for v, s in wanted.items()):
                    return
            time.sleep(0.3)
        raise AssertionError(f"never saw {wanted}; saw {seen}; output: {self.stop()}")

    def stop(self) -> str:
        """Release and end the child (and its session) whatever state it is in."""
        self.release.write_text("go\n")
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
        output, _ = self.proc.communicate(timeout=60)
        return output


def _runs_by_status(tracker) -> dict[str, list[str]]:
    runs = tracker.client.search_runs([tracker.experiment_id()], "", max_results=1000)
    found: dict[str, list[str]] = {}
    for run in runs:
        found.setdefault(run.info.status, []).append(run.data.tags.get("ablate.trial_key", "launch"))
    return found


@pytest.mark.e2e  # a child `ablate run` that starts its own Ray (the default path)
def test_sigterm_stops_like_ctrl_c_and_a_second_launch_is_refused(tmp_path, tracking_uri, capsys):
    from ablate.cli import main

    release = tmp_path / "release"
    path = tmp_path / "term.toml"
    path.write_text(BLOCKED.format(name="term", release=release))
    tracker = Tracker(tracking_uri, "term")

    # 1. SIGTERM: handled as Ctrl-C (no C++ abort), exit 143, the running trial and the launch KILLED.
    first = _Launch(tmp_path, path, tracking_uri, release)
    try:
        first.wait_for(tracker, {"quick": "FINISHED", "blocked": "RUNNING"})
        # 2. Meanwhile a second launch of the experiment on this store is refused in one line naming the first.
        code = main(["run", str(path), "--tracking-uri", tracking_uri, "--no-report"])
        err = capsys.readouterr().err
        assert code == 1 and err.count("\n") == 1 and f"by pid {first.proc.pid} on " in err, err
        first.proc.send_signal(signal.SIGTERM)
        output, _ = first.proc.communicate(timeout=120)
    finally:
        if first.proc.returncode is None:
            first.stop()
    assert first.proc.returncode == 143, output
    assert "interrupted: 1 running trial(s) marked killed (SIGTERM)" in output and "Traceback" not in output
    statuses = _runs_by_status(tracker)
    assert sorted(statuses) == ["FINISHED", "KILLED"] and len(statuses["KILLED"]) == 2, statuses  # trial, launch
    assert not (tmp_path / "ray_results").exists() or not list((tmp_path / "ray_results").iterdir())


def _fake_scheduler(monkeypatch, body):
    """Replace Ray with ``body(trials, events)``: the runner's bookkeeping around the scheduler, without Ray.
    The runner imports the scheduler's functions when it has trials to run, so they are replaced there."""
    import ablate.launch.scheduler as scheduler

    monkeypatch.setattr(scheduler, "ensure_ray", lambda address: False)
    monkeypatch.setattr(scheduler, "largest_node_cpus", lambda: 2.0)
    monkeypatch.setattr(
        scheduler,
        "run_trials",
        lambda plan, events, options, run_name, **_: body([t for p in plan for t in p.members], events),
    )


def test_a_scheduler_crash_records_the_launch_failed_with_the_error(tmp_path, tracking_uri, monkeypatch):
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    def crash(trials, events):
        events.started(trials[0].key)
        raise RuntimeError("RaySystemError: the GCS went away\nmore detail")

    _fake_scheduler(monkeypatch, crash)
    outcome = run_plan(LaunchPlan(_experiment(tmp_path), tracking_uri=tracking_uri, show_progress=False))
    assert outcome.exit_code == 1 and outcome.error == "RuntimeError: RaySystemError: the GCS went away"
    tracker = Tracker(tracking_uri, "tiny")
    launch = _launches(tracker)[0]
    assert launch.info.status == "FAILED"
    assert (
        "The scheduler failed (RuntimeError: RaySystemError: the GCS went away)"
        in launch.data.tags["mlflow.note.content"]
    )
    assert [r.status for r in tracker.trial_runs()] == ["KILLED"]


def test_an_error_before_the_recorder_exists_closes_the_launch_failed_with_that_error(
    tmp_path, tracking_uri, monkeypatch
):
    """``watch`` raising before it builds the recorder: the launch still closes, FAILED with the real error (on
    3e01923 ``close`` read ``self.recorder`` and an ``AttributeError`` replaced it)."""
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    _fake_scheduler(monkeypatch, lambda trials, events: None)

    def earlier_runs(self, keys):
        raise RuntimeError("the store went away")

    monkeypatch.setattr(Tracker, "earlier_runs", earlier_runs)
    outcome = run_plan(LaunchPlan(_experiment(tmp_path), tracking_uri=tracking_uri, show_progress=False))
    assert outcome.error == "RuntimeError: the store went away"
    assert _launches(Tracker(tracking_uri, "tiny"))[0].info.status == "FAILED"


def test_an_interrupt_while_a_run_is_being_opened_leaves_nothing_running(tmp_path, tracking_uri, monkeypatch):
    """Ctrl-C can land after MLflow created a trial's run and before the tracker noted it; and a scheduler
    event can come after the interrupt. Neither may leave a run RUNNING or say "0 marked killed"."""
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    late: list = []

    def interrupted_mid_open(trials, events):
        events.started(trials[0].key)
        original = Tracker.start_trial

        def start_then_interrupt(self, *args, **kwargs):
            original(self, *args, **kwargs)
            self.open_runs.pop(args[2])  # as if the signal landed before the run was recorded
            raise KeyboardInterrupt

        monkeypatch.setattr(Tracker, "start_trial", start_then_interrupt)
        late.append(events)
        events.started(trials[1].key)

    _fake_scheduler(monkeypatch, interrupted_mid_open)
    outcome = run_plan(LaunchPlan(_experiment(tmp_path), tracking_uri=tracking_uri, show_progress=False))
    assert outcome.interrupted and outcome.exit_code == 130 and len(outcome.killed) == 2
    late[0].started(expand(_experiment(tmp_path))[2].key)  # an event after the stop opens no run
    tracker = Tracker(tracking_uri, "tiny")
    assert sorted(r.status for r in tracker.trial_runs()) == ["KILLED", "KILLED"]
    assert _launches(tracker)[0].info.status == "KILLED"


def test_the_next_launch_marks_runs_a_dead_launch_left_running_killed_and_removes_its_tune_folder(
    tmp_path, tracking_uri, monkeypatch
):
    """What kill -9 of a driver leaves (its launch and trial runs RUNNING, ``ray_results/<run>/``), made
    directly: the next launch reaps it, runs the grid, and leaves nothing RUNNING."""
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan, tune_run_name

    experiment = _experiment(tmp_path)
    trials = expand(experiment)
    dead = Tracker(tracking_uri, "tiny")
    generation = "g-dead"
    launch = dead.start_launch(generation, "dead", {"ablate.host": "elsewhere", "ablate.pid": "1"}, {})
    dead.start_trial(launch, generation, trials[0].key, trials[0].variant, 0, {}, "abc")
    leftover = tmp_path / "ray" / tune_run_name("tiny", launch)
    (leftover / trials[0].key).mkdir(parents=True)

    def finish_all(todo, events):
        assert (tmp_path / "ray").exists() and not leftover.exists()  # cleaned before the new launch ran
        for trial in todo:
            events.started(trial.key)
            events.finished(trial.key, {"episodes_to_solve": 5.0}, None, "node-1")

    _fake_scheduler(monkeypatch, finish_all)
    outcome = run_plan(
        LaunchPlan(experiment, tracking_uri=tracking_uri, show_progress=False, storage_path=str(tmp_path / "ray"))
    )
    assert outcome.reaped == 2 and outcome.exit_code == 0 and len(outcome.finished) == 4
    runs = {r.info.run_id: r for r in dead.client.search_runs([dead.experiment_id()], "")}
    assert runs[launch].info.status == "KILLED" and "process died" in runs[launch].data.tags["ablate.error"]
    assert [r.info.status for r in runs.values()].count("RUNNING") == 0
    assert [r.info.status for r in runs.values()].count("KILLED") == 2


def test_trial_params_hold_only_knobs_that_shaped_the_trial():
    from ablate.config import DEFAULT, apply_knobs
    from ablate.launch.records import tracked_params

    mlp = tracked_params("base", DEFAULT)
    assert mlp["variant"] == "base" and mlp["model.hidden_sizes"] == (32,) and "learning_rate" in mlp
    assert not {"fault", "fault_marker", "solve_threshold", "model.history", "model.kernel_size"} & set(mlp)
    cnn = tracked_params("cnn", apply_knobs(DEFAULT, {"architecture": "cnn", "solve_threshold": 400.0}))
    assert cnn["model.history"] == 4 and cnn["model.conv_channels"] == (16,) and cnn["solve_threshold"] == 400.0
    faulty = tracked_params("f", apply_knobs(DEFAULT, {"fault": "raise"}))
    assert faulty["fault"] == "raise" and "fault_marker" not in faulty


def test_the_machine_record_asks_a_child_for_torchs_kernels_and_a_launch_that_runs_nothing_ends_it():
    import torch

    from ablate.launch.records import TorchKernels, environment_document

    asked = TorchKernels()
    assert environment_document(asked)["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert asked.process.returncode == 0
    unused = TorchKernels()
    unused.close()  # before it answered: killed and reaped, not left to run
    assert unused.process.returncode < 0  # killed: a child importing torch answers after ~1 s, not at once


def test_the_commit_is_not_dirty_because_the_committed_report_changed(tmp_path, monkeypatch):
    from ablate.launch.runner import git_commit

    def git(*args):
        subprocess.run(["git", *args], cwd=tmp_path, check=True, capture_output=True)

    git("init", "-q")
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports" / "report.md").write_text("old\n")
    (tmp_path / "code.py").write_text("x = 1\n")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "first")
    monkeypatch.chdir(tmp_path / "reports")  # from a subfolder too
    (tmp_path / "reports" / "report.md").write_text("new\n")
    assert not git_commit().endswith("-dirty")
    (tmp_path / "code.py").write_text("x = 2\n")
    assert git_commit().endswith("-dirty")


def test_a_cluster_whose_nodes_are_all_too_small_is_refused_before_a_launch_is_recorded(
    tmp_path, tracking_uri, monkeypatch
):
    from ablate.config import ConfigError
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    _fake_scheduler(monkeypatch, lambda trials, events: pytest.fail("no trial may be scheduled"))
    import dataclasses

    experiment = dataclasses.replace(_experiment(tmp_path), resources_per_trial=3.0)  # the fake nodes have 2
    with pytest.raises(
        ConfigError, match=r"cpus_per_trial = 3 is more than the largest node of the Ray cluster has \(2 CPUs\)"
    ):
        run_plan(LaunchPlan(experiment, tracking_uri=tracking_uri, address="auto", show_progress=False))
    assert not _launches(Tracker(tracking_uri, "tiny"))


def test_a_name_in_any_script_runs_under_its_storage_name_and_its_costs_are_read_back(
    run_quiet, tmp_path, tracking_uri
):
    import unicodedata

    from ablate.experiment import storage_name

    text = 'name = "实验é"\nseeds = 1\n[base]\nmax_episodes = 4\nrecord_video = false\n[[variants]]\nname = "a"\n'
    experiment = _experiment(tmp_path, text)
    outcome = run_quiet(experiment, tmp_path, tracking_uri)
    assert outcome.exit_code == 0 and len(outcome.finished) == 1
    stored = storage_name("实验é")
    # Asked for by its NFD form, its NFC form or its storage name: one MLflow experiment, named by the last.
    for asked in (unicodedata.normalize("NFD", "实验é"), "实验é", stored):
        tracker = Tracker(tracking_uri, asked)
        assert tracker.experiment_name == stored and len(tracker.trial_runs()) == 1
    mlflow_experiment = tracker.client.get_experiment(tracker.experiment_id())
    assert mlflow_experiment.name == stored and mlflow_experiment.tags["ablate.name"] == "实验é"
    assert (tmp_path / "mlartifacts" / stored).is_dir()
    assert lock_file(tracker.uri, tracker.experiment_name).name == f"mlflow.db.{stored}.lock"
    # What the trial took, for the next launch's time-left estimate and order.
    key = expand(experiment)[0].key
    costs, episodes = tracker.earlier_runs([key, "not-a-key"])
    assert list(costs) == [key] and 0 < costs[key] < 600
    ran = tracker.trial_runs()[0].metrics["episodes_run"]
    assert episodes == {key: ran} and ran > 0


# --- [tune] (issue 19): two stages in one launch ---

TUNE = """
[tune]
learning_rate = [0.01, 0.1]
seeds = 2
max_episodes = 10
"""


def test_a_tuned_ablation_reuses_the_untuned_trials_tunes_then_evaluates_at_the_choice(
    run_quiet, tmp_path, tiny_store, monkeypatch
):
    import json

    tracking_uri, untuned, _ = tiny_store  # the untuned ablation, already in the store
    base_keys = {t.key for t in expand(untuned)}

    tuned = _experiment(tmp_path, TINY + TUNE, name="tuned.toml")
    outcome = run_quiet(tuned, tmp_path, tracking_uri)
    assert outcome.exit_code == 0 and not outcome.failed
    # The store's untuned trials are the base-value trials: not run again.
    assert outcome.skipped == 4 and not base_keys & set(outcome.finished)
    assert len(outcome.finished) == 8 + 4 and outcome.total == 16

    tracker = RunReader(tracking_uri, "tiny")
    runs = [r for r in tracker.trial_runs() if r.status == "FINISHED"]
    assert len({r.key for r in runs}) == len(runs) == 16  # no trial ran twice
    stages = [r.tags.get("ablate.stage") for r in runs]
    assert stages.count("tune") == 2 * 2 * 2 and stages.count("eval") == 4 + 4 + 0
    tuning_runs = [r for r in runs if r.tags["ablate.stage"] == "tune"]
    assert {r.seed for r in tuning_runs} == {10_000, 10_001} and all(
        r.params["max_episodes"] == "10" for r in tuning_runs
    )

    launch = _launches(tracker)[0]  # the newest
    document = json.loads(tracker.load_text(launch.info.run_id, "tuning.json"))
    assert document["metric"] == "auc" and document["seeds"] == [10_000, 10_001]
    for variant in ("narrow", "deep"):
        means = {}
        for lr in (0.01, 0.1):
            aucs = [
                r.metrics["auc"] for r in tuning_runs if r.variant == variant and float(r.params["learning_rate"]) == lr
            ]
            means[lr] = sum(aucs) / len(aucs)
        best = max(means, key=means.get)
        assert document["choices"][variant]["values"] == {"learning_rate": best}, means
        evaluated = sorted(
            r.seed
            for r in runs
            if r.variant == variant and r.tags["ablate.stage"] == "eval" and float(r.params["learning_rate"]) == best
        )
        assert evaluated == [0, 1]

    # Nothing left: the answer comes from the store, without starting (or even asking for) Ray.
    from ablate.launch import scheduler

    def no_ray(address):
        raise AssertionError("a finished ablation started Ray")

    monkeypatch.setattr(scheduler, "ensure_ray", no_ray)
    again = run_quiet(tuned, tmp_path, tracking_uri)
    assert again.launch_run_id is None and again.skipped == again.total == 16 and not again.finished

    from ablate.reporting.status import detail

    status = detail(tracking_uri, "tiny", tuned)
    assert "of which tuning (stage 1): 8 trials: 8 finished" in status and "16 trials: 16 finished" in status

    # issue 27: `ablate train --from` reruns the trial the report shows: the evaluation trial at the chosen value
    # by default, a tuning trial with --stage tune; each the same episodes as its tracked run.
    from ablate.cli import main

    def rerun(out, *argv):
        argv = ["train", "--from", tuned.path, "--variant", "deep", *argv, "--tracking-uri", tracking_uri]
        assert main([*argv, "--no-video", "--out", str(tmp_path / out)]) == 0
        return json.loads((tmp_path / out / "summary.json").read_text())

    chosen = document["choices"]["deep"]["values"]["learning_rate"]
    for summary, stage, seed, lr in (
        (rerun("eval", "--seed", "1"), "eval", 1, chosen),
        (rerun("tune", "--stage", "tune", "--seed", "10001", "--learning-rate", "0.01"), "tune", 10_001, 0.01),
    ):
        (tracked,) = [
            r for r in runs if r.variant == "deep" and r.seed == seed and float(r.params["learning_rate"]) == lr
        ]
        assert summary["trial_key"] == tracked.key and summary["stage"] == stage
        assert summary["tuned_values"] == {"learning_rate": lr}
        assert summary["episodes_run"] == tracked.metrics["episodes_run"]
        assert summary["env_steps"] == tracked.metrics["env_steps"]  # the same episodes, step for step
        assert summary["final_rolling_mean"] == pytest.approx(tracked.metrics["final_rolling_mean"], abs=1e-9)


def test_both_stages_start_their_trials_seeds_interleaved_across_variants(tmp_path, tracking_uri, monkeypatch):
    """Stage 2 (the trials at the chosen values) is handed to Ray in the order stage 1 is: every variant's
    first seed, then every variant's second, the order the time-left estimate assumes."""
    from ablate.launch.grid import schedule_order
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    stages: list[list] = []

    def finish_all(todo, events):
        stages.append(list(todo))
        for trial in todo:
            events.started(trial.key)
            events.finished(trial.key, {"auc": trial.config.learning_rate, "episodes_run": 10.0}, None, "node-1")

    _fake_scheduler(monkeypatch, finish_all)
    # Trials alone (a population starts in the order of its first member: tests/test_plan.py).
    experiment = _experiment(tmp_path, TINY + TUNE)
    outcome = run_plan(LaunchPlan(experiment, tracking_uri=tracking_uri, show_progress=False, population=1))
    assert outcome.exit_code == 0 and len(stages) == 2
    chosen = stages[1]
    assert {t.config.learning_rate for t in chosen} == {0.1}  # the highest AUC won: stage 2 has trials to run
    assert [(t.variant, t.seed) for t in chosen] == [("narrow", 0), ("deep", 0), ("narrow", 1), ("deep", 1)]
    assert chosen == schedule_order(chosen, {}) and stages[0] == schedule_order(stages[0], {})


def test_ctrl_c_during_tuning_then_a_rerun_finishes_both_stages_running_no_trial_twice(
    tmp_path, tracking_uri, ray_address, monkeypatch, capsys
):
    release = tmp_path / "release"
    text = f"""
name = "tuneint"
seeds = 1
[base]
env_id = "CartPole-v1"
max_episodes = 20
episodes_per_update = 10
record_video = false
[[variants]]
name = "quick"
[[variants]]
name = "blocked"
fault = "block"
fault_marker = "{release}"
[tune]
learning_rate = [0.01, 0.1]
seeds = 1
max_episodes = 10
"""
    path = tmp_path / "tuneint.toml"
    path.write_text(text)
    command = [sys.executable, "-m", "ablate.cli", "run", str(path), "--tracking-uri", tracking_uri, "--no-report"]
    command += ["--max-concurrent", "2"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "RAY_ADDRESS": ray_address}  # both launches join the session's Ray
    proc = subprocess.Popen(
        command,
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=env,
        text=True,
        preexec_fn=_restore_sigint,
    )
    tracker = Tracker(tracking_uri, "tuneint")
    # Stage 1 runs first (variant-major: quick's two candidates, then blocked's): with two slots, quick's
    # tuning trials finish and blocked's block, so the signal lands in stage 1 with both stages unfinished.
    wanted = {("quick", "tune", "FINISHED"): 2, ("blocked", "tune", "RUNNING"): 2}
    try:
        # Waits on what it observes (the wanted states, or the child's end), not on a deadline: on a loaded
        # machine the child's imports, Ray's workers and four trials took past the 240 s this loop once allowed.
        seen: dict = {}
        while proc.poll() is None:
            if tracker.experiment_id(create=False):
                seen = {}
                for r in tracker.trial_runs():
                    state = (r.variant, r.tags.get("ablate.stage"), r.status)
                    seen[state] = seen.get(state, 0) + 1
                if seen == wanted:
                    break
            time.sleep(0.5)  # a polling interval: nothing waits on its length
        assert proc.poll() is None, "the run ended before it could be interrupted: " + proc.stdout.read()
        assert seen == wanted, seen
        proc.send_signal(signal.SIGINT)
        output, _ = proc.communicate(timeout=HANG_S)
        assert proc.returncode == 130, output
    finally:
        release.write_text("go\n")
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
    finished_first = {r.key for r in tracker.trial_runs() if r.status == "FINISHED"}
    assert len(finished_first) == 2

    rerun = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, env=env, timeout=HANG_S)
    assert rerun.returncode == 0, rerun.stdout + rerun.stderr
    finished = [r for r in tracker.trial_runs() if r.status == "FINISHED"]
    keys = [r.key for r in finished]
    assert len(keys) == len(set(keys))  # no finished trial ran twice
    assert finished_first <= set(keys)
    stages = [r.tags["ablate.stage"] for r in finished]
    # 2 variants x 2 candidates x 1 tuning seed; the base value on seed 0; the choice on seed 0 (never 0.03)
    assert stages.count("tune") == 4 and stages.count("eval") == 2 + 2

    # Re-running a finished tuned experiment answers from the store without asking for Ray (that the answer
    # imports no Ray at all is test_rerunning_a_finished_ablation_answers_from_the_store_without_importing_ray).
    from ablate.cli import main
    from ablate.launch import scheduler

    def no_ray(address):
        raise AssertionError("a finished ablation asked for Ray")

    monkeypatch.setattr(scheduler, "ensure_ray", no_ray)
    monkeypatch.chdir(tmp_path)
    assert main(command[3:]) == 0
    assert "all 8 trials of tuneint already finished" in capsys.readouterr().out


def test_rerunning_a_finished_ablation_answers_from_the_store_without_importing_ray(tmp_path, tracking_uri):
    # The store is written directly (no Ray): one launch, every trial of the file FINISHED.
    experiment = _experiment(tmp_path)
    tracker = Tracker(tracking_uri, "tiny")
    launch = tracker.start_launch("g1", "tiny", {}, {})
    for trial in expand(experiment):
        tracker.start_trial(launch, "g1", trial.key, trial.variant, trial.seed, {}, "abc")
        tracker.finish_trial(trial.key, {"solved": 0.0}, None)
    tracker.finish_launch(launch, "FINISHED", {})
    code = (
        "import sys; from ablate.cli import main; "
        f"rc = main(['run', {experiment.path!r}, '--tracking-uri', {tracking_uri!r}, '--no-report']); "
        "print('RAY IMPORTED' if 'ray' in sys.modules else 'NO RAY'); sys.exit(rc)"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "all 4 trials of tiny already finished" in proc.stdout and "starting" not in proc.stdout
    assert proc.stdout.splitlines()[-1] == "NO RAY"


def test_a_tuned_launch_counts_stage_2s_stand_ins_from_its_start(tmp_path, tracking_uri, monkeypatch):
    """Before any tuning trial ends, each tuned variant's evaluation trials stand in for its stage 2."""
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    seen = []
    _fake_scheduler(monkeypatch, lambda trials, events: seen.append([t.trial.variant for t in events.state.later]))
    tuned = _experiment(tmp_path, TINY + TUNE, name="tuned.toml")
    run_plan(LaunchPlan(tuned, tracking_uri=tracking_uri, show_progress=False))
    evaluation = sorted(t.variant for t in expand(tuned))
    assert [sorted(variants) for variants in seen] == [evaluation]  # stage 1 (no trial finished: no stage 2)
