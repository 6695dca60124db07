"""The report's primary claims as one family: Holm's step-down over the comparisons at a family-wise 5%,
equivalence by two one-sided tests (TOST), and the group-sequential looks (seeds added in rounds).

``decide`` judges a family at one look (or replays every look the data reach); ``Verdict`` is one comparison's
answer, ``Round`` a look's.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ablate.claims import advice
from ablate.claims.boundaries import ALPHA, Design, nominal_levels
from ablate.claims.permutation import Question, Sample, effect_interval, iqm, p_values, permutations_for
from ablate.design import smallest_permutation_p as smallest_p

BETTER, WORSE, EQUIVALENT, UNDETERMINED = "better", "worse", "equivalent", "undetermined"
SEEDS_CAP = advice.SEEDS_CAP
CENSORED_SHARE = 0.25
"""Where more than this share of a comparison's seeds (both sides pooled, at its first look) never reached the
threshold, it is judged on the question's ``fallback`` measure (the AUC, never censored) instead. A quarter because
the IQM drops a quarter at each end: past it, a side's IQM may rest on the budget itself, and with both sides so,
episodes could decide nothing. The share of the pooled seeds is the same under every relabelling of the seeds,
so the permutation test stays exact, and the rule is fixed before any data."""


@dataclass(frozen=True)
class Verdict:
    """One primary comparison's answer: a row of ``tables/claims.csv`` before the report's units (docs/python.md
    describes each column)."""

    variant: str
    reference: str
    metric: str
    verdict: str
    estimate: float
    """The effect: ``relative``, IQM(variant) / IQM(reference) - 1 (-0.2: 20% fewer episodes); otherwise
    IQM(variant) - IQM(reference). Its sign is not "better": see ``Question.lower_is_better``."""
    low: float
    high: float
    """The effect's interval at the family level (the permutation test inverted at ``alpha / comparisons``);
    ``-inf`` / ``inf`` where censoring leaves an end open; NaN where not computed."""
    p_difference: float
    p_equivalence: float
    level: float
    margin: float
    n_variant: int
    n_reference: int
    look: int
    bound: str = ""
    seeds_needed: int | None = None
    """Where undetermined and ``seeds_estimated``; ``None`` there means more than ``seeds_cap``."""
    seeds_estimated: bool = False
    seeds_cap: int = SEEDS_CAP
    reason: str = ""
    seeds_first: int = 0
    censored: float = 0.0

    @property
    def decided(self) -> bool:
        return self.verdict != UNDETERMINED


@dataclass(frozen=True)
class Round:
    """The family after the last look the data reach."""

    look: int
    """Index of that look in ``Design.looks`` (-1: the data reach no look; judged as they are)."""
    seeds: int
    """Seeds per variant at that look."""
    verdicts: tuple[Verdict, ...]
    needs_seeds: tuple[str, ...]
    """Variants that get ``step`` more seeds in the next round: those whose comparison is open and the references
    of open comparisons. Empty when every comparison is decided or the last look was made."""
    done: bool
    """True when nothing is open or the last look (``max``) was made."""
    spent: tuple[tuple[str, int], ...]
    """(variant, seeds it was run on up to the last look made): a variant stops getting seeds once its
    comparison is decided, unless it is the reference of one still open."""

    @property
    def open(self) -> tuple[str, ...]:
        return tuple(v.variant for v in self.verdicts if not v.decided)


def _bounds(sample: Sample) -> bool:
    """Does the sample's IQM use a censored value (so it is a lower bound on the true IQM)?"""
    censored = 0 if sample.censored is None else int(np.sum(sample.censored))
    return censored > len(sample) // 4  # the IQM trims n // 4 off each end


@dataclass
class _Open:
    pair: tuple[str, str]
    x: Sample
    y: Sample
    question: Question | None = None
    """The question it is judged on, fixed at its first look: the family's, or its fallback (``CENSORED_SHARE``)."""
    censored: float = 0.0
    p_diff: float = 1.0
    p_eq: float = 1.0
    bound: str = ""
    better: bool = False
    estimate: float = float("nan")

    def sides(self, question: Question, x: Sample, y: Sample) -> tuple[Sample, Sample]:
        """The two samples on the question this comparison is judged on (its first call fixes it)."""
        if self.question is None:
            flags = [s.censored for s in (x, y) if s.censored is not None]
            self.censored = float(np.concatenate(flags).mean()) if flags else 0.0
            usable = question.fallback is not None and all(
                s.fallback is not None and np.isfinite(s.fallback).all() for s in (x, y)
            )
            self.question = question.fallback if usable and self.censored > CENSORED_SHARE else question
        if self.question is question:
            return x, y
        return Sample(np.asarray(x.fallback, float)), Sample(np.asarray(y.fallback, float))


