"""The findings (one line per comparison and metric, in words) and the summary (variants ranked, with what
the data support against each one's reference)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ablate.claims import BETTER, EQUIVALENT, WORSE, Question, advice, family_sentence
from ablate.claims.family import CENSORED_SHARE
from ablate.design import CONFIDENCE, percent
from ablate.measures import is_censored, measure
from ablate.reporting.blocks import Block, Item, Items, Paragraph, Table
from ablate.reporting.comparisons import LOO_MAX_SEEDS, claims_design, claims_table, primary_question
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
from ablate.reporting.text import _interval, _metric_name, _pct, _signed, _signed_pct, esc, fmt


def _no_claim_reason(n: int, m: int) -> str:
    if min(n, m) < 2:
        return f"{min(n, m)} seed{'s give' if min(n, m) != 1 else ' gives'} no interval"
    return (
        f"with {n} and {m} seeds no ordering of the seeds can reach {percent(CONFIDENCE)} confidence (smallest "
        "possible "
        f"p = {smallest_p_value(n, m):.2f})"
    )


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
    if row.bound == "censored":
        return " Both sides count seeds that never got there as the budget: episodes cannot separate them."
    stat = stat_name(int(row.n_variant), int(row.n_reference))
    if is_censored(row.metric):
        return (
            f" {_pair(row, table, stat)} episodes, change "
            f"{_signed_pct(-row.point)} ({percent(CONFIDENCE)} bootstrap CI {_signed_pct(-row.high)} to "
            f"{_signed_pct(-row.low)})."
        )
    return (
        f" {stat} {fmt(row.variant_value, 1)} vs {fmt(row.reference_value, 1)}, {_signed(row.point)} "
        f"({percent(CONFIDENCE)} bootstrap CI {_signed(row.low)} to {_signed(row.high)})."
    )


def seeds_reading(row: pd.Series, effect: float) -> str:
    """What "not separated" means for this comparison: too few seeds for a difference this large, or no
    effect this large; and the seeds a difference of the smallest effect of interest would need. On the primary
    metric, the claims' one figure (the seeds that would decide the claim), not a second estimate."""
    needed, smallest = row.get("seeds_needed", np.nan), row.get("seeds_needed_smallest", np.nan)
    if pd.isna(needed):
        return ""
    if row.get("primary", False):
        return f" Seeds needed (the primary claim's): {_seeds_needed_words(needed, int(row.seeds_cap))}."
    if needed > SEEDS_CAP:
        observed = (
            f"**no effect this large**: even {SEEDS_CAP} seeds per variant would not separate a difference as small "
            "as the one observed"
        )
    else:
        observed = f"**too few seeds**: about {int(needed)} per variant would separate a difference this large"
    wanted = f"more than {SEEDS_CAP}" if pd.isna(smallest) or smallest > SEEDS_CAP else f"about {int(smallest)}"
    return f" Seeds needed: {observed}; {wanted} to separate the smallest effect of interest ({_pct(effect)})."


def _stability(row: pd.Series) -> str:
    if row.verdict not in SEPARATED:
        return ""
    if row.fragile_seeds:
        seeds = str(row.fragile_seeds).split()
        return (
            f" **Fragile:** the claim does not survive leaving out seed{'s' if len(seeds) > 1 else ''} "
            f"{', '.join(seeds)}."
        )
    return ""  # holding is the rule, said once before the list


def _never_counts(row: pd.Series, table: pd.DataFrame, n: int, m: int) -> str:
    """``3 of 5 a seeds and 5 of 5 b seeds never solved`` (or ``never reached -15``): the seeds an episodes IQM
    counts as the budget, read from the convergence table."""

    def never(variant: str) -> int:
        return _never(table, variant, row.metric)

    what = measure(row.metric).never
    variant, reference = esc(row.variant), esc(row.reference)
    counts = f"{never(row.variant):,} of {n:,} {variant} seeds and {never(row.reference):,} of {m:,} {reference} seeds"
    return f"{counts} {what}"


