"""The findings (one line per comparison and metric, in words) and the summary (variants ranked, with what
the data support against each one's reference)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ablate.claims import EQUIVALENT, Question, Round, Verdict, family_sentence, iqm
from ablate.reporting.comparisons import claims_design, primary_claims, primary_question
from ablate.reporting.figures import esc as _esc
from ablate.reporting.figures import fmt as _fmt
from ablate.reporting.results import Ablation
from ablate.reporting.sections import _episodes_cell, _extends, _stat_cell
from ablate.reporting.statistics import BETTER, NO_CLAIM, SEEDS_CAP, WORSE, smallest_p_value
from ablate.reporting.text import _interval, _markdown_table, _metric_name, _pct, _signed, _signed_pct


def _findings_intro(ablation: Ablation) -> str:
    extends = _extends(ablation)
    if not extends:
        return f"Each variant against {_esc(ablation.baseline)}"
    pairs = ", ".join(f"{_esc(v)} against {_esc(ablation.reference(v))}" for v in extends)
    return (
        f"Each variant against its reference: {_esc(ablation.baseline)}, or, for a variant that adds one change to "
        f"another variant's, that variant, so each comparison isolates one change ({pairs})"
    )


def _no_claim_reason(n: int, m: int) -> str:
    if min(n, m) < 2:
        return f"{min(n, m)} seed{'s give' if min(n, m) != 1 else ' gives'} no interval"
    return (
        f"with {n} and {m} seeds no ordering of the seeds can reach 95% confidence (smallest possible "
        f"p = {smallest_p_value(n, m):.2f})"
    )


def stat_name(n: int, m: int) -> str:
    """What the report's "IQM" of ``n`` and ``m`` seeds is: with fewer than 4 seeds it trims nothing
    (SciPy's ``trim_mean`` cuts ``int(0.25 n)`` from each end) and is the plain mean."""
    if min(n, m) >= 4:
        return "IQM"
    return "mean" if max(n, m) < 4 else "IQM (the mean where fewer than 4 seeds)"


def _estimate(row: pd.Series) -> str:
    """The estimate and its bootstrap interval for a comparison the seeds cannot decide, with no direction
    words: a percentile bootstrap over 3 seeds runs narrow, so it is a pointer for a larger run."""
    if any(np.isnan(v) for v in (row.point, row.low, row.high)):
        return ""
    if row.bound == "censored":
        return " Both sides count seeds that never got there as the budget: episodes cannot separate them."
    stat = stat_name(int(row.n_variant), int(row.n_reference))
    if row.metric.startswith("episodes_to_"):
        bound = "≥ " if row.bound else ""
        return (
            f" {stat} {bound}{_fmt(row.variant_value)} vs {_fmt(row.reference_value)} episodes, change "
            f"{_signed_pct(-row.point)} (95% bootstrap CI {_signed_pct(-row.high)} to {_signed_pct(-row.low)})."
        )
    return (
        f" {stat} {_fmt(row.variant_value, 1)} vs {_fmt(row.reference_value, 1)}, {_signed(row.point)} "
        f"(95% bootstrap CI {_signed(row.low)} to {_signed(row.high)})."
    )


def seeds_reading(row: pd.Series, effect: float) -> str:
    """What "not separated" means for this comparison: too few seeds for a difference this large, or no
    effect this large; and the seeds a difference of the smallest effect of interest would need."""
    needed, smallest = row.get("seeds_needed", np.nan), row.get("seeds_needed_smallest", np.nan)
    if pd.isna(needed):
        return ""
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
    if row.verdict not in (BETTER, WORSE):
        return ""
    if row.fragile_seeds:
        seeds = str(row.fragile_seeds).split()
        return (
            f" **Fragile:** the claim does not survive leaving out seed{'s' if len(seeds) > 1 else ''} "
            f"{', '.join(seeds)}."
        )
    return ""  # holding is the rule, said once before the list


def finding(row: pd.Series, ablation: Ablation, table: pd.DataFrame) -> str:
    """One metric's comparison in words: what may be claimed, sized as an estimate or as a bound, with its
    interval and whether it survives leaving out any one seed."""
    base, metric, name = _esc(row.reference), row.metric, _metric_name(row.metric)
    n, m = int(row.n_variant), int(row.n_reference)
    stat = stat_name(n, m)
    reading = seeds_reading(row, ablation.smallest_effect)
    if row.verdict == NO_CLAIM:
        return f"{name}: **too few seeds to tell**.{_estimate(row)}{reading}"
    if metric.startswith("episodes_to_"):
        x, y = _fmt(row.variant_value), _fmt(row.reference_value)
        unsolved = (
            (lambda v: int(table.loc[table.variant == v, "unsolved_censored"].iloc[0]))
            if metric == "episodes_to_solve"
            else None
        )
        counts = ""
        if unsolved is not None:
            counts = (
                f"{unsolved(row.variant)} of {n} {_esc(row.variant)} seeds and {unsolved(row.reference)} of {m} "
                f"{base} seeds never solved"
            )
        if row.bound == "censored":
            return (
                f"{name}: cannot separate them: both IQMs count unsolved seeds as the budget ({counts}), so both are "
                "lower bounds; see the returns below."
            )
        change = f"{stat} {'≥ ' if row.bound and row.verdict == WORSE else ''}{x} vs {y}"
        if row.verdict == BETTER and row.bound:
            return (
                f"{name}: **at least {_pct(row.point)} fewer** than {base} ({change}; a bound: {base}'s IQM counts "
                f"unsolved seeds as the budget ({counts}), so the true gap is larger; 95% lower bound "
                f"{_pct(row.low)} fewer).{_stability(row)}"
            )
        if row.verdict == WORSE and row.bound:
            return (
                f"{name}: **at least {_pct(-row.point)} more** than {base} ({change}; a lower bound, since unsolved "
                f"seeds count as the budget: {counts}; 95% lower bound {_pct(-row.high)} more; no upper bound can be "
                f"given).{_stability(row)}"
            )
        if row.verdict == BETTER:
            return (
                f"{name}: **{_pct(row.point)} fewer** than {base} ({change}; 95% CI {_pct(row.low)} to "
                f"{_pct(row.high)} fewer).{_stability(row)}"
            )
        if row.verdict == WORSE:
            return (
                f"{name}: **{_pct(-row.point)} more** than {base} ({change}; 95% CI {_pct(-row.high)} to "
                f"{_pct(-row.low)} more).{_stability(row)}"
            )
        bound = f", the variant's {stat} a lower bound" if row.bound else ""
        return (
            f"{name}: not separated ({change}{bound}; change {_signed_pct(-row.point)}, 95% CI "
            f"{_signed_pct(-row.high)} to {_signed_pct(-row.low)}{'; ' + counts if counts else ''}).{reading}"
        )
    x, y = _fmt(row.variant_value, 1), _fmt(row.reference_value, 1)
    interval = f"95% CI {_signed(row.low)} to {_signed(row.high)}"
    if row.verdict == BETTER:
        return f"{name}: **higher**, {x} vs {y} ({_signed(row.point)}; {interval}).{_stability(row)}"
    if row.verdict == WORSE:
        return f"{name}: **lower**, {x} vs {y} ({_signed(row.point)}; {interval}).{_stability(row)}"
    return f"{name}: not separated, {stat} {x} vs {y} ({_signed(row.point)}; {interval}).{reading}"


def findings(ablation: Ablation, table: pd.DataFrame, compare: pd.DataFrame) -> list[str]:
    """Per variant, one line per metric; no claim without an interval, bounds worded as bounds. What holds
    for every comparison (too few seeds for any claim) is said once, first."""
    lines = [
        "*Exploratory:* every metric, each comparison judged on its own by its 95% bootstrap interval "
        "(unadjusted for the others: about one in twenty true nulls reads as a difference here). The report's "
        "claims are the primary ones, above.",
        "",
    ]
    undecidable = compare[compare.verdict == NO_CLAIM] if len(compare) else compare
    if len(undecidable):
        pairs = sorted({(int(r.n_variant), int(r.n_reference)) for r in undecidable.itertuples()})
        reasons = "; ".join(_no_claim_reason(n, m) for n, m in pairs)
        lines += [
            f"**Too few seeds for a claim** ({reasons}): {len(undecidable)} of {len(compare)} comparisons below "
            "read *too few seeds to tell*. Their estimates are pointers for a larger run, not results; *seeds "
            "needed* says how many would do.",
            "",
        ]
    claims = compare[compare.verdict.isin([BETTER, WORSE])] if len(compare) else compare
    if len(claims):
        checked = claims[claims.loo_checked.astype(bool)] if "loo_checked" in claims else claims
        notes = []
        if len(checked):
            notes.append(
                "Each claim was recomputed without each seed in turn: it holds leaving out any one seed unless "
                "marked **fragile**."
            )
        if len(checked) < len(claims):
            notes.append(
                "Leaving out one of so few seeds leaves too few for any claim, so the claims of a variant with 4 "
                "seeds or fewer were not checked that way."
            )
        lines += [" ".join(notes), ""]
    for variant in ablation.variants:
        rows = compare[compare.variant == variant] if len(compare) else compare
        if rows.empty:
            continue
        lines.append(f"- **{_esc(variant)}** vs {_esc(ablation.reference(variant))}:")
        for _, row in rows.iterrows():
            text = finding(row, ablation, table)
            if row.metric == "episodes_to_solve" and not pd.isna(row.p_improvement):
                text += (
                    f" P(fewer episodes) = {row.p_improvement:.2f} "
                    f"{_interval(row.p_improvement_ci_low, row.p_improvement_ci_high, 2)}."
                )
            lines.append(f"    - {text}")
    for _, row in table.iterrows():
        if row.seeds_run and ablation.threshold is not None and row.solved < row.seeds_run:
            lines.append(
                f"- **{_esc(row.variant)}**: {int(row.seeds_run - row.solved)} of {int(row.seeds_run)} seeds did "
                f"not solve within {_fmt(row.budget)} episodes."
            )
    return lines


def _rank_key(ablation: Ablation, row: pd.Series) -> tuple:
    if ablation.any_solved:
        return (row.episodes_iqm, -row.auc_iqm)
    return (-row.auc_iqm if not pd.isna(row.auc_iqm) else np.inf,)


def _effect_words(v: Verdict, question: Question) -> str:
    """The effect and its family-level interval in words: "35% fewer episodes to solve (interval 12% to 52%
    fewer)"; a difference of AUC or return signed in its units."""
    name = _metric_name(v.metric)
    if question.relative:

        def side(x: float) -> str:
            return f"{_pct(abs(x))} {'fewer' if x < 0 else 'more'}" if x else "no change"

        if np.isnan(v.low) or np.isnan(v.high):
            interval = "no interval"
        elif not np.isfinite(v.low) and not np.isfinite(v.high):
            interval = "its interval at the family level is unbounded with so few seeds"
        elif not np.isfinite(v.high):
            interval = f"interval: at least {side(v.low)}, no upper end"
        elif not np.isfinite(v.low):
            interval = f"interval: at most {side(v.high)}, no lower end"
        elif v.high < 0:
            interval = f"interval {_pct(-v.high)} to {_pct(-v.low)} fewer"
        elif v.low > 0:
            interval = f"interval {_pct(v.low)} to {_pct(v.high)} more"
        else:
            interval = f"interval {side(v.low)} to {side(v.high)}"
        return f"{side(v.estimate)} {name} ({interval})"
    if np.isnan(v.low):
        return f"{name} {_signed(v.estimate)} (no interval)"
    low = "−∞" if not np.isfinite(v.low) else _signed(v.low)
    high = "+∞" if not np.isfinite(v.high) else _signed(v.high)
    return f"{name} {_signed(v.estimate)} (interval {low} to {high})"


def _seeds_words(v: Verdict) -> str:
    if not v.seeds_estimated:
        return ""
    if v.seeds_needed is None:
        return f"; more than {v.seeds_cap} seeds per variant would be needed to decide it"
    return f"; about {v.seeds_needed} seeds per variant would decide it (in 80% of runs like this one)"


def claim_line(v: Verdict, question: Question, values: tuple[float, float]) -> str:
    """One primary claim in words a student can hand in."""
    variant, reference = _esc(v.variant), _esc(v.reference)
    stat = stat_name(v.n_variant, v.n_reference)
    digits = 0 if question.relative else 1
    at_least = "≥ " if v.bound and v.verdict == WORSE else ""
    iqms = f"{stat} {at_least}{_fmt(values[0], digits)} vs {_fmt(values[1], digits)}"
    seeds = f"{v.n_variant} and {v.n_reference} seeds"
    effect = _effect_words(v, question)
    if v.verdict in (BETTER, WORSE):
        bound = " at least" if v.bound else ""
        reaches = not (np.isnan(v.low) or np.isnan(v.high)) and v.low <= 0 <= v.high
        step = (
            f" (Holm's step-down made this claim at the {v.level:.2%} level; the interval, at the stricter level "
            "shared by all the family's intervals, still reaches no change)"
            if reaches
            else ""
        )
        return f"- **{variant}** is **{v.verdict}** than {reference}:{bound} {effect}; {iqms}; {seeds}{step}."
    if v.verdict == EQUIVALENT:
        margin = _pct(question.smallest_effect)
        return f"- **{variant}** is **equivalent** to {reference} within ±{margin}: {effect}; {iqms}; {seeds}."
    return f"- **{variant}** vs {reference}: **undetermined** ({v.reason}): {effect}; {iqms}; {seeds}{_seeds_words(v)}."


def claims(ablation: Ablation, result: Round | None = None) -> list[str]:
    """The primary claims: one sentence naming the family, the correction and the level, then one line per
    variant with its verdict, effect, interval and seeds."""
    result = result if result is not None else primary_claims(ablation)
    question = primary_question(ablation)
    k = len(result.verdicts)
    if not k:
        return ["No variant has finished seeds to compare with its reference."]
    done, design = ablation.finished, claims_design(ablation)
    lines = [
        f"{family_sentence(k, sequential=design.max > design.start)} The claims are on "
        f"{_metric_name(question.metric)} (the experiment's primary question); each interval is simultaneous "
        f"over the {k} (95% for all of them together); "
        f"*equivalent* means within ±{_pct(question.smallest_effect)} of the reference.",
        "",
    ]
    column = "censored_episodes" if question.metric == "episodes_to_solve" else question.metric
    for v in result.verdicts:
        x = done.loc[done.variant == v.variant, column].to_numpy(float)
        y = done.loc[done.variant == v.reference, column].to_numpy(float)
        lines.append(claim_line(v, question, (float(iqm(x)), float(iqm(y)))))
    return lines


def summary(ablation: Ablation, table: pd.DataFrame, compare: pd.DataFrame) -> str:
    """The primary claims first; then the variants ranked on the primary metric with each one's own 95%
    interval (exploratory: unadjusted)."""
    result = primary_claims(ablation)
    verdicts = {v.variant: v for v in result.verdicts}
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
                verdict = f"vs {_esc(ablation.reference(row.variant))}: {verdict}"
        entry = {"rank": rank, "variant": _esc(row.variant)}
        if ablation.threshold is not None:
            entry["solved"] = f"{int(row.solved)}/{int(row.seeds_run)}"
        if ablation.any_solved:
            entry["episodes to solve, IQM [95% CI]"] = _episodes_cell(row, "iqm")
        entry["AUC, IQM [95% CI]"] = _stat_cell(row, "auc_iqm", low_key="auc_ci_low", high_key="auc_ci_high")
        entry["primary claim"] = verdict
        rows.append(entry)
    how = (
        "fewest episodes to solve (IQM, censored), ties by AUC"
        if ablation.any_solved
        else "highest area under the learning curve (IQM)"
    )
    return "\n".join(
        [
            *claims(ablation, result),
            "",
            f"*Exploratory:* the variants ranked by {how}, each interval a 95% bootstrap interval of that variant "
            f"alone (unadjusted: not a claim). A rank orders point estimates only; the last column repeats the "
            f"primary claim on {_metric_name(primary)}.",
            "",
            _markdown_table(pd.DataFrame(rows)),
        ]
    )
