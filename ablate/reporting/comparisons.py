"""Each variant against its reference on each metric: the estimate, its 95% interval, the verdict and whether
it survives leaving out any one seed (the report's findings and ``tables/comparisons.csv``)."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pandas as pd

from ablate.claims import Design, Question, Round, Sample, decide
from ablate.claims import primary_question as claims_question
from ablate.measures import AUC, EPISODES_TO_SOLVE, episodes_to, is_censored, measure, return_at
from ablate.reporting.results import Ablation
from ablate.reporting.statistics import (
    CONFIDENCE,
    SEEDS_CAP,
    SEPARATED,
    exploratory_comparison,
    iqm,
    probability_of_improvement_interval,
    seeds_needed,
    smallest_p_value,
)

COLUMNS = ["variant", "metric", "point", "low", "high", "verdict", "bound", "variant_value", "reference_value"]
COLUMNS += ["fragile_seeds", "n_variant", "n_reference", "loo_checked", "seeds_needed", "seeds_needed_smallest"]
"""A row of ``results.comparisons`` (docs/python.md describes each column; ``point``/``low``/``high``: positive is
better); the report's columns follow (``comparisons``)."""
P_IMPROVEMENT = ("p_improvement", "p_improvement_ci_low", "p_improvement_ci_high")


LOO_MAX_SEEDS = 50
"""The leave-one-seed-out check is made where each side has at most this many seeds: beyond, one seed is under 2%
of its sample, and the check (a bootstrap per seed: 640 for 640 seeds) cost the report minutes."""


def compare_metric(ablation: Ablation, variant: str, metric: str, stability: bool = True, power: bool = True) -> dict:
    """``variant`` against its reference on ``metric`` (a row of ``COLUMNS``), with a leave-one-seed-out check of
    the verdict."""
    done, reference, entry = ablation.finished, ablation.reference(variant), measure(metric)

    def samples(frame: pd.DataFrame):
        v, b = frame[frame.variant == variant], frame[frame.variant == reference]
        x, y = v[entry.column].to_numpy(float), b[entry.column].to_numpy(float)
        if entry.reached is None:
            return x, y, None, None
        return x, y, (v[entry.reached] != 1).to_numpy(), (b[entry.reached] != 1).to_numpy()

    x, y, x_cens, y_cens = samples(done)
    point, low, high, verdict, bound = exploratory_comparison(x, y, x_cens, y_cens)
    needed = smallest = np.nan
    if power and verdict not in SEPARATED and bound != "censored" and min(len(x), len(y)) >= 2:
        relative = x_cens is not None
        needed = seeds_needed(x, y, relative, x_cens, y_cens)
        smallest = seeds_needed(x, y, relative, x_cens, y_cens, effect=ablation.smallest_effect)
    fragile: list[int] = []
    loo_checked = smallest_p_value(len(x) - 1, len(y) - 1) <= 1 - CONFIDENCE and max(len(x), len(y)) <= LOO_MAX_SEEDS
    if stability and verdict in SEPARATED and loo_checked:
        for seed in sorted(set(done.seed)):
            if exploratory_comparison(*samples(done[done.seed != seed]))[3] != verdict:
                fragile.append(int(seed))
    row = {
        "variant": variant,
        "metric": metric,
        "point": point,
        "low": low,
        "high": high,
        "verdict": verdict,
        "bound": bound,
        "variant_value": float(iqm(x)) if len(x) else np.nan,
        "reference_value": float(iqm(y)) if len(y) else np.nan,
        "fragile_seeds": " ".join(map(str, fragile)),
        "n_variant": len(x),
        "n_reference": len(y),
        "loo_checked": loo_checked,  # False also where a side has more than LOO_MAX_SEEDS seeds: no check made
        "seeds_needed": needed,  # statistics.seeds_needed: SEEDS_CAP + 1 is more than the cap, inf in the table
        "seeds_needed_smallest": smallest,
    }
    if metric == EPISODES_TO_SOLVE.name:
        row |= zip(P_IMPROVEMENT, probability_of_improvement_interval(x, y), strict=True)
    return row


