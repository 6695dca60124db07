"""Each measure of a trial, defined once: the area under its learning curve, its episodes to solve (censored at
the budget), the primary metric an experiment's claims default to, and what the report reads off a whole curve
(``trial_measures``: the untrained return, the return at fixed budgets, episodes to a return level). Pure (numpy;
a curve frame's columns), below every layer.

The trainer records them, the launch's rounds judge on them and the report recomputes them from the curve: all
through these functions, so the three agree to the bit on the same curve.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the report passes a curve frame; the trainer never imports pandas for these
    import pandas as pd

SEED_COUNTS = (4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50, 60, 80, 100)
"""Seeds per variant ``seeds_needed`` tries, smallest first (3 and 3 can never reach 95% with a rank test)."""
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


def seeds_needed(power: Callable[[int], float], counts: Sequence[int]) -> int | None:
    """The fewest seeds per variant, of ``counts`` (ascending, a subset of ``SEED_COUNTS``), at which ``power(n)`` (the
    share of experiments of n seeds each, drawn with replacement from the observed ones, that the comparison's own
    decision rule decides) reaches ``POWER``; ``None``: not even the largest. Power grows with seeds, so the search
    bisects. The one definition of seeds needed: the claims' family and the report's exploratory rows differ only in
    the decision rule their ``power`` applies."""
    counts = list(counts)
    if not counts or power(counts[-1]) < POWER:
        return None
    low, high = 0, len(counts) - 1
    while low < high:
        middle = (low + high) // 2
        if power(counts[middle]) >= POWER:
            high = middle
        else:
            low = middle + 1
    return counts[low]


INITIAL_EPISODES = 10
"""The untrained policy's return: the mean of a trial's first 10 episodes."""


def fixed_budgets(budget: int) -> list[int]:
    """The episode budgets every variant's return is compared at: a quarter, half and all of ``budget``."""
    return sorted({max(1, budget // 4), max(1, budget // 2), budget})


def trial_measures(curve: pd.DataFrame, budget: int, levels: tuple[float, ...], window: int) -> dict[str, float]:
    """What one trial's curve says beyond its summary metrics: AUC, the untrained return, the improvement
    over it, the rolling return after each fixed budget, and the first episode the rolling mean (over a full
    window, or a quarter of the budget if shorter) reaches each return level (censored at the budget)."""
    rolling = curve.rolling_mean.to_numpy(float)
    returns = curve["return"].to_numpy(float)
    measures: dict[str, float] = {"auc": area_under_curve(rolling, budget)}
    if len(returns) == 0:
        return measures
    initial = float(returns[: min(INITIAL_EPISODES, len(returns))].mean())
    measures["initial_return"] = initial
    measures["improvement"] = float(rolling[-1]) - initial
    for episodes in fixed_budgets(budget):
        measures[f"return_at_{episodes}"] = float(rolling[min(episodes, len(rolling)) - 1])
    full = curve["return"].rolling(min(window, max(1, budget // 4)), min_periods=min(window, max(1, budget // 4)))
    full_mean = full.mean().to_numpy(float)
    episodes_axis = curve.episode.to_numpy(int)
    for level in levels:
        hits = np.flatnonzero(full_mean >= level)
        measures[f"reached_{level:g}"] = float(len(hits) > 0)
        measures[f"episodes_to_{level:g}"] = float(episodes_axis[hits[0]]) if len(hits) else float(budget)
    return measures
