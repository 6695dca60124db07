"""The statistics the report rests on: interquartile means, percentile bootstrap intervals, the probability
of improvement, the smallest p-value a rank test can give, and the decision rule that turns them into a verdict.

The IQM is ``claims.permutation.iqm`` (one IQM for the claims and the report: SciPy's ``trim_mean`` exactly);
SciPy's ``bootstrap`` for 95% intervals, ``mannwhitneyu`` for the probability of improvement. Pure
functions of arrays (and one of a curves frame); nothing here reads the tracking store.
"""

from __future__ import annotations

from bisect import bisect_left

import numpy as np
import pandas as pd
from scipy import stats

from ablate.claims.advice import SEED_COUNTS
from ablate.claims.permutation import iqm
from ablate.design import CONFIDENCE, smallest_p_value  # noqa: F401  (the rule --dry-run applies, one copy)
from ablate.measures import POWER

N_RESAMPLES = 2000
SEED = 12345  # bootstrap resampling is seeded: the same runs give the same report


def _percentile_bootstrap(samples: tuple, statistic, n_resamples: int = N_RESAMPLES):
    """SciPy's percentile bootstrap, 95%, seeded, vectorised along the last axis; independent samples are
    resampled independently."""
    result = stats.bootstrap(
        samples,
        statistic,
        confidence_level=CONFIDENCE,
        n_resamples=n_resamples,
        method="percentile",
        vectorized=True,
        paired=False,
        axis=-1,
        rng=np.random.default_rng(SEED),
    )
    return result.confidence_interval.low, result.confidence_interval.high


def bootstrap_interval(values: np.ndarray, statistic=iqm) -> tuple[float, float]:
    """Percentile bootstrap 95% interval of ``statistic`` over one sample (NaNs when fewer than 2 values:
    no interval can be computed from one seed)."""
    values = np.asarray(values, dtype=float)
    values = values[~np.isnan(values)]
    if len(values) < 2:
        return (float("nan"), float("nan"))
    if np.all(values == values[0]):
        return (float(values[0]), float(values[0]))
    low, high = _percentile_bootstrap((values,), statistic)
    return (float(low), float(high))