def finding(row: pd.Series, ablation: Ablation, table: pd.DataFrame) -> str:
    """One metric's comparison in words: what may be claimed, sized as an estimate or as a bound, with its
    interval and whether it survives leaving out any one seed."""
    base, metric, name = esc(row.reference), row.metric, _metric_name(row.metric)
    n, m = int(row.n_variant), int(row.n_reference)
    stat = stat_name(n, m)
    reading = seeds_reading(row, ablation.smallest_effect)
    if row.verdict == TOO_FEW_SEEDS:
        return f"{name}: *{TOO_FEW_SEEDS}*.{_estimate(row, table)}{reading}"
    if is_censored(metric):
        counts = _never_counts(row, table, n, m)
        if row.bound == "censored":
            never = "unsolved seeds" if metric == "episodes_to_solve" else "the seeds that never got there"
            return (
                f"{name}: *{NOT_SEPARATED}*: episodes cannot separate them: both IQMs count {never} as the budget "
                f"({counts}), so both are lower bounds; see the returns below."
            )
        change = _pair(row, table, stat)
        if row.verdict == EXPLORATORY_BETTER and row.bound:
            return (
                f"{name}: *{row.verdict}*, **at least {_pct(row.point)} fewer** than {base} ({change}; a bound: "
                f"{base}'s IQM counts "
                f"unsolved seeds as the budget ({counts}), so the true gap is larger; {percent(CONFIDENCE)} lower "
                "bound "
                f"{_pct(row.low)} fewer).{_stability(row)}"
            )
        if row.verdict == EXPLORATORY_WORSE and row.bound:
            return (
                f"{name}: *{row.verdict}*, **at least {_pct(-row.point)} more** than {base} ({change}; a lower bound, "
                "since unsolved "
                f"seeds count as the budget: {counts}; {percent(CONFIDENCE)} lower bound {_pct(-row.high)} more; no "
                "upper bound can be "
                f"given).{_stability(row)}"
            )
        if row.verdict == EXPLORATORY_BETTER:
            return (
                f"{name}: *{row.verdict}*, **{_pct(row.point)} fewer** than {base} ({change}; {percent(CONFIDENCE)} CI "
                f"{_pct(row.low)} to "
                f"{_pct(row.high)} fewer).{_stability(row)}"
            )
        if row.verdict == EXPLORATORY_WORSE:
            return (
                f"{name}: *{row.verdict}*, **{_pct(-row.point)} more** than {base} ({change}; {percent(CONFIDENCE)} CI "
                f"{_pct(-row.high)} to "
                f"{_pct(-row.low)} more).{_stability(row)}"
            )
        bound = ", ≥: a lower bound" if row.bound else ""
        return (
            f"{name}: *{NOT_SEPARATED}* ({change}{bound}; change {_signed_pct(-row.point)}, {percent(CONFIDENCE)} CI "
            f"{_signed_pct(-row.high)} to {_signed_pct(-row.low)}{'; ' + counts if counts else ''}).{reading}"
        )
    x, y = fmt(row.variant_value, 1), fmt(row.reference_value, 1)
    interval = f"{percent(CONFIDENCE)} CI {_signed(row.low)} to {_signed(row.high)}"
    if row.verdict == EXPLORATORY_BETTER:
        return f"{name}: *{row.verdict}*, **higher**, {x} vs {y} ({_signed(row.point)}; {interval}).{_stability(row)}"
    if row.verdict == EXPLORATORY_WORSE:
        return f"{name}: *{row.verdict}*, **lower**, {x} vs {y} ({_signed(row.point)}; {interval}).{_stability(row)}"
    return f"{name}: *{NOT_SEPARATED}*, {stat} {x} vs {y} ({_signed(row.point)}; {interval}).{reading}"


