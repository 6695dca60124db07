"""`make bench` section `trainer`: this checkout's trainer against an earlier commit's, side by side in one run.

Machines of one kind differ 2-3x in speed, so a figure only means something against another measured in the same
run: each case runs in a fresh process pinned to one core, alternating this checkout and the earlier one (a git
worktree of ``--trainer-against``, by default the last commit before the stacked trainer), pair after pair. Each
pair also compares what the two computed (a digest of every episode's return, length, loss and entropy).

Cases (issue 45's goals): populations of 16 CartPole members of the built-in default (>= 0.8x the earlier
trainer), of a user's MLP of the default's shape written as its own class (``examples/models/mlp_class.py``,
>= 0.8x the built-in default), of ``examples/models/layernorm.py`` (>= 0.8x the default) and of ``residual.py``
(>= 1.5x its own speed before); one Breakout trial of the built-in ``cnn`` and of a user's CNN
(``examples/models/atari_cnn.py``); one Pong trial of each arm of ``pong.toml`` (>= 0.8x the earlier trainer).
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
BEFORE_STACKED = "16a33d5"
"""The last commit before the stacked trainer (issue 45): numpy acting stacks, each member's own module and Adam."""
MODELS = ROOT / "examples" / "models"

CASES = {
    "cartpole-16": ("experiments/cartpole.toml", "baseline", 16, 1024, None),
    "mlp-class-16": ("experiments/cartpole.toml", "baseline", 16, 1024, "mlp_class.py"),
    "layernorm-16": ("experiments/your-model.toml", "layernorm", 16, 1024, None),
    "residual-16": ("experiments/cartpole.toml", "baseline", 16, 1024, "residual.py"),
    "breakout-cnn": ("experiments/pong.toml", "cnn", 1, 8, "ALE/Breakout-v5"),
    "breakout-user-cnn": ("experiments/pong.toml", "cnn", 1, 8, "ALE/Breakout-v5 atari_cnn.py"),
    "pong-cnn": ("experiments/pong.toml", "cnn", 1, 20, None),
    "pong-mlp": ("experiments/pong.toml", "mlp", 1, 20, None),
}
"""name: (experiment file, variant, members, episodes per member, what replaces the variant's network or env:
a file in examples/models, an Atari env id, or both). A Pong trial plays 20 episodes (~20,000 steps, ~10 s on
one core): at 3 it was mostly its four emulators' setup (ale-py loads the ROM when an env is built and again at
its first seeded reset, ~0.07 s each), which a trial of the ablation's 300-400 episodes pays once."""
OVER_DEFAULT = {"mlp-class-16": "cartpole-16", "layernorm-16": "cartpole-16", "residual-16": "cartpole-16",
                "breakout-user-cnn": "breakout-cnn"}  # fmt: skip
"""Cases also measured against another case of this checkout (a user's network against the built-in one)."""
COSTS = ("acting_us", "update_us")
"""What ``_network_costs`` measures (microseconds of an acting step, of a member's update)."""


def _child(case: str) -> None:
    """Run one case in this process (``PYTHONPATH`` says whose ``ablate``) and print its figures as JSON."""
    import torch

    from ablate.experiment import load_experiment

    try:
        from ablate.agent.trainer import run_population
    except ImportError:  # before the one trainer
        from ablate.agent.population import run_population

    from ablate.config import apply_knobs

    torch.set_num_threads(1)
    path, variant, members, episodes, changes = CASES[case]
    config = {v.name: v for v in load_experiment(ROOT / path).variants}[variant].config
    for change in (changes or "").split():
        if change.endswith(".py"):  # the variant's settings with a user's network
            config = apply_knobs(config, {"model": f"{MODELS / change}:create_model"})
        else:
            config = apply_knobs(config, {"env_id": change, "action_set": "all"})  # Pong's two moves stay Pong's
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
    figures = {"steps_per_s": steps / wall_s, "wall_s": wall_s, "digest": digest.hexdigest()[:16]}
    if members > 1:
        figures.update(_network_costs(configs))
    print(json.dumps(figures))


