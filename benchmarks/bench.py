"""`make bench`: speed and memory figures, measured in one process run, medians over several runs.

Sections: `core` (course-style loop vs our trial, time to solve CartPole-v1), and the sections that the
runner and the report add. `python benchmarks/bench.py [SECTION ...]`; no argument runs them all.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

from ablate.config import COURSE, DEFAULT
from ablate.course import course_loop
from ablate.trial import run_trial

RESULTS: dict[str, object] = {}


def bench_core(seeds: int = 5) -> None:
    """Env steps/s per core of the course-style loop and of our trial, same process, interleaved per seed;
    then time to solve CartPole-v1 (rolling mean >= 475 over 100 episodes) with the default config."""
    torch.set_num_threads(1)  # per core: both run on one thread
    course_sps, ours_sps, ratios = [], [], []
    for seed in range(seeds):
        course = course_loop(replace(COURSE, env_id="CartPole-v1", seed=seed), max_episodes=150)
        ours = run_trial(replace(DEFAULT, env_id="CartPole-v1", seed=seed, max_episodes=1024, record_video=False))
        sps = ours.env_steps / ours.wall_s
        course_sps.append(course["steps_per_s"])
        ours_sps.append(sps)
        ratios.append(sps / course["steps_per_s"])
        print(
            f"  seed {seed}: course-style {course['steps_per_s']:8,.0f} steps/s | ours {sps:8,.0f} steps/s"
            f" | ratio {ratios[-1]:5.1f}x",
            flush=True,
        )
    print(
        f"core: course-style median {statistics.median(course_sps):,.0f} steps/s/core; ours median "
        f"{statistics.median(ours_sps):,.0f} steps/s/core; ratio median {statistics.median(ratios):.1f}x"
    )

    walls, episodes = [], []
    for seed in range(seeds):
        result = run_trial(replace(DEFAULT, env_id="CartPole-v1", seed=seed, record_video=False))
        status = f"solved at episode {result.episodes_to_solve}" if result.solved else "NOT solved"
        print(
            f"  CartPole-v1 seed {seed}: {status}, {result.wall_s:.2f} s, {result.env_steps:,} steps",
            flush=True,
        )
        if result.solved:
            walls.append(result.wall_s)
            episodes.append(result.episodes_to_solve)
    median_wall = statistics.median(walls) if walls else float("nan")
    print(
        f"core: CartPole-v1 solved by {len(walls)}/{seeds} seeds; median wall to solve {median_wall:.2f} s; "
        f"median episodes {statistics.median(episodes) if episodes else float('nan')}"
    )
    RESULTS["core"] = {
        "course_steps_per_s_median": statistics.median(course_sps),
        "ours_steps_per_s_median": statistics.median(ours_sps),
        "speedup_median": statistics.median(ratios),
        "solved_seeds": len(walls),
        "seeds": seeds,
        "median_wall_s_to_solve": median_wall,
    }


class _NullEvents:
    """Scheduler events that go nowhere: the same trials without any tracking."""

    def started(self, key): ...
    def episodes(self, key, rows): ...
    def restarted(self, key, reason): ...
    def finished(self, key, summary, artifacts): ...
    def failed(self, key, message): ...


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
    """(1) Parallel speed-up: 8 trials of fixed work (~4 s each), 2 at a time vs one after another, through
    Ray, untracked. (2) Tracking overhead: the same 8 trials, 2 at a time, tracked in MLflow (a fresh SQLite
    store) vs untracked; interleaved, medians."""
    import shutil
    import tempfile

    from ablate.config import load_experiment
    from ablate.grid import expand
    from ablate.runner import run_experiment
    from ablate.scheduler import ClusterOptions, ensure_ray, run_trials
    from ablate.tracking import Tracker

    ensure_ray(None)
    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-"))
    try:
        (folder / "fixed.toml").write_text(FIXED_WORK)
        experiment = load_experiment(folder / "fixed.toml")
        trials = expand(experiment)
        speedups, overheads = [], []
        for i in range(repeats):
            times = {}
            for concurrent in (1, 2):
                started = time.perf_counter()
                options = ClusterOptions(max_concurrent=concurrent, storage_path=str(folder / "ray"))
                run_trials(trials, _NullEvents(), options, f"speedup-{i}-{concurrent}")
                times[concurrent] = time.perf_counter() - started
            uri = f"sqlite:///{folder / f'mlflow-{i}.db'}"
            Tracker(uri, "warm").experiment_id()  # a user's store exists already: create its tables first
            started = time.perf_counter()
            run_experiment(
                experiment,
                tracking_uri=uri,
                max_concurrent=2,
                storage_path=str(folder / "ray"),
                show_progress=False,
            )
            tracked = time.perf_counter() - started
            speedups.append(times[1] / times[2])
            overheads.append(tracked / times[2] - 1)
            print(
                f"  8 trials: one at a time {times[1]:.1f} s, two at a time {times[2]:.1f} s (speed-up "
                f"{speedups[-1]:.2f}x); two at a time tracked in MLflow {tracked:.1f} s (overhead "
                f"{100 * overheads[-1]:+.1f}%)",
                flush=True,
            )
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    print(
        f"runner: parallel speed-up (2 concurrent vs sequential) median {statistics.median(speedups):.2f}x; "
        f"tracking overhead median {100 * statistics.median(overheads):+.1f}%"
    )
    RESULTS["runner"] = {"speedup_median": statistics.median(speedups), "tracking_overhead": overheads}


def _tracked_run(experiment_path: str, folder: Path) -> tuple[float, float, float]:
    """Run an experiment into a fresh store under ``folder``; return (wall s, s inside MLflow, peak RSS GB)."""
    import threading

    import psutil

    from ablate.config import load_experiment
    from ablate.runner import run_experiment
    from ablate.tracking import Tracker

    in_tracker = [0.0]
    originals = {}
    for name in ("start_trial", "log_episodes", "finish_trial", "fail_trial", "start_launch", "finish_launch"):
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
        outcome = run_experiment(
            load_experiment(experiment_path),
            tracking_uri=f"sqlite:///{folder / 'mlflow.db'}",
            storage_path=str(folder / "ray"),
            show_progress=False,
        )
        wall = time.perf_counter() - started
    finally:
        stop.set()
        sampler.join()
        for name, original in originals.items():
            setattr(Tracker, name, original)
    assert outcome.exit_code == 0, outcome.failed
    return wall, in_tracker[0], peak[0] / 2**30


def bench_ablation() -> None:
    """The default CartPole ablation end to end (a fresh store; Ray already up, as `make ablation-cartpole`
    pays ~7 s more to start it), its MLflow share, peak memory, then its report."""
    import shutil
    import tempfile

    import ray

    from ablate.report import write_report
    from ablate.scheduler import ensure_ray

    # Ray's own start is part of what a user waits for: start it inside the timed region.
    if ray.is_initialized():
        ray.shutdown()
    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-"))
    try:
        started = time.perf_counter()
        ensure_ray(None)
        ray_start = time.perf_counter() - started
        wall, mlflow_s, peak_gb = _tracked_run("experiments/cartpole.toml", folder)
        total = ray_start + wall
        print(
            f"ablation: experiments/cartpole.toml end to end {total:.0f} s ({total / 60:.1f} min; Ray start "
            f"{ray_start:.1f} s); driver time in MLflow writes {mlflow_s:.1f} s ({100 * mlflow_s / wall:.1f}% of wall, "
            "on cores shared with the trials); "
            f"peak memory {peak_gb:.2f} GB"
        )
        report_times = []
        for _ in range(3):
            started = time.perf_counter()
            write_report("cartpole", tracking_uri=f"sqlite:///{folder / 'mlflow.db'}", out_root=folder / "reports")
            report_times.append(time.perf_counter() - started)
        print(
            f"report: cartpole report generation median {statistics.median(report_times):.1f} s "
            f"(runs: {', '.join(f'{t:.1f}' for t in report_times)})"
        )
        RESULTS["ablation"] = {
            "wall_s": total,
            "mlflow_share": mlflow_s / wall,
            "peak_memory_gb": peak_gb,
            "report_s_median": statistics.median(report_times),
        }
    finally:
        shutil.rmtree(folder, ignore_errors=True)


SECTIONS = {"core": bench_core, "runner": bench_runner, "ablation": bench_ablation}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("sections", nargs="*", help=f"any of {', '.join(SECTIONS)} (default: all)")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    print(f"python {sys.version.split()[0]}, torch {torch.__version__}, {time.strftime('%Y-%m-%d %H:%M')}")
    unknown = [name for name in args.sections if name not in SECTIONS]
    if unknown:
        parser.error(f"unknown section {unknown[0]!r}; valid: {', '.join(SECTIONS)}")
    for name in args.sections or SECTIONS:
        print(f"== {name}", flush=True)
        SECTIONS[name]()
    if args.json:
        args.json.write_text(json.dumps(RESULTS, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
