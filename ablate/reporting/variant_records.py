"""Each variant as its MLflow run holds it (``launch.variant_runs.VariantRecord``), computed from the report's data:
its settings, its learning curve as the report's figure draws it, its primary claim and its convergence row.

Nothing here is computed anew: every value is a cell of a table the report writes (``tables/claims.csv``,
``tables/convergence.csv``, ``tables/trials.csv``) or the band of its learning-curve figure (``variant_band``).
"""

from __future__ import annotations

import math
from typing import Any

from ablate.launch.variant_runs import TAG_VERDICT, VariantRecord
from ablate.reporting.data import ReportData
from ablate.reporting.figures import episode_grid, variant_band, variant_band_png
from ablate.reporting.settings import own_changes
from ablate.reporting.tables import settings_of
from ablate.reporting.tuning import EVAL
from ablate.reporting.tuning import knobs as tuning_knobs

BAND_FIGURE = "learning_curve.png"
"""The variant run's artifact: its curve and its reference's, each with its 95% band (MLflow's charts draw lines)."""
CURVE_METRICS = ("curve/iqm", "curve/low", "curve/high")
"""The learning curve (IQM over seeds of the rolling mean return) and its 95% band, at the episodes of the figure."""
CLAIM_METRICS = {
    "claim/change": "change",
    "claim/low": "change_low",
    "claim/high": "change_high",
    "claim/n_variant": "n_variant",
    "claim/n_reference": "n_reference",
}
"""Metric: its ``tables/claims.csv`` column (the change in the claim's ``change_unit``, its interval, the seeds)."""
CONVERGENCE_COLUMNS = (
    "seeds_run",
    "fraction_solved",
    "episodes_iqm",
    "episodes_iqm_ci_low",
    "episodes_iqm_ci_high",
    "auc_iqm",
    "auc_ci_low",
    "auc_ci_high",
    "final_rolling_mean_iqm",
    "parameter_count",
)
"""``tables/convergence.csv``'s columns a variant run holds, as metrics ``convergence/<column>``."""
TAG_REFERENCE, TAG_CHANGES = "ablate.reference", "ablate.changes"
TAG_CLAIM_METRIC, TAG_CHANGE_UNIT = "ablate.claim_metric", "ablate.change_unit"
TAG_BOUND = "ablate.bound"
"""``tables/claims.csv``'s ``bound`` where it has one; an end of the interval that is infinite is not logged (MLflow
would store it as the largest float)."""


def variant_records(data: ReportData) -> list[VariantRecord]:
    """One record per variant of the report, in the experiment file's order."""
    ablation = data.ablation
    settings = _settings(data)
    grid = episode_grid(ablation) if len(ablation.finished) else None
    records = []
    for variant in ablation.variants:
        changed = own_changes(ablation.grid, variant)
        tags = {TAG_CHANGES: ", ".join(f"{k} = {v}" for k, v in changed.items()) or "nothing (the base)"}
        metrics: dict[str, float] = {}
        claim = data.claims[data.claims.variant == variant]
        if len(claim):
            row = claim.iloc[0]
            tags |= {TAG_VERDICT: str(row.verdict), TAG_REFERENCE: str(row.reference)}
            tags |= {TAG_CLAIM_METRIC: str(row.metric), TAG_CHANGE_UNIT: str(row.change_unit)}
            if isinstance(row.bound, str) and row.bound:  # "at least": censored seeds leave an end unbounded
                tags[TAG_BOUND] = row.bound
            metrics |= {key: row[column] for key, column in CLAIM_METRICS.items()}
        elif variant != ablation.baseline:
            tags[TAG_REFERENCE] = ablation.reference(variant)
        convergence = data.convergence[data.convergence.variant == variant]
        if len(convergence):
            row = convergence.iloc[0]
            metrics |= {f"convergence/{c}": row[c] for c in CONVERGENCE_COLUMNS if c in row.index}
        series: dict[str, list[tuple[int, float]]] = {}
        band = variant_band(ablation, variant) if grid is not None else None
        if band is not None:
            for key, values in zip(CURVE_METRICS, band, strict=True):
                series[key] = [(int(e), float(v)) for e, v in zip(grid, values, strict=True) if _number(v)]
        picture = variant_band_png(ablation, variant) if band is not None else None
        records.append(
            VariantRecord(
                name=variant,
                params=settings.get(variant, {}),
                tags=tags,
                metrics={k: float(v) for k, v in metrics.items() if _number(v)},
                series=series,
                artifacts={BAND_FIGURE: picture} if picture else {},
            )
        )
    return records


def _settings(data: ReportData) -> dict[str, dict[str, Any]]:
    """Per variant, its settings as ``tables/trials.csv`` holds them for its evaluation trials: the knobs
    ``tables.settings_of`` picks and a tuned knob's chosen value (its trials' own column), one value each."""
    ablation, table = data.ablation, data.trials
    tuned = tuning_knobs(ablation.tuning) if ablation.tuning else []
    knobs = [k for k in (*tuned, *settings_of(ablation, ablation.trials).columns) if k in table]
    rows = table[table.stage == EVAL] if "stage" in table else table
    found = {}
    for variant, group in rows.groupby("variant", sort=False):
        found[str(variant)] = {k: _value(v) for k, v in group.iloc[0][knobs].dropna().items()}
    return found


def _value(value: Any) -> Any:
    return value.item() if hasattr(value, "item") else value


def _number(value: Any) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False
