"""The time-left estimate's arithmetic: finished trials' seconds carried over to another episode budget, and
the expected costs placed on the trial slots in the order the trials start."""

from __future__ import annotations

import heapq
from collections.abc import Sequence


def makespan(running_left_s: Sequence[float], pending_cost_s: Sequence[float], slots: int) -> float:
    """Seconds until the last trial ends when ``pending_cost_s`` (in scheduling order) each take the next free
    one of ``slots`` trial slots, the running trials holding theirs for ``running_left_s``: a long trial
    that starts last runs alone, which a mean cost over the remaining count would not see."""
    free_at = sorted([max(s, 0.0) for s in running_left_s] + [0.0] * max(slots - len(running_left_s), 0))
    if not free_at:
        free_at = [0.0]
    heapq.heapify(free_at)
    for cost in pending_cost_s:
        heapq.heappush(free_at, heapq.heappop(free_at) + cost)
    return max(free_at)


def at_budget(cost: float, ran: int, budget: int, rate: float | None, wanted: int) -> float:
    """A finished trial's seconds carried over to an episode budget of ``wanted``: one that stopped early
    (solved) would stop there again; one that ran its whole budget runs on at its last pace."""
    if ran < budget and ran <= wanted:
        return cost
    if wanted <= ran:
        return cost * wanted / max(ran, 1)
    return cost + (wanted - budget) * (rate if rate is not None else cost / max(budget, 1))
