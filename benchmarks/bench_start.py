"""`make bench` section `start`: how fast `ablate run` gets to work, this checkout against an earlier commit's
(a git worktree), alternating in one run (issue 37).

- time to first trial, **cold** (a new folder: no store, no Ray) and **warm** (the same folder again with
  `--fresh`: the store exists): from the command's spawn to the first trial run's start in MLflow (ms);
- **64 seeds** of one CartPole variant end to end through `ablate run --no-report`: env steps per second of
  wall time per core, over one trial's env steps per second alone (`run_trial` in this process; the goal is
  >= 2x).
"""

from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_results import RESULTS
from bench_trainer import _worktree

ROOT = Path(__file__).resolve().parents[1]
BEFORE_START = ("47dacbe", "96efcee")
"""The last commit before issue 37's launch work (stop 40), and the end of stop 41 (before the lean Ray start)."""

BASE = """baseline = "baseline"
[base]
env_id = "CartPole-v1"
max_episodes = {episodes}
episodes_per_update = 32
learning_rate = 0.03
gamma = 0.95
hidden_sizes = [32]
[[variants]]
name = "baseline"
"""


def _ablate(checkout: Path, folder: Path, *argv: str) -> float:
    """``ablate`` of ``checkout`` in ``folder``; returns when it was spawned (``time.time()``)."""
    code = "import sys; from ablate.cli import main; sys.exit(main(sys.argv[1:]))"
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    spawned = time.time()
    proc = subprocess.run([sys.executable, "-c", code, *argv], cwd=folder, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return spawned


def _runs(folder: Path, name: str) -> list:
    from ablate.reporting.reader import RunReader

    reader = RunReader(f"sqlite:///{folder / 'mlflow.db'}", name)
    query = "tags.`ablate.role` = 'trial'"
    return reader.client.search_runs([reader.experiment_id()], query, max_results=1000)


def _first_trial(checkout: Path, folder: Path, fresh: bool) -> float:
    spawned = _ablate(checkout, folder, "run", "one.toml", "--no-report", *(["--fresh"] if fresh else []))
    starts = [r.info.start_time / 1000 for r in _runs(folder, "one") if r.info.start_time / 1000 >= spawned]
    return min(starts) - spawned


def _first_trial_joined(folder: Path) -> float:
    """Warm, joining a Ray head that already runs on this machine (``tools/local_cluster.py node``, as ``make
    cluster-up`` keeps one): what the start costs when Ray is not started per launch."""
    tool = str(ROOT / "tools" / "local_cluster.py")
    command = [sys.executable, tool, "node", "--head", "--cpus", str(os.cpu_count())]
    node = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        line = node.stdout.readline().split()  # ready <node id> <gcs address>: the head is up
        assert line and line[0] == "ready", line
        spawned = _ablate(ROOT, folder, "run", "one.toml", "--no-report", "--fresh", "--address", line[2])
        starts = [r.info.start_time / 1000 for r in _runs(folder, "one") if r.info.start_time / 1000 >= spawned]
        return min(starts) - spawned
    finally:
        node.terminate()
        node.wait(timeout=60)


def _launch_64(checkout: Path, folder: Path) -> tuple[float, float]:
    """(wall seconds, env steps) of 64 seeds through ``ablate run``."""
    spawned = _ablate(checkout, folder, "run", "s64.toml", "--no-report")
    steps = sum(r.data.metrics.get("env_steps", 0.0) for r in _runs(folder, "s64"))
    return time.time() - spawned, steps


def _one_trial_steps_per_s(episodes: int) -> float:
    """One trial of the 64-seed launch's variant (seed 0) alone, in this process."""
    from ablate.agent.trainer import run_trial
    from ablate.experiment import load_experiment
    from ablate.launch.grid import expand

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "one.toml"
        path.write_text('name = "one"\nseeds = 1\n' + BASE.format(episodes=episodes))
        config = expand(load_experiment(path))[0].config
    result = run_trial(config)
    return result.env_steps / result.wall_s


def bench_start(against: tuple[str, ...] | str = BEFORE_START, repeats: int = 3, episodes: int = 1500) -> None:
    against = (against,) if isinstance(against, str) else tuple(against)
    checkouts = {"this": ROOT, **{ref: _worktree(ref) for ref in against}}
    figures: dict[str, dict[str, list[float]]] = {k: {"cold": [], "warm": [], "ratio": []} for k in checkouts}
    figures["this"]["joined"] = []
    cores = os.cpu_count() or 1
    try:
        alone = statistics.median(_one_trial_steps_per_s(episodes) for _ in range(3))
        print(f"  one trial alone: {alone:,.0f} env steps/s", flush=True)
        for i in range(repeats):
            for name, checkout in checkouts.items():
                folder = Path(tempfile.mkdtemp(prefix="ablate-bench-start-"))
                try:
                    (folder / "one.toml").write_text('name = "one"\nseeds = 1\n' + BASE.format(episodes=50))
                    (folder / "s64.toml").write_text('name = "s64"\nseeds = 64\n' + BASE.format(episodes=episodes))
                    cold = _first_trial(checkout, folder, fresh=False)
                    warm = _first_trial(checkout, folder, fresh=True)
                    wall, steps = _launch_64(checkout, folder)
                    if name == "this":
                        figures[name]["joined"].append(_first_trial_joined(folder))
                finally:
                    shutil.rmtree(folder, ignore_errors=True)
                ratio = steps / wall / cores / alone
                figures[name]["cold"].append(cold)
                figures[name]["warm"].append(warm)
                figures[name]["ratio"].append(ratio)
                joined = f", joining a running head {figures[name]['joined'][-1]:.1f} s" if name == "this" else ""
                print(f"  {name} {i}: first trial cold {cold:.1f} s, warm {warm:.1f} s{joined}; 64 seeds {wall:.1f} s, "
                      f"{steps / 1e6:.1f}M env steps: {ratio:.2f}x one trial per core", flush=True)  # fmt: skip
    finally:
        for ref in against:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(checkouts[ref])],
                           check=False, capture_output=True)  # fmt: skip
    for name in checkouts:
        f = figures[name]
        print(
            f"start ({name}): time to first trial cold "
            f"{statistics.median(f['cold']):.1f} s, warm {statistics.median(f['warm']):.1f} s"
            + (f", joining a running head {statistics.median(f['joined']):.1f} s" if f.get("joined") else "")
            + " (goal ~3 s); 64 seeds "
            f"end to end {statistics.median(f['ratio']):.2f}x one trial's env steps/s per core (goal >= 2x); "
            f"medians of {repeats}"
        )
    RESULTS["start"] = {"against": list(against), "alone_steps_per_s": alone, **figures}
