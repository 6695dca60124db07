"""What a tuned ablation's report adds (issue 19): the Tuning section (candidates, seeds, metric, rule, each
variant's choice, flags) and "Does the finding depend on the learning rate?" (each comparison at the shared
base value beside the comparison at the chosen values, on the same evaluation seeds, and what "no finding
changes" means for the run: every verdict held, none was separated, or none could have been)."""

from __future__ import annotations

import pandas as pd

from ablate.design import CONFIDENCE, percent
from ablate.measures import is_censored
from ablate.reporting.blocks import Block, Items, Paragraph, Table
from ablate.reporting.results import Ablation
from ablate.reporting.statistics import SEPARATED, TOO_FEW_SEEDS
from ablate.reporting.text import NO_REFS, Refs, _metric_name, _signed, _signed_pct, esc, fmt
from ablate.reporting.tuning import base_values, chosen_values, edge, knobs, metric_words, same_value, sensitivity


def _value(value) -> str:
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError):
        return str(value)


def _values(values: dict) -> str:
    return ", ".join(f"{k.replace('_', ' ')} {_value(v)}" for k, v in values.items())


def _pair(mine: dict, theirs: dict) -> str:
    """``learning rate 0.1`` when both sides share the values, else ``learning rate 0.03 against 0.1``."""
    if all(same_value(mine[k], theirs.get(k)) for k in mine):
        return f"both at {_values(mine)}"
    return f"{_values(mine)} against {', '.join(_value(v) for v in theirs.values())}"


def knob_words(ablation: Ablation) -> str:
    """``the learning rate`` when that is the only tuned knob, else ``the tuned settings``."""
    names = knobs(ablation.tuning or {})
    return "the learning rate" if names == ["learning_rate"] else "the tuned settings"


def tuning_section(ablation: Ablation, refs: Refs = NO_REFS) -> list[Block]:
    """The Tuning section: how each variant's values were chosen, on seeds the comparison never sees."""
    tuning = ablation.tuning or {}
    words, direction = metric_words(tuning)
    seeds = tuning.get("seeds", [])
    evaluation = sorted(set(ablation.trials.seed)) if len(ablation.trials) else ablation.grid.get("seeds", [])
    budget = int(ablation.grid["base"].get("max_episodes", 0))
    rule = tuning.get("rule", "the candidate with the best mean metric over the tuning seeds")
    tune_budget = tuning.get("max_episodes") or budget
    candidates = "; ".join(
        f"{k.replace('_', ' ')}: {', '.join(_value(c) for c in values)} (base value {_value(tuning['base'].get(k))})"
        for k, values in tuning.get("knobs", {}).items()
    )
    intro = Paragraph(
        f"Each variant's {knob_words(ablation).removeprefix('the ')} was chosen on tuning seeds of its own, then the "
        "variants were compared at their chosen values on evaluation seeds tuning never saw, so that no variant is "
        "judged at a setting chosen for another, and the winner of tuning is not inflated by re-using its seeds "
        "(Patterson et al., 2024; Eimer et al., 2023). **The summary, findings and figures use the evaluation "
        "seeds only, at the chosen values.**"
    )
    lines = [
        f"**Candidates.** {esc(candidates)}.",
        f"**Tuning seeds.** {len(seeds)} per candidate ({', '.join(map(str, seeds))}), disjoint from the "
        f"{len(evaluation)} evaluation seeds ({', '.join(map(str, evaluation))}).",
        f"**Metric.** {words}, {'higher' if direction == 'max' else 'lower'} is better, over each tuning trial's "
        f"budget of {int(tune_budget):,} episodes.",
        f"**Rule.** {esc(rule.rstrip('.'))}.",
    ]
    if tune_budget < budget:
        lines.append(
            f"**Short horizon.** Tuning trials ran {int(tune_budget):,} episodes, the evaluation {budget:,}: a value "
            "that learns fast early is favoured over one that learns slower but further (short-horizon bias), so a "
            "choice can be worse at the full budget than a candidate tuning passed over."
        )
    table = ablation.tuning_trials if ablation.tuning_trials is not None else pd.DataFrame()
    summary = sensitivity(table, tuning) if len(table) else pd.DataFrame()
    rows, kept = [], []
    for variant in ablation.variants:
        choice = tuning.get("choices", {}).get(variant)
        if choice is None:
            continue
        values = chosen_values(tuning, variant)
        if not choice.get("tuned", True):
            kept.append(f"{esc(variant)} ({_values(values)})")
        at = summary[summary.variant == variant] if len(summary) else summary
        for knob, value in values.items():
            at = at[[same_value(v, value) for v in at[knob]]] if len(at) else at
        score = (
            f"{fmt(at['mean'].iloc[0], 1)} [{fmt(at['low'].iloc[0], 1)}, {fmt(at['high'].iloc[0], 1)}]"
            if len(at)
            else "–"
        )
        flags = edge(tuning, values) if choice.get("tuned", True) else []
        rows.append(
            {
                "variant": esc(variant),
                **{f"{k.replace('_', ' ')} chosen": _value(v) for k, v in values.items()},
                f"mean {words} at the choice [lowest, highest seed]": score,
                "how": esc(choice.get("reason", "")) if choice.get("tuned", True) else "set by the variant: not tuned",
                "flag": "; ".join(f"{f}: the best may lie beyond the grid" for f in flags) or "",
            }
        )
    blocks: list[Block] = [intro, Items.of(lines)]
    blocks += [Table(pd.DataFrame(rows))] if rows else []
    if kept:
        blocks.append(
            Paragraph(f"Kept their own value, not tuned (the variant sets the knob itself): {', '.join(kept)}.")
        )
    blocks.append(
        Paragraph(
            f"{refs.figure('tuning_sensitivity')} shows each variant's metric against every candidate; every tuning "
            "trial is in tables/tuning.csv."
        )
    )
    return blocks


