"""An experiment's evaluation seeds: a fixed count or list, or a table of rounds (``seeds = { start = 5, step = 5,
max = 40 }``) that ``ablate.launch.rounds`` adds seeds by. Standard library only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ablate.config import ConfigError, clipped, is_int, is_number


@dataclass(frozen=True)
class SeedRounds:
    """``seeds = { start = 5, step = 5, max = 40 }``: evaluation seeds added in rounds until the primary
    comparisons are decided (``ablate.launch.rounds``). Round 1 runs seeds ``0 .. start - 1``; each later round
    gives the variants whose comparison is still open (and their references) ``step`` more, up to ``max``."""

    start: int
    step: int
    max: int
    max_minutes: float | None = None
    """No new round starts once a launch has run this long (minutes); ``None``: no time budget."""
    growth: float = 1.0
    """Each round adds ``growth`` times the seeds the round before added (``step`` first): 1 adds ``step`` every
    round; 2 doubles the seeds per round (start 10, step 10: 10, 20, 40, 80 ...), so a cap in the hundreds costs
    a handful of looks."""

    spending: str = "obrien-fleming"
    """How the error rate is spent across the looks (``claims.Design``): ``obrien-fleming`` keeps almost all of it
    for the last look; ``pocock`` spreads it, so that doubling rounds (whose early looks hold a small share of
    the seeds) can stop a large effect early."""

    @property
    def looks(self) -> tuple[int, ...]:
        """Seeds per variant after each round (the looks of ``claims.Design`` with the same numbers)."""
        return seed_looks(self.start, self.step, self.max, self.growth)


def added_words(step: int, growth: float) -> str:
    """How a round adds seeds, in words: "5 more" or "10 more, then 2x as many each round"."""
    return f"{step} more" + (f", then {growth:g}x as many each round" if growth > 1 else "")


def seed_looks(start: int, step: int, most: int, growth: float = 1.0) -> tuple[int, ...]:
    """Seeds per variant at each look: ``start``, then ``step`` more, then ``step * growth`` more, ``step *
    growth**2`` more ..., and ``most`` last. The one definition, read by the launch's rounds and the claims'
    boundary."""
    looks, added = [start], float(step)
    while looks[-1] < most and step > 0:
        looks.append(min(most, looks[-1] + max(1, round(added))))
        added *= growth
    return tuple(looks)


SEEDS_RULE = (
    "valid: a count in [1, 1000], a list of distinct non-negative integers, or a table of rounds "
    "{ start = 5, step = 5, max = 40 } (optional max_minutes = 15, growth = 2, spending = 'pocock')"
)
ROUND_KEYS = ("start", "step", "max", "max_minutes", "growth", "spending")
SPENDINGS = ("obrien-fleming", "pocock")


def parse_seeds(value: Any, where: str) -> tuple[tuple[int, ...], SeedRounds | None]:
    """``seeds`` (top level or a variant's): a count, a list, or a table of rounds -> (round 1's seeds, the
    rounds or ``None``). ``where``: ``<file>: seeds`` or ``<file>: variants[i].seeds``, for the error."""
    if is_int(value) and 1 <= value <= 1000:
        return tuple(range(value)), None
    if (
        isinstance(value, list)
        and value
        and all(is_int(s) and 0 <= s < 2**31 for s in value)
        and len(set(value)) == len(value)
    ):
        return tuple(value), None
    if not isinstance(value, dict):
        raise ConfigError(f"{where} = {clipped(value)} is invalid; {SEEDS_RULE}")
    for key in value:
        if key not in ROUND_KEYS:
            raise ConfigError(f"{where}.{key}: unknown key; valid keys of a seeds table: {', '.join(ROUND_KEYS)}")
    for key in ("start", "max"):
        if key not in value:
            raise ConfigError(f"{where}.{key}: missing; valid: e.g. seeds = {{ start = 5, step = 5, max = 40 }}")
    start, most = value["start"], value["max"]
    if not (is_int(start) and 1 <= start <= 1000):
        raise ConfigError(f"{where}.start = {clipped(start)} is invalid; valid: a count of seeds in [1, 1000]")
    if not (is_int(most) and start <= most <= 1000):
        raise ConfigError(
            f"{where}.max = {clipped(most)} is invalid; valid: a count of seeds in [start = {start}, 1000]"
        )
    step = value.get("step", start)
    if not (is_int(step) and 1 <= step <= 1000):
        raise ConfigError(f"{where}.step = {clipped(step)} is invalid; valid: seeds added per round, in [1, 1000]")
    minutes = value.get("max_minutes")
    if minutes is not None and not (is_number(minutes) and 0 < minutes <= 100_000):
        raise ConfigError(
            f"{where}.max_minutes = {clipped(minutes)} is invalid; valid: minutes in (0, 100000] by which the rounds "
            "end: none starts that would end later at the pace measured (or leave it out: no time budget)"
        )
    growth = value.get("growth", 1.0)
    if not (is_number(growth) and 1 <= growth <= 10):
        raise ConfigError(
            f"{where}.growth = {clipped(growth)} is invalid; valid: a factor in [1, 10] by which each round's added "
            "seeds grow (1: step every round; 2: doubling)"
        )
    spending = value.get("spending", SPENDINGS[0])
    if spending not in SPENDINGS:
        raise ConfigError(
            f"{where}.spending = {clipped(spending)} is invalid; valid: {' or '.join(repr(s) for s in SPENDINGS)}"
        )
    if most == start:  # one round: exactly ``seeds = start`` (its trial keys too)
        return tuple(range(start)), None
    return tuple(range(start)), SeedRounds(
        start, step, most, None if minutes is None else float(minutes), float(growth), spending
    )
