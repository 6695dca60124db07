"""Measure the claims rule on real seeds: a large pool of seeds per variant of an experiment, trained by the
population trainer directly (no launch, no store), then

- ``advice``: the seeds advice's calibration: draw a small experiment (n0 seeds a side) of a variant against its
  reference from the pool, predict N (``claims.advice.seeds_needed`` at the family's level), draw N fresh seeds a
  side from the rest of the pool and judge them as a fixed design; the share decided at N should be the stated
  ``advice.POWER``.
- ``aa``: the A/A false-claim share of the experiment's design (its seed rounds, its family of comparisons): every
  "variant" dealt from the reference's pool, judged by ``claims.decide`` as ``ablate.load(...).claims`` and the
  report judge them; where a report needs more seeds than the pool holds, each side draws with replacement from
  it (every side then samples one distribution, so the null holds exactly).

    .venv/bin/python tools/seed_advice.py pool experiments/cartpole.toml --variants baseline,deep --seeds 2048
    .venv/bin/python tools/seed_advice.py advice experiments/cartpole.toml --variants deep,wide,narrow
    .venv/bin/python tools/seed_advice.py aa experiments/cartpole.toml --reports 200
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ablate.claims import (  # noqa: E402
    BETTER,
    EQUIVALENT,
    UNDETERMINED,
    WORSE,
    Design,
    Sample,
    advice,  # noqa: E402
    decide,
    primary_question,
)
from ablate.claims.family import _claim, _estimate, _Open  # noqa: E402
from ablate.claims.permutation import p_values, permutations_for  # noqa: E402
from ablate.design import CONFIDENCE  # noqa: E402
from ablate.experiment import load_experiment  # noqa: E402
from ablate.measures import area_under_curve  # noqa: E402

POOL_SEED = 100_000
"""The pool's seeds start here: above the evaluation (0 up), tuning (10,000 up) and A/A (20,000 up) seeds."""


def build_pool(
    experiment_path: str, variants: list[str], seeds: int, folder: Path, rates: dict[str, float], chunk: int = 64
) -> None:
    """Train ``seeds`` seeds of each variant (at its learning rate in ``rates``, the one its tuning chose, else its
    own) into
    ``folder/<variant>.jsonl``, resuming where a file stops."""
    from ablate.agent.trainer import run_population

    experiment = load_experiment(experiment_path)
    by_name = {v.name: v for v in experiment.variants}
    folder.mkdir(parents=True, exist_ok=True)
    for name in variants:
        path = folder / f"{name}.jsonl"
        done = sum(1 for _ in path.open()) if path.exists() else 0
        with path.open("a") as out:
            for first in range(POOL_SEED + done, POOL_SEED + seeds, chunk):
                configs = [
                    replace(
                        by_name[name].config,
                        seed=s,
                        record_video=False,
                        learning_rate=rates.get(name, by_name[name].config.learning_rate),
                    )
                    for s in range(first, min(first + chunk, POOL_SEED + seeds))
                ]
                started = time.perf_counter()
                outcomes = run_population(configs)
                for config, outcome in zip(configs, outcomes, strict=True):
                    curve = [m.rolling_mean for m in outcome.episodes]
                    row = {
                        "variant": name,
                        "seed": config.seed,
                        "solved": outcome.solved,
                        "episodes_to_solve": outcome.episodes_to_solve,
                        "budget": config.max_episodes,
                        "auc": area_under_curve(curve, config.max_episodes),
                        "env_steps": outcome.env_steps,
                    }
                    out.write(json.dumps(row) + "\n")
                out.flush()
                print(f"{name} seeds {first}+{len(configs)}: {time.perf_counter() - started:.1f} s", flush=True)


def load_pool(folder: Path, name: str) -> Sample:
    rows = [json.loads(line) for line in (folder / f"{name}.jsonl").open()]
    solved = np.array([r["solved"] for r in rows], bool)
    episodes = np.array([r["episodes_to_solve"] if r["solved"] else r["budget"] for r in rows], float)
    return Sample(episodes, ~solved, np.array([r["auc"] for r in rows], float))


def _take(sample: Sample, index: np.ndarray) -> Sample:
    return Sample(sample.values[index], sample.censored[index], sample.fallback[index])


def _decided_fixed(x: Sample, y: Sample, question, level: float) -> bool:
    """Does a fixed design decide x against y at ``level`` (the family's rule for one comparison)?"""
    item = _Open(("x", "y"), x, y)
    x, y = item.sides(question, x, y)
    item.x, item.y = x, y
    item.p_diff, item.p_eq = p_values(x, y, item.question, permutations_for(level))
    estimate = _estimate(x, y, item.question)
    item.better = (estimate < 0) == item.question.lower_is_better if estimate else False
    return _claim(item, level, level) != UNDETERMINED


