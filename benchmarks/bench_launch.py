"""`make bench` sections of a launch's own costs: `runner` (the runner beside the trials), `ablation` (the
default ablation: speed-up, tracking overhead, memory), `tracking` (the single writer with 256 synthetic
trials), `cluster` (a tiny ablation on the local default vs a joined head and a tracking server), `launch`
(a thousand seeds of the default CartPole trial through `ablate run` against the trainer's own rate, and the
report of them)."""

from __future__ import annotations

import contextlib
import os
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

from bench_results import RESULTS

from ablate.agent.trainer import run_trial
from ablate.config import DEFAULT
from ablate.trial_files import write_artifacts


class _TimedEvents:
    """Scheduler events that go nowhere but the clock: the same trials without any tracking, and when the
    first of them started (the launch's fixed cost: Tune's setup and the worker processes' imports)."""

    def __init__(self) -> None:
        self.created = time.perf_counter()
        self.first_start: float | None = None

    def started(self, key):
        if self.first_start is None:
            self.first_start = time.perf_counter() - self.created

    def episodes(self, key, points): ...
    def checkpoint(self, key, blob): ...
    def restarted(self, key, reason): ...
    def finished(self, key, summary, artifacts, node, population=""): ...
    def failed(self, key, message):
        raise RuntimeError(f"benchmark trial {key} failed: {message}")


def _untracked(trials, concurrent: int, storage: Path, name: str) -> tuple[float, float]:
    """Run ``trials`` through Ray Tune untracked, ``concurrent`` at a time: (wall s, s to the first start)."""
    from ablate.launch.plan import plan_populations
    from ablate.launch.scheduler import ClusterOptions, run_trials

    events = _TimedEvents()
    run_trials(
        plan_populations(trials), events, ClusterOptions(max_concurrent=concurrent, storage_path=str(storage)), name
    )
    return time.perf_counter() - events.created, events.first_start or float("nan")


FIXED_WORK = """
name = "bench-fixed"
seeds = 8
[base]
env_id = "CartPole-v1"
max_episodes = 1500
solve_threshold = 1e9      # never solved: every trial runs its whole budget, the same work every time
[[variants]]
name = "fixed"
"""


def bench_runner(repeats: int = 3) -> None:
    """A short workload, medians over repeats: 8 trials of fixed work (~4 s each), 2 at a time vs one after
    another, untracked; then 2 at a time tracked in MLflow (a fresh SQLite store). With so few, short trials
    the launch's fixed cost (worker start, printed) and the last trial's tail weigh on both figures; the
    `ablation` section measures the same on the default ablation's 50 trials."""
    import shutil
    import tempfile

    from ablate.experiment import load_experiment
    from ablate.launch.grid import expand
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan
    from ablate.launch.scheduler import ensure_ray
    from ablate.launch.tracking import Tracker

    ensure_ray(None)
    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-"))
    try:
        (folder / "fixed.toml").write_text(FIXED_WORK)
        experiment = load_experiment(folder / "fixed.toml")
        trials = expand(experiment)
        speedups, overheads, launches = [], [], []
        for i in range(repeats):
            one, launch = _untracked(trials, 1, folder / "ray", f"speedup-{i}-1")
            two, _ = _untracked(trials, 2, folder / "ray", f"speedup-{i}-2")
            launches.append(launch)
            uri = f"sqlite:///{folder / f'mlflow-{i}.db'}"
            Tracker(uri, "warm").experiment_id()  # a user's store exists already: create its tables first
            started = time.perf_counter()
            run_plan(
                LaunchPlan(
                    experiment,
                    tracking_uri=uri,
                    max_concurrent=2,
                    storage_path=str(folder / "ray"),
                    show_progress=False,
                )
            )
            tracked = time.perf_counter() - started
            speedups.append(one / two)
            overheads.append(tracked / two - 1)
            print(
                f"  8 trials: one at a time {one:.1f} s (first trial started after {launch:.1f} s), two at a "
                f"time {two:.1f} s (speed-up {speedups[-1]:.2f}x); two at a time tracked in MLflow {tracked:.1f} s "
                f"(overhead {100 * overheads[-1]:+.1f}%)",
                flush=True,
            )
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    print(
        f"runner (8 short trials): parallel speed-up (2 concurrent vs one after another) median "
        f"{statistics.median(speedups):.2f}x; tracking overhead median {100 * statistics.median(overheads):+.1f}%; "
        f"launch cost median {statistics.median(launches):.1f} s"
    )
    RESULTS["runner"] = {
        "speedup_median": statistics.median(speedups),
        "speedups": speedups,
        "tracking_overhead_median": statistics.median(overheads),
        "tracking_overheads": overheads,
        "launch_s_median": statistics.median(launches),
    }


