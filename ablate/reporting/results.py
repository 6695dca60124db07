"""Tidy pandas frames from tracked runs: the ``Ablation`` (grid, trials, curves) of one generation, what each
trial's curve says (AUC, returns at fixed budgets, episodes to reach return levels) and the per-variant
convergence table. Unsolved trials are censored at the budget. The statistics live in ``statistics``.
"""

from __future__ import annotations

import json
import tomllib
from collections import Counter
from dataclasses import dataclass, field, replace
from functools import cached_property, partial
from types import SimpleNamespace
from typing import Any

import numpy as np
import pandas as pd

from ablate.config import ConfigError
from ablate.env_spec import Profile, profile_named, solve_threshold_or_none
from ablate.experiment import Experiment
from ablate.launch.mlflow_store import TAG_GENERATION, TAG_STAGE
from ablate.launch.store import check_store
from ablate.measures import (
    FINAL_RETURN,
    Measure,
    censored_episodes,
    claim_names,
    default_primary_metric,
    fixed_budgets,
    lookup,
    return_at,
    trial_measures,
)
from ablate.reporting import settings
from ablate.reporting.experiment_file import read_from_disk
from ablate.reporting.networks import layers
from ablate.reporting.planned import TUNE, answers, earlier_trials, plan_keys, planned_trials, stage_two
from ablate.reporting.reader import RunReader, TrackingError, TrialRun
from ablate.reporting.tuning import EVAL, at_values, base_values, chosen_values, tuning_table
from ablate.reporting.tuning import knobs as tuning_knobs


def _profile(grid: dict) -> Profile:
    base = grid.get("base", {})
    return profile_named(str(base.get("env_id", "")), str(base.get("env_profile", "")))


class NoResults(LookupError):
    """Nothing to report: the message says what is missing and what to run."""