def findings(ablation: Ablation, table: pd.DataFrame, compare: pd.DataFrame) -> list[Block]:
    """Per variant, one line per metric; no claim without an interval, bounds worded as bounds. What holds
    for every comparison (too few seeds for any claim) is said once, first."""
    blocks: list[Block] = [
        Paragraph(
            f"*Exploratory:* every metric, each comparison judged on its own by its {percent(CONFIDENCE)} bootstrap "
            "interval "
            "(unadjusted for the others: about one in twenty true nulls reads as a difference here). The report's "
            "claims are the primary ones, above."
        )
    ]
    undecidable = compare[compare.verdict == TOO_FEW_SEEDS] if len(compare) else compare
    if len(undecidable):
        pairs = sorted({(int(r.n_variant), int(r.n_reference)) for r in undecidable.itertuples()})
        reasons = "; ".join(_no_claim_reason(n, m) for n, m in pairs)
        blocks.append(
            Paragraph(
                f"**Too few seeds for a claim** ({reasons}): {len(undecidable)} of {len(compare)} comparisons below "
                f"read *{TOO_FEW_SEEDS}*. Their estimates are pointers for a larger run, not results; *seeds "
                "needed* says how many would do."
            )
        )
    claims = compare[compare.verdict.isin(list(SEPARATED))] if len(compare) else compare
    if len(claims):
        checked = claims[claims.loo_checked.astype(bool)] if "loo_checked" in claims else claims
        notes = []
        if len(checked):
            notes.append(
                "Each claim was recomputed without each seed in turn: it holds leaving out any one seed unless "
                "marked **fragile**."
            )
        unchecked = claims[~claims.index.isin(checked.index)]
        many = unchecked[unchecked[["n_variant", "n_reference"]].max(axis=1) > LOO_MAX_SEEDS]
        if len(many) < len(unchecked):
            notes.append(
                "Leaving out one of so few seeds leaves too few for any claim, so the claims of a variant with 4 "
                "seeds or fewer were not checked that way."
            )
        if len(many):
            notes.append(
                f"Where a side has more than {LOO_MAX_SEEDS} seeds, one seed is under {percent(1 / LOO_MAX_SEEDS)} of "
                "its sample and the "
                "check is not made."
            )
        blocks.append(Paragraph(" ".join(notes)))
    items: list[Item] = []
    for variant in ablation.variants:
        rows = compare[compare.variant == variant] if len(compare) else compare
        if rows.empty:
            continue
        sub = []
        for _, row in rows.iterrows():
            text = finding(row, ablation, table)
            if row.get("primary", False) and row.claim:
                text += f" The primary claim (above): **{row.claim}**."
            if row.metric == "episodes_to_solve" and not pd.isna(row.p_improvement):
                text += (
                    f" P(fewer episodes) = {row.p_improvement:.2f} "
                    f"{_interval(row.p_improvement_ci_low, row.p_improvement_ci_high, 2)}."
                )
            sub.append(text)
        items.append(Item(f"**{esc(variant)}** vs {esc(ablation.reference(variant))}:", tuple(sub)))
    for _, row in table.iterrows():
        if row.seeds_run and ablation.threshold is not None and row.solved < row.seeds_run:
            items.append(
                Item(
                    f"**{esc(row.variant)}**: {int(row.seeds_run - row.solved):,} of {int(row.seeds_run):,} seeds did "
                    f"not solve within {fmt(row.budget)} episodes."
                )
            )
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
            return f"{_pct(abs(x) / 100)} {'fewer' if x < 0 else 'more'}" if x else "0%"

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
            interval = f"interval {_pct(-high / 100)} to {_pct(-low / 100)} fewer"
        elif low > 0:
            interval = f"interval {_pct(low / 100)} to {_pct(high / 100)} more"
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
    if np.isinf(needed):
        return f"more than {cap} seeds per variant would be needed to decide it"
    return (
        f"about {int(needed)} seeds per variant would decide it (in {_pct(advice.POWER)} of runs like this one; "
        f"`seeds = {{ start = {advice.MIN_SEEDS}, step = {advice.MIN_SEEDS}, max = {int(needed)}, growth = 2 }}` "
        "adds them in rounds, stopping as soon as it is decided)"
    )


def claim_line(row: pd.Series, primary: Question, pace: float | None = None) -> str:
    """One primary claim (a row of ``claims_table``) in words a student can hand in. ``pace``: seconds a seed
    added in rounds cost this launch (``rounds.seconds_per_trial``), for what more seeds would cost."""
    variant, reference = esc(row.variant), esc(row.reference)
    question = primary if row.metric == primary.metric or primary.fallback is None else primary.fallback
    switched = (
        f" Judged on {_metric_name(row.metric)}, not {_metric_name(primary.metric)}: {_pct(row.censored)} of its "
        f"seeds {measure(primary.metric).never} within the budget, so episodes cannot rank them (the rule, fixed "
        f"before the data: more than {_pct(CENSORED_SHARE)} unsolved)."
        if question is not primary
        else ""
    )
    stat = stat_name(int(row.n_variant), int(row.n_reference))
    digits = 0 if question.relative else 1
    # a one-sided bound supports only the claim it leans towards: worse when the variant's IQM is the bound,
    # better when the reference's is (statistics: _episodes_comparison)
    # "censored": both IQMs count unsolved seeds as the budget, so both are bounds, as Table 1 writes them
    x_bound = "≥ " if row.bound == "censored" or (row.bound and row.verdict == WORSE) else ""
    y_bound = "≥ " if row.bound == "censored" or (row.bound and row.verdict == BETTER) else ""
    iqms = f"{stat} {x_bound}{fmt(row.variant_value, digits)} vs {y_bound}{fmt(row.reference_value, digits)}"
    seeds = f"{int(row.n_variant)} and {int(row.n_reference)} seeds"
    effect = _effect_words(row, question)
    if row.verdict in (BETTER, WORSE):
        bound = " at least" if row.bound else ""
        low, high = row.change_low, row.change_high
        reaches = not (np.isnan(low) or np.isnan(high)) and low <= 0 <= high
        step = (
            f" (Holm's step-down made this claim at the {row.level:.2%} level; the interval, at the stricter level "
            "shared by all the family's intervals, still reaches no change)"
            if reaches
            else ""
        )
        return f"**{variant}** is **{row.verdict}** than {reference}:{bound} {effect}; {iqms}; {seeds}{step}.{switched}"
    if row.verdict == EQUIVALENT:
        margin = _pct(question.smallest_effect)
        return f"**{variant}** is **equivalent** to {reference} within ±{margin}: {effect}; {iqms}; {seeds}.{switched}"
    needed = "" if pd.isna(row.seeds_needed) else f"; {_seeds_needed_words(row.seeds_needed, int(row.seeds_cap))}"
    if needed and pace and np.isfinite(row.seeds_needed):
        more = 2 * max(int(row.seeds_needed) - int(min(row.n_variant, row.n_reference)), 0)
        needed += f", {more:,} more trials: about {_duration(more * pace)} on this machine at this launch's pace"
    if row.get("seeds_first", 0) and pd.isna(row.seeds_needed):
        needed = (
            f"; {int(row.n_variant)} seeds cannot support a prediction of the seeds that would decide it: run "
            f"{int(row.seeds_first)} per variant first"
        )
    return (
        f"**{variant}** vs {reference}: **undetermined** ({row.reason}): {effect}; {iqms}; {seeds}{needed}.{switched}"
    )