def comparison_metrics(ablation: Ablation) -> list[str]:
    """Which metrics the findings rest on: episodes to solve where a threshold exists and some seed solved;
    always the area under the curve and the return after the whole budget; episodes to reach the env's
    return levels where no seed solved."""
    metrics = [EPISODES_TO_SOLVE] if ablation.any_solved else []
    metrics.append(AUC)
    if ablation.budgets:
        metrics.append(return_at(ablation.budgets[-1]))
    if not ablation.any_solved:
        metrics += [episodes_to(level) for level in ablation.levels]
    return [m.name for m in metrics if m is EPISODES_TO_SOLVE or m.column in ablation.trials]


def comparisons(
    ablation: Ablation, stability: bool = True, power: bool = True, claims: pd.DataFrame | None = None
) -> pd.DataFrame:
    """Each variant against its reference on each metric of ``comparison_metrics``: ``results.comparisons``.
    ``claims``: the claims table (``claims_table``), whose verdicts and seeds the primary rows carry."""
    if claims is None:
        claims = claims_table(ablation, primary_claims(ablation, estimate_seeds=power))
    claimed = {(r.variant, r.reference): r for r in claims.itertuples()}
    done = ablation.finished
    rows = []
    for variant in ablation.variants:
        if variant == ablation.baseline:
            continue
        if not (done.variant == variant).any() or not (done.variant == ablation.reference(variant)).any():
            continue
        for metric in comparison_metrics(ablation):
            claim = claimed.get((variant, ablation.reference(variant))) if metric == ablation.primary_metric else None
            row = compare_metric(ablation, variant, metric, stability, power and claim is None)
            row["reference"] = ablation.reference(variant)
            row["primary"] = claim is not None
            row["claim"] = claim.verdict if claim is not None else ""
            if claim is not None:  # the claims' seeds, not a second estimate beside them
                row["seeds_needed"], row["seeds_needed_smallest"] = claim.seeds_needed, np.nan
                row["seeds_cap"] = claim.seeds_cap
            rows.append(row)
    columns = [*COLUMNS, "reference", "primary", "claim", *P_IMPROVEMENT, "seeds_cap"]
    frame = pd.DataFrame(rows, columns=columns)
    frame["primary"] = frame.primary.astype(bool)
    return in_report_units(frame)


CHANGE_UNITS = {
    True: "% episodes (variant against reference; + is more episodes)",
    False: "return (variant minus reference; + is higher)",
}


