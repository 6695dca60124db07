"""The permutation test of the IQM difference between a variant's seeds and its reference's: exact over every
split of the pooled seeds where there are at most 20,000, else over random splits; its TOST form for
equivalence, and the interval of effects it does not reject. Pure: numpy only.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations

import numpy as np

from ablate.measures import AUC, measure

EXACT_SPLITS = 20_000
"""Up to this many ways to split the pooled seeds, the permutation test enumerates them all (5 and 5: 252)."""
PERMUTATIONS = 9_999
"""Otherwise, at least this many random splits (more where the level tested needs it: see ``permutations_for``)."""
SEED = 20_251
"""Random splits are seeded from the data: the same runs give the same report."""
RATIO_LIMIT = 20.0
"""Intervals of a ratio search within [1/20, 20]; an end at the limit is open (``inf``)."""


@dataclass(frozen=True)
class Question:
    """What the family's comparisons ask, on the primary metric."""

    metric: str
    """``episodes_to_solve``, ``auc`` or ``return_at_<E>``."""
    relative: bool
    """True: effects are ratios (episodes: the variant needs ``1 + effect`` times the reference's episodes);
    False: differences in the metric's own units (AUC, return)."""
    lower_is_better: bool
    smallest_effect: float = 0.1
    """The equivalence margin: ``relative``, a fraction (0.1: between 10% fewer and 10% more episodes);
    otherwise a fraction of the reference's IQM (``margin``)."""
    budget: float | None = None
    """Where values are censored at a budget (unsolved seeds counted as it), that budget; else ``None``."""
    fallback: Question | None = None
    """The question a comparison is judged on instead where most of its seeds are censored (``family.CENSORED_SHARE``):
    the area under the learning curve, which every seed has. ``None``: always this one."""

    def margin(self, reference: np.ndarray) -> float:
        """± the margin in the effect's units."""
        if self.relative:
            return self.smallest_effect
        return self.smallest_effect * abs(float(iqm(np.asarray(reference, float)))) if len(reference) else 0.0


def primary_question(metric: str, smallest_effect: float, budget: float | None = None) -> Question:
    """The one way a report, the launch's rounds and the A/A calibration ask their claims: a censored measure
    (episodes to solve) as ratios, censored at ``budget``, falling back to the AUC where most seeds are censored;
    any other measure as differences, in its direction (``measures.measure``)."""
    entry = measure(metric)
    lower = not entry.higher_is_better
    fallback = Question(AUC.name, False, not AUC.higher_is_better, smallest_effect) if entry.censored else None
    return Question(metric, entry.censored, lower, smallest_effect, budget if entry.censored else None, fallback)


@dataclass(frozen=True)
class Sample:
    """One variant's values on the primary metric, in seed order (a look uses the first n)."""

    values: np.ndarray
    censored: np.ndarray | None = None
    """Per seed, whether the value is the budget standing for "never got there" (``None``: nothing censored)."""
    fallback: np.ndarray | None = None
    """The same seeds on the question's ``fallback`` measure (the AUC), where it has one."""

    def __getitem__(self, seeds) -> Sample:
        """The same seeds of all three (a look's first n: ``sample[:n]``)."""
        return Sample(
            self.values[seeds],
            None if self.censored is None else self.censored[seeds],
            None if self.fallback is None else self.fallback[seeds],
        )

    def __len__(self) -> int:
        return len(self.values)


def iqm(values: np.ndarray, axis: int | None = None):
    """The interquartile mean, the claims' and the report's one: the mean of the middle 50%, ``int(n / 4)`` values
    off each end, computed as SciPy's ``trim_mean(values, 0.25)`` computes it (a partition, then the mean of the
    middle) without its per-call overhead. One sample (``axis=None``, 1-D): a float; otherwise along ``axis``
    (default: the last, the bootstrap's resamples), an array."""
    values = np.asarray(values, float)
    single = axis is None and values.ndim <= 1
    axis = -1 if axis is None else axis
    n = values.shape[axis]
    g = n // 4
    if n == 0:
        return float("nan") if single else np.full(np.delete(values.shape, axis), np.nan)
    middle = [slice(None)] * values.ndim
    middle[axis] = slice(g, n - g)
    mean = np.partition(values, (g, n - g - 1), axis)[tuple(middle)].mean(axis=axis)
    return float(mean) if single else mean


