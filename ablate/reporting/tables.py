"""The per-variant and per-trial tables the report writes (``tables/convergence.csv``, ``tables/trials.csv``):
seeds, solved fractions, episodes to solve censored at the budget, returns, each with its 95% interval."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from ablate.config import KNOBS, SETTING_KNOBS, freeze
from ablate.measures import episodes_to, is_censored, lookup, measure, return_at
from ablate.reporting.results import Ablation
from ablate.reporting.settings import DERIVED, setting
from ablate.reporting.statistics import bootstrap_interval, iqm, is_censored_statistic
from ablate.reporting.tuning import EVAL

INTEGER_COLUMNS = ("seed", "budget", "solved", "episodes_to_solve", "env_steps_to_solve", "episodes_run", "env_steps")
INTEGER_COLUMNS += ("parameter_count", "censored_episodes", "episodes_per_update", "depth", "width")
BASE = "base"
"""The stage of a trial run at the shared base values only (the word of ``train_from.STAGES``)."""


def trials_table(ablation: Ablation) -> pd.DataFrame:
    """Every evaluation trial the report uses, as ``tables/trials.csv`` and ``ablate.load(...).trials`` hold them:
    ``stage`` ``eval`` (the claims' trials: at each variant's chosen values when tuned) or ``base`` (a tuned
    ablation's trials at the shared base values only, the data of "does the finding depend on the learning
    rate?"), ``at_base_values`` (tuned only: the trial is in that section's comparison), then each trial's
    settings (``settings_of``) beside its results. Counts and flags are integers (``solved`` 1, not 1.0), empty
    where a trial has none: MLflow stores every metric as a float."""
    table = ablation.trials.copy()
    if "stage" not in table:
        table.insert(min(3, len(table.columns)), "stage", EVAL)
    if ablation.untuned is not None:
        shared = ablation.untuned.trials
        extra = shared[~shared.key.isin(set(table.key))].assign(stage=BASE)
        table = pd.concat([table, extra], ignore_index=True) if len(extra) else table
        table.insert(4, "at_base_values", table.key.isin(set(shared.key)))
    settings = settings_of(ablation, table)
    after = list(table.columns).index("stage") + 1 + ("at_base_values" in table)
    for position, column in enumerate(c for c in settings.columns if c not in table):
        table.insert(after + position, column, settings[column])
    reached = {measure(c).reached for c in table if is_censored(c)}
    columns = [c for c in table if c in INTEGER_COLUMNS or c in reached or is_censored(c)]
    for column in columns:
        values = pd.to_numeric(table[column], errors="coerce")
        present = values.dropna()
        if len(present) and (present == present.round()).all():
            table[column] = values.round().astype("Int64")
    return table


def settings_of(ablation: Ablation, trials: pd.DataFrame) -> pd.DataFrame:
    """Each trial's settings as columns: ``config.SETTING_KNOBS`` (whether or not a variant changes them) and
    every knob a variant writes (``hidden_sizes`` with its ``depth`` and ``width``), each the variant's value or
    the base's (``settings.setting``), typed as the schema declares it (``cells``); a tuned knob keeps the trial's
    own column. A knob the grid holds for no variant (an older store) is left out."""
    per_variant = variant_settings(ablation)
    columns = {c: trials.variant.map(per_variant[c]) for c in per_variant if c not in trials}
    return pd.DataFrame(columns, index=trials.index)


def variant_settings(ablation: Ablation) -> pd.DataFrame:
    """One row per variant (the index), one column per setting ``settings_of`` gives a trial: the grid's values,
    and a tuned knob at the value the variant's evaluation trials ran (its choice)."""
    written = sorted({k for v in ablation.grid["variants"] for k in v.get("overrides", {})})
    knobs = [*SETTING_KNOBS, *(k for k in written if k not in SETTING_KNOBS)]
    if any(knob in ("hidden_sizes", *DERIVED) for knob in knobs):
        knobs += [k for k in ("hidden_sizes", *DERIVED) if k not in knobs]
    rows: dict[str, dict[str, Any]] = {v: {} for v in ablation.variants}
    for knob in knobs:
        values = {v: setting(ablation.grid, v, knob) for v in ablation.variants}
        if knob in ablation.trials:  # tuned: the trials ran the chosen value, not the grid's
            ran = ablation.trials.dropna(subset=[knob]).groupby("variant")[knob].first()
            values |= {v: ran[v] for v in ablation.variants if v in ran}
        if all(value is None for value in values.values()):
            continue
        for variant, value in values.items():
            rows[variant] |= cells(knob, value)
    frame = pd.DataFrame.from_dict(rows, orient="index")
    return frame.reindex(ablation.variants)


def cells(knob: str, value: Any) -> dict[str, Any]:
    """A knob's value as table cells, typed by its schema entry (``config.KNOBS``): a list as a tuple
    (``(32, 32)``, as ``TrialConfig`` holds it), a table (``model_args``) as one column per key
    (``model_args.width``), anything else as it is; a knob the schema lacks (``depth``, ``width``) as it is."""
    knob_entry = KNOBS.get(knob)
    if knob_entry is not None and knob_entry.type.startswith("tuple[tuple[str"):  # a table: (name, value) pairs
        return {f"{knob}.{name}": item for name, item in freeze(dict(knob_entry.convert(value or ())))}
    if knob_entry is None or value is None:
        return {knob: value}
    return {knob: knob_entry.convert(value)}


def side_settings(claims: pd.DataFrame, ablation: Ablation) -> pd.DataFrame:
    """``claims`` (or any table of ``variant`` against ``reference``) with each side's settings beside it:
    ``variant.<setting>`` and ``reference.<setting>``, the same settings ``trials`` carries."""
    per_variant = variant_settings(ablation)
    sides = [
        pd.DataFrame({f"{side}.{c}": claims[side].map(per_variant[c]) for c in per_variant.columns}, index=claims.index)
        for side in ("variant", "reference")
    ]
    return pd.concat([claims, *sides], axis=1)


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
            row["episodes_median_ci_low"], row["episodes_median_ci_high"] = bootstrap_interval(episodes, np.median)
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
                column = return_at(episodes_budget).column
                if column in done:
                    _with_interval(row, f"{column}_iqm", done[column].to_numpy(float))
            for level in map(episodes_to, ablation.levels):
                column = level.column
                if column in done:
                    values = done[column].to_numpy(float)
                    unreached = int((done[level.reached] != 1).sum())
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


_POINTS = {
    "return_at": {"return_iqm": "_iqm", "return_iqm_ci_low": "_iqm_ci_low", "return_iqm_ci_high": "_iqm_ci_high"},
    "episodes_to": {
        "episodes_to_level_median": "_median",
        "reached": "_reached",
        "episodes_to_level_median_censored": "_median_censored",
    },
}
"""A checkpoint's columns in ``convergence_long`` (after ``episode`` or ``return_level``): the wide column each is
read from, the checkpoint's column with this suffix."""


def convergence_long(table: pd.DataFrame) -> pd.DataFrame:
    """``convergence_table`` in long form, as ``ablate.load(...).convergence`` gives it: the per-variant columns
    repeated on one row per checkpoint, a fixed episode budget (``episode``, with ``return_iqm`` and its interval)
    or a return level (``return_level``, with ``episodes_to_level_median``, ``reached``,
    ``episodes_to_level_median_censored``), the other's columns empty; a variant with neither keeps one row. No
    column is named by a budget or a level, so ablations with different budgets concatenate."""
    named = {c: lookup(c.rsplit("_", 1)[0]) for c in table.columns if c.endswith(("_iqm", "_median"))}
    checkpoints = [entry for entry in named.values() if entry is not None and entry.family]
    fixed = [c for c in table.columns if not any(c.startswith(f"{m.column}_") for m in checkpoints)]
    table = table.reset_index(drop=True)  # its rows' order, which the points of each keep
    parts = []
    for entry in checkpoints:
        label = {"episode": int(entry.parameter)} if entry.family == "return_at" else {"return_level": entry.parameter}
        values = {name: table[entry.column + suffix] for name, suffix in _POINTS[entry.family].items()}
        parts.append(table[fixed].assign(**label, **values))
    frame = pd.concat(parts).sort_index(kind="stable").reset_index(drop=True) if parts else table[fixed]
    frame = frame.reindex(columns=[*fixed, "episode", *_POINTS["return_at"], "return_level", *_POINTS["episodes_to"]])
    for column in ("episode", "reached"):
        frame[column] = frame[column].astype("Int64")
    return frame


def curves_table(ablation: Ablation) -> pd.DataFrame:
    """Every trial's learning curve, long form, as ``ablate.load(...).curves``: one row per trial and episode,
    with the trial's ``key`` and ``stage`` (as in ``trials_table``: a tuned ablation's ``base`` trials too)."""
    curves = ablation.curves.copy()
    trials = ablation.trials
    stages = dict(zip(trials.key, trials.stage, strict=True)) if "stage" in trials else {}
    curves.insert(3, "stage", [stages.get(k, EVAL) for k in curves.key])
    if ablation.untuned is not None and len(ablation.untuned.curves):
        extra = ablation.untuned.curves[~ablation.untuned.curves.key.isin(set(curves.key))]
        if len(extra):
            curves = pd.concat([curves, extra.assign(stage=BASE)[curves.columns]], ignore_index=True)
    return curves


BUDGET_FRACTIONS = ("quarter", "half", "budget")
"""``return_at_<E>`` of the trials' table, by its share of the trial's budget (``measures.fixed_budgets``)."""


def meeting(table: pd.DataFrame, ablation: Ablation, settings: bool = False) -> pd.DataFrame:
    """``table`` as ``ablate.load`` returns it, so that the tables of two ablations meet (``pd.concat``): the
    ablation's name and ``env_id`` first; no column named by a budget or an env's return level
    (``return_at_750`` is ``return_at_half``; a level's episodes are in ``convergence``'s ``return_level`` rows);
    ``settings``: each row's settings (``settings_of``) after its key columns, as ``trials`` has them."""
    out = table.copy()
    budgets = ablation.budgets
    names = dict(zip((return_at(b).column for b in budgets), BUDGET_FRACTIONS[-len(budgets) :], strict=True))
    out = out.rename(columns={c: f"return_at_{names[c]}" for c in out.columns if c in names})
    levels = {name for entry in map(episodes_to, ablation.levels) for name in (entry.column, entry.reached)}
    named = {c: lookup(c) for c in out.columns}
    out = out.drop(columns=[c for c, m in named.items() if c in levels or (m is not None and m.family == "return_at")])
    if settings and "variant" in out and len(out):
        extra = settings_of(ablation, out)
        after = list(out.columns).index("stage") + 1 if "stage" in out else min(3, len(out.columns))
        for position, column in enumerate(c for c in extra.columns if c not in out):
            out.insert(after + position, column, extra[column])
    out.insert(0, "env_id", ablation.env_id)
    out.insert(0, "ablation", ablation.name)
    return out
