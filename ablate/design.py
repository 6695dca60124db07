"""Can an experiment's design support a claim at all? The report's decision rule, before any compute is spent.

Standard library only, so ``ablate run --dry-run`` answers without pandas or SciPy; the report's statistics
import the rule from here, so there is one copy of it.
"""

from __future__ import annotations

import math

CONFIDENCE = 0.95
"""The report's confidence level for a claim."""
MAX_SEEDS_ASKED = 1000


def smallest_p_value(n: int, m: int) -> float:
    """The smallest two-sided p-value a rank test can give with ``n`` and ``m`` seeds (complete separation):
    above 0.05, no ordering of the seeds can support a claim at 95%."""
    if n < 1 or m < 1:
        return 1.0
    return min(1.0, 2 / math.comb(n + m, n))


def can_claim(n: int, m: int) -> bool:
    """Could any outcome of ``n`` against ``m`` seeds reach a claim under the report's rule?"""
    return min(n, m) >= 2 and smallest_p_value(n, m) <= 1 - CONFIDENCE


def smallest_seed_count() -> int:
    """The fewest seeds per variant (equal on both sides) with which a comparison can reach a claim."""
    return next(n for n in range(2, MAX_SEEDS_ASKED) if can_claim(n, n))


def design_warning(seeds_per_variant: int) -> str | None:
    """One line when ``seeds_per_variant`` seeds per variant cannot reach a claim at 95%, else ``None``."""
    if can_claim(seeds_per_variant, seeds_per_variant):
        return None
    needed = smallest_seed_count()
    return (
        f"design: with {seeds_per_variant} seeds per variant no comparison can reach a claim at "
        f"{CONFIDENCE:.0%} (the report's rank rule: the best possible p-value is "
        f"{smallest_p_value(seeds_per_variant, seeds_per_variant):.2g}); it takes at least {needed} seeds per "
        f"variant (seeds = {needed})"
    )


def smallest_permutation_p(n: int, m: int) -> float:
    """The smallest two-sided p-value the permutation test of the IQM difference can give with ``n`` and ``m``
    seeds (complete separation, all values distinct). The IQM trims ``int(n / 4)`` seeds off each end, so the
    splits that swap the variant's top trimmed seeds with the reference's bottom ones give the same difference:
    ``C(gx + gy, gx)`` splits of the ``C(n + m, n)`` on each side (both sides where ``n == m``)."""
    if n < 2 or m < 2:
        return 1.0
    gx, gy = n // 4, m // 4
    return min(1.0, (2 if n == m else 1) * math.comb(gx + gy, gx) / math.comb(n + m, n))