def _network_costs(configs: list) -> dict[str, float]:
    """What the network costs, apart from how it learns: median microseconds of one acting step of every member
    (all of its slots, sampling included) and of one member's update on a fixed 512-step batch, on inputs drawn
    once. Env steps/s also moves with the learning: a network whose members solve sooner runs more of its
    steps in a smaller population, and one whose episodes differ more in length waits longer for its batch's
    last episode; these two figures do not. ``{}`` before the stacked trainer (``agent.stacking``)."""
    import importlib.util
    import inspect

    import numpy as np
    import torch

    if importlib.util.find_spec("ablate.agent.stacking") is None:
        return {}
    from ablate.agent.population import Population
    from ablate.agent.records import Batch
    from ablate.agent.reinforce import choose_action
    from ablate.envs import describe

    where = (torch.device("cpu"), [None] * len(configs))
    if "env" in inspect.signature(Population).parameters:  # since 686f41f the trainer hands the Described down
        population = Population(configs, describe(configs[0]), *where)
    else:
        population = Population(configs, *where)
    try:
        for position in range(len(configs)):
            population.start(position)
        observations = population.slots.observations()
        observations = observations.reshape(len(configs), -1, *observations.shape[1:])
        rng = np.random.default_rng(0)
        uniforms = rng.random(observations.shape[:2])

        def act() -> None:
            choose_action(population.network, observations, single=False, uniforms=uniforms)

        steps = 512
        batch = Batch(
            np.array([steps]),
            np.array([float(steps)]),
            rng.standard_normal((steps, *observations.shape[2:])).astype(np.float32),
            rng.integers(0, population.env.n_actions, steps),
            rng.standard_normal(steps).astype(np.float32),
        )

        def update() -> None:
            for position in range(len(configs)):
                population.update({position: batch})

        acting_us, update_us = _median_us(act, 500, per_call=1), _median_us(update, 5, per_call=len(configs))
        return dict(zip(COSTS, (acting_us, update_us), strict=True))
    finally:
        population.close()


def _median_us(function, calls: int, per_call: int, repeats: int = 5) -> float:
    """Median over ``repeats`` blocks of ``calls`` calls (after one warm-up block) of microseconds per unit of work
    (``per_call`` units a call)."""
    times = []
    for block in range(repeats + 1):
        started = time.perf_counter()
        for _ in range(calls):
            function()
        if block:
            times.append((time.perf_counter() - started) / calls / per_call * 1e6)
    return statistics.median(times)


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


def bench_trainer(against: str = BEFORE_STACKED, pairs: int = 5, cases: tuple[str, ...] = tuple(CASES)) -> None:
    """Each case ``pairs`` times here and at ``against``, alternating; medians of steps/s and of the ratios."""
    before = _worktree(against)
    figures: dict[str, object] = {"against": against, "pairs": pairs}
    try:
        for case in cases:
            trees = [("now", ROOT), ("before", before)]
            runs: dict[str, list[dict]] = {name: [] for name, _ in trees}
            for pair in range(pairs):
                for name, tree in trees if pair % 2 == 0 else trees[::-1]:  # alternate who goes first
                    runs[name].append(_run(case, tree))
            now = [r["steps_per_s"] for r in runs["now"]]
            figure = {"now_steps_per_s": now, "now_median": statistics.median(now)}
            for measure in COSTS:  # the network's own cost, where this checkout's child measured it
                if all(measure in r for r in runs["now"]):
                    figure[f"now_{measure}"] = statistics.median(r[measure] for r in runs["now"])
            figure["before_median"] = statistics.median(r["steps_per_s"] for r in runs["before"])
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
        for case, default in OVER_DEFAULT.items():
            if case in figures and default in figures:
                for when in ("now", "before"):
                    ratio = figures[case][f"{when}_median"] / figures[default][f"{when}_median"]
                    figures[case][f"{when}_over_{default}"] = ratio
                    print(f"trainer: {case} (a user's network) {when}: {ratio:.2f}x {default}'s env steps/s")
                costs = {
                    measure: figures[case][f"now_{measure}"] / figures[default][f"now_{measure}"]
                    for measure in COSTS
                    if f"now_{measure}" in figures[case] and f"now_{measure}" in figures[default]
                }
                if costs:
                    figures[case][f"cost_over_{default}"] = costs
                    print(
                        f"trainer: {case} (a user's network) now: an acting step {costs['acting_us']:.2f}x, a "
                        f"member's update {costs['update_us']:.2f}x {default}'s time (the network's cost alone)"
                    )
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(before)], check=False,
                       capture_output=True)  # fmt: skip
    RESULTS["trainer"] = figures


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        _child(sys.argv[2])
    else:
        bench_trainer(pairs=int(sys.argv[1]) if len(sys.argv) > 1 else 5)
