"""Tidy pandas frames from tracked runs, and the per-variant statistics the report shows.

Statistics use SciPy: ``trim_mean`` for the interquartile mean (IQM), ``bootstrap`` for 95% intervals,
``mannwhitneyu`` for the probability of improvement. Unsolved trials are censored at the budget.
"""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from ablate.config import ConfigError
from ablate.report.reader import RunReader

CONFIDENCE = 0.95
N_RESAMPLES = 2000
SEED = 12345  # bootstrap resampling is seeded: the same runs give the same report
INITIAL_EPISODES = 10
"""The untrained policy's return: the mean of a trial's first 10 episodes."""
RETURN_LEVELS = {"ALE/Pong-v5": (-15.0, -10.0)}
"""Return levels whose first crossing (rolling mean) is timed, for envs where few seeds reach a threshold."""


class NoResults(LookupError):
    """Nothing to report: the message says what is missing and what to run."""


@dataclass
class Ablation:
    """Everything the report needs, read from the tracking store."""

    name: str
    grid: dict[str, Any]
    launch: dict[str, Any]
    """Tags and files of the reported launch: command, commit, environment; ``generations``: every
    generation of the experiment, newest first, with its trial counts."""
    trials: pd.DataFrame
    """One row per trial of the grid: variant, seed, status, summary metrics, ``censored_episodes``, ``auc``,
    ``initial_return``, ``improvement``, ``return_at_<E>``, ``episodes_to_<L>`` (and ``reached_<L>``)."""
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

    def changes(self, variant: str, against: str | None = None) -> dict[str, Any]:
        """The knobs ``variant`` sets differently from ``against`` (default: the baseline), with its values."""
        overrides = {v["name"]: v.get("overrides", {}) for v in self.grid["variants"]}
        base, mine, theirs = self.grid.get("base", {}), overrides[variant], overrides[against or self.baseline]
        return {
            knob: mine.get(knob, base.get(knob))
            for knob in sorted(set(mine) | set(theirs))
            if mine.get(knob, base.get(knob)) != theirs.get(knob, base.get(knob))
        }

    def reference(self, variant: str) -> str:
        """The variant ``variant`` is compared with: of the others, the one whose changes from the baseline
        are the largest part of its own (``mlp-dropout`` against ``mlp`` when ``mlp`` changes only the
        architecture), so that each comparison isolates what the variant adds; else the baseline. Between
        two as large, the one of the variant's own architecture family (``mlp-l2``: ``mlp``, not ``cnn-l2``),
        then the first in the experiment file."""
        return self._references[variant]

    @cached_property
    def _references(self) -> dict[str, str]:
        """``reference`` of every variant, found once: the report asks for them per row and per figure panel."""
        changes = {v: list(self.changes(v).items()) for v in self.variants}
        references = {}
        for variant, mine in changes.items():
            best, rank = self.baseline, (0, False)
            for other, theirs in changes.items():
                if other == variant or not len(theirs) < len(mine) or any(item not in mine for item in theirs):
                    continue
                same_architecture = "architecture" not in self.changes(variant, other)
                if (len(theirs), same_architecture) > rank:
                    best, rank = other, (len(theirs), same_architecture)
            references[variant] = best
        return references

    @property
    def finished(self) -> pd.DataFrame:
        return self.trials[self.trials.status == "FINISHED"]

    @property
    def env_id(self) -> str:
        return str(self.grid.get("base", {}).get("env_id", ""))

    @property
    def threshold(self) -> float | None:
        """The solve threshold the trials used: the file's, else the env's; None (Pong) when there is none."""
        for params in self.params.values():
            value = params.get("solve_threshold", "None")
            if value not in ("None", ""):
                return float(value)
        value = self.grid.get("base", {}).get("solve_threshold")
        if value is not None:
            return float(value)
        return {"CartPole-v0": 195.0, "CartPole-v1": 475.0}.get(self.env_id)

    @property
    def any_solved(self) -> bool:
        return self.threshold is not None and bool((self.finished.solved == 1).any())

    @property
    def budgets(self) -> list[int]:
        """Fixed episode budgets at which every variant's return is compared: a quarter, half and all of it."""
        return fixed_budgets(int(self.finished.budget.max())) if len(self.finished) else []

    @property
    def levels(self) -> tuple[float, ...]:
        return RETURN_LEVELS.get(self.env_id, ())


