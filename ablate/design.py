"""Can an experiment's design support a claim at all? The report's rules, before any compute is spent.

Standard library only, so ``ablate run --dry-run`` answers without pandas or SciPy; the report's statistics
import the rule from here, so there is one copy of it.
"""

from __future__ import annotations

import math

ALPHA = 0.05
"""The chance of a false claim the report allows: a family's primary claims' together, and each comparison's alone."""
CONFIDENCE = 1 - ALPHA
"""The report's confidence level for a claim and its intervals (0.95, the same float as the literal)."""
MAX_SEEDS_ASKED = 1000


def percent(share: float) -> str:
    """A share as the report's prose writes it: ``percent(CONFIDENCE)`` is "95%"."""
    return f"{share:.0%}"


def smallest_p_value(n: int, m: int) -> float:
    """The smallest two-sided p-value a rank test can give with ``n`` and ``m`` seeds (complete separation):
    above 0.05, no ordering of the seeds can support a claim at 95%."""
    if n < 1 or m < 1:
        return 1.0
    return min(1.0, 2 / math.comb(n + m, n))


def design_warning(seeds_per_variant: int, comparisons: int = 1) -> str | None:
    """One line when ``seeds_per_variant`` seeds per variant can never reach a primary claim in a family of
    ``comparisons`` (the report's rule: a permutation test of the IQM difference, Holm at 5%), else ``None``."""
    level = (1 - CONFIDENCE) / max(comparisons, 1)  # Holm's first step
    if smallest_permutation_p(seeds_per_variant, seeds_per_variant) <= level:
        return None
    needed = next(n for n in range(2, MAX_SEEDS_ASKED) if smallest_permutation_p(n, n) <= level)
    return (
        f"design: with {seeds_per_variant} seeds per variant no primary comparison can reach a claim at the family "
        f"level ({comparisons} comparison{'s' if comparisons != 1 else ''}, Holm at {1 - CONFIDENCE:.0%}: the first "
        f"needs p <= {level:.2g}, and the best possible with {seeds_per_variant} and {seeds_per_variant} seeds is "
        f"{smallest_permutation_p(seeds_per_variant, seeds_per_variant):.2g}); it takes at least {needed} seeds per "
        f"variant (seeds = {needed}); every verdict would read undetermined"
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
