"""An experiment's evaluation seeds: a fixed count or list, or a table of rounds (``seeds = { start = 5, step = 5,
max = 40 }``) that ``ablate.launch.rounds`` adds seeds by. Standard library only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ablate.config import ConfigError, is_int, is_number


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

    @property
    def looks(self) -> tuple[int, ...]:
        """Seeds per variant after each round: ``start``, ``start + step``, ... and ``max`` last (the looks of
        ``reporting.claims.Design`` with the same three numbers)."""
        if self.max == self.start:
            return (self.start,)
        return (*range(self.start, self.max, self.step), self.max)


SEEDS_RULE = (
    "valid: a count in [1, 1000], a list of distinct non-negative integers, or a table of rounds "
    "{ start = 5, step = 5, max = 40 } (optional max_minutes = 15)"
)
ROUND_KEYS = ("start", "step", "max", "max_minutes")


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
        raise ConfigError(f"{where} = {_shown(value)} is invalid; {SEEDS_RULE}")
    for key in value:
        if key not in ROUND_KEYS:
            raise ConfigError(f"{where}.{key}: unknown key; valid keys of a seeds table: {', '.join(ROUND_KEYS)}")
    for key in ("start", "max"):
        if key not in value:
            raise ConfigError(f"{where}.{key}: missing; valid: e.g. seeds = {{ start = 5, step = 5, max = 40 }}")
    start, most = value["start"], value["max"]
    if not (is_int(start) and 1 <= start <= 1000):
        raise ConfigError(f"{where}.start = {_shown(start)} is invalid; valid: a count of seeds in [1, 1000]")
    if not (is_int(most) and start <= most <= 1000):
        raise ConfigError(
            f"{where}.max = {_shown(most)} is invalid; valid: a count of seeds in [start = {start}, 1000]"
        )
    step = value.get("step", start)
    if not (is_int(step) and 1 <= step <= 1000):
        raise ConfigError(f"{where}.step = {_shown(step)} is invalid; valid: seeds added per round, in [1, 1000]")
    minutes = value.get("max_minutes")
    if minutes is not None and not (is_number(minutes) and 0 < minutes <= 100_000):
        raise ConfigError(
            f"{where}.max_minutes = {_shown(minutes)} is invalid; valid: minutes in (0, 100000] after which no new "
            "round starts (or leave it out: no time budget)"
        )
    if most == start:  # one round: exactly ``seeds = start`` (its trial keys too)
        return tuple(range(start)), None
    return tuple(range(start)), SeedRounds(start, step, most, None if minutes is None else float(minutes))


def _shown(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"
