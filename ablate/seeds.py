"""An experiment's evaluation seeds: a fixed count or list, or a table of rounds (``seeds = { start = 5, step = 5,
max = 40 }``) that ``ablate.launch.rounds`` adds seeds by. Standard library only.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields
from typing import Any

from ablate.config import ConfigError, clipped, declared_values, is_int, is_number
from ablate.schema import integer, knob, number, one_of


def _count(valid: str) -> dict[str, Any]:
    return integer(1, 1000) | {"valid": valid}


SPENDINGS = ("obrien-fleming", "pocock")


@dataclass(frozen=True)
class SeedRounds:
    """``seeds = { start = 5, step = 5, max = 40 }``: evaluation seeds added in rounds (``ablate.launch.rounds``),
    round 1 running seeds ``0 .. start - 1``. Each field is a key of the table, checked as declared."""

    start: int = knob(MISSING, **_count("a count of seeds in [1, 1000]"))
    step: int = knob(MISSING, **_count("seeds added per round, in [1, 1000]"))
    max: int = knob(MISSING, check=lambda v: True, valid="")  # its range starts at start: parse_seeds checks it
    max_minutes: float | None = knob(
        None,
        check=lambda v: v is None or (is_number(v) and 0 < v <= 100_000),
        valid="minutes in (0, 100000] by which the rounds end: none starts that would end later at the pace "
        "measured (or leave it out: no time budget)",
        convert=lambda v: v if v is None else float(v),
    )
    """No new round starts once a launch has run this long (minutes); ``None``: no time budget."""
    growth: float = knob(
        1.0,
        **number(1, 10)
        | {"valid": "a factor in [1, 10] by which each round's added seeds grow (1: step every round; 2: doubling)"},
    )
    """Each round adds ``growth`` times the seeds the round before added (``step`` first): 1 adds ``step`` every
    round; 2 doubles the seeds per round (start 10, step 10: 10, 20, 40, 80 ...), so a cap in the hundreds costs
    a handful of looks."""

    spending: str = knob(SPENDINGS[0], **one_of(SPENDINGS, " or ".join(map(repr, SPENDINGS))))
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
ROUND_KEYS = tuple(f.name for f in fields(SeedRounds))


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
    rounds = SeedRounds(**declared_values(SeedRounds, {"step": value["start"], **value}, f"{where}."))
    if not (is_int(rounds.max) and rounds.start <= rounds.max <= 1000):
        raise ConfigError(
            f"{where}.max = {clipped(rounds.max)} is invalid; valid: a count of seeds in [start = {rounds.start}, 1000]"
        )
    # one round: exactly ``seeds = start`` (its trial keys too)
    return tuple(range(rounds.start)), None if rounds.max == rounds.start else rounds