def _tracked_run(experiment_path: str, folder: Path) -> tuple[float, float, float]:
    """Run an experiment into a fresh store under ``folder``; return (wall s, s inside MLflow, peak RSS GB)."""
    import threading

    import psutil

    from ablate.experiment import load_experiment
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan
    from ablate.launch.tracking import Tracker

    in_tracker = [0.0]
    originals = {}
    for name in (
        "start_trial",
        "log_points",
        "log_checkpoint",
        "finish_trial",
        "fail_trial",
        "start_launch",
        "finish_launch",
    ):
        original = getattr(Tracker, name)
        originals[name] = original

        def timed(self, *args, _original=original, **kwargs):
            started = time.perf_counter()
            try:
                return _original(self, *args, **kwargs)
            finally:
                in_tracker[0] += time.perf_counter() - started

        setattr(Tracker, name, timed)
    peak = [0.0]
    stop = threading.Event()

    def sample() -> None:
        # Everything this benchmark runs: the driver, Ray's processes and its workers (children of raylet).
        me = psutil.Process()
        while not stop.is_set():
            total = 0
            for process in [me, *me.children(recursive=True)]:
                with contextlib.suppress(psutil.Error):  # a process may end between listing and reading
                    total += process.memory_info().rss
            peak[0] = max(peak[0], total)
            stop.wait(0.5)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    try:
        started = time.perf_counter()
        outcome = run_plan(
            LaunchPlan(
                load_experiment(experiment_path),
                tracking_uri=f"sqlite:///{folder / 'mlflow.db'}",
                storage_path=str(folder / "ray"),
                show_progress=False,
            )
        )
        wall = time.perf_counter() - started
    finally:
        stop.set()
        sampler.join()
        for name, original in originals.items():
            setattr(Tracker, name, original)
    assert outcome.exit_code == 0, outcome.failed
    return wall, in_tracker[0], peak[0] / 2**30