def advice_table(experiment_path: str, folder: Path, variants: list[str], draws: int, starts: list[int]) -> None:
    experiment = load_experiment(experiment_path)
    question = primary_question(experiment.primary_metric, experiment.smallest_effect, experiment.base.max_episodes)
    k = len(experiment.variants) - 1
    level = 0.05 / k
    reference = load_pool(folder, experiment.baseline)
    rng = np.random.default_rng(55)
    rows = []
    for name in variants:
        pool = load_pool(folder, name)
        for n0 in starts:
            for _ in range(draws):
                px, py = rng.permutation(len(pool)), rng.permutation(len(reference))
                x0, y0 = _take(pool, px[:n0]), _take(reference, py[:n0])
                if _decided_fixed(x0, y0, question, level):
                    continue  # already decided: no advice given
                item = _Open(("x", "y"), x0, y0)
                x1, y1 = item.sides(question, x0, y0)
                needed = advice.seeds_needed(x1, y1, item.question, level)
                room = min(len(pool), len(reference)) - n0
                if needed is None or needed > room:
                    rows.append((name, n0, needed, None))
                    continue
                fresh = _decided_fixed(
                    _take(pool, px[n0 : n0 + needed]), _take(reference, py[n0 : n0 + needed]), question, level
                )
                rows.append((name, n0, needed, fresh))
    print(f"level {level:.4f} ({k} comparisons), stated share {advice.POWER:.0%}")
    print("| start seeds | advice given | checkable (N within the pool) | decided at N | share [95% CI] | median N |")
    print("| --- | --- | --- | --- | --- | --- |")
    for n0 in starts + [0]:
        group = [r for r in rows if r[1] == n0 or n0 == 0]
        checked = [r for r in group if r[3] is not None]
        hits = sum(r[3] for r in checked)
        low, high = wilson(hits, len(checked))
        median = int(np.median([r[2] for r in checked])) if checked else 0
        label = "all" if n0 == 0 else str(n0)
        print(
            f"| {label} | {len(group)} | {len(checked)} | {hits} | {hits / max(len(checked), 1):.2f} "
            f"[{low:.2f}, {high:.2f}] | {median} |"
        )


def wilson(hits: int, n: int) -> tuple[float, float]:
    """The 95% Wilson interval of ``hits`` in ``n`` (SciPy's, as ``ablate calibrate`` gives it); NaN for none."""
    if n == 0:
        return float("nan"), float("nan")
    interval = stats.binomtest(hits, n).proportion_ci(CONFIDENCE, method="wilson")
    return interval.low, interval.high


def aa_share(experiment_path: str, folder: Path, reports: int) -> None:
    experiment = load_experiment(experiment_path)
    question = primary_question(experiment.primary_metric, experiment.smallest_effect, experiment.base.max_episodes)
    design = Design.of(experiment.rounds) if experiment.rounds else Design.fixed(len(experiment.seeds))
    pool = load_pool(folder, experiment.baseline)
    variants = len(experiment.variants)
    seeds = design.looks[-1]
    with_replacement = len(pool) < variants * seeds
    references = {f"v{i}": "v0" for i in range(1, variants)}
    rng = np.random.default_rng(2025)
    claimed = equivalent = 0
    looks: list[int] = []
    started = time.perf_counter()
    for _ in range(reports):
        if with_replacement:
            order = rng.integers(0, len(pool), (variants, seeds))
        else:
            order = rng.permutation(len(pool))[: variants * seeds].reshape(variants, seeds)
        samples = {f"v{i}": _take(pool, order[i]) for i in range(variants)}
        result = decide(samples, references, question, design, intervals=False, estimate_seeds=False)
        claimed += any(v.verdict in (BETTER, WORSE) for v in result.verdicts)
        equivalent += any(v.verdict == EQUIVALENT for v in result.verdicts)
        looks.append(max(v.look for v in result.verdicts) + 1)
    low, high = wilson(claimed, reports)
    print(
        f"A/A: {reports} reports of {variants} identical variants ({experiment.baseline}), looks {design.looks}, "
        f"pool {len(pool)} seeds ({'with' if with_replacement else 'without'} replacement): "
        f"{claimed} claim a difference = {claimed / reports:.1%} [95% CI {low:.1%}, {high:.1%}]; "
        f"{equivalent} decide an equivalence; median last look {int(np.median(looks))} "
        f"({time.perf_counter() - started:.0f} s)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=("pool", "advice", "aa"))
    parser.add_argument("experiment")
    parser.add_argument("--folder", type=Path, default=Path("outputs/seed-pool"))
    parser.add_argument("--variants", default="")
    parser.add_argument("--seeds", type=int, default=1024, help="pool: seeds per variant")
    parser.add_argument("--draws", type=int, default=60, help="advice: small experiments per variant and start")
    parser.add_argument("--starts", default="10,20,40", help="advice: seeds a side of the small experiments")
    parser.add_argument("--reports", type=int, default=200, help="aa: A/A reports")
    parser.add_argument(
        "--learning-rates", default="", help="pool: the rates tuning chose, e.g. baseline=0.1,deep=0.03 (claims.csv)"
    )
    args = parser.parse_args()
    names = [v for v in args.variants.split(",") if v]
    if args.command == "pool":
        rates = {k: float(v) for k, v in (p.split("=") for p in args.learning_rates.split(",") if p)}
        build_pool(args.experiment, names, args.seeds, args.folder, rates)
    elif args.command == "advice":
        advice_table(args.experiment, args.folder, names, args.draws, [int(s) for s in args.starts.split(",")])
    else:
        aa_share(args.experiment, args.folder, args.reports)


if __name__ == "__main__":
    main()