@dataclass
class Ablation:
    """Everything the report needs, read from the tracking store."""

    name: str
    grid: dict[str, Any]
    launch: dict[str, Any]
    """Tags and files of the reported launch: command, commit, environment; ``generations``: every
    generation of the experiment, newest first, with its trial counts; ``rounds``: its ``rounds.json`` (seeds in
    rounds) or None."""
    trials: pd.DataFrame
    """One row per trial of the grid: variant, seed, status, summary metrics, ``censored_episodes``, ``auc``,
    ``initial_return``, ``improvement``, ``return_at_<E>``, ``episodes_to_<L>`` (and ``reached_<L>``)."""
    curves: pd.DataFrame
    """Long form: variant, seed, episode, return, rolling_mean, wall_s (finished trials only)."""
    params: dict[str, dict[str, str]] = field(default_factory=dict)
    """Flattened config per variant (from its first finished run)."""
    tuning: dict[str, Any] | None = None
    """The launch's ``tuning.json`` (candidates, tuning seeds, metric, rule, each variant's choice); None for
    an ablation without ``[tune]``. Then ``trials`` and ``curves`` hold the evaluation seeds at the chosen values."""
    tuning_trials: pd.DataFrame | None = None
    """``tables/tuning.csv``: one row per tuning trial (``tuning.tuning_table``)."""
    untuned: Ablation | None = None
    """The same evaluation seeds at the shared base values (the untuned comparison), when tuned."""
    missing: list[tuple[str, str]] = field(default_factory=list)
    """(variant, key) of finished trials whose ``episodes.csv`` the store could not give (their artifact folder moved or
    removed): their rows hold the tracked metrics and params, without the measures and curves of that file."""
    earlier: dict[str, int] = field(default_factory=dict)
    """Per variant, its trials in the generation under keys the plan no longer holds (an earlier version of its
    settings or code: ``planned``): in the store, in none of the frames."""
    bands: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)
    """Each variant's learning curve and its band (``figures.variant_band``), once computed."""

    @property
    def seed_span(self) -> tuple[int, int]:
        """The fewest and most finished evaluation seeds a variant has (seeds in rounds give variants different
        counts); the grid's seed count where no trial finished."""
        done = self.finished
        counts = done.groupby("variant").seed.nunique() if len(done) else None
        if counts is None or counts.empty:
            n = len(self.grid["seeds"])
            return n, n
        return int(counts.min()), int(counts.max())

    @property
    def variants(self) -> list[str]:
        return [v["name"] for v in self.grid["variants"]]

    @property
    def baseline(self) -> str:
        return self.grid["baseline"]

    def changes(self, variant: str, against: str | None = None) -> dict[str, Any]:
        """The knobs ``variant`` runs at another value than ``against`` (default: the baseline), with its values
        (``settings.changes``: by value, not by the keys written)."""
        return settings.changes(self.grid, variant, against or self.baseline)

    def reference(self, variant: str) -> str:
        """The variant ``variant`` is compared with (``settings.references``)."""
        return self._references[variant]

    @cached_property
    def _references(self) -> dict[str, str]:
        """Found once: the report asks for them per row and per figure panel."""
        return settings.references(self.grid)

    @property
    def finished(self) -> pd.DataFrame:
        return self.trials[self.trials.status == "FINISHED"]

    @property
    def env_id(self) -> str:
        return str(self.grid.get("base", {}).get("env_id", ""))

    @property
    def profile(self) -> Profile:
        """The env profile the trials ran under (``env_spec.PROFILES``)."""
        return _profile(self.grid)

    @cached_property
    def threshold(self) -> float | None:
        """The solve threshold the trials stopped at, as they recorded it (``env.solve_threshold``); for trials
        of a store from before that record, ``env_spec.solve_threshold`` of the launch's base config. None (Pong)
        when there is none."""
        for params in self.params.values():
            if "env.solve_threshold" in params:
                value = params["env.solve_threshold"]
                return None if value in ("None", "") else float(value)
        base = self.grid.get("base", {})
        own = [p["solve_threshold"] for p in self.params.values() if p.get("solve_threshold") not in (None, "None", "")]
        threshold = float(own[0]) if own else base.get("solve_threshold")
        config = SimpleNamespace(env_id=self.env_id, env_module=base.get("env_module", ""), solve_threshold=threshold)
        return solve_threshold_or_none(config)

    @property
    def any_solved(self) -> bool:
        return self.threshold is not None and bool((self.finished.solved == 1).any())

    @property
    def budgets(self) -> list[int]:
        """Fixed episode budgets at which every variant's return is compared: a quarter, half and all of it."""
        return fixed_budgets(int(self.finished.budget.max())) if len(self.finished) else []

    @property
    def smallest_effect(self) -> float:
        """The experiment file's ``smallest_effect`` (read from the file the launch ran), else the default."""
        try:
            value = tomllib.loads(self.launch.get("experiment_text") or "").get("smallest_effect")
        except tomllib.TOMLDecodeError:
            value = None
        valid = isinstance(value, int | float) and not isinstance(value, bool) and 0 < value < 1
        return float(value) if valid else Experiment.smallest_effect

    @property
    def primary_metric(self) -> str:
        """The metric the primary claims are made on: the file's ``primary`` (``return`` is the return after the
        whole budget), else episodes to solve where a solve threshold exists, else the AUC."""
        entry = _primary(self.launch.get("experiment_text"))
        if entry is FINAL_RETURN:
            return return_at(self.budgets[-1]).name if self.budgets else default_primary_metric([self.threshold])
        if entry is not None and not (entry.needs_threshold and self.threshold is None):
            return entry.name
        return default_primary_metric([self.threshold])

    @property
    def levels(self) -> tuple[float, ...]:
        return self.profile.return_levels.get(self.env_id, ())


def _generation_summary(runs: list[TrialRun], launches: list[Any]) -> list[dict[str, Any]]:
    """Every generation (of ``launches``, newest first) and how many of its keys have a finished run (of ``runs``:
    every trial run of the experiment)."""
    done = {(run.tags.get(TAG_GENERATION, ""), run.key) for run in runs if run.status == "FINISHED"}
    finished = Counter(generation for generation, _ in done)
    generations = dict.fromkeys(launch.data.tags.get(TAG_GENERATION, "") for launch in launches)
    return [{"generation": generation, "finished": finished[generation]} for generation in generations]


def _primary(experiment_text: str | None) -> Measure | None:
    """The measure the experiment file's ``primary`` names, if any."""
    try:
        value = tomllib.loads(experiment_text or "").get("primary")
    except tomllib.TOMLDecodeError:
        value = None
    return lookup(value) if value in claim_names() else None


def _threshold(params: dict[str, str], grid: dict[str, Any]) -> float | None:
    """The solve threshold a run recorded it ran against (else its own, else the base's); ``None``: none."""
    value = params.get("env.solve_threshold", params.get("solve_threshold", grid["base"].get("solve_threshold")))
    return None if value in (None, "None", "") else float(value)


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
    launches = tracker.launches()
    if not launches:
        raise NoResults(f"experiment {name!r} at {tracker.shown_uri} has no launches; run `ablate run` first")
    every_run = tracker.trial_runs()  # read once: a search of thousands of runs takes seconds
    generations = _generation_summary(every_run, launches)
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
        launch = next(run for run in launches if run.data.tags.get(TAG_GENERATION) == matching[0]["generation"])
    generation_id = launch.data.tags.get(TAG_GENERATION)
    runs = [run for run in every_run if run.tags.get(TAG_GENERATION) == generation_id]
    return _read_launch(tracker, name, launch, generations, runs)