def bench_ablation(repeats: int = 1) -> None:
    """The default CartPole ablation (50 trials), the workload users run. Each repeat, back to back: its
    trials untracked one after another, untracked two at a time, then `ablate run`'s own path end to end
    (Ray's start, MLflow tracking into a fresh store; peak memory sampled). Speed-up = one at a time / two
    at a time; tracking overhead = tracked / untracked two at a time - 1. Then the report, three times."""
    import shutil
    import tempfile

    import ray

    from ablate.experiment import load_experiment
    from ablate.launch.grid import expand
    from ablate.launch.scheduler import ensure_ray
    from ablate.launch.tracking import Tracker
    from ablate.reporting.document import build_report

    path = "experiments/cartpole.toml"
    trials = expand(load_experiment(path))
    speedups, overheads, totals, peaks = [], [], [], []
    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-"))
    try:
        for i in range(repeats):
            ensure_ray(None)
            one, _ = _untracked(trials, 1, folder / "ray", f"ablation-{i}-1")
            two, launch = _untracked(trials, 2, folder / "ray", f"ablation-{i}-2")
            # Ray's own start is part of what a user waits for: restart it inside the timed region.
            ray.shutdown()
            store = folder / f"store-{i}"
            store.mkdir()
            started = time.perf_counter()
            ensure_ray(None)
            ray_start = time.perf_counter() - started
            # A first run also creates the store's tables (MLflow's migrations, ~3 s): part of the end-to-end
            # time, not of the per-trial tracking overhead, which compares runs into an existing store.
            started = time.perf_counter()
            Tracker(f"sqlite:///{store / 'mlflow.db'}", "warm").experiment_id()
            store_s = time.perf_counter() - started
            wall, mlflow_s, peak_gb = _tracked_run(path, store)
            total = ray_start + store_s + wall
            speedups.append(one / two)
            overheads.append(wall / two - 1)
            totals.append(total)
            peaks.append(peak_gb)
            print(
                f"  {len(trials)} trials untracked: one at a time {one:.0f} s, two at a time {two:.0f} s (first trial "
                f"after {launch:.1f} s), speed-up {speedups[-1]:.2f}x | `ablate run` end to end {total:.0f} s "
                f"({total / 60:.1f} min; Ray start {ray_start:.1f} s, new store {store_s:.1f} s), "
                f"tracking overhead {100 * overheads[-1]:+.1f}% "
                f"(driver time in MLflow writes {mlflow_s:.1f} s), peak memory {peak_gb:.2f} GB",
                flush=True,
            )
        print(
            f"ablation: {path} end to end median {statistics.median(totals):.0f} s "
            f"({statistics.median(totals) / 60:.1f} min); parallel speed-up (2 concurrent vs one after another) "
            f"median {statistics.median(speedups):.2f}x; tracking overhead median "
            f"{100 * statistics.median(overheads):+.1f}%; peak memory max {max(peaks):.2f} GB"
        )
        report_times = []
        for _ in range(3):
            started = time.perf_counter()
            build_report(
                "cartpole", tracking_uri=f"sqlite:///{folder / 'store-0' / 'mlflow.db'}", out_root=folder / "reports"
            )
            report_times.append(time.perf_counter() - started)
        print(
            f"report: cartpole report generation median {statistics.median(report_times):.1f} s "
            f"(runs: {', '.join(f'{t:.1f}' for t in report_times)})"
        )
        RESULTS["ablation"] = {
            "wall_s_median": statistics.median(totals),
            "walls_s": totals,
            "speedup_median": statistics.median(speedups),
            "speedups": speedups,
            "tracking_overhead_median": statistics.median(overheads),
            "tracking_overheads": overheads,
            "peak_memory_gb_max": max(peaks),
            "report_s_median": statistics.median(report_times),
        }
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _cartpole_stream() -> tuple[list, float, Path]:
    """One default CartPole-v1 trial's episodes as they came (each update's rows, with its clock), its wall
    time, and its artifacts folder (a real episodes.csv, weights, curve): what a synthetic trial replays."""
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-artifacts-"))
    updates: list = []
    started = time.perf_counter()
    result = run_trial(
        replace(DEFAULT, env_id="CartPole-v1", seed=0, solve_threshold=1e9, record_video=False),
        on_episodes=lambda rows: updates.append((time.perf_counter() - started, list(rows))),
    )
    write_artifacts(result, folder)
    return updates, result.wall_s, folder


