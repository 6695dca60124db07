"""Stage 1 -> stage 2 of a tuned ablation: pick each variant's knob values from its finished tuning trials,
and the trials each stage runs. Pure: no Ray, no MLflow, no file.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ablate.experiment import Experiment, TuneSpec, Variant
from ablate.launch.grid import GridTrial, chosen_trials
from ablate.measures import AUC, measure

RULE = (
    "Each variant takes the candidate with the best mean {metric} over its tuning seeds; where that leaves a tie "
    "(or, for episodes to solve, the best mean is a bound because a seed never solved within the tuning budget), "
    "the tied candidates are ranked by mean AUC, then by nearness to the base value (distance in log space, the "
    "smaller value first on equal distance). A variant that sets a tuned knob itself keeps its value."
)
_TOLERANCE = 1e-9


@dataclass(frozen=True)
class TuningResult:
    """One finished stage-1 trial, as selection needs it."""

    variant: str
    values: Mapping[str, Any]
    """The candidate: the tuned knobs' values."""
    seed: int
    metrics: Mapping[str, float]
    """The trial's summary metrics (``auc``, ``episodes_to_solve`` when solved, ``final_rolling_mean``, ...)."""
    budget: int
    """The trial's ``max_episodes``: an unsolved trial's episodes to solve are censored here."""


@dataclass(frozen=True)
class Choice:
    """A variant's values for stage 2, and why."""

    values: dict[str, Any]
    tuned: bool
    reason: str
    scores: dict[str, float] = field(default_factory=dict)
    """Mean metric per candidate (``"learning_rate=0.1"``), for the record."""


def _label(values: Mapping[str, Any]) -> str:
    return ",".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items()) or "-"


def _distance(values: Mapping[str, Any], base: Mapping[str, Any]) -> float:
    """How far a candidate is from the base values: summed |log ratio| (every tunable knob is positive)."""
    return sum(abs(math.log(float(v)) - math.log(float(base[k]))) for k, v in values.items())


def choose(spec: TuneSpec, tuned: tuple[str, ...], base: Mapping[str, Any], results: Iterable[TuningResult]) -> Choice:
    """One variant's choice from its finished tuning trials (every candidate on every tuning seed): see ``RULE``.
    ``tuned``: the knobs it is tuned on; ``base``: its own values of every knob of ``[tune]``."""
    if not tuned:
        return Choice({k: base[k] for k in spec.knob_names}, False, "set by the variant")
    by_candidate: dict[tuple, list[TuningResult]] = {}
    for result in results:
        by_candidate.setdefault(tuple((k, result.values[k]) for k in tuned), []).append(result)

    def mean(rows: list[TuningResult], metric: str) -> tuple[float, bool]:
        pairs = [measure(metric).from_summary(r.metrics, r.budget) for r in rows]  # censored: a bound
        values = [v for v, _ in pairs]
        value = sum(values) / len(values) if values and all(math.isfinite(v) for v in values) else float("nan")
        return value, any(c for _, c in pairs)

    def best(candidates: Iterable[tuple], metric: str, sign: float) -> list[tuple]:
        """The candidates whose mean ``metric`` is the best (lowest ``sign`` x mean; NaN last), within tolerance."""
        means = {c: mean(by_candidate[c], metric)[0] for c in candidates}
        keyed = {c: (sign * v if math.isfinite(v) else math.inf) for c, v in means.items()}
        top = min(keyed.values())
        return [c for c, k in keyed.items() if abs(k - top) <= _TOLERANCE * max(1.0, abs(top))]

    scores = {cand: mean(rows, spec.metric) for cand, rows in by_candidate.items()}
    tied = best(by_candidate, spec.metric, -1.0 if spec.direction == "max" else 1.0)
    if measure(spec.metric).censored and any(scores[c][1] for c in tied):
        # The lowest mean uses a never-solved seed: its true mean is higher by an unknown amount, so episodes
        # cannot order the candidates at all.
        tied = list(by_candidate)
        reason = "episodes to solve censored (a tuning seed never solved)"
    else:
        reason = f"tie on mean {spec.metric}"
    if len(tied) == 1:
        chosen, why = tied[0], f"best mean {spec.metric}"
    else:
        by_auc = best(tied, AUC.name, -1.0) if spec.metric != AUC.name else tied
        if len(by_auc) == 1:
            chosen, why = by_auc[0], f"{reason}: best mean auc"
        else:
            chosen = min(by_auc, key=lambda c: (_distance(dict(c), base), [float(v) for _, v in c]))
            why = f"{reason}{' and on mean auc' if spec.metric != 'auc' else ''}: nearest the base value"
    values = {k: base[k] for k in spec.knob_names} | dict(chosen)
    return Choice(values, True, why, {_label(dict(c)): scores[c][0] for c in by_candidate})