def _read_launch(
    tracker: RunReader, name: str, launch: Any, generations: list[dict[str, Any]], runs: list[TrialRun]
) -> Ablation:
    """The launch's grid and documents, and ``runs`` (its generation's trial runs, oldest first) as the trials
    that answer them."""
    launch_id = launch.info.run_id
    grid = json.loads(tracker.load_text(launch_id, "grid.json"))
    environment = tracker.load_json(launch_id, "environment.json") or {}  # older launches have none
    try:
        experiment_text = tracker.load_text(launch_id, "experiment.toml")
    except Exception:  # noqa: BLE001 - a launch written by hand (tests) has no experiment file
        experiment_text = None
    path = launch.data.tags.get("ablate.experiment_file", "")
    edited = read_from_disk(grid, path, experiment_text)  # changed since, in no trial key: read as it is now
    if edited is not None:
        grid, experiment_text = edited
    best_run = answers(runs)
    levels = _profile(grid).return_levels.get(str(grid.get("base", {}).get("env_id", "")), ())
    # The curve measures the file names beside AUC (its primary, its tuning metric) get columns of their own.
    tuning = tracker.load_json(launch_id, "tuning.json")
    asked = tuple(m for m in (_primary(experiment_text), lookup(str((tuning or {}).get("metric")))) if m is not None)
    names = tuning_knobs(tuning) if tuning else []
    planned = planned_trials(grid)
    keys = {trial["key"] for trial in planned}
    # A tuned launch's evaluation trials at the chosen values are known only once tuning ends: not in grid.json.
    later = (
        [t for t in stage_two(tuning, grid, best_run) if t["key"] in best_run and t["key"] not in keys]
        if tuning
        else []
    )
    counted = plan_keys(grid, tuning, best_run)
    variants = [v["name"] for v in grid["variants"]]
    earlier = earlier_trials(runs, counted, variants) if counted is not None else {}
    rows, tune_rows, curves, params, missing = [], [], {}, {}, []
    for trial in [*planned, *later]:
        run = best_run.get(trial["key"])
        row = {"key": trial["key"], "variant": trial["variant"], "seed": trial["seed"]}
        if tuning:
            stage = (run.tags.get(TAG_STAGE) if run else None) or trial.get("stage")
            row["stage"] = stage or (TUNE if trial["seed"] in tuning.get("seeds", []) else EVAL)
            fallback = base_values(tuning, trial["variant"], settings.overrides(grid, trial["variant"]))
            for knob in names:
                row[knob] = run.params.get(knob, fallback[knob]) if run else trial.get(knob, fallback[knob])
        if run is None:
            (tune_rows if row.get("stage") == TUNE else rows).append(row | {"status": "NOT RUN"})
            continue
        budget = int(run.params.get("max_episodes", grid["base"].get("max_episodes", 0)))
        row |= {"status": run.status, "run_id": run.run_id, "budget": budget, "error": run.tags.get("ablate.error", "")}
        row |= {k: run.metrics.get(k, np.nan) for k in SUMMARY_COLUMNS}
        if run.status == "FINISHED":
            curve = _curve(tracker, run, trial)
            if curve is None:
                missing.append((trial["variant"], trial["key"]))
            else:
                window = int(run.params.get("solve_window", grid["base"].get("solve_window", 100)))
                threshold = _threshold(run.params, grid)
                row |= trial_measures(curve, budget, levels, window, threshold, asked)
            if row.get("stage") != TUNE:
                if trial["variant"] not in params:  # a user's network is described from its recorded source
                    described = layers(tracker, run.run_id, run.params)
                    params[trial["variant"]] = run.params | ({"model.layers": described} if described else {})
                if curve is not None:
                    curves[trial["key"]] = curve
            else:
                row["tracked"] = dict(run.metrics)
        (tune_rows if row.get("stage") == TUNE else rows).append(row)
    launch_info = {
        "rounds": tracker.load_json(launch_id, "rounds.json"),
        "run_id": launch_id,
        "started_ms": launch.info.start_time,
        "tags": dict(launch.data.tags),
        "environment": environment,
        "experiment_text": experiment_text,
        "read_from_disk": edited is not None,
        "generations": generations,
    }
    # The name as written in the experiment file, whichever form (it or its storage name) asked for it.
    ablation = partial(_ablation, grid.get("experiment", name), grid, launch_info, params=params)
    if not tuning:
        return ablation(pd.DataFrame(rows), list(curves.values()), missing=missing, earlier=earlier)
    trials = pd.DataFrame(rows)
    for knob in names:
        trials[knob] = pd.to_numeric(trials[knob], errors="coerce")

    def at(values_of) -> tuple[pd.DataFrame, list[pd.DataFrame]]:
        """The evaluation trials at ``values_of(variant)``, by variant in the file's order, then by seed."""
        chosen = trials[at_values(trials, values_of)].sort_values("seed", kind="stable")
        order = chosen.variant.map({variant: i for i, variant in enumerate(variants)})
        chosen = chosen.iloc[order.argsort(kind="stable")].reset_index(drop=True)
        return chosen, [curves[k] for k in chosen.key if k in curves]

    untuned = ablation(*at(lambda v: base_values(tuning, v, settings.overrides(grid, v))))
    tuning_trials = tuning_table(tune_rows, tuning, variants)
    more = dict(tuning=tuning, tuning_trials=tuning_trials, untuned=untuned, missing=missing, earlier=earlier)
    return ablation(*at(lambda v: chosen_values(tuning, v)), **more)