def fixed_budgets(budget: int) -> list[int]:
    return sorted({max(1, budget // 4), max(1, budget // 2), budget})


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
    """Percentile bootstrap 95% interval of ``statistic`` over one sample (NaNs when fewer than 2 values:
    no interval can be computed from one seed)."""
    values = np.asarray(values, dtype=float)
    values = values[~np.isnan(values)]
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
    """95% interval of P(X < Y) + P(X = Y) / 2. The percentile bootstrap collapses to a point when every
    pair is ordered the same way (5 seeds each give "1.00 [1.00, 1.00]"), which only says the sample has no
    other pair to resample; there the interval is the exact Clopper-Pearson one for ``min(n, m)`` successes
    in ``min(n, m)`` independent comparisons, as if only that many pairs carried information."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < 2 or len(y) < 2:
        return (float("nan"), float("nan"))
    point = _pairwise_improvement(x, y)
    if np.all(np.concatenate([x, y]) == x[0]):
        return (0.5, 0.5)
    low, high = _percentile_bootstrap((x, y), _pairwise_improvement)
    n = min(len(x), len(y))
    edge = (1 - CONFIDENCE) / 2
    if point >= 1.0 or high - low < 1e-12 and point > 0.5:
        low, high = edge ** (1 / n), 1.0
    elif point <= 0.0 or high - low < 1e-12 and point < 0.5:
        low, high = 0.0, 1 - edge ** (1 / n)
    return (float(low), float(high))


def smallest_p_value(n: int, m: int) -> float:
    """The smallest two-sided p-value a rank test can give with ``n`` and ``m`` seeds (complete separation):
    above 0.05, no ordering of the seeds can support a claim at 95%."""
    if n < 1 or m < 1:
        return 1.0
    return min(1.0, 2 / math.comb(n + m, n))


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


def iqm_difference(variant: np.ndarray, reference: np.ndarray) -> tuple[float, float, float]:
    """IQM(variant) - IQM(reference), with a 95% bootstrap interval: for returns, which can be negative
    (Pong), where a ratio means nothing."""
    variant, reference = np.asarray(variant, float), np.asarray(reference, float)

    def statistic(a, b, axis=-1):
        return iqm(a, axis=axis) - iqm(b, axis=axis)

    point = float(statistic(variant, reference))
    if len(variant) < 2 or len(reference) < 2:
        return point, float("nan"), float("nan")
    if np.all(variant == variant[0]) and np.all(reference == reference[0]):
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


def is_censored_statistic(n_censored: int, n: int, statistic: str) -> bool:
    """Does the median or IQM of ``n`` values use one of the ``n_censored`` largest (censored) ones? Then it
    is a lower bound, not an estimate. The median uses the middle one or two; the IQM the middle 50%
    (SciPy's ``trim_mean`` cuts ``int(0.25 n)`` from each end)."""
    if n == 0:
        return False
    if statistic == "median":
        return n_censored >= n - n // 2
    return n_censored > int(np.floor(0.25 * n))


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


def _launches(tracker: RunReader) -> list[Any]:
    return tracker.launches()


def _generation_summary(tracker: RunReader, launches: list[Any]) -> list[dict[str, Any]]:
    """Every generation, newest first: its id, when it started, trials in its grid, trials finished."""
    runs = tracker.trial_runs()
    finished: dict[str, set[str]] = {}
    for run in runs:
        if run.status == "FINISHED":
            finished.setdefault(run.tags.get("ablate.generation", ""), set()).add(run.key)
    seen, out = set(), []
    for launch in launches:
        generation = launch.data.tags.get("ablate.generation", "")
        if generation in seen:
            continue
        seen.add(generation)
        out.append(
            {
                "generation": generation,
                "started_ms": launch.info.start_time,
                "launch_run_id": launch.info.run_id,
                "finished": len(finished.get(generation, set())),
            }
        )
    return out


def check_store(tracking_uri: str | None) -> str:
    """The store's URI; a local store (SQLite file or folder) that does not exist is a ``ConfigError``, so
    that reading never creates an empty database where a user mistyped a path."""
    from ablate.run.tracking import resolve_uri

    uri = resolve_uri(tracking_uri)
    if uri.startswith("sqlite:///"):
        path = Path(uri.removeprefix("sqlite:///"))
    elif uri.startswith("file:"):
        path = Path(uri.removeprefix("file://").removeprefix("file:"))
    elif "://" not in uri:
        path = Path(uri)
    else:
        return uri
    if not path.exists():
        raise ConfigError(f"--tracking-uri {uri}: no MLflow store at {path}; valid: the store `ablate run` wrote")
    return uri


def load_ablation(name: str, tracking_uri: str | None = None, generation: str | None = None) -> Ablation:
    """The grid of one generation (default: the newest launch's), and for every trial of it the run that
    answers it. Reads only; a missing store is a ``ConfigError``, a store without the experiment, its launches
    or the asked-for generation is ``NoResults``."""
    uri = check_store(tracking_uri)
    tracker = RunReader(uri, name)
    if tracker.experiment_id(create=False) is None:
        raise NoResults(
            f"no MLflow experiment named {name!r} at {tracker.shown_uri}; "
            f"run `ablate run experiments/{name}.toml` first"
        )
    launches = _launches(tracker)
    if not launches:
        raise NoResults(f"experiment {name!r} at {tracker.shown_uri} has no launches; run `ablate run` first")
    generations = _generation_summary(tracker, launches)
    if generation is None:
        launch = launches[0]
    else:
        matching = [g for g in generations if g["generation"].startswith(generation)]
        if len(matching) != 1:
            known = ", ".join(f"{g['generation']} ({g['finished']} trials finished)" for g in generations)
            raise ConfigError(
                f"--generation {generation}: {'no' if not matching else 'more than one'} generation of "
                f"{name!r} matches; valid: {known}"
            )
        launch = next(run for run in launches if run.data.tags.get("ablate.generation") == matching[0]["generation"])
    return _read_launch(tracker, name, launch, generations)


def _read_launch(tracker: RunReader, name: str, launch: Any, generations: list[dict[str, Any]]) -> Ablation:
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
    levels = RETURN_LEVELS.get(str(grid.get("base", {}).get("env_id", "")), ())

    rows, curves, params = [], [], {}
    for trial in grid["trials"]:
        run = best_run.get(trial["key"])
        row = {"key": trial["key"], "variant": trial["variant"], "seed": trial["seed"]}
        if run is None:
            rows.append(row | {"status": "NOT RUN"})
            continue
        budget = int(run.params.get("max_episodes", grid["base"].get("max_episodes", 0)))
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
            row |= trial_measures(curve, budget, levels, window)
        rows.append(row)
    launch_info = {
        "run_id": launch_id,
        "tags": dict(launch.data.tags),
        "environment": environment,
        "generations": generations,
    }
    return _ablation(name, grid, launch_info, pd.DataFrame(rows), curves, params)


def _ablation(name, grid, launch_info, trials: pd.DataFrame, curves: list[pd.DataFrame], params) -> Ablation:
    for column in (*SUMMARY_COLUMNS, "auc", "budget", "run_id", "error", "initial_return", "improvement"):
        if column not in trials:
            trials[column] = np.nan
    solved = trials["solved"] == 1
    trials["censored_episodes"] = np.where(solved, trials["episodes_to_solve"], trials["budget"])
    curves_frame = (
        pd.concat(curves, ignore_index=True)
        if curves
        else pd.DataFrame(columns=["variant", "seed", "solved", "episode", "return", "rolling_mean", "wall_s"])
    )
    return Ablation(name, grid, launch_info, trials, curves_frame, params)


def select(ablation: Ablation, variants: list[str] | None = None, baseline: str | None = None) -> Ablation:
    """The ablation restricted to ``variants`` (in that order), compared to ``baseline``. Unknown names are a
    ``ConfigError`` naming what is valid."""
    known = ablation.variants
    chosen = variants or known
    unknown = [v for v in chosen if v not in known]
    if unknown:
        raise ConfigError(f"--variants: unknown variant {unknown[0]!r}; valid: {', '.join(known)}")
    base = baseline or ablation.baseline
    if base not in known:
        raise ConfigError(f"--baseline {base!r}: unknown variant; valid: {', '.join(known)}")
    if base not in chosen:
        chosen = [base, *chosen]
    by_name = {v["name"]: v for v in ablation.grid["variants"]}
    grid = ablation.grid | {"variants": [by_name[v] for v in chosen], "baseline": base}
    keep = ablation.trials.variant.isin(chosen)
    curves = ablation.curves[ablation.curves.variant.isin(chosen)] if len(ablation.curves) else ablation.curves
    params = {k: v for k, v in ablation.params.items() if k in chosen}
    return replace(
        ablation, grid=grid, trials=ablation.trials[keep].reset_index(drop=True), curves=curves, params=params
    )


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


def _with_interval(row: dict[str, Any], prefix: str, values: np.ndarray) -> None:
    values = np.asarray(values, float)
    values = values[~np.isnan(values)]
    row[prefix] = float(iqm(values)) if len(values) else np.nan
    row[f"{prefix}_ci_low"], row[f"{prefix}_ci_high"] = bootstrap_interval(values)


def convergence_table(ablation: Ablation) -> pd.DataFrame:
    """One row per variant: seeds, fraction solved, episodes-to-solve (median, IQM, 95% CIs, censored at the
    budget), env steps and seconds to solve (solved seeds), final rolling mean, AUC, the return after fixed
    budgets, the improvement over the untrained policy and episodes to reach return levels (censored)."""
    rows = []
    budgets = ablation.budgets
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
            row["episodes_median"] = float(np.median(episodes))
            row["episodes_median_ci_low"], row["episodes_median_ci_high"] = bootstrap_interval(episodes, _median)
            row["episodes_iqm"] = float(iqm(episodes))
            row["episodes_iqm_ci_low"], row["episodes_iqm_ci_high"] = bootstrap_interval(episodes)
            row["median_censored"] = is_censored_statistic(n_censored, len(done), "median")
            row["iqm_censored"] = is_censored_statistic(n_censored, len(done), "iqm")
            row["env_steps_to_solve_median"] = float(solved.env_steps_to_solve.median()) if len(solved) else np.nan
            row["wall_s_to_solve_median"] = float(solved.wall_s_to_solve.median()) if len(solved) else np.nan
            row["final_rolling_mean_iqm"] = float(iqm(done.final_rolling_mean.to_numpy(float)))
            _with_interval(row, "auc_iqm", _values(done, "auc"))
            row["auc_ci_low"], row["auc_ci_high"] = row.pop("auc_iqm_ci_low"), row.pop("auc_iqm_ci_high")
            _with_interval(row, "improvement_iqm", _values(done, "improvement"))
            initial = _values(done, "initial_return")
            row["initial_return_iqm"] = float(iqm(initial)) if not np.isnan(initial).all() else np.nan
            for episodes_budget in budgets:
                column = f"return_at_{episodes_budget}"
                if column in done:
                    _with_interval(row, f"{column}_iqm", done[column].to_numpy(float))
            for level in ablation.levels:
                column = f"episodes_to_{level:g}"
                if column in done:
                    values = done[column].to_numpy(float)
                    unreached = int((done[f"reached_{level:g}"] != 1).sum())
                    row[f"{column}_median"] = float(np.median(values))
                    row[f"{column}_reached"] = len(done) - unreached
                    row[f"{column}_median_censored"] = is_censored_statistic(unreached, len(done), "median")
            row["parameter_count"] = (
                int(done.parameter_count.iloc[0]) if not pd.isna(done.parameter_count.iloc[0]) else np.nan
            )
        rows.append(row)
    return pd.DataFrame(rows)


def _values(frame: pd.DataFrame, column: str) -> np.ndarray:
    """A column as floats; NaNs where the frame lacks it (a trial table built by hand, an older store)."""
    return frame[column].to_numpy(float) if column in frame else np.full(len(frame), np.nan)


def _median(values: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.median(values, axis=axis)


# --- comparisons --------------------------------------------------------------------------------------------
BETTER, WORSE, UNSEPARATED, NO_CLAIM = "better", "worse", "not separated", "no claim"


@dataclass(frozen=True)
class Comparison:
    """One variant against its reference (the baseline, or the variant it extends) on one metric: the
    estimate, its 95% interval, what may be claimed and whether the claim survives leaving out any one seed."""

    variant: str
    metric: str
    """``episodes_to_solve``, ``auc``, ``return_at_<E>``, ``episodes_to_<L>``."""
    point: float
    """Episodes metrics: 1 - IQM(variant) / IQM(reference) (positive: fewer episodes). Return metrics:
    IQM(variant) - IQM(reference) (positive: higher return)."""
    low: float
    high: float
    verdict: str
    """``better``, ``worse``, ``not separated`` or ``no claim``."""
    bound: str
    """``""`` (an estimate), ``"at least"`` (censoring makes the point a bound on the size of the
    difference) or ``"censored"`` (both sides censored: episodes cannot separate them)."""
    variant_value: float
    reference_value: float
    fragile_seeds: tuple[int, ...] = ()
    """Seeds whose removal changes the verdict (empty: the verdict holds leaving out any one seed)."""
    n_variant: int = 0
    n_reference: int = 0


def _verdict(low: float, high: float) -> str:
    if np.isnan(low) or np.isnan(high):
        return NO_CLAIM
    if low > 0:
        return BETTER
    if high < 0:
        return WORSE
    return UNSEPARATED


def _episodes_comparison(x: np.ndarray, y: np.ndarray, x_cens: np.ndarray, y_cens: np.ndarray):
    """Episodes (lower is better) censored at the budget. Returns (point, low, high, verdict, bound). The
    IQM of a sample whose IQM uses a censored value is a lower bound on the true IQM: with only the variant
    censored, the variant is at least as slow as measured (a claim "worse" holds, sized "at least"); with only
    the baseline censored, a claim "better" holds the same way; with both, episodes say nothing."""
    point, low, high = relative_reduction(x, y)
    x_bound = is_censored_statistic(int(x_cens.sum()), len(x), "iqm")
    y_bound = is_censored_statistic(int(y_cens.sum()), len(y), "iqm")
    verdict = _verdict(low, high)
    if verdict == NO_CLAIM or min(len(x), len(y)) < 2 or smallest_p_value(len(x), len(y)) > 1 - CONFIDENCE:
        return (
            point,
            low,
            high,
            NO_CLAIM,
            "censored" if x_bound and y_bound else "at least" if x_bound or y_bound else "",
        )
    if x_bound and y_bound:
        return point, low, high, UNSEPARATED, "censored"
    if x_bound:  # the variant's true IQM is larger: "worse" can only grow; "better" is not supported
        return point, low, high, (WORSE if verdict == WORSE else UNSEPARATED), "at least"
    if y_bound:
        return point, low, high, (BETTER if verdict == BETTER else UNSEPARATED), "at least"
    return point, low, high, verdict, ""


def _return_comparison(x: np.ndarray, y: np.ndarray):
    point, low, high = iqm_difference(x, y)
    if min(len(x), len(y)) < 2 or smallest_p_value(len(x), len(y)) > 1 - CONFIDENCE:
        return point, low, high, NO_CLAIM, ""
    return point, low, high, _verdict(low, high), ""


def compare_metric(ablation: Ablation, variant: str, metric: str, stability: bool = True) -> Comparison:
    """``variant`` against its reference on ``metric``, with a leave-one-seed-out check of the verdict."""
    done, reference = ablation.finished, ablation.reference(variant)

    def samples(frame: pd.DataFrame):
        v, b = frame[frame.variant == variant], frame[frame.variant == reference]
        if metric == "episodes_to_solve":
            return (
                v.censored_episodes.to_numpy(float),
                b.censored_episodes.to_numpy(float),
                (v.solved != 1).to_numpy(),
                (b.solved != 1).to_numpy(),
            )
        if metric.startswith("episodes_to_"):
            level = metric.removeprefix("episodes_to_")
            return (
                v[metric].to_numpy(float),
                b[metric].to_numpy(float),
                (v[f"reached_{level}"] != 1).to_numpy(),
                (b[f"reached_{level}"] != 1).to_numpy(),
            )
        return v[metric].to_numpy(float), b[metric].to_numpy(float), None, None

    def judge(frame: pd.DataFrame):
        x, y, x_cens, y_cens = samples(frame)
        if x_cens is not None:
            return _episodes_comparison(x, y, x_cens, y_cens)
        return _return_comparison(x, y)

    x, y, _, _ = samples(done)
    point, low, high, verdict, bound = judge(done)
    fragile: list[int] = []
    if stability and verdict in (BETTER, WORSE):
        for seed in sorted(set(done.seed)):
            if judge(done[done.seed != seed])[3] != verdict:
                fragile.append(int(seed))
    return Comparison(
        variant,
        metric,
        point,
        low,
        high,
        verdict,
        bound,
        float(iqm(x)) if len(x) else np.nan,
        float(iqm(y)) if len(y) else np.nan,
        tuple(fragile),
        len(x),
        len(y),
    )


def comparison_metrics(ablation: Ablation) -> list[str]:
    """Which metrics the findings rest on: episodes to solve where a threshold exists and some seed solved;
    always the area under the curve and the return after the whole budget; episodes to reach the env's
    return levels where no seed solved."""
    metrics = ["episodes_to_solve"] if ablation.any_solved else []
    metrics.append("auc")
    if ablation.budgets:
        metrics.append(f"return_at_{ablation.budgets[-1]}")
    if not ablation.any_solved:
        metrics += [f"episodes_to_{level:g}" for level in ablation.levels]
    return [m for m in metrics if m == "episodes_to_solve" or m in ablation.trials]


def comparisons(ablation: Ablation, stability: bool = True) -> pd.DataFrame:
    """Each variant against its reference (``Ablation.reference``) on each metric of ``comparison_metrics``,
    plus the probability of improvement on episodes to solve (censored): one row per (variant, metric)."""
    done = ablation.finished
    rows = []
    for variant in ablation.variants:
        if variant == ablation.baseline:
            continue
        reference = done[done.variant == ablation.reference(variant)].censored_episodes.to_numpy(float)
        sample = done[done.variant == variant].censored_episodes.to_numpy(float)
        if len(sample) == 0 or len(reference) == 0:
            continue
        for metric in comparison_metrics(ablation):
            c = compare_metric(ablation, variant, metric, stability)
            row = {k: getattr(c, k) for k in Comparison.__dataclass_fields__}
            row["fragile_seeds"] = " ".join(map(str, c.fragile_seeds))
            row["reference"] = ablation.reference(variant)
            if metric == "episodes_to_solve":
                row["p_improvement"] = probability_of_improvement(sample, reference)
                row["p_improvement_ci_low"], row["p_improvement_ci_high"] = probability_of_improvement_interval(
                    sample, reference
                )
            rows.append(row)
    columns = [
        *Comparison.__dataclass_fields__,
        "reference",
        "p_improvement",
        "p_improvement_ci_low",
        "p_improvement_ci_high",
    ]
    frame = pd.DataFrame(rows)
    for column in columns:
        if column not in frame:
            frame[column] = np.nan if column.startswith("p_") else ""
    return frame


def curve_band(curves: pd.DataFrame, x: str, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IQM across seeds of the rolling mean at each point of ``grid`` (of column ``x``), with a 95% bootstrap
    band. A seed that stopped because it solved carries its last value forward; one that ran out of budget
    ends there. Where fewer than half the seeds have a value, the curve stops. One seed: no band."""
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
