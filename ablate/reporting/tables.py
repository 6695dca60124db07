"""The per-variant and per-trial tables the report writes (``tables/convergence.csv``, ``tables/trials.csv``):
seeds, solved fractions, episodes to solve censored at the budget, returns, each with its 95% interval."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from ablate.reporting.results import Ablation
from ablate.reporting.statistics import _median, bootstrap_interval, iqm, is_censored_statistic

INTEGER_COLUMNS = ("seed", "budget", "solved", "episodes_to_solve", "env_steps_to_solve", "episodes_run", "env_steps")
INTEGER_COLUMNS += ("parameter_count", "censored_episodes")


def trials_table(trials: pd.DataFrame) -> pd.DataFrame:
    """The trials as ``tables/trials.csv`` holds them: counts and flags as integers (``solved`` 1, not 1.0;
    ``episodes_run`` 1000, not 1000.0), empty where a trial has none. MLflow stores every metric as a float."""
    table = trials.copy()
    columns = [c for c in table if c in INTEGER_COLUMNS or c.startswith(("reached_", "episodes_to_"))]
    for column in columns:
        values = pd.to_numeric(table[column], errors="coerce")
        present = values.dropna()
        if len(present) and (present == present.round()).all():
            table[column] = values.round().astype("Int64")
    return table


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
