"""Each measure of a trial, defined once: the registry (``MEASURES``; ``measure`` maps a name back to its entry).
Pure (numpy; a curve frame's columns), below every layer.

The trainer, the launch's rounds and tuning and the report all read them through this registry, so they agree to
the bit on the same curve.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the report passes a curve frame; the trainer never imports pandas for these
    import pandas as pd

POWER = 0.8
"""The share of resampled experiments in which a comparison must be decided for its seeds to count as enough."""


def area_under_curve(rolling_means: Sequence[float] | np.ndarray, budget: int) -> float:
    """Mean rolling return over the whole budget of ``budget`` episodes; a trial that stopped when solved keeps its
    last value (the stop rule assumes a solved agent stays solved). Higher is better; it rewards learning early.
    NaN for an empty curve."""
    curve = np.asarray(rolling_means, float)
    if len(curve) == 0:
        return float("nan")
    padded = np.concatenate([curve, np.full(max(budget - len(curve), 0), curve[-1])])[:budget]
    return float(padded.mean())


@dataclass(frozen=True)
class Curve:
    """A trial's learning curve as a measure reads it: ``rolling``, the rolling mean return over the last ``window``
    (the solve window) episodes, fewer at the start; its ``budget``; its solve ``threshold`` (``None``: none)."""

    rolling: np.ndarray
    budget: int
    threshold: float | None
    window: int

    def first_full(self, level: float) -> float:
        """The first episode whose rolling mean over a full window reaches ``level`` (the solve rule); NaN: never."""
        hits = np.flatnonzero(np.asarray(self.rolling, float)[self.window - 1 :] >= level)
        return float(hits[0] + self.window) if len(hits) else math.nan


def _auc(curve: Curve) -> float:
    return area_under_curve(curve.rolling, curve.budget)


@dataclass(frozen=True)
class Measure:
    """One measure of a trial, declared once: tuning, the rounds, the claims, the tables and the report's words
    read it here, none from a table of its own."""

    name: str
    """Its name in experiment files (``[tune] metric``), the trials table, comparisons and claims."""
    words: str
    """Its name in the report's sentences."""
    higher_is_better: bool
    reached: str | None = None
    """Censored (episodes until something happens): the 0/1 column and summary metric saying it happened; where it
    did not, its value is the trial's budget, a lower bound. ``None``: never censored."""
    never: str = ""
    """A censored measure's words for a seed that never got there."""
    column: str = ""
    """The trials table's column of its values, censored at the budget (default: ``name``)."""
    summary: str = ""
    """The trial's summary metric tuning and the rounds read it from (default: ``name``)."""
    curve: Callable[[Curve], float] | None = None
    """How the trainer records it and the report recomputes it from a trial's curve (NaN: never got there)."""
    tune: bool = False
    """Whether ``[tune] metric`` may name it."""
    claim: str | None = None
    """Its name as an experiment's ``primary``; ``None``: no claim is made on it."""
    needs_threshold: bool = False
    """Whether it exists only where the env has a solve threshold."""
    family: str = ""
    """A parameterised measure's family (``FAMILIES``) and ``parameter`` (the episodes, the return level)."""
    parameter: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "column", self.column or self.name)
        object.__setattr__(self, "summary", self.summary or self.name)

    @property
    def censored(self) -> bool:
        return self.reached is not None

    @property
    def direction(self) -> str:
        """``max`` or ``min``: which way it is better."""
        return "max" if self.higher_is_better else "min"

    def from_summary(self, metrics: Mapping[str, float], budget: float) -> tuple[float, bool]:
        """A trial's value from its summary metrics (or a trials table's row) and whether it is censored (never got
        there: the budget). A missing value of an uncensored measure is NaN."""
        value = metrics.get(self.summary)
        if self.reached is None:
            return (math.nan if value is None else float(value)), False
        if value is None or not math.isfinite(value) or metrics.get(self.reached, 1.0) != 1.0:
            return float(budget), True
        return float(value), False


AUC = Measure("auc", "area under the curve (AUC)", True, curve=_auc, tune=True, claim="auc")
EPISODES_TO_SOLVE = Measure(
    "episodes_to_solve",
    "episodes to solve",
    False,
    reached="solved",
    never="never solved",
    column="censored_episodes",
    tune=True,
    claim="episodes_to_solve",
    needs_threshold=True,
)
FINAL_RETURN = Measure(
    "final_return",
    "return at the budget",
    True,
    column="final_rolling_mean",
    summary="final_rolling_mean",
    tune=True,
    claim="return",  # the report claims on it as the return after the whole budget (``return_at``)
)
EPISODES_TO_NEAR = Measure(
    "episodes_to_90pct_threshold",
    "episodes to reach 90% of the solve threshold",
    False,
    reached="reached_90pct_threshold",
    never="never reached 90% of the solve threshold",
    curve=lambda c: c.first_full(0.9 * c.threshold) if c.threshold is not None else math.nan,
    tune=True,
    claim="episodes_to_90pct_threshold",
    needs_threshold=True,
)
MEASURES = (EPISODES_TO_SOLVE, AUC, FINAL_RETURN, EPISODES_TO_NEAR)
"""Every measure with a name of its own, in the order experiment-file errors list them."""


def return_at(episodes: int) -> Measure:
    """The rolling mean return after ``episodes`` episodes (the last one where the trial stopped sooner)."""
    return Measure(
        f"return_at_{episodes}", f"return after {episodes:,} episodes", True, family="return_at", parameter=episodes
    )