def _claim(item: _Open, level_diff: float, level_eq: float) -> str:
    """The claim the p-values support at these levels, with the care censoring needs; ``UNDETERMINED`` if none."""
    x_bound, y_bound = _bounds(item.x), _bounds(item.y)
    if x_bound and y_bound:
        return UNDETERMINED
    if item.p_diff <= level_diff:
        verdict = BETTER if item.better else WORSE
        # A variant's bound IQM can only grow (so "worse" stands, "better" does not); a reference's likewise.
        if (x_bound and verdict == BETTER) or (y_bound and verdict == WORSE):
            return UNDETERMINED
        return verdict
    if item.p_eq <= level_eq and not (x_bound or y_bound):
        return EQUIVALENT
    return UNDETERMINED


def _estimate(x: Sample, y: Sample, question: Question) -> float:
    ref, var = float(iqm(np.asarray(y.values, float))), float(iqm(np.asarray(x.values, float)))
    return var / ref - 1 if question.relative else var - ref


def decide(
    samples: Mapping[str, Sample],
    references: Mapping[str, str],
    question: Question,
    design: Design,
    *,
    intervals: bool = True,
    estimate_seeds: bool = True,
    permutations: int | None = None,
) -> Round:
    """The family's verdicts after every look the data reach, replayed from the first: ``samples`` maps each
    variant (references included) to its values in seed order; ``references`` maps each compared variant to
    its reference. At look j each open comparison uses the first ``design.looks[j]`` seeds of both sides;
    Holm's step-down runs over the comparisons still open, each at ``alpha / open`` through the look's
    spending boundary (a decided comparison's level passes to the rest, as in Maurer & Bretz 2013); a
    comparison decided stays decided. A look is made when every variant it needs has its seeds; where the data
    reach no look (fewer seeds than ``start``), the family is judged once on the seeds there are, as a
    fixed design. ``intervals``: compute each verdict's interval (slower); ``estimate_seeds``: the seeds an
    undetermined comparison would need (slowest; the launch's judge does not ask, a report does, rounds over or not)."""
    order = [v for v in references]
    state = {v: _Open((v, references[v]), samples[v], samples[references[v]]) for v in order}
    decided: dict[str, tuple[str, int, float]] = {}
    looks = design.looks
    k = len(order)
    made, last_n, levels = -1, 0, []
    spent: dict[str, int] = {}

    def needed(open_names) -> set[str]:
        return set(open_names) | {references[v] for v in open_names}

    def judge(look_index: int, n: int, fractions: tuple[float, ...]) -> None:
        open_names = [v for v in order if v not in decided]
        for v in open_names:
            item = state[v]
            x, y = item.sides(question, samples[v][:n], samples[references[v]][:n])
            item.x, item.y = x, y
            first_level = design.alpha / max(k, 1)
            count = permutations or permutations_for(nominal_levels(fractions, first_level, design.spending)[-1])
            asked = item.question
            item.p_diff, item.p_eq = p_values(x, y, asked, count)
            item.estimate = _estimate(x, y, asked)
            item.better = (item.estimate < 0) == asked.lower_is_better if item.estimate != 0 else False
        while open_names:
            # Holm's step-down, released only by difference claims: a comparison shown equivalent keeps its
            # share, since its "no difference" may be true (releasing it let a family of identical variants
            # claim differences 18% of the time in tests/test_claims.py's narrow null at 30 seeds).
            different = sum(1 for verdict, _, _ in decided.values() if verdict in (BETTER, WORSE))
            level = design.alpha / (k - different)
            level_diff = nominal_levels(fractions, level, design.spending, 2)[-1]
            level_eq = nominal_levels(fractions, level, design.spending, 1)[-1]
            claims = {v: _claim(state[v], level_diff, level_eq) for v in open_names}
            for v in open_names:
                state[v].last_level = level_diff  # type: ignore[attr-defined]
                if claims[v] in (BETTER, WORSE):
                    decided[v] = (claims[v], look_index, level_diff)
                elif claims[v] == EQUIVALENT:
                    decided[v] = (claims[v], look_index, level_eq)
            if not any(claims[v] in (BETTER, WORSE) for v in open_names):
                break
            open_names = [v for v in open_names if v not in decided]

    for j, n in enumerate(looks):
        open_names = [v for v in order if v not in decided]
        if not open_names:
            break
        if any(len(samples[v]) < n for v in needed(open_names)):
            break
        fractions = design.fractions[: j + 1]
        for v in needed(open_names):
            spent[v] = n
        judge(j, n, fractions)
        levels.append(nominal_levels(fractions, design.alpha / max(k, 1), design.spending)[-1])
        made, last_n = j, n
    if made < 0:  # the data reach no look: one judgment on what there is, as a fixed design
        last_n = min((len(s) for s in samples.values()), default=0)
        spent = {v: len(s) for v, s in samples.items()}
        judge(-1, max(len(s) for s in samples.values()) if samples else 0, (1.0,))
        levels.append(design.alpha / max(k, 1))
    final = made < 0 or made == len(looks) - 1
    open_names = [v for v in order if v not in decided]
    done = final or not open_names
    verdicts = []
    family_level = design.alpha / max(k, 1)
    for v in order:
        item = state[v]
        asked = item.question or question
        verdict, look_index, level = decided.get(v, (UNDETERMINED, made, getattr(item, "last_level", family_level)))
        margin = asked.margin(item.y.values)
        low = high = float("nan")
        if intervals and len(item.x) >= 2 and len(item.y) >= 2:
            interval_level = levels[look_index] if look_index >= 0 and look_index < len(levels) else levels[-1]
            _, low, high = effect_interval(item.x, item.y, asked, interval_level)
        xb, yb = _bounds(item.x), _bounds(item.y)
        bound = "censored" if xb and yb else "at least" if xb or yb else ""
        seeds, estimated, reason, first = None, False, "", 0
        if verdict == UNDETERMINED:
            reason = _reason(item, asked, levels[-1] if levels else family_level, bound)
            if estimate_seeds and bound != "censored":  # also where rounds stopped early (a time budget)
                if min(len(item.x), len(item.y)) >= advice.MIN_SEEDS:
                    seeds, estimated = advice.seeds_needed(item.x, item.y, asked, family_level), True
                else:
                    first = advice.MIN_SEEDS
        verdicts.append(
            Verdict(
                v,
                references[v],
                asked.metric,
                verdict,
                item.estimate,
                low,
                high,
                item.p_diff,
                item.p_eq,
                level,
                margin,
                len(item.x),
                len(item.y),
                look_index,
                bound,
                seeds,
                estimated,
                SEEDS_CAP,
                reason,
                first,
                item.censored,
            )
        )
    needs = () if done else tuple(v for v in samples if v in needed(open_names))
    return Round(made, last_n, tuple(verdicts), needs, done, tuple((v, spent.get(v, 0)) for v in samples))


