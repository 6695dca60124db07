"""What a tuned ablation's report adds (issue 19): the Tuning section and "Does the finding depend on the learning
rate?"."""

from __future__ import annotations

import pandas as pd

from ablate.measures import is_censored
from ablate.reporting.blocks import Block, Items, Paragraph, Table
from ablate.reporting.prose import say
from ablate.reporting.results import Ablation
from ablate.reporting.settings import overrides
from ablate.reporting.statistics import SEPARATED, TOO_FEW_SEEDS
from ablate.reporting.text import NO_REFS, Refs, _signed, _signed_pct, esc, fmt, setting_value
from ablate.reporting.tuning import base_values, chosen_values, edge, knobs, metric_words, same_value, sensitivity


def _values(values: dict) -> str:
    return ", ".join(f"{k.replace('_', ' ')} {setting_value(v)}" for k, v in values.items())


def _pair(mine: dict, theirs: dict) -> str:
    """``learning rate 0.1`` when both sides share the values, else ``learning rate 0.03 against 0.1``."""
    if all(same_value(mine[k], theirs.get(k)) for k in mine):
        return f"both at {_values(mine)}"
    return f"{_values(mine)} against {', '.join(setting_value(v) for v in theirs.values())}"


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
        f"{k.replace('_', ' ')}: {', '.join(setting_value(c) for c in values)} "
        f"(base value {setting_value(tuning['base'].get(k))})"
        for k, values in tuning.get("knobs", {}).items()
    )
    intro = Paragraph(say("tuning.intro", knobs=knob_words(ablation).removeprefix("the ")))
    lines = [
        say("tuning.candidates", candidates=candidates),
        say("tuning.seeds", seeds=seeds, evaluation=evaluation),
        say("tuning.metric", words=words, higher=direction == "max", budget=int(tune_budget)),
        say("tuning.rule", rule=rule),
    ]
    if tune_budget < budget:
        lines.append(say("tuning.short_horizon", tune_budget=int(tune_budget), budget=budget))
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
                **{f"{k.replace('_', ' ')} chosen": setting_value(v) for k, v in values.items()},
                f"mean {words} at the choice [lowest, highest seed]": score,
                "how": esc(choice.get("reason", "")) if choice.get("tuned", True) else "set by the variant: not tuned",
                "flag": "; ".join(f"{f}: the best may lie beyond the grid" for f in flags) or "",
            }
        )
    blocks: list[Block] = [intro, Items.of(lines)]
    blocks += [Table(pd.DataFrame(rows))] if rows else []
    blocks += [Paragraph(say("tuning.kept", kept=kept))] if kept else []
    return [*blocks, Paragraph(say("tuning.sensitivity", figure=refs.figure("tuning_sensitivity")))]


def _estimate(row: pd.Series) -> str:
    return f"{_signed_pct(-row.point)} episodes" if is_censored(row.metric) else _signed(row.point)


def _verdict_words(row: pd.Series) -> str:
    if row is None:
        return "not compared"
    word = f"**{row.verdict}**" if row.verdict in SEPARATED else f"*{row.verdict}*"  # the table's own words
    return f"{word} ({_estimate(row)})"


def _at_base(untuned: pd.DataFrame, row: pd.Series) -> pd.Series | None:
    """The comparison ``row`` (at the chosen values) at the shared base value; None where it was not made."""
    match = untuned[(untuned.variant == row.variant) & (untuned.metric == row.metric)] if len(untuned) else untuned
    return match.iloc[0] if len(match) else None


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
        base = _at_base(untuned, row)
        kind = change_kind(base.verdict if base is not None else "", row.verdict)
        reference = row.reference
        at_base = _pair(*(base_values(tuning, v, overrides(ablation.grid, v)) for v in (row.variant, reference)))
        at_choice = _pair(chosen_values(tuning, row.variant), chosen_values(tuning, reference))
        label = {"holds": kind, "none": "no finding at either"}.get(kind, f"**{kind}**")
        if kind not in ("holds", "none"):
            changed.append(say("tuning.changed", row=row, kind=kind))
        words = dict(base_words=_verdict_words(base), choice_words=_verdict_words(row))
        lines.append(say("tuning.comparison", row=row, at_base=at_base, at_choice=at_choice, label=label, **words))
    unchanged = "" if changed else unchanged_words(ablation, tuned, untuned)
    facts = dict(changed=changed, findings=len(lines), knobs=knob_words(ablation), unchanged=unchanged)
    return [Paragraph(say("tuning.dependence", **facts)), Items.of(lines)]


def unchanged_words(ablation: Ablation, tuned: pd.DataFrame, untuned: pd.DataFrame) -> str:
    """What "no finding changes" means for this run: that every verdict held, that none was separated at either
    value, or that none could have been (too few seeds at both), with the estimate that moved most."""
    pairs = [(base, row) for _, row in tuned.iterrows() if (base := _at_base(untuned, row)) is not None]
    could = not (pairs and all(base.verdict == TOO_FEW_SEEDS and row.verdict == TOO_FEW_SEEDS for base, row in pairs))
    separated = not all(change_kind(base.verdict, row.verdict) == "none" for base, row in pairs)
    moved, moved_from, moved_to = None, None, None
    if not could:
        primary = pairs[0][1].metric  # the first metric compared: episodes to solve where seeds solved, else AUC
        points = [(abs(row.point - base.point), base, row) for base, row in pairs if row.metric == primary]
        points = [item for item in points if pd.notna(item[0])]
        if points:
            _, base, moved = max(points, key=lambda item: item[0])
            moved_from, moved_to = _estimate(base), _estimate(moved)
    facts = dict(could=could, separated=separated, moved=moved, moved_from=moved_from, moved_to=moved_to)
    return say("tuning.unchanged", knobs=knob_words(ablation), **facts)
