"""Tidy pandas frames from tracked runs, and the per-variant statistics the report shows.

Statistics use SciPy: ``trim_mean`` for the interquartile mean (IQM), ``bootstrap`` for 95% intervals,
``mannwhitneyu`` for the probability of improvement. Unsolved trials are censored at the budget.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from ablate.tracking import Tracker

CONFIDENCE = 0.95
N_RESAMPLES = 2000
SEED = 12345  # bootstrap resampling is seeded: the same runs give the same report


class NoResults(LookupError):
    """Nothing to report: the message says what is missing and what to run."""


@dataclass
class Ablation:
    """Everything the report needs, read from the tracking store."""

    name: str
    grid: dict[str, Any]
    launch: dict[str, Any]
    """Tags and files of the newest launch: command, commit, environment."""
    trials: pd.DataFrame
    """One row per trial of the grid: variant, seed, status, summary metrics, ``censored_episodes``."""
    curves: pd.DataFrame
    """Long form: variant, seed, episode, return, rolling_mean, wall_s (finished trials only)."""
    params: dict[str, dict[str, str]] = field(default_factory=dict)
    """Flattened config per variant (from its first finished run)."""

    @property
    def variants(self) -> list[str]:
        return [v["name"] for v in self.grid["variants"]]

    @property
    def baseline(self) -> str:
        return self.grid["baseline"]

    @property
    def finished(self) -> pd.DataFrame:
        return self.trials[self.trials.status == "FINISHED"]


def iqm(values: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50% (25% trimmed from each end)."""
    return stats.trim_mean(values, 0.25, axis=axis)


def _percentile_bootstrap(samples: tuple, statistic, n_resamples: int = N_RESAMPLES):
    """SciPy's percentile bootstrap, 95%, seeded, vectorised along the last axis; independent samples are
    resampled independently."""
    result = stats.bootstrap(
        samples,
        statistic,
        confidence_level=CONFIDENCE,
        n_resamples=n_resamples,
        method="percentile",
        vectorized=True,
        paired=False,
        axis=-1,
        rng=np.random.default_rng(SEED),
    )
    return result.confidence_interval.low, result.confidence_interval.high


def bootstrap_interval(values: np.ndarray, statistic=iqm) -> tuple[float, float]:
    """Percentile bootstrap 95% interval of ``statistic`` over one sample (NaNs when fewer than 2 values)."""
    values = np.asarray(values, dtype=float)
    if len(values) < 2:
        return (float("nan"), float("nan"))
    if np.all(values == values[0]):
        return (float(values[0]), float(values[0]))
    low, high = _percentile_bootstrap((values,), statistic)
    return (float(low), float(high))


def probability_of_improvement(lower_is_better: np.ndarray, reference: np.ndarray) -> float:
    """P(X < Y) + P(X = Y) / 2 for X from the variant, Y from the reference: the chance that a random seed
    of the variant needs fewer episodes than a random seed of the reference. Identical samples give 0.5."""
    x, y = np.asarray(lower_is_better, float), np.asarray(reference, float)
    # Mann-Whitney's U for (y, x) counts pairs with y > x, ties counting one half.
    return float(stats.mannwhitneyu(y, x, alternative="two-sided").statistic / (len(x) * len(y)))