def claims(ablation: Ablation, table: pd.DataFrame | None = None) -> list[Block]:
    """The primary claims (``table``: ``claims_table``, computed when not given): one sentence naming the family,
    the correction and the level, then a list of one item per row with its verdict, effect, interval and seeds."""
    table = table if table is not None else claims_table(ablation)
    question = primary_question(ablation)
    k = len(table)
    if not k:
        return [Paragraph("No variant has finished seeds to compare with its reference.")]
    design = claims_design(ablation)
    intro = (
        f"{family_sentence(k, sequential=design.max > design.start, spending=design.spending)} The claims are on "
        f"{_metric_name(question.metric)} (the experiment's primary question); each interval is simultaneous "
        f"over the {k} ({percent(CONFIDENCE)} for all of them together); "
        f"*equivalent* means within ±{_pct(question.smallest_effect)} of the reference{_margin_why(ablation, table)}."
    )
    pace = seconds_per_trial((ablation.launch or {}).get("rounds"))
    return [Paragraph(intro), Items.of(claim_line(row, question, pace) for _, row in table.iterrows())]


def _duration(seconds: float) -> str:
    minutes = seconds / 60
    return f"{seconds:.0f} s" if minutes < 2 else f"{minutes:.0f} min" if minutes < 120 else f"{minutes / 60:.1f} h"


def _margin_why(ablation: Ablation, table: pd.DataFrame) -> str:
    """Why the margin: what ± ``smallest_effect`` of the baseline is in episodes and in updates, a difference
    below what changes how fast an agent learns in practice (on episodes to solve; else nothing)."""
    episodes = table[table.metric == "episodes_to_solve"]
    rows = episodes[episodes.reference == ablation.baseline]
    if rows.empty:
        return ""
    reference = float(rows.reference_value.iloc[0])
    per_update = int(ablation.grid.get("base", {}).get("episodes_per_update", 1) or 1)
    margin = ablation.smallest_effect * reference
    updates = f", {margin / per_update:.1f} updates of {per_update} episodes" if per_update > 1 else ""
    return (
        f" (the experiment's `smallest_effect`: about {margin:.0f} episodes of the baseline's {reference:.0f}"
        f"{updates}, a difference too small to change how fast an agent learns in practice, and one that "
        "hundreds of seeds can resolve)"
    )


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
        entry[f"AUC, IQM [{percent(CONFIDENCE)} CI]"] = _stat_cell(
            row, "auc_iqm", low_key="auc_ci_low", high_key="auc_ci_high"
        )
        entry["primary claim"] = verdict
        rows.append(entry)
    how = (
        "fewest episodes to solve (IQM, censored), ties by AUC"
        if ablation.any_solved
        else "highest area under the learning curve (IQM)"
    )
    return [
        *claims(ablation, claimed),
        Paragraph(
            f"*Exploratory:* the variants ranked by {how}, each interval a {percent(CONFIDENCE)} bootstrap interval of "
            "that variant "
            f"alone (unadjusted: not a claim). A rank orders point estimates only; the last column repeats the "
            f"primary claim on {_metric_name(primary)}."
        ),
        Table(pd.DataFrame(rows), "The variants ranked (exploratory)"),
    ]
