"""Group-sequential boundaries: Lan-DeMets alpha spending over the looks of a design (seeds per variant at each
round), and each look's nominal p-value threshold. Pure: numpy and SciPy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import optimize, stats

from ablate.design import ALPHA
from ablate.seeds import seed_looks


@dataclass(frozen=True)
class Design:
    """The seeds per variant at each look, ``start`` to ``max`` (a fixed design: one look, ``start == max``), and
    the spending function that shares ``alpha`` among the looks."""

    start: int
    step: int = 0
    max: int = 0
    alpha: float = ALPHA
    spending: str = "obrien-fleming"
    """``obrien-fleming`` (Lan-DeMets' O'Brien-Fleming-type) or ``pocock`` (Lan-DeMets' Pocock-type)."""
    growth: float = 1.0
    """Each look adds ``growth`` times the seeds the look before added (``seeds.seed_looks``)."""

    def __post_init__(self):
        if self.max == 0:
            object.__setattr__(self, "max", self.start)
        if self.start < 1 or self.max < self.start or (self.max > self.start and self.step < 1):
            raise ValueError(f"design {self}: valid: 1 <= start <= max, step >= 1 when max > start")

    @classmethod
    def fixed(cls, seeds: int, alpha: float = ALPHA) -> Design:
        return cls(seeds, 0, seeds, alpha)

    @classmethod
    def of(cls, rounds) -> Design:
        """The design of an experiment's seed rounds (``seeds.SeedRounds``, or its ``rounds.json`` entry)."""
        get = rounds.get if isinstance(rounds, dict) else lambda key, default=None: getattr(rounds, key, default)
        return cls(
            int(get("start")),
            int(get("step")),
            int(get("max")),
            spending=get("spending", None) or "obrien-fleming",
            growth=float(get("growth", 1.0) or 1.0),
        )

    @property
    def looks(self) -> tuple[int, ...]:
        """Seeds per variant at each look, the last one ``max``."""
        return seed_looks(self.start, self.step, self.max, self.growth)

    @property
    def fractions(self) -> tuple[float, ...]:
        """Each look's information as a fraction of the last one's (seeds per variant / ``max``)."""
        return tuple(n / self.max for n in self.looks)


def alpha_spent(t: float, alpha: float, spending: str) -> float:
    """Lan-DeMets spending: the share of ``alpha`` spent by information fraction ``t``."""
    if t <= 0:
        return 0.0
    t = min(t, 1.0)
    if spending == "pocock":
        return alpha * math.log(1 + (math.e - 1) * t)
    return float(2 * stats.norm.sf(stats.norm.isf(alpha / 2) / math.sqrt(t)))


@lru_cache(maxsize=4096)
def nominal_levels(
    fractions: tuple[float, ...], alpha: float, spending: str = "obrien-fleming", sides: int = 2
) -> tuple[float, ...]:
    """Each look's nominal p-value threshold such that a test run at every look rejects a true null with
    probability ``alpha`` in all (``sides`` 2: two-sided; 1: one-sided), the statistics across looks being
    those of a Brownian motion observed at ``fractions`` (Armitage-McPherson-Rowe recursion on a grid)."""
    grid_size = 401
    levels, density, nodes, weights = [], None, None, None
    previous_t, previous_spent = 0.0, 0.0
    for t in fractions:
        target = alpha_spent(t, alpha, spending) - previous_spent
        dt = t - previous_t
        if density is None:

            def crossing(c, t=t):
                return sides * stats.norm.sf(c)
        else:

            def crossing(c, t=t, dt=dt, density=density, nodes=nodes, weights=weights):
                up = stats.norm.sf((c * math.sqrt(t) - nodes) / math.sqrt(dt))
                down = stats.norm.cdf((-c * math.sqrt(t) - nodes) / math.sqrt(dt)) if sides == 2 else 0.0
                return float(np.sum(weights * density * (up + down)))

        c = math.inf if target <= 1e-15 else optimize.brentq(lambda c, f=crossing, s=target: f(c) - s, 1e-6, 40.0)
        levels.append(float(sides * stats.norm.sf(c)) if math.isfinite(c) else 0.0)
        # The density of the score S = Z sqrt(t) on the continuation region, for the next look.
        top = (c if math.isfinite(c) else 12.0) * math.sqrt(t)
        bottom = -top if sides == 2 else -12.0 * math.sqrt(t)
        new_nodes = np.linspace(bottom, top, grid_size)
        new_weights = np.full(grid_size, (top - bottom) / (grid_size - 1))
        new_weights[[0, -1]] /= 2
        if density is None:
            new_density = stats.norm.pdf(new_nodes / math.sqrt(t)) / math.sqrt(t)
        else:
            kernel = stats.norm.pdf((new_nodes[:, None] - nodes[None, :]) / math.sqrt(dt)) / math.sqrt(dt)
            new_density = kernel @ (weights * density)
        density, nodes, weights = new_density, new_nodes, new_weights
        previous_t, previous_spent = t, previous_spent + target
    return tuple(levels)
