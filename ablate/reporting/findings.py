"""The findings (one line per comparison and metric, in words) and the summary (variants ranked, with what
the data support against each one's reference)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ablate.claims import BETTER, EQUIVALENT, WORSE, Question, advice, family_sentence
from ablate.design import CONFIDENCE, percent
from ablate.measures import is_censored, measure
from ablate.reporting.blocks import Block, Item, Items, Paragraph, Table
from ablate.reporting.comparisons import LOO_MAX_SEEDS, claims_design, claims_table, primary_question
from ablate.reporting.prose import say
from ablate.reporting.results import Ablation
from ablate.reporting.rounds import seconds_per_trial
from ablate.reporting.sections import _episodes_cell, _extends, _stat_cell
from ablate.reporting.statistics import (
    EXPLORATORY_BETTER,
    EXPLORATORY_WORSE,
    NOT_SEPARATED,
    SEEDS_CAP,
    SEPARATED,
    TOO_FEW_SEEDS,
    is_censored_statistic,
    smallest_p_value,
)
from ablate.reporting.text import _metric_name, _signed, esc, fmt


def stat_name(n: int, m: int) -> str:
    """What the report's "IQM" of ``n`` and ``m`` seeds is: with fewer than 4 seeds it trims nothing
    (SciPy's ``trim_mean`` cuts ``int(0.25 n)`` from each end) and is the plain mean."""
    if min(n, m) >= 4:
        return "IQM"
    return "mean" if max(n, m) < 4 else "IQM (the mean where fewer than 4 seeds)"


def _never(table: pd.DataFrame, variant: str, metric: str) -> int:
    """How many of ``variant``'s seeds never got there on an episodes metric: counted as the budget."""
    at = table.loc[table.variant == variant].iloc[0]
    if metric == "episodes_to_solve":
        return int(at.unsolved_censored)
    return int(at.seeds_run - at[f"{metric}_reached"])


def _pair(row: pd.Series, table: pd.DataFrame, stat: str) -> str:
    """``mean 492 vs ≥ 917``: the two sides' episodes, ≥ on each side whose statistic counts unsolved seeds as
    the budget (``statistics.is_censored_statistic``, the rule that made the row's ``bound``)."""

    def side(variant: str, value: float, n: int) -> str:
        bounded = row.bound and is_censored_statistic(_never(table, variant, row.metric), n, "iqm")
        return f"{'≥ ' if bounded else ''}{fmt(value)}"

    x = side(row.variant, row.variant_value, int(row.n_variant))
    return f"{stat} {x} vs {side(row.reference, row.reference_value, int(row.n_reference))}"


def _estimate(row: pd.Series, table: pd.DataFrame) -> str:
    """The estimate and its bootstrap interval for a comparison the seeds cannot decide, with no direction
    words: a percentile bootstrap over 3 seeds runs narrow, so it is a pointer for a larger run."""
    if any(np.isnan(v) for v in (row.point, row.low, row.high)):
        return ""
    stat = stat_name(int(row.n_variant), int(row.n_reference))
    pair = _pair(row, table, stat) if is_censored(row.metric) and row.bound != "censored" else None
    return say("findings.estimate", row=row, stat=stat, pair=pair)


def seeds_reading(row: pd.Series, effect: float) -> str:
    """What "not separated" means for this comparison: too few seeds for a difference this large, or no
    effect this large; and the seeds a difference of the smallest effect of interest would need. On the primary
    metric, the claims' one figure (the seeds that would decide the claim), not a second estimate."""
    needed, smallest = row.get("seeds_needed", np.nan), row.get("seeds_needed_smallest", np.nan)
    if pd.isna(needed):
        return ""
    if row.get("primary", False):
        return say("findings.primary_reading", needed=_seeds_needed_words(needed, int(row.seeds_cap)))
    wanted = None if pd.isna(smallest) or smallest > SEEDS_CAP else int(smallest)
    needed = None if needed > SEEDS_CAP else int(needed)
    return say("findings.seeds_needed", needed=needed, wanted=wanted, cap=SEEDS_CAP, effect=effect)


def _fragile(row: pd.Series) -> str:
    if row.verdict not in SEPARATED or not row.fragile_seeds:
        return ""  # holding is the rule, said once before the list
    return say("findings.fragile", seeds=str(row.fragile_seeds).split())


def finding(row: pd.Series, ablation: Ablation, table: pd.DataFrame) -> str:
    """One metric's comparison in words: what may be claimed, sized as an estimate or as a bound, with its
    interval and whether it survives leaving out any one seed."""
    base, metric, name = esc(row.reference), row.metric, _metric_name(row.metric)
    n, m = int(row.n_variant), int(row.n_reference)
    stat = stat_name(n, m)
    reading = seeds_reading(row, ablation.smallest_effect)
    if row.verdict == TOO_FEW_SEEDS:
        estimate = _estimate(row, table)
        return say("findings.too_few_seeds", name=name, verdict=TOO_FEW_SEEDS, estimate=estimate, reading=reading)
    if not is_censored(metric):
        higher = {EXPLORATORY_BETTER: True, EXPLORATORY_WORSE: False}.get(row.verdict)
        verdict = row.verdict if higher is not None else NOT_SEPARATED
        facts = dict(name=name, verdict=verdict, row=row, stat=stat, higher=higher, reading=reading)
        return say("findings.returns", fragile=_fragile(row), **facts)
    # the seeds an episodes IQM counts as the budget: "3 of 5 a seeds and 5 of 5 b seeds never solved"
    variant_never, reference_never = (_never(table, v, metric) for v in (row.variant, row.reference))
    facts = dict(row=row, n=n, m=m, variant_never=variant_never, reference_never=reference_never)
    counts = say("findings.never_counts", never=measure(metric).never, **facts)
    if row.bound == "censored":
        return say("findings.both_bounds", name=name, verdict=NOT_SEPARATED, metric=metric, counts=counts)
    change = _pair(row, table, stat)
    if row.verdict in SEPARATED:
        fewer = row.verdict == EXPLORATORY_BETTER
        facts = dict(name=name, row=row, base=base, change=change, counts=counts, fewer=fewer)
        return say("findings.fewer_or_more", fragile=_fragile(row), **facts)
    facts = dict(name=name, verdict=NOT_SEPARATED, row=row, change=change, counts=counts, reading=reading)
    return say("findings.episodes_not_separated", **facts)


def findings(ablation: Ablation, table: pd.DataFrame, compare: pd.DataFrame) -> list[Block]:
    """Per variant, one line per metric; no claim without an interval, bounds worded as bounds. What holds
    for every comparison (too few seeds for any claim) is said once, first."""
    blocks: list[Block] = [Paragraph(say("findings.exploratory"))]
    undecidable = compare[compare.verdict == TOO_FEW_SEEDS] if len(compare) else compare
    if len(undecidable):
        pairs = sorted({(int(r.n_variant), int(r.n_reference)) for r in undecidable.itertuples()})
        reasons = [say("findings.no_claim_reason", n=n, m=m, smallest_p=smallest_p_value(n, m)) for n, m in pairs]
        facts = dict(reasons=reasons, undecidable=len(undecidable), comparisons=len(compare), verdict=TOO_FEW_SEEDS)
        blocks.append(Paragraph(say("findings.too_few_for_a_claim", **facts)))
    claims = compare[compare.verdict.isin(list(SEPARATED))] if len(compare) else compare
    if len(claims):
        checked = claims[claims.loo_checked.astype(bool)] if "loo_checked" in claims else claims
        unchecked = claims[~claims.index.isin(checked.index)]
        many = unchecked[unchecked[["n_variant", "n_reference"]].max(axis=1) > LOO_MAX_SEEDS]
        few = len(many) < len(unchecked)
        facts = dict(checked=len(checked), unchecked_few=few, unchecked_many=len(many), most=LOO_MAX_SEEDS)
        blocks.append(Paragraph(say("findings.leave_one_out", **facts)))
    items: list[Item] = []
    for variant in ablation.variants:
        rows = compare[compare.variant == variant] if len(compare) else compare
        if rows.empty:
            continue
        sub = []
        for _, row in rows.iterrows():
            text = finding(row, ablation, table)
            if row.get("primary", False) and row.claim:
                text += " " + say("findings.primary_claim", claim=row.claim)
            if row.metric == "episodes_to_solve" and not pd.isna(row.p_improvement):
                text += " " + say("findings.p_improvement", row=row)
            sub.append(text)
        items.append(Item(f"**{esc(variant)}** vs {esc(ablation.reference(variant))}:", tuple(sub)))
    for _, row in table.iterrows():
        if row.seeds_run and ablation.threshold is not None and row.solved < row.seeds_run:
            items.append(Item(say("findings.unsolved", row=row)))
    return blocks + ([Items(tuple(items))] if items else [])


def _rank_key(ablation: Ablation, row: pd.Series) -> tuple:
    if ablation.any_solved:
        return (row.episodes_iqm, -row.auc_iqm)
    return (-row.auc_iqm if not pd.isna(row.auc_iqm) else np.inf,)


def _effect_words(row: pd.Series, question: Question) -> str:
    """The effect and its family-level interval in words: "35% fewer episodes to solve (interval 12% to 52%
    fewer)"; a difference of AUC or return signed in its units."""
    name = _metric_name(row.metric)
    if question.relative:  # the table's change is in percent

        def side(x: float) -> str:
            return f"{percent(abs(x) / 100)} {'fewer' if x < 0 else 'more'}" if x else "0%"

        low, high = row.change_low, row.change_high
        if np.isnan(low) or np.isnan(high):
            interval = "no interval"
        elif not np.isfinite(low) and not np.isfinite(high):
            interval = "its interval at the family level is unbounded with so few seeds"
        elif not np.isfinite(high):  # [low, +inf): at least low more, or anything from low fewer up
            interval = f"interval: {'at least' if low >= 0 else 'from'} {side(low)}, no upper end"
        elif not np.isfinite(low):  # (-inf, high]: at least high fewer, or anything up to high more
            interval = f"interval: {'at least' if high <= 0 else 'at most'} {side(high)}, no lower end"
        elif high < 0:
            interval = f"interval {percent(-high / 100)} to {percent(-low / 100)} fewer"
        elif low > 0:
            interval = f"interval {percent(low / 100)} to {percent(high / 100)} more"
        else:
            interval = f"interval {side(low)} to {side(high)}"
        change = f"no change in {name}" if row.change == 0 else f"{side(row.change)} {name}"
        return f"{change} ({interval})"
    if np.isnan(row.change_low):
        return f"{name} {_signed(row.change)} (no interval)"
    low = "−∞" if not np.isfinite(row.change_low) else _signed(row.change_low)
    high = "+∞" if not np.isfinite(row.change_high) else _signed(row.change_high)
    return f"{name} {_signed(row.change)} (interval {low} to {high})"


def _seeds_needed_words(needed: float, cap: int) -> str:
    needed = None if np.isinf(needed) else int(needed)
    return say("findings.primary_seeds_needed", needed=needed, cap=cap, min_seeds=advice.MIN_SEEDS)


def claim_line(row: pd.Series, primary: Question, pace: float | None = None) -> str:
    """One primary claim (a row of ``claims_table``) in words a student can hand in. ``pace``: seconds a seed
    added in rounds cost this launch (``rounds.seconds_per_trial``), for what more seeds would cost."""
    question = primary if row.metric == primary.metric or primary.fallback is None else primary.fallback
    never = measure(primary.metric).never
    switched = "" if question is primary else say("findings.switched", row=row, primary=primary.metric, never=never)
    stat = stat_name(int(row.n_variant), int(row.n_reference))
    digits = 0 if question.relative else 1
    # a one-sided bound supports only the claim it leans towards: worse when the variant's IQM is the bound,
    # better when the reference's is (statistics: exploratory_comparison)
    # "censored": both IQMs count unsolved seeds as the budget, so both are bounds, as Table 1 writes them
    x_bound = "≥ " if row.bound == "censored" or (row.bound and row.verdict == WORSE) else ""
    y_bound = "≥ " if row.bound == "censored" or (row.bound and row.verdict == BETTER) else ""
    iqms = f"{stat} {x_bound}{fmt(row.variant_value, digits)} vs {y_bound}{fmt(row.reference_value, digits)}"
    effect = _effect_words(row, question)
    low, high = row.change_low, row.change_high
    reaches = not (np.isnan(low) or np.isnan(high)) and low <= 0 <= high
    margin = percent(question.smallest_effect) if row.verdict == EQUIVALENT else None
    words = None if pd.isna(row.seeds_needed) else _seeds_needed_words(row.seeds_needed, int(row.seeds_cap))
    more = None
    if words and pace and np.isfinite(row.seeds_needed):
        more = 2 * max(int(row.seeds_needed) - int(min(row.n_variant, row.n_reference)), 0)
    first = int(row.seeds_first) if row.get("seeds_first", 0) and pd.isna(row.seeds_needed) else None
    facts = dict(effect=effect, iqms=iqms, reaches=reaches, margin=margin, words=words, first=first)
    duration = None if more is None else _duration(more * pace)
    claimed = row.verdict in (BETTER, WORSE)
    return say("findings.claim", row=row, claimed=claimed, more=more, duration=duration, switched=switched, **facts)


def claims(ablation: Ablation, table: pd.DataFrame | None = None) -> list[Block]:
    """The primary claims (``table``: ``claims_table``, computed when not given): one sentence naming the family,
    the correction and the level, then a list of one item per row with its verdict, effect, interval and seeds."""
    table = table if table is not None else claims_table(ablation)
    question = primary_question(ablation)
    k = len(table)
    if not k:
        return [Paragraph(say("findings.no_claims"))]
    design = claims_design(ablation)
    family = family_sentence(k, sequential=design.max > design.start, spending=design.spending)
    facts = dict(family=family, metric=question.metric, k=k, effect=question.smallest_effect)
    intro = say("findings.claims_intro", **facts, **_margin(ablation, table))
    pace = seconds_per_trial((ablation.launch or {}).get("rounds"))
    return [Paragraph(intro), Items.of(claim_line(row, question, pace) for _, row in table.iterrows())]


def _duration(seconds: float) -> str:
    minutes = seconds / 60
    return f"{seconds:.0f} s" if minutes < 2 else f"{minutes:.0f} min" if minutes < 120 else f"{minutes / 60:.1f} h"


def _margin(ablation: Ablation, table: pd.DataFrame) -> dict:
    """Why the margin: what ± ``smallest_effect`` of the baseline is in episodes and in updates, a difference
    below what changes how fast an agent learns in practice (on episodes to solve; else nothing)."""
    episodes = table[table.metric == "episodes_to_solve"]
    rows = episodes[episodes.reference == ablation.baseline]
    if rows.empty:
        return dict(margin=None, reference=None, per_update=1)
    reference = float(rows.reference_value.iloc[0])
    per_update = int(ablation.grid.get("base", {}).get("episodes_per_update", 1) or 1)
    return dict(margin=ablation.smallest_effect * reference, reference=reference, per_update=per_update)


def summary(
    ablation: Ablation, table: pd.DataFrame, compare: pd.DataFrame, claimed: pd.DataFrame | None = None
) -> list[Block]:
    """The primary claims first (``claimed``: ``claims_table``, computed when not given); then the variants
    ranked on the primary metric with each one's own 95% interval (exploratory: unadjusted)."""
    claimed = claimed if claimed is not None else claims_table(ablation)
    verdicts = {row.variant: row for row in claimed.itertuples()}
    ran = table[table.seeds_run > 0]
    ranked = sorted(ran.iterrows(), key=lambda item: _rank_key(ablation, item[1]))
    primary = ablation.primary_metric
    extends = _extends(ablation)
    rows = []
    for rank, (_, row) in enumerate(ranked, 1):
        verdict = "reference" if row.variant == ablation.baseline else "–"
        if row.variant in verdicts:
            verdict = verdicts[row.variant].verdict
            if extends:
                verdict = f"vs {esc(ablation.reference(row.variant))}: {verdict}"
        entry = {"rank": rank, "variant": esc(row.variant)}
        if ablation.threshold is not None:
            entry["solved"] = f"{int(row.solved)}/{int(row.seeds_run)}"
        if ablation.any_solved:
            entry[f"episodes to solve, IQM [{percent(CONFIDENCE)} CI]"] = _episodes_cell(row, "iqm")
        entry[f"AUC, IQM [{percent(CONFIDENCE)} CI]"] = _stat_cell(row, "auc_iqm", ci="auc")
        entry["primary claim"] = verdict
        rows.append(entry)
    return [
        *claims(ablation, claimed),
        Paragraph(say("findings.ranked", any_solved=ablation.any_solved, primary=primary)),
        Table(pd.DataFrame(rows), "The variants ranked (exploratory)"),
    ]
