"""How many seeds would decide an open comparison: the predictive probability ("assurance") that a fixed design
of n seeds per variant decides it at the family's level, over what the observed seeds leave uncertain about the
effect. Pure: numpy and SciPy.

Why not resample the observed seeds (the estimator before issue 55): with a few seeds, resampling sees a clean
separation that the next seeds do not keep (3 seeds said "about 8", and 42 were not enough). Here the effect
itself is uncertain: the future estimate is drawn around the observed one with the observed standard error
*plus* the future one, so a noisy start predicts many seeds, not few. tools/seed_advice.py measures the stated
share on real seeds: predict N from a small experiment, run N fresh seeds, count how often they decide.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ablate.claims.permutation import Question, Sample, iqm
from ablate.design import smallest_permutation_p
from ablate.measures import POWER  # the share of experiments in which the named number of seeds decides

SEED_COUNTS = (4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50, 60, 80, 100)
SEED_COUNTS += (120, 160, 200, 250, 320, 400, 500, 640, 800, 1000)
"""Seeds per variant the advice names, smallest first; past the last it says "more than 1,000"."""
SEEDS_CAP = SEED_COUNTS[-1]
MIN_SEEDS = 10
"""Fewer seeds a side support no prediction (a bootstrap standard error of 3 or 5 seeds is itself a guess): the
advice is then to run this many first. Measured from 10 up (tools/seed_advice.py, docs/report.md): 10 seeds a
side 77% decided at N [69%, 84%], 20: 79%, 40: 90%, all: 81% [77%, 85%]."""
BOOTSTRAP = 400
SEED = 20_251


def effect_scale(x: np.ndarray, y: np.ndarray, question: Question) -> float:
    """The effect on the scale the advice works on: log(IQM(x) / IQM(y)) for relative effects, else the
    difference of the IQMs."""
    if question.relative:
        return math.log(max(float(iqm(x)), 1e-12) / max(float(iqm(y)), 1e-12))
    return float(iqm(x)) - float(iqm(y))


def _standard_error(x: np.ndarray, y: np.ndarray, question: Question) -> float:
    """The bootstrap standard error of ``effect_scale``, with the small-sample correction n / (n - 1)."""
    rng = np.random.default_rng([SEED, len(x), len(y)])
    bx = x[rng.integers(0, len(x), (BOOTSTRAP, len(x)))]
    by = y[rng.integers(0, len(y), (BOOTSTRAP, len(y)))]
    ix, iy = iqm(bx, axis=1), iqm(by, axis=1)
    draws = np.log(np.maximum(ix, 1e-12) / np.maximum(iy, 1e-12)) if question.relative else ix - iy
    n = min(len(x), len(y))
    return float(np.std(draws, ddof=1)) * math.sqrt(n / (n - 1))


def assurance(estimate: float, se: float, se_future: float, low: float, high: float, level: float) -> float:
    """P(a fixed design with standard error ``se_future`` decides): its estimate D ~ N(estimate, se² +
    se_future²); a difference where |D| > z(level / 2) se_future, equivalence where D's (1 - 2 level) interval
    lies inside (``low``, ``high``)."""
    spread = math.sqrt(se**2 + se_future**2)
    z_diff, z_eq = stats.norm.isf(level / 2), stats.norm.isf(level)

    def mass(a: float, b: float) -> float:
        if b <= a:
            return 0.0
        return float(stats.norm.cdf((b - estimate) / spread) - stats.norm.cdf((a - estimate) / spread))

    cut = z_diff * se_future
    eq_low, eq_high = low + z_eq * se_future, high - z_eq * se_future
    # the two difference regions, and the part of the equivalence region between them (the union, counted once)
    decided = mass(-math.inf, -cut) + mass(cut, math.inf) + mass(max(eq_low, -cut), min(eq_high, cut))
    return min(decided, 1.0)


def seeds_needed(x: Sample, y: Sample, question: Question, level: float) -> int | None:
    """The fewest seeds per variant (of ``SEED_COUNTS``) at which a fixed design decides the comparison (better,
    worse or equivalent within the margin) at ``level`` with probability ``POWER``; ``None``: more than
    ``SEEDS_CAP``. Call it only with ``MIN_SEEDS`` or more a side."""
    xv, yv = np.asarray(x.values, float), np.asarray(y.values, float)
    estimate, se = effect_scale(xv, yv, question), _standard_error(xv, yv, question)
    margin = question.margin(yv)
    low, high = (math.log(1 - margin), math.log(1 + margin)) if question.relative else (-margin, margin)
    observed = 1 / len(xv) + 1 / len(yv)
    for n in SEED_COUNTS:
        if smallest_permutation_p(n, n) > level:  # no ordering of n and n seeds could reach the level
            continue
        if assurance(estimate, se, se * math.sqrt((2 / n) / observed), low, high, level) >= POWER:
            return n
    return None
