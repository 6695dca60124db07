"""`make bench` sections on populations: `population` (CartPole populations against one trial; the same
results), `seeds` (the tuned default ablation at 4x its seeds in populations against today's launch)."""

from __future__ import annotations

import statistics
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


def bench_population(
    repeats: int = 3,
    members: tuple[int, ...] = (16, 64),
    budget: int = 1024,
    seeds: int = 32,
    variant: str | None = None,
) -> None:
    """CartPole env steps/s per core of a population of M default trials (``agent.trainer``) against the same
    M trials run one at a time, in this run, medians of ``repeats`` (issue 26's goal at M = 16: >= 8x); then
    the science: over ``seeds`` seeds at the default budget, each member's whole run against its trial's, and
    episodes to solve and AUC compared by a two-sample test (Mann-Whitney U). ``variant``: that variant of
    experiments/cartpole.toml instead of the default trial (``cnn``, say)."""
    from scipy.stats import mannwhitneyu

    torch.set_num_threads(1)
    base = _variant_config(variant)
    figures: dict[str, object] = {"variant": variant or "default"}
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
    from ablate.launch.runner import run_experiment
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
            outcome = run_experiment(
                load_experiment(folder / f"{kind}.toml"),
                tracking_uri=f"sqlite:///{store / 'mlflow.db'}",
                storage_path=str(folder / "ray"),
                show_progress=False,
                started_at=started,
                log_estimates=True,
                population=population,
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