def _verdict_words(row: pd.Series) -> str:
    if row is None:
        return "not compared"
    estimate = f"{_signed_pct(-row.point)} episodes" if is_censored(row.metric) else _signed(row.point)
    word = f"**{row.verdict}**" if row.verdict in SEPARATED else f"*{row.verdict}*"  # the table's own words
    return f"{word} ({estimate})"


def change_kind(base: str, tuned: str) -> str:
    """How a finding moves from the base value to the chosen values: ``holds``, ``flips`` (better <-> worse),
    ``vanishes`` (separated at the base value, not at the chosen ones), ``appears`` (the reverse), or ``none``
    (separated at neither)."""
    if base in SEPARATED and tuned in SEPARATED:
        return "holds" if base == tuned else "flips"
    if base in SEPARATED:
        return "vanishes"
    if tuned in SEPARATED:
        return "appears"
    return "none"


def dependence_section(ablation: Ablation, tuned: pd.DataFrame, untuned: pd.DataFrame) -> list[Block]:
    """Each comparison at the shared base value beside the same comparison at the chosen values, both on the
    evaluation seeds, naming every finding that flips, vanishes or appears."""
    tuning = ablation.tuning or {}
    lines, changed = [], []
    for _, row in tuned.iterrows():
        match = untuned[(untuned.variant == row.variant) & (untuned.metric == row.metric)] if len(untuned) else untuned
        base = match.iloc[0] if len(match) else None
        kind = change_kind(base.verdict if base is not None else "", row.verdict)
        reference = row.reference
        at_base = _pair(_base_values(ablation, row.variant), _base_values(ablation, reference))
        at_choice = _pair(chosen_values(tuning, row.variant), chosen_values(tuning, reference))
        label = {"flips": "**flips**", "vanishes": "**vanishes**", "appears": "**appears**"}.get(kind, kind)
        if kind in ("flips", "vanishes", "appears"):
            changed.append(f"{esc(row.variant)} vs {esc(reference)} on {_metric_name(row.metric)} ({kind})")
        if kind == "none":
            label = "no finding at either"
        lines.append(
            f"{esc(row.variant)} vs {esc(reference)}, {_metric_name(row.metric)}: at the base value "
            f"({at_base}) {_verdict_words(base)}; at the chosen values ({at_choice}) "
            f"{_verdict_words(row)}: {label}."
        )
    head = (
        f"*Exploratory* (unadjusted {percent(CONFIDENCE)} intervals, each comparison on its own; the claims are the "
        "primary ones). "
        "The same comparisons on the same evaluation seeds and budget, once with every variant at the shared base "
        "value (as an untuned ablation runs them) and once at each variant's chosen value. "
    )
    if changed:
        head += (
            f"**{len(changed)} of {len(lines)} findings change with {knob_words(ablation)}:** "
            + "; ".join(changed)
            + "."
        )
    else:
        head += unchanged_words(ablation, tuned, untuned)
    return [Paragraph(head), Items.of(lines)]


def _estimate(row: pd.Series) -> str:
    return f"{_signed_pct(-row.point)} episodes" if is_censored(row.metric) else _signed(row.point)


def unchanged_words(ablation: Ablation, tuned: pd.DataFrame, untuned: pd.DataFrame) -> str:
    """What "no finding changes" means for this run: that every verdict held, that none was separated at either
    value, or that none could have been (too few seeds at both), with the estimate that moved most."""
    pairs = []
    for _, row in tuned.iterrows():
        match = untuned[(untuned.variant == row.variant) & (untuned.metric == row.metric)] if len(untuned) else untuned
        if len(match):
            pairs.append((match.iloc[0], row))
    words = knob_words(ablation)
    if pairs and all(base.verdict == TOO_FEW_SEEDS and row.verdict == TOO_FEW_SEEDS for base, row in pairs):
        text = (
            f"No finding changes with {words}, but none could: with these seeds no comparison can reach a verdict "
            f"at either value, so this says nothing about whether {words} matters."
        )
        primary = pairs[0][1].metric  # the first metric compared: episodes to solve where seeds solved, else AUC
        moved = [
            (abs(row.point - base.point), base, row)
            for base, row in pairs
            if row.metric == primary and pd.notna(row.point - base.point)
        ]
        if moved:
            _, base, row = max(moved, key=lambda item: item[0])
            text += (
                f" The estimates did move: {esc(row.variant)} vs {esc(row.reference)} on {_metric_name(row.metric)} "
                f"went from {_estimate(base)} at the base value to {_estimate(row)} at the chosen values."
            )
        return text
    if all(change_kind(base.verdict, row.verdict) == "none" for base, row in pairs):
        return f"No finding changes with {words}: no comparison was separated at either value."
    return f"No finding changes with {words}: every verdict is the same at the base value and at the chosen values."


def _base_values(ablation: Ablation, variant: str) -> dict:
    overrides = next((v.get("overrides", {}) for v in ablation.grid["variants"] if v["name"] == variant), {})
    return base_values(ablation.tuning or {}, variant, overrides)