def _writer_run(trials: int, seconds: float, trial_wall: float, reports: list, artifacts: Path, folder: Path) -> dict:
    """``trials`` synthetic trials at once, each replaying ``reports`` ((s into the trial, curve points)) and
    ending at ``trial_wall`` (then a new one starts), through the real recorder and tracker on one thread."""
    import queue
    import threading

    from ablate.launch.grid import GridTrial
    from ablate.launch.progress import ProgressView
    from ablate.launch.runner import RunOutcome, _Recorder
    from ablate.launch.scheduler import REPORT_EVERY_S
    from ablate.launch.state import LaunchState
    from ablate.launch.tracking import Tracker

    tracker = Tracker(f"sqlite:///{folder / 'mlflow.db'}", "bench-tracking")
    launch = tracker.start_launch("g", "bench", {}, {})
    config = replace(DEFAULT, env_id="CartPole-v1")
    summary = {"solved": 0.0, "episodes_run": 1.0, "wall_s": trial_wall}
    grid: dict[str, GridTrial] = {}
    schedule = []
    for i in range(trials):
        begin = (i / trials) * REPORT_EVERY_S  # staggered, as trials started by Tune are
        while begin < seconds:
            key = f"synthetic-{len(grid)}"
            grid[key] = GridTrial(key, "synthetic", len(grid), config)
            schedule.append((begin, 0, key, None))
            schedule += [(begin + at, 1, key, points) for at, points in reports if points]
            schedule.append((begin + trial_wall, 2, key, None))
            begin += trial_wall
    schedule = sorted((e for e in schedule if e[0] < seconds), key=lambda e: e[0])
    outcome = RunOutcome("bench-tracking", "g", launch, 0, 0, "")
    state = LaunchState("b", list(grid.values()), 0)
    recorder = _Recorder(tracker, launch, "g", grid, "commit", state, ProgressView(state, False), outcome)
    events: queue.Queue = queue.Queue()
    lags: list[float] = []
    cpu = [0.0]

    def writer() -> None:
        while (item := events.get()) is not None:
            due, kind, key, payload = item
            began = time.thread_time()
            if kind == 0:
                recorder.started(key)
            elif kind == 1:
                recorder.episodes(key, payload)
            else:
                recorder.finished(key, summary, artifacts, "node")
            cpu[0] += time.thread_time() - began
            lags.append(time.perf_counter() - due)

    thread = threading.Thread(target=writer)
    thread.start()
    started = time.perf_counter()
    for at, kind, key, payload in schedule:
        delay = started + at - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        events.put((started + at, kind, key, payload))
    wall = time.perf_counter() - started
    events.put(None)
    thread.join()
    lags.sort()
    return {
        "writer_cores": cpu[0] / wall,
        "lag_median_s": lags[len(lags) // 2],
        "lag_p99_s": lags[int(len(lags) * 0.99)],
        "backlog_s": time.perf_counter() - started - wall,
        "trials_finished": len(outcome.finished),
        "trials_started": sum(1 for e in schedule if e[1] == 0),
    }


def bench_tracking(trials: int = 256, seconds: float = 60.0) -> None:
    """The single writer (``ablate run``'s recorder and MLflow tracker, on the driver) fed by ``trials``
    synthetic trials at once, streaming at the measured rate of a real default CartPole trial, into a fresh
    SQLite store for ``seconds``: (a) long trials (the whole run: ``rate x seconds`` episodes each, reduced
    in the "worker" to the same <= 100 curve points), the cost per streamed episode; (b) trials exactly as
    long as the real one, each replaced when it ends, adding each run's start and finish with artifacts.
    Figures: the writer thread's CPU (cores) and the lag of events behind their schedule (keeping up: the
    lag stays within a flush interval, no backlog at the end). Tune's own per-result cost is not included."""
    import shutil
    import tempfile

    from ablate.launch.curve import CURVE_POINTS, CurvePoint, CurveReducer
    from ablate.launch.scheduler import REPORT_EVERY_S

    updates, trial_wall, artifacts = _cartpole_stream()
    episodes = sum(len(rows) for _, rows in updates)
    rate = episodes / trial_wall
    reducer = CurveReducer(DEFAULT.max_episodes)
    real: list[tuple[float, list]] = []  # what the worker sends: every REPORT_EVERY_S, the points so far
    pending, last = [], 0.0
    for at, rows in updates:
        pending += reducer.add(rows)
        if at - last >= REPORT_EVERY_S:
            real.append((at, pending))
            pending, last = [], at
    real.append((trial_wall, pending + reducer.flush()))
    print(f"  a default CartPole-v1 trial: {episodes} episodes in {trial_wall:.1f} s ({rate:,.0f} episodes/s)")
    reports_per_trial = int(seconds / REPORT_EVERY_S)
    per_report = CURVE_POINTS / reports_per_trial
    template = real[-1][1][-1]
    long = [
        (
            REPORT_EVERY_S * (r + 1),
            [template._replace(episode=int(rate * REPORT_EVERY_S * (r + 1)))]
            * int((r + 1) * per_report - int(r * per_report)),
        )
        for r in range(reports_per_trial)
    ]
    assert all(isinstance(p, CurvePoint) for _, points in long for p in points)
    figures = {}
    try:
        for name, wall, reports in (("long", seconds + 1, long), ("cartpole-length", trial_wall, real)):
            folder = Path(tempfile.mkdtemp(prefix="ablate-bench-"))
            try:
                figures[name] = run = _writer_run(trials, seconds, wall, reports, artifacts, folder)
            finally:
                shutil.rmtree(folder, ignore_errors=True)
            print(
                f"  {name} trials: {run['trials_started']} started, {run['trials_finished']} finished in "
                f"{seconds:.0f} s;"
                f" writer CPU {run['writer_cores']:.2f} cores; lag median {run['lag_median_s']:.2f} s, p99 "
                f"{run['lag_p99_s']:.2f} s; backlog at the end {run['backlog_s']:.1f} s",
                flush=True,
            )
    finally:
        shutil.rmtree(artifacts, ignore_errors=True)
    long_run, short_run = figures["long"], figures["cartpole-length"]
    print(
        f"tracking: {trials} concurrent trials at {rate:,.0f} episodes/s each ({trials * rate:,.0f} episodes/s): "
        f"long trials, writer {long_run['writer_cores']:.2f} cores (lag p99 {long_run['lag_p99_s']:.2f} s); "
        f"{trial_wall:.0f}-s trials replaced as they end, writer {short_run['writer_cores']:.2f} cores "
        f"(backlog {short_run['backlog_s']:.0f} s)"
    )
    RESULTS["tracking"] = {"trials": trials, "episodes_per_s_per_trial": rate, **figures}


TINY = """
name = "bench-cluster"
seeds = 2
[base]
env_id = "CartPole-v1"
max_episodes = 200
episodes_per_update = 16
video_max_frames = 100
[[variants]]
name = "narrow"
hidden_sizes = [16]
[[variants]]
name = "deep"
hidden_sizes = [32, 32]
"""


def bench_cluster(repeats: int = 3) -> None:
    """A tiny ablation (4 trials) end to end with `ablate run`, interleaved per repeat: the local default (a
    fresh local Ray, an SQLite store) vs the cluster path (joining a running head node on 127.0.0.1 with this machine's
    cores, tracked on an ``mlflow server`` with served artifacts). The head and server are started once,
    outside the timing, as they are in use; the local default pays Ray's start, as a user does."""
    import shutil
    import tempfile

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
    import local_cluster

    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-"))
    log = open(folder / "cluster.log", "w")  # noqa: SIM115 - closed below
    port = local_cluster.free_port()
    server = local_cluster.mlflow_server(folder / "server", port, log=log)
    head, _, gcs = local_cluster.start_node_process(True, os.cpu_count(), port=local_cluster.free_port(), log=log)
    try:
        local_cluster.wait_http(f"http://127.0.0.1:{port}/health", 120, server)
        (folder / "tiny.toml").write_text(TINY)
        ratios = []
        for i in range(repeats):
            walls = {}
            for path, uri, address in (
                ("local", f"sqlite:///{folder / f'local-{i}.db'}", None),
                ("cluster", f"http://127.0.0.1:{port}", gcs),
            ):
                # `ablate run` as a user types it, one process per launch (process start and imports included)
                command = [sys.executable, "-m", "ablate.cli", "run", str(folder / "tiny.toml"), "--fresh"]
                command += ["--tracking-uri", uri, "--storage-path", str(folder / "ray")]
                command += ["--address", gcs] if address else []
                started = time.perf_counter()
                done = subprocess.run(command, capture_output=True, text=True, cwd=folder)
                walls[path] = time.perf_counter() - started
                assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
            ratios.append(walls["cluster"] / walls["local"] - 1)
            print(
                f"  4 trials: local default {walls['local']:.1f} s, joined head + tracking server "
                f"{walls['cluster']:.1f} s ({100 * ratios[-1]:+.0f}%)",
                flush=True,
            )
    finally:
        local_cluster.stop_process(head)
        local_cluster.stop_process(server)
        log.close()
        shutil.rmtree(folder, ignore_errors=True)
    print(
        f"cluster: the cluster path vs the local default on a 4-trial ablation, "
        f"median {100 * statistics.median(ratios):+.0f}%"
    )
    RESULTS["cluster"] = {"overhead_median": statistics.median(ratios), "overheads": ratios}


THOUSAND = """
name = "bench-thousand"
seeds = {seeds}
[base]
env_id = "CartPole-v1"
max_episodes = 1000
[[variants]]
name = "default"
"""


def _trainer_rate(path: Path, members: int) -> float:
    """The trainer's own env steps/s on one core (``run_population`` in a process of its own, one torch thread):
    the launch's first ``members`` trials as one population, no tracking, no files."""
    code = (
        "import sys, time; from ablate.agent.trainer import run_population; "
        "from ablate.experiment import load_experiment; from ablate.launch.grid import expand; "
        f"configs = [t.config for t in expand(load_experiment({str(path)!r}))[:{members}]]; "
        "started = time.perf_counter(); outcomes = run_population(configs); "
        "print(sum(o.env_steps for o in outcomes) / (time.perf_counter() - started))"
    )
    done = subprocess.run(["taskset", "-c", "0", sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    return float(done.stdout.split()[-1])


def _launch_rate(path: Path, folder: Path, population: int) -> tuple[float, float, int, float]:
    """``ablate run --no-report`` as a user types it, into a fresh store: (wall s from the command's spawn to its
    exit, Ray's start included; env steps; trials finished; s to write the report of them)."""
    uri = f"sqlite:///{folder / 'mlflow.db'}"
    command = [sys.executable, "-m", "ablate.cli", "run", str(path), "--no-report", "--population", str(population)]
    command += ["--tracking-uri", uri, "--storage-path", str(folder / "ray")]
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, cwd=folder)
    wall = time.perf_counter() - started
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    from ablate.reporting.reader import RunReader

    runs = [r for r in RunReader(uri, "bench-thousand").trial_runs() if r.status == "FINISHED"]
    steps = sum(r.metrics.get("env_steps", 0.0) for r in runs)
    command = [sys.executable, "-m", "ablate.cli", "report", str(path), "--tracking-uri", uri]
    started = time.perf_counter()
    done = subprocess.run([*command, "--out", str(folder / "reports")], capture_output=True, text=True, cwd=folder)
    report = time.perf_counter() - started
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return wall, steps, len(runs), report


def bench_launch(seeds: int = 1000, populations: tuple[int, ...] = (64,), repeats: int = 1) -> None:
    """``seeds`` seeds of the default CartPole trial (one variant, 1,000 episodes at most, no tuning) through
    `ablate run` end to end, Ray's start included, in env steps per second of wall time per core, against the
    trainer's own rate on one core (``run_population`` of the launch's first members, as large as one of its
    populations), measured just before and just after each launch in the same run (their mean: a shared
    machine's load moves both); then `ablate report` of that store. Per ``--population`` in ``populations``."""
    import shutil
    import tempfile

    from ablate.launch.plan import population_size

    cores = os.cpu_count() or 1
    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-launch-"))
    path = folder / "thousand.toml"
    path.write_text(THOUSAND.format(seeds=seeds))
    figures: dict[str, dict[str, list[float]]] = {}
    try:
        for repeat in range(repeats):
            for population in populations:
                members = population_size(seeds, cores, population)
                before = _trainer_rate(path, members)
                store = folder / f"store-{population}-{repeat}"
                store.mkdir()
                wall, steps, trials, report = _launch_rate(path, store, population)
                after = _trainer_rate(path, members)
                trainer = (before + after) / 2
                launch = steps / wall / cores
                shutil.rmtree(store, ignore_errors=True)
                f = figures.setdefault(str(population), {"ratio": [], "launch": [], "trainer": [], "report_s": []})
                f["ratio"].append(launch / trainer)
                f["launch"].append(launch)
                f["trainer"].append(trainer)
                f["report_s"].append(report)
                print(
                    f"  --population {population} ({members} members), repeat {repeat}: {trials} trials, "
                    f"{steps / 1e6:.1f}M env steps in {wall:.0f} s: {launch:,.0f} env steps/s per core; the trainer "
                    f"{trainer:,.0f} on one core ({before:,.0f} before, {after:,.0f} after): {launch / trainer:.2f}x; "
                    f"ablate report {report:.0f} s",
                    flush=True,
                )
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    for population, f in figures.items():
        print(
            f"launch: {seeds} default CartPole trials through `ablate run --population {population}`, Ray's start "
            f"included: {statistics.median(f['launch']):,.0f} env steps/s per core, "
            f"{statistics.median(f['ratio']):.2f}x the trainer's {statistics.median(f['trainer']):,.0f} on one core "
            f"(goal >= 0.5x); `ablate report` of them {statistics.median(f['report_s']):.0f} s; medians of {repeats}"
        )
    RESULTS["launch"] = {"seeds": seeds, "cores": cores, **figures}