@lru_cache(maxsize=64)
def _exact_middles(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Every split of the pooled ``n + m`` values sorted ascending, as the positions each side's IQM averages
    (its values less ``int(n / 4)`` each end): the variant's first ``n`` of a row, each part in increasing
    order, so the values it picks come out sorted."""
    total, gx, gy = n + m, n // 4, m // 4
    rows = []
    for chosen in combinations(range(total), n):
        rest = sorted(set(range(total)) - set(chosen))
        rows.append((*chosen, *rest))
    rows = np.array(rows, dtype=np.int64)
    return np.ascontiguousarray(rows[:, gx : n - gx]), np.ascontiguousarray(rows[:, n + gy : total - gy])


def _random_middles(n: int, m: int, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` random splits, as ``_exact_middles``. Drawn afresh for each test (seeded from its data): one
    fixed set shared by every test would carry its own error in the tail into every p-value of a report (a
    set of 4,999 measured 0.8% for a nominal 0.56% on nulls)."""
    total, gx, gy = n + m, n // 4, m // 4
    perms = rng.permuted(np.broadcast_to(np.arange(total), (count, total)), axis=1)
    left, right = np.sort(perms[:, :n], axis=1), np.sort(perms[:, n:], axis=1)
    return left[:, gx : n - gx], right[:, gy : m - gy]


def _splits_for(x: np.ndarray, y: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, bool]:
    n, m = len(x), len(y)
    if math.comb(n + m, n) <= EXACT_SPLITS:
        return (*_exact_middles(n, m), True)
    digest = hashlib.sha256(np.concatenate([x, y]).astype(float).tobytes()).digest()
    rng = np.random.default_rng([SEED, n, m, count, int.from_bytes(digest[:8], "little")])
    return (*_random_middles(n, m, count, rng), False)


def permutations_for(level: float) -> int:
    """Random splits enough to resolve ``level``: p-values step by 1 / (count + 1)."""
    return int(min(200_000, max(PERMUTATIONS, math.ceil(20 / max(level, 1e-12)))))


def _shifted(x: Sample, y: Sample, question: Question, effect: float) -> tuple[np.ndarray, np.ndarray]:
    """The two samples as they would be exchangeable if the effect were ``effect``: the variant scaled by
    1 / (1 + effect) (``relative``) or shifted by -effect; censored values stay exchangeable by re-censoring
    both at the lower of the two budgets the scaling leaves (min(B, B / (1 + effect)))."""
    a, b = np.asarray(x.values, float), np.asarray(y.values, float)
    if not question.relative:
        return a - effect, b
    ratio = 1.0 + effect
    a = a / ratio
    if question.budget is not None:
        cap = min(question.budget, question.budget / ratio)
        a, b = np.minimum(a, cap), np.minimum(b, cap)
    return a, b


def _tolerance(values: np.ndarray) -> float:
    return 1e-9 * max(1.0, float(np.max(np.abs(values))) if len(values) else 1.0)


EXCEEDANCES = 20
"""Random splits stop once each test has seen this many splits at least as extreme as the observed one: its
p-value is then far above any level a claim needs (Besag & Clifford 1991's sequential Monte Carlo p-value,
exceedances / splits drawn, is valid as it stands), so an open comparison at hundreds of seeds costs a few
hundred splits, not tens of thousands."""
BLOCK = 500


def p_values(x: Sample, y: Sample, question: Question, count: int = PERMUTATIONS) -> tuple[float, float]:
    """(two-sided p of "no difference", TOST p of "a difference of at least the margin") for variant ``x``
    against reference ``y``, by permutation of the IQM difference: over every split where there are at most
    ``EXACT_SPLITS``, else over up to ``count`` random splits drawn in blocks (the same splits serve the three
    tests), stopping early once every test has ``EXCEEDANCES`` (its p-value is then exceedances / splits)."""
    if len(x) < 2 or len(y) < 2:
        return 1.0, 1.0
    a, b = np.asarray(x.values, float), np.asarray(y.values, float)
    margin = question.margin(y.values)
    tost = not (margin <= 0 or (question.relative and margin >= 1))
    shifts = [0.0, margin, -margin] if tost else [0.0]
    pairs = [_shifted(x, y, question, s) for s in shifts]
    observed = [float(iqm(u) - iqm(v)) for u, v in pairs]
    pooled = [np.sort(np.concatenate(pair)) for pair in pairs]

    def extreme(diffs: list[np.ndarray]) -> list[np.ndarray]:
        out = [np.abs(diffs[0]) >= abs(observed[0]) - _tolerance(diffs[0])]
        if tost:  # H: effect >= +margin is rejected by a small (shifted) difference; H: <= -margin by a large one
            out += [diffs[1] <= observed[1] + _tolerance(diffs[1]), diffs[2] >= observed[2] - _tolerance(diffs[2])]
        return out

    def at(left: np.ndarray, right: np.ndarray) -> list[np.ndarray]:
        return extreme([p[left].mean(axis=1) - p[right].mean(axis=1) for p in pooled])

    n, m = len(a), len(b)
    if math.comb(n + m, n) <= EXACT_SPLITS:
        ps = [float(e.mean()) for e in at(*_exact_middles(n, m))]
    else:
        digest = hashlib.sha256(np.concatenate([a, b]).tobytes()).digest()
        rng = np.random.default_rng([SEED, n, m, count, int.from_bytes(digest[:8], "little")])
        hits, drawn = np.zeros(len(shifts), np.int64), 0
        while drawn < count:
            size = min(BLOCK * min(1 + drawn // BLOCK, 16), count - drawn)  # blocks grow to 8,000 splits
            hits += [int(e.sum()) for e in at(*_random_middles(n, m, size, rng))]
            drawn += size
            # TOST's p is the larger of its two: one of them past the count settles it
            if hits[0] >= EXCEEDANCES and (not tost or hits[1:].max() >= EXCEEDANCES):
                break
        ps = [float(h / drawn) if h >= EXCEEDANCES else float((1 + h) / (drawn + 1)) for h in hits]
    return ps[0], (max(ps[1], ps[2]) if tost else 1.0)


def _two_sided_p(x: Sample, y: Sample, question: Question, effect: float, splits) -> float:
    """The two-sided p of ``effect``: the share of ``splits`` whose IQM difference is as extreme as the observed
    one (exact: the observed split is one of them; random: it counts once more, (1 + b) / (B + 1))."""
    a, b = _shifted(x, y, question, effect)
    pooled = np.sort(np.concatenate([a, b]))
    left, right, exact = splits
    diffs = pooled[left].mean(axis=1) - pooled[right].mean(axis=1)
    extreme = np.abs(diffs) >= abs(float(iqm(a) - iqm(b))) - _tolerance(diffs)
    return float(extreme.mean()) if exact else float((1 + extreme.sum()) / (len(extreme) + 1))


def effect_interval(
    x: Sample, y: Sample, question: Question, level: float, count: int | None = None
) -> tuple[float, float, float]:
    """(estimate, low, high): the effect and the interval of effects the two-sided permutation test does not
    reject at ``level`` (its inversion: under the shift or scale model, censoring included, it covers the true
    effect with probability at least 1 - ``level``). An end past the search range is infinite."""
    a, b = np.asarray(x.values, float), np.asarray(y.values, float)
    if len(a) < 2 or len(b) < 2:
        return float("nan"), float("nan"), float("nan")
    ref = float(iqm(b))
    estimate = float(iqm(a)) / ref - 1 if question.relative else float(iqm(a)) - ref
    if question.relative:
        to_effect, lo, hi = (lambda s: math.exp(s) - 1), -math.log(RATIO_LIMIT), math.log(RATIO_LIMIT)
        centre = math.log(max(estimate + 1, 1 / RATIO_LIMIT))
        centre = min(max(centre, lo), hi)
    else:
        spread = float(np.ptp(np.concatenate([a, b]))) or 1.0
        to_effect, lo, hi, centre = (lambda s: s), estimate - 10 * spread, estimate + 10 * spread, estimate

    # Enough random splits to resolve the level (p-values step by 1 / (count + 1)), at most 50,000.
    splits = _splits_for(a, b, count or int(min(50_000, max(1999, math.ceil(20 / max(level, 1e-12))))))

    def accepted(s: float) -> bool:
        return _two_sided_p(x, y, question, to_effect(s), splits) > level

    def end(outer: float) -> float:
        if accepted(outer):
            return -math.inf if outer < centre else math.inf
        inner = centre
        if not accepted(inner):  # the estimate itself is rejected only through ties of a step function
            return to_effect(inner)
        for _ in range(30):
            mid = (inner + outer) / 2
            inner, outer = (mid, outer) if accepted(mid) else (inner, mid)
        return to_effect(inner)

    return estimate, end(lo), end(hi)
