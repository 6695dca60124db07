"""The tuning stage as the report reads it: which evaluation trials ran at each variant's chosen values and
which at the shared base values, and one row per tuning trial with the metric tuning ranked candidates by.

Follows the launch's ``tuning.json`` (issue 19): candidates per knob, tuning seeds, metric and direction,
the base values and each variant's choice. Pure functions of frames and that document: no store access.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from ablate.measures import lookup, measure

EVAL = "eval"
"""An evaluation trial's stage (``GridTrial.stage``); a tuning trial's is ``planned.TUNE``."""


def knobs(tuning: dict[str, Any]) -> list[str]:
    """The tuned knobs, in the experiment file's order."""
    return list(tuning.get("knobs", {}))


def same_value(a: Any, b: Any) -> bool:
    """Two knob values equal as the trials would use them (a param read back from MLflow is text)."""
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=0.0)
    except (TypeError, ValueError):
        return str(a) == str(b)


def chosen_values(tuning: dict[str, Any], variant: str) -> dict[str, Any]:
    """The values ``variant`` is evaluated at: its tuning choice, or its own where it set the knob itself."""
    choice = tuning.get("choices", {}).get(variant, {})
    return {k: choice.get("values", {}).get(k, tuning.get("base", {}).get(k)) for k in knobs(tuning)}


def base_values(tuning: dict[str, Any], variant: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The values the untuned comparison runs ``variant`` at: the shared base value, except where the variant
    sets the knob itself (``course`` keeps its 1e-3), which tuning never touched."""
    choice = tuning.get("choices", {}).get(variant, {})
    if choice and not choice.get("tuned", True):
        return chosen_values(tuning, variant)
    return {k: overrides.get(k, tuning.get("base", {}).get(k)) for k in knobs(tuning)}


def at_values(trials: pd.DataFrame, values_of) -> pd.Series:
    """Which evaluation trials ran at ``values_of(variant)`` on every tuned knob (a boolean mask)."""
    mask = []
    for row in trials.itertuples(index=False):
        wanted = values_of(row.variant)
        mask.append(all(same_value(getattr(row, k, None), v) for k, v in wanted.items()))
    return pd.Series(mask, index=trials.index, dtype=bool)


def metric_words(tuning: dict[str, Any]) -> tuple[str, str]:
    """The tuning metric's words and direction (``max`` or ``min``), from the registry; a name it lacks as written,
    with the document's direction."""
    metric = tuning.get("metric", "auc")
    entry = lookup(metric)
    return (entry.words, entry.direction) if entry else (metric, tuning.get("direction", "max"))


def trial_metric(row: dict[str, Any], metric: str) -> float:
    """One finished trial's value of the tuning ``metric`` (``Measure.from_summary``: AUC over its own budget,
    episodes to solve censored at its budget, the rolling return when it ended)."""
    if row.get("status") != "FINISHED":
        return float("nan")
    tracked = row.get("tracked", {}).get(metric)
    if tracked is not None:  # what the tuning stage itself recorded and selected on
        return float(tracked)
    return measure(metric).from_summary(row, row.get("budget", np.nan))[0]


def tuning_table(rows: list[dict[str, Any]], tuning: dict[str, Any], variants: list[str]) -> pd.DataFrame:
    """``tables/tuning.csv``: one row per tuning trial, in the experiment's variant order, then by candidate
    and seed: ``variant``, ``seed``, each tuned knob, the metric under its own name, and ``status``."""
    metric, names = tuning.get("metric", "auc"), knobs(tuning)
    records = [
        {"variant": r["variant"], "seed": int(r["seed"]), **{k: r.get(k) for k in names}}
        | {metric: trial_metric(r, metric), "status": r.get("status", "NOT RUN")}
        for r in rows
    ]
    table = pd.DataFrame(records, columns=["variant", "seed", *names, metric, "status"])
    for k in names:
        numbers = pd.to_numeric(table[k], errors="coerce")
        if numbers.notna().all():
            table[k] = numbers
    order = {v: i for i, v in enumerate(variants)}
    table["_order"] = table.variant.map(order).fillna(len(order))
    return table.sort_values(["_order", *names, "seed"]).drop(columns="_order").reset_index(drop=True)


def sensitivity(table: pd.DataFrame, tuning: dict[str, Any]) -> pd.DataFrame:
    """Per variant and candidate: the mean metric over its finished tuning seeds, their lowest and highest
    value and how many seeds finished (what the sensitivity figure draws and the Tuning section quotes)."""
    metric, names = tuning.get("metric", "auc"), knobs(tuning)
    done = table[table.status == "FINISHED"]
    if done.empty:
        return pd.DataFrame(columns=["variant", *names, "mean", "low", "high", "seeds"])
    grouped = done.groupby(["variant", *names], sort=False)[metric]
    return grouped.agg(mean="mean", low="min", high="max", seeds="count").reset_index()


def edge(tuning: dict[str, Any], values: dict[str, Any]) -> list[str]:
    """The knobs whose chosen value is the lowest or highest candidate: the best may lie beyond the grid."""
    flags = []
    for knob, candidates in tuning.get("knobs", {}).items():
        numbers = sorted(float(c) for c in candidates)
        if len(numbers) < 2 or knob not in values:
            continue
        if same_value(values[knob], numbers[0]):
            flags.append(f"{knob.replace('_', ' ')} at the lowest candidate")
        elif same_value(values[knob], numbers[-1]):
            flags.append(f"{knob.replace('_', ' ')} at the highest candidate")
    return flags
