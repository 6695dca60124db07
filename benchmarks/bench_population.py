"""`make bench` sections on populations: `population` (a population's env steps/s as it grows from 16 to 1,024
members; CartPole populations against one trial; the same results), `seeds` (the tuned default ablation at 4x its
seeds in populations against today's launch).

`python benchmarks/bench_population.py scaling [--against REF] [--repeats N] [--members 16,64,256,1024]` prints
the growth table alone (with ``--against``, beside a git ref's trainer in the same run).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch
from bench_estimate import _eta_figure
from bench_results import RESULTS

from ablate.agent.trainer import run_trial
from ablate.config import DEFAULT


def _population_speed(configs: list) -> tuple[float, float, float, list]:
    """The same trials one at a time and as one population, on one core: (steps/s alone, steps/s together,
    s together, (alone, member) outcome pairs)."""
    from ablate.agent.trainer import run_population

    started = time.perf_counter()
    alone = [run_trial(c) for c in configs]
    alone_s = time.perf_counter() - started
    started = time.perf_counter()
    together = run_population(configs)
    together_s = time.perf_counter() - started
    steps = sum(o.env_steps for o in alone)
    return (
        steps / alone_s,
        sum(o.env_steps for o in together) / together_s,
        together_s,
        list(zip(alone, together, strict=True)),
    )


def _variant_config(variant: str | None, path: str = "experiments/cartpole.toml"):
    """``variant``'s trial config in ``path`` (its base with its overrides), no video; ``None``: ``DEFAULT``."""
    if variant is None:
        return replace(DEFAULT, record_video=False)
    from ablate.experiment import load_experiment

    variants = {v.name: v for v in load_experiment(path).variants}
    if variant not in variants:
        raise SystemExit(f"--population-variant: {variant!r} is not a variant of {path}; valid: {', '.join(variants)}")
    return replace(variants[variant].config, record_video=False)


ROOT = Path(__file__).resolve().parent.parent
SCALING_MEMBERS = (16, 64, 256, 1024)
SCALING_EPISODES = 256
"""Issue 55's measure: the default config, 256 episodes a member, seeds 0..M-1; no size below 0.9x of 16's."""


def _scaling_child(members: int, episodes: int) -> None:
    """One population of ``members`` default trials (seeds 0..M-1, ``episodes`` each) in this process
    (``PYTHONPATH`` says whose ``ablate``); prints its env steps, CPU and wall seconds and a digest of every
    member's episodes (return, length, loss, entropy) and episodes to solve, as JSON."""
    from ablate.agent.trainer import run_population
    from ablate.config import DEFAULT

    configs = [replace(DEFAULT, record_video=False, max_episodes=episodes, seed=seed) for seed in range(members)]
    cpu, wall = time.process_time(), time.perf_counter()
    outcomes = run_population(configs)
    cpu_s, wall_s = time.process_time() - cpu, time.perf_counter() - wall
    digest = hashlib.sha1()
    for outcome in outcomes:
        digest.update(repr(outcome.episodes_to_solve).encode())
        for e in outcome.episodes:
            digest.update(repr((e.episode, e.episode_return, e.length, e.loss, e.entropy)).encode())
    steps = sum(o.env_steps for o in outcomes)
    print(json.dumps({"steps": steps, "cpu_s": cpu_s, "wall_s": wall_s, "digest": digest.hexdigest()[:16]}))