def _pairwise_improvement(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """P(X < Y) + P(X = Y) / 2 over all pairs, vectorised over leading (resample) axes."""
    x, y = np.moveaxis(x, axis, -1), np.moveaxis(y, axis, -1)
    less = (x[..., :, None] < y[..., None, :]).mean(axis=(-2, -1))
    ties = (x[..., :, None] == y[..., None, :]).mean(axis=(-2, -1))
    return less + 0.5 * ties


def probability_of_improvement_interval(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < 2 or len(y) < 2:
        return (float("nan"), float("nan"))
    if np.all(np.concatenate([x, y]) == x[0]):
        return (0.5, 0.5)
    low, high = _percentile_bootstrap((x, y), _pairwise_improvement)
    return (float(low), float(high))


def relative_reduction(variant: np.ndarray, reference: np.ndarray) -> tuple[float, float, float]:
    """1 - IQM(variant) / IQM(reference), with a 95% bootstrap interval (samples resampled independently).
    Positive: the variant needs fewer (episodes); negative: more."""
    variant, reference = np.asarray(variant, float), np.asarray(reference, float)

    def statistic(a, b, axis=-1):
        return 1 - iqm(a, axis=axis) / iqm(b, axis=axis)

    point = float(statistic(variant, reference))
    if len(variant) < 2 or len(reference) < 2:
        return point, float("nan"), float("nan")
    if np.all(np.concatenate([variant, reference]) == variant[0]):
        return point, point, point
    low, high = _percentile_bootstrap((variant, reference), statistic)
    return point, float(low), float(high)


def area_under_curve(rolling_means: np.ndarray, budget: int) -> float:
    """Mean rolling return over the whole budget; a trial that stopped when solved keeps its last value
    (the stop rule assumes a solved agent stays solved). Higher is better; it rewards learning early."""
    curve = np.asarray(rolling_means, float)
    if len(curve) == 0:
        return float("nan")
    padded = np.concatenate([curve, np.full(max(budget - len(curve), 0), curve[-1])])[:budget]
    return float(padded.mean())


def load_ablation(name: str, tracking_uri: str | None = None) -> Ablation:
    """The newest launch's grid, and for every trial of it the run that answers it."""
    tracker = Tracker(tracking_uri, name)
    if tracker.experiment_id(create=False) is None:
        raise NoResults(
            f"no MLflow experiment named {name!r} at {tracker.uri}; run `ablate run experiments/{name}.toml` first"
        )
    launch = tracker.latest_launch()
    if launch is None:
        raise NoResults(f"experiment {name!r} at {tracker.uri} has no launches; run `ablate run` first")
    launch_id = launch.info.run_id
    grid = json.loads(tracker.load_text(launch_id, "grid.json"))
    try:
        environment = json.loads(tracker.load_text(launch_id, "environment.json"))
    except Exception:  # noqa: BLE001 - older launches have no environment file
        environment = {}
    generation = launch.data.tags.get("ablate.generation")
    runs = tracker.trial_runs(generation)
    # The answer for a key: its newest finished run, else its newest run of any status.
    best_run: dict[str, Any] = {}
    for run in runs:
        current = best_run.get(run.key)
        if current is None or run.status == "FINISHED" or current.status != "FINISHED":
            best_run[run.key] = run

    rows, curves, params = [], [], {}
    budget_of: dict[str, int] = {}
    for trial in grid["trials"]:
        run = best_run.get(trial["key"])
        row = {"key": trial["key"], "variant": trial["variant"], "seed": trial["seed"]}
        if run is None:
            rows.append(row | {"status": "NOT RUN"})
            continue
        budget = int(run.params.get("max_episodes", grid["base"].get("max_episodes", 0)))
        budget_of[trial["variant"]] = budget
        row |= {"status": run.status, "run_id": run.run_id, "budget": budget, "error": run.tags.get("ablate.error", "")}
        row |= {k: run.metrics.get(k, np.nan) for k in SUMMARY_COLUMNS}
        if run.status == "FINISHED":
            params.setdefault(trial["variant"], run.params)
            # The exact per-episode table is the run's episodes.csv (MLflow holds a bounded curve); the rolling
            # mean is recomputed from the returns with the trial's own window, exactly as the trial computed it.
            with tempfile.TemporaryDirectory(prefix="ablate-episodes-") as folder:
                table = pd.read_csv(tracker.download(run.run_id, "episodes.csv", folder))
            returns = dict(zip(table["episode"], table["episode_return"], strict=True))
            wall = dict(zip(table["episode"], table["wall_s"], strict=True))
            episodes = sorted(returns)
            window = int(run.params.get("solve_window", grid["base"].get("solve_window", 100)))
            curve = pd.DataFrame(
                {
                    "variant": trial["variant"],
                    "seed": trial["seed"],
                    "solved": run.metrics.get("solved", 0.0) == 1.0,
                    "episode": episodes,
                    "return": [returns[e] for e in episodes],
                    "wall_s": [wall.get(e, np.nan) for e in episodes],
                }
            )
            # the clock is logged when an update ends: each episode gets the time of its update's end
            curve["wall_s"] = curve["wall_s"].bfill()
            curve["rolling_mean"] = curve["return"].rolling(window, min_periods=1).mean()
            curves.append(curve)
            row["auc"] = area_under_curve(curve.rolling_mean.to_numpy(), budget)
        rows.append(row)
    trials = pd.DataFrame(rows)
    for column in (*SUMMARY_COLUMNS, "auc", "budget", "run_id", "error"):
        if column not in trials:
            trials[column] = np.nan
    solved = trials["solved"] == 1
    trials["censored_episodes"] = np.where(solved, trials["episodes_to_solve"], trials["budget"])
    curves_frame = (
        pd.concat(curves, ignore_index=True)
        if curves
        else pd.DataFrame(columns=["variant", "seed", "solved", "episode", "return", "rolling_mean", "wall_s"])
    )
    launch_info = {"run_id": launch_id, "tags": dict(launch.data.tags), "environment": environment}
    return Ablation(name, grid, launch_info, trials, curves_frame, params)


SUMMARY_COLUMNS = (
    "solved",
    "episodes_to_solve",
    "env_steps_to_solve",
    "wall_s_to_solve",
    "final_rolling_mean",
    "episodes_run",
    "env_steps",
    "wall_s",
    "steps_per_s",
    "parameter_count",
    "greedy_return",
)


def convergence_table(ablation: Ablation) -> pd.DataFrame:
    """One row per variant: seeds, fraction solved, episodes-to-solve (median, IQM, 95% CIs, censored at the
    budget), env steps and seconds to solve (solved seeds), final rolling mean, AUC."""
    rows = []
    for variant in ablation.variants:
        group = ablation.trials[ablation.trials.variant == variant]
        done = group[group.status == "FINISHED"]
        episodes = done.censored_episodes.to_numpy(float)
        n_censored = int((done.solved != 1).sum())
        solved = done[done.solved == 1]
        row: dict[str, Any] = {
            "variant": variant,
            "seeds_run": len(done),
            "seeds_failed": int((group.status.isin(["FAILED", "KILLED"])).sum()),
            "solved": int(len(solved)),
            "fraction_solved": len(solved) / len(done) if len(done) else np.nan,
            "unsolved_censored": n_censored,
            "budget": int(done.budget.max()) if len(done) else np.nan,
        }
        if len(done):
            median = float(np.median(episodes))
            row["episodes_median"] = median
            row["episodes_median_ci_low"], row["episodes_median_ci_high"] = bootstrap_interval(episodes, _median)
            row["episodes_iqm"] = float(iqm(episodes))
            row["episodes_iqm_ci_low"], row["episodes_iqm_ci_high"] = bootstrap_interval(episodes)
            # a statistic is censored (a lower bound) when unsolved seeds reach into the values it uses
            # A statistic is a lower bound (censored) when it uses an unsolved seed's value. Unsolved seeds
            # sort last (at the budget); the median uses the middle one or two, IQM the middle 50%.
            row["median_censored"] = n_censored >= len(done) - len(done) // 2
            row["iqm_censored"] = n_censored > int(np.floor(0.25 * len(done)))
            row["env_steps_to_solve_median"] = float(solved.env_steps_to_solve.median()) if len(solved) else np.nan
            row["wall_s_to_solve_median"] = float(solved.wall_s_to_solve.median()) if len(solved) else np.nan
            row["final_rolling_mean_iqm"] = float(iqm(done.final_rolling_mean.to_numpy(float)))
            row["auc_iqm"] = float(iqm(done.auc.to_numpy(float)))
            row["auc_ci_low"], row["auc_ci_high"] = bootstrap_interval(done.auc.to_numpy(float))
            row["parameter_count"] = int(done.parameter_count.iloc[0])
        rows.append(row)
    return pd.DataFrame(rows)


def _median(values: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.median(values, axis=axis)


def comparisons(ablation: Ablation) -> pd.DataFrame:
    """Each variant against the baseline, on episodes-to-solve (censored): probability of improvement and
    the relative reduction of the IQM, each with its 95% interval."""
    done = ablation.finished
    reference = done[done.variant == ablation.baseline].censored_episodes.to_numpy(float)
    rows = []
    for variant in ablation.variants:
        if variant == ablation.baseline:
            continue
        sample = done[done.variant == variant].censored_episodes.to_numpy(float)
        if len(sample) == 0 or len(reference) == 0:
            continue
        poi = probability_of_improvement(sample, reference)
        poi_low, poi_high = probability_of_improvement_interval(sample, reference)
        reduction, low, high = relative_reduction(sample, reference)
        auc_sample = done[done.variant == variant].auc.to_numpy(float)
        auc_reference = done[done.variant == ablation.baseline].auc.to_numpy(float)
        auc_drop, auc_low, auc_high = relative_reduction(auc_sample, auc_reference)
        rows.append(
            {
                "variant": variant,
                "baseline": ablation.baseline,
                "p_improvement": poi,
                "p_improvement_ci_low": poi_low,
                "p_improvement_ci_high": poi_high,
                "episodes_reduction": reduction,
                "episodes_reduction_ci_low": low,
                "episodes_reduction_ci_high": high,
                "variant_censored": bool((done[done.variant == variant].solved != 1).any()),
                "baseline_censored": bool((done[done.variant == ablation.baseline].solved != 1).any()),
                "auc_change": -auc_drop,
                "auc_change_ci_low": -auc_high,
                "auc_change_ci_high": -auc_low,
            }
        )
    return pd.DataFrame(rows)


def curve_band(curves: pd.DataFrame, x: str, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IQM across seeds of the rolling mean at each point of ``grid`` (of column ``x``), with a 95% bootstrap
    band. A seed that stopped because it solved carries its last value forward; one that ran out of budget
    ends there. Where fewer than half the seeds have a value, the curve stops."""
    per_seed = []
    for _, seed_curve in curves.groupby("seed"):
        seed_curve = seed_curve.sort_values(x)
        xs, ys = seed_curve[x].to_numpy(float), seed_curve.rolling_mean.to_numpy(float)
        carry = ys[-1] if bool(seed_curve.solved.iloc[-1]) or x == "episode" else np.nan
        per_seed.append(np.interp(grid, xs, ys, left=np.nan, right=carry))
    matrix = np.array(per_seed).T  # (points, seeds)
    enough = (~np.isnan(matrix)).sum(axis=1) * 2 >= matrix.shape[1]
    centre = np.full(len(grid), np.nan)
    low, high = centre.copy(), centre.copy()
    for i in np.flatnonzero(enough):
        values = matrix[i][~np.isnan(matrix[i])]
        centre[i] = iqm(values)
        low[i], high[i] = centre[i], centre[i]
    # One vectorised bootstrap over the points where every seed has a value and they are not all equal.
    full = enough & ~np.isnan(matrix).any(axis=1) & (np.ptp(np.nan_to_num(matrix), axis=1) > 0)
    if full.any() and matrix.shape[1] >= 2:
        band_low, band_high = _percentile_bootstrap((matrix[full],), iqm, n_resamples=N_RESAMPLES // 4)
        low[full], high[full] = band_low, band_high
    return centre, low, high