def _reason(item: _Open, question: Question, level: float, bound: str) -> str:
    n, m = len(item.x), len(item.y)
    if min(n, m) < 2:
        return f"{min(n, m)} seed{'s' if min(n, m) != 1 else ''}: no test"
    if bound == "censored":
        return "both IQMs count unsolved seeds as the budget: episodes cannot decide"
    if smallest_p(n, m) > level:
        return (
            f"no ordering of {n} and {m} seeds reaches the family level (smallest possible p = "
            f"{smallest_p(n, m):.3g} > {level:.2g})"
        )
    return "neither a difference nor equivalence within the margin is shown at the family level"


SPENDING_WORDS = {"obrien-fleming": "O'Brien-Fleming-type", "pocock": "Pocock-type"}


def family_sentence(k: int, alpha: float = ALPHA, sequential: bool = False, spending: str = "obrien-fleming") -> str:
    """The one sentence a student can repeat: which family, which correction, what level."""
    kind = SPENDING_WORDS[spending]
    looks = f" across the rounds of seeds (a {kind} alpha-spending boundary)" if sequential else ""
    family = f"The {k} primary comparisons form one family" if k != 1 else "The one primary comparison is a family"
    return (
        f"{family} whose chance of any false claim is at most {alpha:.0%}: each is a permutation test of the IQM "
        f"difference, corrected by Holm's step-down{looks}."
    )