def in_report_units(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with ``change``, ``change_low``, ``change_high`` and ``change_unit`` (the report's sign and units)
    beside ``point``/``low``/``high``, and ``seeds_needed`` past ``seeds_cap`` as ``inf``."""
    frame = frame.copy()
    episodes = np.asarray([is_censored(str(m)) for m in frame.metric], bool)
    point, low, high = (pd.to_numeric(frame[c], errors="coerce").to_numpy(float) for c in ("point", "low", "high"))
    frame["change"] = np.where(episodes, -100 * point, point)
    frame["change_low"] = np.where(episodes, -100 * high, low)
    frame["change_high"] = np.where(episodes, -100 * low, high)
    frame["change_unit"] = [CHANGE_UNITS[bool(e)] for e in episodes]
    cap = pd.to_numeric(frame.get("seeds_cap", pd.Series(np.nan, frame.index)), errors="coerce").fillna(SEEDS_CAP)
    frame["seeds_cap"] = cap.astype(int)  # the exploratory rule's cap; a primary row's is the claims'
    for column in ("seeds_needed", "seeds_needed_smallest"):
        values = pd.to_numeric(frame[column], errors="coerce")
        frame[column] = values.where(~(values > cap), np.inf)
    return frame


def primary_question(ablation: Ablation) -> Question:
    """What the primary claims ask (``claims.primary_question``), censored at the longest budget that finished."""
    budget = float(ablation.finished.budget.max()) if len(ablation.finished) else None
    return claims_question(ablation.primary_metric, ablation.smallest_effect, budget)


def _claim_samples(ablation: Ablation, question: Question) -> dict[str, Sample]:
    """Each variant's values on the primary metric in seed order (what ``decide`` reads the looks from)."""
    done = ablation.finished.sort_values("seed")
    samples = {}
    for variant in ablation.variants:
        rows, entry = done[done.variant == variant], measure(question.metric)
        if entry.reached is not None:
            values, censored = rows[entry.column].to_numpy(float), (rows[entry.reached] != 1).to_numpy()
            samples[variant] = Sample(values, censored, rows[AUC.column].to_numpy(float))
        elif entry.column in rows:
            samples[variant] = Sample(rows[entry.column].to_numpy(float))
    return samples


def primary_claims(ablation: Ablation, intervals: bool = True, estimate_seeds: bool = True) -> Round:
    """Every variant against its reference on the primary metric, as one family (``ablate.claims.decide``),
    judged as a fixed design at the seeds that finished: each verdict with its interval and, where
    undetermined, the seeds per variant it would take."""
    question = primary_question(ablation)
    samples = _claim_samples(ablation, question)
    references = {
        v: ablation.reference(v)
        for v in ablation.variants
        if v != ablation.baseline and v in samples and ablation.reference(v) in samples and len(samples[v])
    }
    design = claims_design(ablation)
    return decide(samples, references, question, design, intervals=intervals, estimate_seeds=estimate_seeds)


def claims_design(ablation: Ablation) -> Design:
    """The looks the claims are judged at: the launch's seed rounds (``rounds.json``), replayed as the runner
    judged them; else one look at the seeds that finished (a fixed design)."""
    rounds = (ablation.launch.get("rounds") or {}).get("design") if isinstance(ablation.launch, dict) else None
    if rounds:
        return Design.of(rounds)
    done = ablation.finished
    seeds = int(done.groupby("variant").size().max()) if len(done) else 1
    return Design.fixed(max(seeds, 1))


CLAIM_COLUMNS = (
    "variant",
    "reference",
    "metric",
    "verdict",
    "change",
    "change_low",
    "change_high",
    "change_unit",
    "bound",
    "variant_value",
    "reference_value",
    "n_variant",
    "n_reference",
    "level",
    "margin",
    "p_difference",
    "p_equivalence",
    "seeds_needed",
    "seeds_cap",
    "look",
    "reason",
    "seeds_first",
    "censored",
)
"""The columns of ``tables/claims.csv`` and ``Results.claims`` (docs/python.md describes each)."""


def claims_table(ablation: Ablation, result: Round | None = None) -> pd.DataFrame:
    """The primary claims (``primary_claims``), one row per comparison in the report's sign and units: the table
    the report's claims are written in words from (its columns: ``CLAIM_COLUMNS``)."""
    result = result if result is not None else primary_claims(ablation)
    primary = primary_question(ablation)
    samples = _claim_samples(ablation, primary)
    rows = []
    for v in result.verdicts:
        question = primary if v.metric == primary.metric else primary.fallback
        scale = 100.0 if question.relative else 1.0
        side = (lambda s: s.values) if question is primary else (lambda s: s.fallback)
        x = np.asarray(side(samples[v.variant]), float)[: v.n_variant]
        y = np.asarray(side(samples[v.reference]), float)[: v.n_reference]
        needed = np.nan if not v.seeds_estimated else np.inf if v.seeds_needed is None else float(v.seeds_needed)
        changes = {"change": v.estimate, "change_low": v.low, "change_high": v.high, "margin": v.margin}
        row = asdict(v) | {name: scale * value for name, value in changes.items()}
        row["change_unit"] = CHANGE_UNITS[question.relative]
        row["variant_value"] = float(iqm(x)) if len(x) else np.nan
        row["reference_value"] = float(iqm(y)) if len(y) else np.nan
        rows.append(row | {"seeds_needed": needed})
    return pd.DataFrame(rows, columns=list(CLAIM_COLUMNS))