def episodes_to(level: float) -> Measure:
    """The first episode whose rolling mean over a full window (or a quarter of the budget, if shorter) reaches the
    return ``level``, censored at the budget (``trial_measures``)."""
    level_words = f"{level:g}"
    return Measure(
        f"episodes_to_{level_words}",
        f"episodes to reach a rolling return of {level_words}",
        False,
        reached=f"reached_{level_words}",
        never=f"never reached {level_words}",
        family="episodes_to",
        parameter=level,
    )


FAMILIES: tuple[tuple[re.Pattern[str], Callable[[str], Measure]], ...] = (
    (re.compile(r"return_at_(\d+)"), lambda p: return_at(int(p))),
    (re.compile(r"episodes_to_(-?\d+(?:\.\d*)?(?:e[+-]?\d+)?)"), lambda p: episodes_to(float(p))),
)
"""Each parameterised family: the pattern of its names and its entry from the parameter."""


def lookup(name: str) -> Measure | None:
    """The entry ``name`` means: by its name or its ``claim`` name, or a parameterised family's; ``None``: none."""
    entry = next((m for m in MEASURES if name in (m.name, m.claim)), None)
    matches = ((pattern.fullmatch(name), make) for pattern, make in FAMILIES)
    return entry or next((make(match[1]) for match, make in matches if match), None)


def measure(name: str) -> Measure:
    """The entry ``name`` means (``lookup``); a ``KeyError`` where none."""
    if (entry := lookup(name)) is None:
        raise KeyError(name)
    return entry


def is_censored(name: str) -> bool:
    """Whether ``name`` is a censored measure (episodes until something happens: ratios, lower is better)."""
    return (entry := lookup(name)) is not None and entry.censored


def tune_names() -> list[str]:
    """The names ``[tune] metric`` may take."""
    return [m.name for m in MEASURES if m.tune]


def claim_names() -> list[str]:
    """The names an experiment's ``primary`` may take."""
    return [m.claim for m in MEASURES if m.claim]


def recorded(curve: Curve) -> dict[str, float]:
    """What a trial records of the registry among its summary metrics (tuning and the rounds read them): each
    entry with a curve function, a censored one only where it got there."""
    values = {m: m.curve(curve) for m in MEASURES if m.curve is not None and len(curve.rolling)}
    return {m.summary: v for m, v in values.items() if not (m.censored and not math.isfinite(v))}


def reaches_threshold(rolling_mean: float, window_filled: bool, threshold: float | None) -> bool:
    """The solve rule: the rolling mean over a full ``solve_window`` at or above the threshold (never without
    one)."""
    return threshold is not None and window_filled and rolling_mean >= threshold


def censored_episodes(solved: np.ndarray, episodes_to_solve: np.ndarray, budget: np.ndarray) -> np.ndarray:
    """Episodes to solve with an unsolved trial counted as its budget (censored): what claims and tables compare."""
    return np.where(np.asarray(solved, bool), np.asarray(episodes_to_solve, float), np.asarray(budget, float))


def default_primary_metric(solve_thresholds: Sequence[float | None]) -> str:
    """The metric claims are made on when an experiment names none: episodes to solve where every trial has a solve
    threshold, else the area under the learning curve (Pong has no threshold)."""
    return "episodes_to_solve" if all(t is not None for t in solve_thresholds) else "auc"


INITIAL_EPISODES = 10
"""The untrained policy's return: the mean of a trial's first 10 episodes."""


def fixed_budgets(budget: int) -> list[int]:
    """The episode budgets every variant's return is compared at: a quarter, half and all of ``budget``."""
    return sorted({max(1, budget // 4), max(1, budget // 2), budget})


def trial_measures(
    curve: pd.DataFrame,
    budget: int,
    levels: tuple[float, ...],
    window: int,
    threshold: float | None = None,
    asked: Sequence[Measure] = (),
) -> dict[str, float]:
    """What one trial's curve says beyond its summary metrics: AUC, the untrained return, the improvement
    over it, the rolling return after each fixed budget, ``episodes_to`` each return level, and each measure of
    ``asked`` computed from the curve (``curve_columns``)."""
    rolling = curve.rolling_mean.to_numpy(float)
    returns = curve["return"].to_numpy(float)
    measures: dict[str, float] = {}
    for entry in dict.fromkeys((AUC, *(m for m in asked if m.curve is not None))):
        measures |= curve_columns(entry, Curve(rolling, budget, threshold, window))
    if len(returns) == 0:
        return measures
    initial = float(returns[: min(INITIAL_EPISODES, len(returns))].mean())
    measures["initial_return"] = initial
    measures["improvement"] = float(rolling[-1]) - initial
    for episodes in fixed_budgets(budget):
        measures[return_at(episodes).column] = float(rolling[min(episodes, len(rolling)) - 1])
    full = curve["return"].rolling(min(window, max(1, budget // 4)), min_periods=min(window, max(1, budget // 4)))
    full_mean = full.mean().to_numpy(float)
    episodes_axis = curve.episode.to_numpy(int)
    for level in levels:
        hits, entry = np.flatnonzero(full_mean >= level), episodes_to(level)
        measures[entry.reached] = float(len(hits) > 0)
        measures[entry.column] = float(episodes_axis[hits[0]]) if len(hits) else float(budget)
    return measures


def curve_columns(entry: Measure, curve: Curve) -> dict[str, float]:
    """A curve measure as the trials table holds it: its value (censored: the budget where it never got there)
    and, where censored, its ``reached`` flag."""
    assert entry.curve is not None
    value = entry.curve(curve)
    if entry.reached is None:
        return {entry.column: value}
    return {
        entry.column: value if math.isfinite(value) else float(curve.budget),
        entry.reached: float(math.isfinite(value)),
    }