def probability_of_improvement(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """P(X < Y) + P(X = Y) / 2 for X from the variant, Y from the reference: the chance that a random seed of the
    variant needs fewer episodes than a random seed of the reference (identical samples give 0.5). SciPy's
    Mann-Whitney U of ``y`` over n m, vectorised over leading (resample) axes."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    return stats.mannwhitneyu(y, x, axis=axis).statistic / (x.shape[axis] * y.shape[axis])


def probability_of_improvement_interval(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """P(X < Y) + P(X = Y) / 2 and its 95% interval (NaN with fewer than 2 seeds a side). The percentile bootstrap
    collapses to a point when every pair is ordered the same way (5 seeds each give "1.00 [1.00, 1.00]"), which only
    says the sample has no other pair to resample; there the interval is the exact Clopper-Pearson one for
    ``min(n, m)`` successes in ``min(n, m)`` independent comparisons, as if only that many pairs carried
    information."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    point = probability_of_improvement(x, y)
    if len(x) < 2 or len(y) < 2:
        return (point, float("nan"), float("nan"))
    if np.all(np.concatenate([x, y]) == x[0]):
        return (point, 0.5, 0.5)
    low, high = _percentile_bootstrap((x, y), probability_of_improvement)
    n = min(len(x), len(y))
    edge = (1 - CONFIDENCE) / 2
    if point >= 1.0 or high - low < 1e-12 and point > 0.5:
        low, high = edge ** (1 / n), 1.0
    elif point <= 0.0 or high - low < 1e-12 and point < 0.5:
        low, high = 0.0, 1 - edge ** (1 / n)
    return (point, float(low), float(high))


def iqm_change(variant: np.ndarray, reference: np.ndarray, relative: bool) -> tuple[float, float, float]:
    """With a 95% bootstrap interval (samples resampled independently): ``relative`` (episodes),
    1 - IQM(variant) / IQM(reference), positive where the variant needs fewer; else (returns, which can be
    negative, as Pong's, where a ratio means nothing) IQM(variant) - IQM(reference)."""
    variant, reference = np.asarray(variant, float), np.asarray(reference, float)

    def statistic(a, b, axis=-1):
        if relative:
            return 1 - iqm(a, axis=axis) / iqm(b, axis=axis)
        return iqm(a, axis=axis) - iqm(b, axis=axis)

    point = float(statistic(variant, reference))
    if len(variant) < 2 or len(reference) < 2:
        return point, float("nan"), float("nan")
    if relative and np.all(np.concatenate([variant, reference]) == variant[0]):
        return point, point, point
    if not relative and np.all(variant == variant[0]) and np.all(reference == reference[0]):
        return point, point, point
    low, high = _percentile_bootstrap((variant, reference), statistic)
    return point, float(low), float(high)


def is_censored_statistic(n_censored: int, n: int, statistic: str) -> bool:
    """Does the median or IQM of ``n`` values use one of the ``n_censored`` largest (censored) ones? Then it
    is a lower bound, not an estimate. The median uses the middle one or two; the IQM the middle 50%
    (SciPy's ``trim_mean`` cuts ``int(0.25 n)`` from each end)."""
    if n == 0:
        return False
    if statistic == "median":
        return n_censored >= n - n // 2
    return n_censored > int(np.floor(0.25 * n))


# --- comparisons --------------------------------------------------------------------------------------------
# The exploratory rule's verdicts (each comparison on its own 95% bootstrap interval, unadjusted), worded so that
# no one reads them as the primary claims' (``ablate.claims``: better, worse, equivalent, undetermined).
EXPLORATORY_BETTER = "exploratory: better"
EXPLORATORY_WORSE = "exploratory: worse"
NOT_SEPARATED = "exploratory: not separated"
TOO_FEW_SEEDS = "exploratory: too few seeds"
SEPARATED = (EXPLORATORY_BETTER, EXPLORATORY_WORSE)


def _verdict(low: float, high: float) -> str:
    if np.isnan(low) or np.isnan(high):
        return TOO_FEW_SEEDS
    if low > 0:
        return EXPLORATORY_BETTER
    if high < 0:
        return EXPLORATORY_WORSE
    return NOT_SEPARATED


def exploratory_comparison(x: np.ndarray, y: np.ndarray, x_cens: np.ndarray | None = None, y_cens=None):
    """The exploratory rule on one comparison: (point, low, high, verdict, bound). ``x_cens`` given: episodes (lower
    is better) censored at the budget, else returns. The IQM of a sample whose IQM uses a censored value is a
    lower bound on the true IQM: with only the variant censored, the variant is at least as slow as measured (a
    claim "worse" holds, sized "at least"); with only the baseline censored, a claim "better" holds the same way;
    with both, episodes say nothing."""
    relative = x_cens is not None
    point, low, high = iqm_change(x, y, relative)
    x_bound = relative and is_censored_statistic(int(x_cens.sum()), len(x), "iqm")
    y_bound = relative and is_censored_statistic(int(y_cens.sum()), len(y), "iqm")
    bound = "censored" if x_bound and y_bound else "at least" if x_bound or y_bound else ""
    verdict = _verdict(low, high)
    if verdict == TOO_FEW_SEEDS or min(len(x), len(y)) < 2 or smallest_p_value(len(x), len(y)) > 1 - CONFIDENCE:
        verdict = TOO_FEW_SEEDS
    elif (x_bound and verdict != EXPLORATORY_WORSE) or (y_bound and verdict != EXPLORATORY_BETTER):
        verdict = NOT_SEPARATED  # as the docstring: a bound supports only the claim it leans towards
    return point, low, high, verdict, bound


def curve_band(
    curves: pd.DataFrame, x: str, grid: np.ndarray, band: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IQM across seeds of the rolling mean at each point of ``grid`` (of column ``x``), with a 95% bootstrap
    band (``band``; else the centre as both ends: a figure that draws the lines alone). A seed that stopped because
    it solved carries its last value forward; one that ran out of budget ends there. Where fewer than half the
    seeds have a value, the curve stops. One seed: no band."""
    per_seed = []
    for _, seed_curve in curves.groupby("seed"):
        seed_curve = seed_curve.sort_values(x)
        xs, ys = seed_curve[x].to_numpy(float), seed_curve.rolling_mean.to_numpy(float)
        carry = ys[-1] if bool(seed_curve.solved.iloc[-1]) or x == "episode" else np.nan
        per_seed.append(np.interp(grid, xs, ys, left=np.nan, right=carry))
    matrix = np.array(per_seed).T  # (points, seeds)
    enough = (~np.isnan(matrix)).sum(axis=1) * 2 >= matrix.shape[1]
    centre = np.full(len(grid), np.nan)
    low, high = centre.copy(), centre.copy()
    for i in np.flatnonzero(enough):
        values = matrix[i][~np.isnan(matrix[i])]
        centre[i] = iqm(values)
        low[i], high[i] = centre[i], centre[i]
    # One vectorised bootstrap over the points where every seed has a value and they are not all equal.
    full = enough & ~np.isnan(matrix).any(axis=1) & (np.ptp(np.nan_to_num(matrix), axis=1) > 0)
    if band and full.any() and matrix.shape[1] >= 2:
        # At most BAND_POINTS of them, evenly spread, the band between drawn straight: a rolling mean moves slowly,
        # and the bootstrap's array is points x resamples x seeds (640 seeds: 64M values at 200 points).
        at = np.flatnonzero(full)
        picked = at[np.unique(np.linspace(0, len(at) - 1, min(len(at), BAND_POINTS)).round().astype(int))]
        band_low, band_high = _percentile_bootstrap((matrix[picked],), iqm, n_resamples=N_RESAMPLES // 4)
        low[at], high[at] = np.interp(at, picked, band_low), np.interp(at, picked, band_high)
    return centre, low, high


BAND_POINTS = 50
"""The points of a learning curve its band is bootstrapped at (``curve_band``); the others are interpolated."""


# --- seeds needed -------------------------------------------------------------------------------------------
SEEDS_CAP = 50
"""The most seeds per variant ``seeds_needed`` tries for an exploratory row; past it the answer is "more than 50"."""
SIMULATIONS, INNER_RESAMPLES = 100, 200


def seeds_needed(
    x: np.ndarray,
    y: np.ndarray,
    relative: bool,
    x_censored: np.ndarray | None = None,
    y_censored: np.ndarray | None = None,
    effect: float | None = None,
) -> int:
    """How many seeds per variant the report's decision rule would need to separate the difference between
    samples ``x`` (the variant) and ``y`` (its reference) at 95% in ``POWER`` of experiments, found by
    resampling the observed seeds: draw n seeds of each with replacement, compute the 95% percentile bootstrap
    interval of the difference (``relative``: 1 - IQM(x) / IQM(y), episodes; else IQM(x) - IQM(y), returns),
    count a separation where it excludes 0 on the observed side and censoring allows the claim (as
    ``exploratory_comparison``). ``effect``: first shift ``x`` so that the difference is ``effect`` times the
    reference's IQM on the observed side (the smallest effect of interest). ``SEEDS_CAP + 1`` means more
    than ``SEEDS_CAP``."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    x_censored = np.zeros(len(x), bool) if x_censored is None else np.asarray(x_censored, bool)
    y_censored = np.zeros(len(y), bool) if y_censored is None else np.asarray(y_censored, bool)
    if len(x) < 2 or len(y) < 2:
        return SEEDS_CAP + 1
    reference = float(iqm(y))
    point = 1 - float(iqm(x)) / reference if relative else float(iqm(x)) - reference
    if effect is not None:
        side = 1.0 if point >= 0 else -1.0
        if relative:
            x = x * (1 - side * effect) * reference / float(iqm(x))
        else:
            x = x + side * effect * abs(reference) - point
        point = side * effect
    if point == 0 or not np.isfinite(point):
        return SEEDS_CAP + 1

    def power(n: int) -> float:
        rng = np.random.default_rng([SEED, n])
        ix, iy = rng.integers(0, len(x), (SIMULATIONS, n)), rng.integers(0, len(y), (SIMULATIONS, n))
        bx, by = rng.integers(0, n, (INNER_RESAMPLES, n)), rng.integers(0, n, (INNER_RESAMPLES, n))
        xs, ys = x[ix][:, bx], y[iy][:, by]  # (experiments, resamples, seeds)
        stat = 1 - iqm(xs) / iqm(ys) if relative else iqm(xs) - iqm(ys)
        low, high = np.percentile(stat, [2.5, 97.5], axis=1)
        separated = low > 0 if point > 0 else high < 0
        if relative:  # the IQM of a sample that uses a censored seed is a bound: as the findings' rule
            x_bound = x_censored[ix].sum(axis=1) > int(np.floor(0.25 * n))
            y_bound = y_censored[iy].sum(axis=1) > int(np.floor(0.25 * n))
            separated &= ~(x_bound if point > 0 else y_bound)
        return float(separated.mean())

    counts = [n for n in SEED_COUNTS if n <= SEEDS_CAP and smallest_p_value(n, n) <= 1 - CONFIDENCE]
    if power(counts[-1]) < POWER:  # power grows with seeds: the fewest count that reaches it, by bisection
        return SEEDS_CAP + 1
    return counts[bisect_left(counts, True, 0, len(counts) - 1, key=lambda n: power(n) >= POWER)]