def base_values(spec: TuneSpec, variant: Variant) -> dict[str, Any]:
    """The variant's own values of the knobs in ``[tune]`` (the base's unless it sets them)."""
    return {k: getattr(variant.config, k) for k in spec.knob_names}


def choose_all(
    experiment: Experiment,
    trials: Iterable[GridTrial],
    finished: Mapping[str, Mapping[str, float]],
    so_far: bool = False,
) -> dict[str, Choice]:
    """A choice for every variant whose stage 1 is complete (every candidate on every tuning seed finished), or
    with ``so_far`` has any finished trial (its best candidate so far); the others are left out. ``trials``: stage
    1's (``grid.tuning_trials``); ``finished``: trial key -> summary metrics, from this launch or read back from the
    store. Requires ``experiment.tune``."""
    spec = experiment.tune
    assert spec is not None
    variants = {v.name: v for v in experiment.variants}
    by_variant: dict[str, list[TuningResult]] = {}
    for t in trials:
        if t.key in finished:
            values = {k: getattr(t.config, k) for k in spec.tuned_knobs(variants[t.variant])}
            result = TuningResult(t.variant, values, t.seed, finished[t.key], t.config.max_episodes)
            by_variant.setdefault(t.variant, []).append(result)
    choices = {}
    for variant in experiment.variants:
        tuned = spec.tuned_knobs(variant)
        rows = by_variant.get(variant.name, [])
        done = {(tuple(sorted(r.values.items())), r.seed) for r in rows}
        wanted = {(tuple(sorted(c.items())), s) for c in spec.candidates(variant) for s in spec.seeds}
        complete = bool(done) if so_far else wanted <= done  # so far: any result chooses a provisional value
        if tuned and not complete:
            continue
        choices[variant.name] = choose(spec, tuned, base_values(spec, variant), rows)
    return choices


def tuning_document(experiment: Experiment, choices: Mapping[str, Choice]) -> dict[str, Any]:
    """``tuning.json`` of a launch run: the contract other modules read (docs/tuning.md lists its fields and
    what the report counts by its ``trials``)."""
    spec = experiment.tune
    assert spec is not None
    stage_two = chosen_trials(experiment, {name: c.values for name, c in choices.items() if c.tuned})
    return {
        "knobs": {k: list(v) for k, v in spec.knobs},
        "seeds": list(spec.seeds),
        "metric": spec.metric,
        "direction": spec.direction,
        "max_episodes": spec.max_episodes,
        "rule": RULE.format(metric=spec.metric.replace("_", " ")),
        "base": {k: getattr(experiment.base, k) for k in spec.knob_names},
        "choices": {
            name: {"values": c.values, "tuned": c.tuned, "reason": c.reason, "scores": c.scores}
            for name, c in choices.items()
        },
        "trials": [{"key": t.key, "variant": t.variant, "seed": t.seed} for t in stage_two],
    }


def unique(trials: list[GridTrial], skip: set[str]) -> list[GridTrial]:
    """``trials`` without repeated keys and without the keys in ``skip``, in order (a chosen value equal to the
    base value gives the base-value trial again)."""
    seen, out = set(skip), []
    for trial in trials:
        if trial.key not in seen:
            seen.add(trial.key)
            out.append(trial)
    return out