def _tuning_document(tracker: RunReader, launch_id: str) -> dict[str, Any] | None:
    """The launch's ``tuning.json``; None for a launch without ``[tune]`` (``train_from`` reads it)."""
    return tracker.load_json(launch_id, "tuning.json")


_EPISODE_COLUMNS = ["episode", "episode_return", "rolling_mean", "wall_s"]


def _curve(tracker: RunReader, run: Any, trial: dict[str, Any]) -> pd.DataFrame | None:
    """One finished trial's learning curve, its rolling mean as the trial computed it; None where the store cannot
    give its episodes.csv (the run's artifact folder moved or removed). The exact per-episode table is the run's
    episodes.csv (MLflow holds a bounded curve)."""
    try:
        table = tracker.read_artifact(run, "episodes.csv", lambda path: pd.read_csv(path, usecols=_EPISODE_COLUMNS))
    except TrackingError:
        return None
    if not table.episode.is_monotonic_increasing or not table.episode.is_unique:  # a resumed trial wrote some twice
        table = table.drop_duplicates("episode", keep="last").sort_values("episode", kind="stable")
    return pd.DataFrame(
        {
            "key": trial["key"],
            "variant": trial["variant"],
            "seed": trial["seed"],
            "solved": run.metrics.get("solved", 0.0) == 1.0,
            "episode": table["episode"].to_numpy(),
            "return": table["episode_return"].to_numpy(float),
            # the clock is logged when an update ends: each episode gets the time of its update's end
            "wall_s": table["wall_s"].bfill().to_numpy(),
            "rolling_mean": table["rolling_mean"].to_numpy(float),
        }
    )


def _ablation(name, grid, launch_info, trials: pd.DataFrame, curves: list[pd.DataFrame], **more) -> Ablation:
    for column in (*SUMMARY_COLUMNS, "auc", "budget", "run_id", "error", "initial_return", "improvement"):
        if column not in trials:
            trials[column] = np.nan
    solved = trials["solved"] == 1
    trials["censored_episodes"] = censored_episodes(solved, trials["episodes_to_solve"], trials["budget"])
    curves_frame = (
        pd.concat(curves, ignore_index=True)
        if curves
        else pd.DataFrame(columns=["key", "variant", "seed", "solved", "episode", "return", "rolling_mean", "wall_s"])
    )
    return Ablation(name, grid, launch_info, trials, curves_frame, **more)


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
    tuning_trials = ablation.tuning_trials
    if tuning_trials is not None:
        tuning_trials = tuning_trials[tuning_trials.variant.isin(chosen)].reset_index(drop=True)
    untuned = select(ablation.untuned, variants, baseline) if ablation.untuned is not None else None
    return replace(
        ablation,
        grid=grid,
        trials=ablation.trials[keep].reset_index(drop=True),
        curves=curves,
        params=params,
        tuning_trials=tuning_trials,
        untuned=untuned,
        missing=[(variant, key) for variant, key in ablation.missing if variant in chosen],
        earlier={variant: n for variant, n in ablation.earlier.items() if variant in chosen},
        bands={},  # another budget may give another episode grid
    )


SUMMARY_COLUMNS = ("solved", "episodes_to_solve", "env_steps_to_solve", "wall_s_to_solve", "final_rolling_mean")
SUMMARY_COLUMNS += ("episodes_run", "env_steps", "wall_s", "steps_per_s", "parameter_count", "greedy_return")