def _one_core() -> list[str]:
    """``taskset`` onto this process's last allowed core (``[]`` where there is none to pin to)."""
    core = max(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    if core is None or subprocess.run(["taskset", "-c", str(core), "true"], capture_output=True).returncode:
        return []
    return ["taskset", "-c", str(core)]


def _scaling_run(members: int, episodes: int, tree: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    command = [*_one_core(), sys.executable, str(Path(__file__).resolve()), "--scaling-child", str(members)]
    done = subprocess.run([*command, str(episodes)], env=env, capture_output=True, text=True, cwd=tree, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{members} members in {tree} failed: {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def bench_scaling(
    members: tuple[int, ...] = SCALING_MEMBERS,
    episodes: int = SCALING_EPISODES,
    repeats: int = 3,
    against: str | None = None,
) -> dict:
    """Env steps/s per core (per CPU second of one pinned core) of a population of M default trials, M in
    ``members`` (the first is the base), each in a fresh process, ``repeats`` times, the sizes in turn (up, then
    down); with ``against`` (a git ref) that ref's trainer too, alternating with this checkout's at every size.
    Prints the table "members | env steps/s per core | ratio to 16": medians over the repeats, and the ratio
    to the base size's rate in the same repeat (its median, then each repeat's)."""
    from bench_trainer import _worktree

    trees = [("now", ROOT)]
    if against:
        trees.append((against, _worktree(against)))
    runs: dict[str, dict[int, list[dict]]] = {name: {m: [] for m in members} for name, _ in trees}
    try:
        for repeat in range(repeats):
            for m in members if repeat % 2 == 0 else members[::-1]:
                for name, tree in trees if repeat % 2 == 0 else trees[::-1]:
                    run = _scaling_run(m, episodes, tree)
                    runs[name][m].append(run)
                    print(
                        f"  repeat {repeat} {name} M={m}: {run['steps'] / run['cpu_s']:,.0f} env steps/s per core "
                        f"({run['steps']:,} steps, {run['cpu_s']:.1f} s CPU, {run['wall_s']:.1f} s wall)",
                        flush=True,
                    )
    finally:
        for _, tree in trees[1:]:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], capture_output=True)
    base = members[0]
    figures: dict[str, object] = {"episodes": episodes, "repeats": repeats}
    for name, _ in trees:
        rates = {m: [r["steps"] / r["cpu_s"] for r in runs[name][m]] for m in members}
        ratios = {m: [a / b for a, b in zip(rates[m], rates[base], strict=True)] for m in members}
        figures[name] = {
            m: {"steps_per_cpu_s": statistics.median(rates[m]), "ratio": statistics.median(ratios[m]),
                "ratios": ratios[m], "digest": runs[name][m][0]["digest"]}
            for m in members
        }  # fmt: skip
        print(f"scaling ({name}): {episodes} episodes a member, medians of {repeats}, one core")
        print(f"  members | env steps/s per core | ratio to {base}")
        for m in members:
            each = ", ".join(f"{r:.2f}" for r in ratios[m])
            print(f"  {m:>7} | {statistics.median(rates[m]):>20,.0f} | {statistics.median(ratios[m]):.2f}x ({each})")
    for m in members:
        digests = {r["digest"] for name, _ in trees for r in runs[name][m]}
        figures[f"same_runs_M={m}"] = len(digests) == 1
        print(f"scaling: M={m}: {'every run the same, bit for bit' if len(digests) == 1 else 'the runs differ'}")
    return figures


def bench_population(
    repeats: int = 3,
    members: tuple[int, ...] = (16, 64),
    budget: int = 1024,
    seeds: int = 32,
    variant: str | None = None,
    scaling: tuple[int, ...] = SCALING_MEMBERS,
) -> None:
    """First a population's env steps/s per core as it grows (``bench_scaling`` at ``scaling``, ``repeats``
    times; ``()``: skipped). Then CartPole env steps/s per core of a population of M default trials
    (``agent.trainer``) against the same M trials run one at a time, in this run, medians of ``repeats``
    (issue 26's goal at M = 16: >= 8x); then the science: over ``seeds`` seeds at the default budget, each
    member's whole run against its trial's, and episodes to solve and AUC compared by a two-sample test
    (Mann-Whitney U). ``variant``: that variant of experiments/cartpole.toml instead of the default trial (``cnn``,
    say)."""
    from scipy.stats import mannwhitneyu

    figures: dict[str, object] = {"variant": variant or "default"}
    if scaling:
        figures["scaling"] = bench_scaling(scaling, repeats=repeats)
    torch.set_num_threads(1)
    base = _variant_config(variant)
    for m in members:
        single, population, ratios = [], [], []
        for repeat in range(repeats):
            configs = [replace(base, seed=1000 * repeat + i, max_episodes=budget) for i in range(m)]
            one, many, wall, _ = _population_speed(configs)
            single.append(one)
            population.append(many)
            ratios.append(many / one)
            print(
                f"  M={m} repeat {repeat}: one at a time {one:10,.0f} steps/s | population {many:10,.0f} steps/s "
                f"({wall:.1f} s) | ratio {ratios[-1]:.1f}x",
                flush=True,
            )
        print(
            f"population: {m} trials one at a time median {statistics.median(single):,.0f} steps/s/core; as a "
            f"population median {statistics.median(population):,.0f} steps/s/core; ratio median "
            f"{statistics.median(ratios):.1f}x"
        )
        figures[f"M={m}"] = {"alone": single, "population": population, "ratio_median": statistics.median(ratios)}
    if seeds:
        configs = [replace(base, seed=seed) for seed in range(seeds)]
        pairs = [pair for i in range(0, seeds, 16) for pair in _population_speed(configs[i : i + 16])[3]]
        identical = sum([m[:7] for m in a.episodes] == [m[:7] for m in b.episodes] for a, b in pairs)
        for metric in ("episodes_to_solve", "auc"):
            alone = [a.summary().get(metric, base.max_episodes + 1) for a, _ in pairs]
            together = [b.summary().get(metric, base.max_episodes + 1) for _, b in pairs]
            p_value = float(mannwhitneyu(together, alone).pvalue)
            figures[metric] = {
                "population": statistics.median(together),
                "alone": statistics.median(alone),
                "p": p_value,
            }
            print(
                f"population: {metric} over {seeds} seeds: in populations of 16 median "
                f"{statistics.median(together):.1f}, "
                f"one at a time median {statistics.median(alone):.1f}; Mann-Whitney p = {p_value:.2f}"
            )
        print(f"population: {identical}/{seeds} members' whole runs identical to their trials' (episodes, losses)")
        figures["identical_runs"] = identical
    RESULTS["population"] = figures


def bench_seeds(factor: int = 4, cap: int = 16, path: str = "experiments/cartpole.toml", seeds: int = 5) -> None:
    """The tuned default ablation on ``seeds`` evaluation seeds, each trial alone (the 5-seed launch of issue 26),
    against the same file at ``factor`` times the seeds with ``--population cap``, one after the other into fresh
    stores on one running Ray (the tuning stage included); the goal is no more wall time. Both run a fixed count
    of seeds (the file's own ``seeds``, rounds or not, is replaced). Time-left estimates scored as in ``eta``."""
    import re
    import shutil
    import tempfile

    from ablate.experiment import load_experiment
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan
    from ablate.launch.scheduler import ensure_ray

    ensure_ray(None)
    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-"))
    text = Path(path).read_text()
    for kind, count in (("today", seeds), ("more", factor * seeds)):
        fixed = re.sub(r"(?m)^seeds = .*$", f"seeds = {count}", text, count=1)
        assert fixed != text or f"seeds = {count}" in text, f"{path}: no top-level 'seeds = ...' line"
        (folder / f"{kind}.toml").write_text(fixed)
    figures: dict[str, dict] = {}
    try:
        for kind, population in (("today", 1), ("more", cap)):
            store = folder / kind
            store.mkdir()
            started = time.monotonic()
            outcome = run_plan(
                LaunchPlan(
                    load_experiment(folder / f"{kind}.toml"),
                    tracking_uri=f"sqlite:///{store / 'mlflow.db'}",
                    storage_path=str(folder / "ray"),
                    show_progress=False,
                    started_at=started,
                    log_estimates=True,
                    population=population,
                )
            )
            wall = time.monotonic() - started
            assert outcome.exit_code == 0 and outcome.view is not None, outcome.failed
            figures[kind] = {"wall_s": wall, "trials": len(outcome.finished), "population": population}
            figures[kind]["eta"] = _eta_figure(f"{kind} launch", outcome.view)
            print(f"  {kind}: {len(outcome.finished)} trials, --population {population}: {wall:.0f} s", flush=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    today, more = figures["today"], figures["more"]
    print(
        f"seeds: {path} tuned, {seeds} seeds alone {today['wall_s']:.0f} s ({today['trials']} trials); "
        f"{factor * seeds} seeds in populations of up to {cap} {more['wall_s']:.0f} s ({more['trials']} trials): "
        f"{more['wall_s'] / today['wall_s']:.2f}x the wall time (goal <= 1)"
    )
    RESULTS["seeds"] = figures


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--scaling-child":
        _scaling_child(int(sys.argv[2]), int(sys.argv[3]))
    else:
        parser = argparse.ArgumentParser(description="A population's env steps/s per core as it grows.")
        parser.add_argument("what", choices=["scaling"])
        parser.add_argument("--against", help="a git ref whose trainer runs beside this checkout's")
        parser.add_argument("--repeats", type=int, default=3)
        parser.add_argument("--episodes", type=int, default=SCALING_EPISODES)
        parser.add_argument("--members", default=",".join(map(str, SCALING_MEMBERS)))
        args = parser.parse_args()
        members = tuple(int(m) for m in args.members.split(","))
        RESULTS["scaling"] = bench_scaling(members, args.episodes, args.repeats, args.against)
