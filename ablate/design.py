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
