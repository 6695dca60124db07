"""`make bench` section `trainer`: this checkout's trainer against an earlier commit's, side by side in one run.

Machines of one kind differ 2-3x in speed, so a figure only means something against another measured in the same
run: each case runs in a fresh process pinned to one core, alternating this checkout and the earlier one (a git
worktree of ``--trainer-against``, by default the last commit before the one trainer), pair after pair. Each pair
also compares what the two computed (a digest of every episode's return, length, loss and entropy).

Cases: a population of 16 default CartPole members (issue 35's goal: >= 0.9x the earlier trainer); a population
of 16 of a user's network (``examples/models/layernorm.py``, a plain stack that acts in numpy, and ``residual.py``,
which acts through ``vmap``: >= 0.5x this checkout's default population); one
Pong trial of each arm of ``pong.toml`` (no slower than the earlier trainer).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from bench_results import RESULTS

ROOT = Path(__file__).resolve().parent.parent
BEFORE_ONE_TRAINER = "ba1e889"
"""The last commit with the bespoke CartPole and Pong populations (issue 35 replaced them by the one trainer)."""

CASES = {
    "cartpole-16": ("experiments/cartpole.toml", "baseline", 16, 1024),
    "layernorm-16": ("experiments/your-model.toml", "layernorm", 16, 1024),
    "residual-16": ("experiments/your-model.toml", "baseline", 16, 1024),
    "pong-cnn": ("experiments/pong.toml", "cnn", 1, 3),
    "pong-mlp": ("experiments/pong.toml", "mlp", 1, 3),
}
"""name: (experiment file, variant, members, episodes per member)."""
CUSTOM = ("layernorm-16", "residual-16")
"""Cases the earlier trainer cannot run (a user's network): measured against this checkout's default."""


def _child(case: str) -> None:
    """Run one case in this process (``PYTHONPATH`` says whose ``ablate``) and print its figures as JSON."""
    import torch

    from ablate.experiment import load_experiment

    try:
        from ablate.agent.trainer import run_population
    except ImportError:  # before the one trainer
        from ablate.agent.population import run_population

    torch.set_num_threads(1)
    path, variant, members, episodes = CASES[case]
    config = {v.name: v for v in load_experiment(ROOT / path).variants}[variant].config
    if case == "residual-16":  # the baseline's settings with a user's network that is not a plain stack
        from ablate.config import apply_knobs

        config = apply_knobs(config, {"model": f"{ROOT}/examples/models/residual.py:create_model"})
    config = replace(config, record_video=False, video_every=0, max_episodes=episodes, checkpoint_every=0)
    configs = [replace(config, seed=seed) for seed in range(members)]
    started = time.perf_counter()
    outcomes = run_population(configs)
    wall_s = time.perf_counter() - started
    digest = hashlib.sha1()
    for outcome in outcomes:
        for e in outcome.episodes:
            digest.update(repr((e.episode, e.episode_return, e.length, e.loss, e.entropy)).encode())
    steps = sum(o.env_steps for o in outcomes)
    print(json.dumps({"steps_per_s": steps / wall_s, "wall_s": wall_s, "digest": digest.hexdigest()[:16]}))


def _run(case: str, tree: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    command = [sys.executable, str(Path(__file__).resolve()), "--child", case]
    if _can_pin():
        command = ["taskset", "-c", "0", *command]
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=False, cwd=tree)
    if done.returncode != 0:
        raise RuntimeError(f"{case} in {tree} failed: {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


@functools.cache
def _can_pin() -> bool:
    return subprocess.run(["taskset", "-c", "0", "true"], capture_output=True, check=False).returncode == 0


def _worktree(ref: str) -> Path:
    folder = Path(tempfile.mkdtemp(prefix="ablate-before-"))
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(folder), ref], check=True,
                   capture_output=True)  # fmt: skip
    return folder


def bench_trainer(against: str = BEFORE_ONE_TRAINER, pairs: int = 5, cases: tuple[str, ...] = tuple(CASES)) -> None:
    """Each case ``pairs`` times here and at ``against``, alternating; medians of steps/s and of the ratios."""
    before = _worktree(against)
    figures: dict[str, object] = {"against": against, "pairs": pairs}
    try:
        for case in cases:
            trees = [("now", ROOT)] + ([("before", before)] if case not in CUSTOM else [])
            runs: dict[str, list[dict]] = {name: [] for name, _ in trees}
            for pair in range(pairs):
                for name, tree in trees if pair % 2 == 0 else trees[::-1]:  # alternate who goes first
                    runs[name].append(_run(case, tree))
            now = [r["steps_per_s"] for r in runs["now"]]
            figure = {"now_steps_per_s": now, "now_median": statistics.median(now)}
            line = f"trainer: {case}: now median {statistics.median(now):,.0f} env steps/s"
            if "before" in runs:
                then = [r["steps_per_s"] for r in runs["before"]]
                ratios = [a / b for a, b in zip(now, then, strict=True)]
                same = all(a["digest"] == b["digest"] for a, b in zip(runs["now"], runs["before"], strict=True))
                figure.update(before_steps_per_s=then, ratios=ratios, ratio_median=statistics.median(ratios))
                figure["same_runs"] = same
                line += (
                    f", {against} median {statistics.median(then):,.0f}; pair ratios "
                    f"{', '.join(f'{r:.2f}' for r in ratios)}, median {statistics.median(ratios):.2f}x; "
                    f"{'the same runs bit for bit' if same else 'the runs differ'}"
                )
            figures[case] = figure
            print(line, flush=True)
        for case in (c for c in CUSTOM if c in figures and "cartpole-16" in figures):
            ratio = figures[case]["now_median"] / figures["cartpole-16"]["now_median"]
            figures[f"{case}_over_default"] = ratio
            print(f"trainer: {case} (a user's network) runs {ratio:.2f}x the default population's env steps/s")
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(before)], check=False,
                       capture_output=True)  # fmt: skip
    RESULTS["trainer"] = figures


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        _child(sys.argv[2])
    else:
        bench_trainer(pairs=int(sys.argv[1]) if len(sys.argv) > 1 else 5)
