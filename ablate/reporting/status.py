"""``ablate status``: what the MLflow store holds: ablations, their launches and generations, trials by state.

Reads through ``tracking`` and writes nothing (not even an empty SQLite file where there is none).
"""

from __future__ import annotations

import re
import time
from collections import Counter, defaultdict
from collections.abc import Iterable
from typing import Any

from ablate.config import ConfigError
from ablate.experiment import Experiment, storage_name
from ablate.launch.grid import chosen_trials, expand, tuning_trials
from ablate.launch.mlflow_store import TAG_GENERATION, TAG_STAGE, ui_hint
from ablate.launch.secrets import shown_uri
from ablate.launch.store import resolve_uri
from ablate.reporting.planned import TUNE, answers, earlier_trials, plan_keys
from ablate.reporting.reader import RunReader, TrialRun, ablation_names

STATES = ("FINISHED", "FAILED", "KILLED", "RUNNING", "PENDING")
"""A trial's states: MLflow's run statuses, and PENDING for a trial of the experiment file with no run yet."""


def describe(counts: Counter) -> str:
    """``48 finished, 1 failed`` (states with no trial left out)."""
    parts = [f"{counts[s]} {s.lower()}" for s in STATES if counts[s]]
    return _count(sum(counts.values()), "trial") + (f": {', '.join(parts)}" if parts else "")


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 'es' if noun.endswith('ch') else 's'}"


def _generation(launch: Any) -> str:
    return launch.data.tags.get(TAG_GENERATION, "")


def _when(ms: int) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(ms / 1000))


def current_plan(
    tracker: RunReader, launch_id: str, runs: list[TrialRun], experiment: Experiment | None = None
) -> set[str] | None:
    """The keys the plan holds (``reporting.planned``): with ``experiment`` (its file), the file's trials, its
    tuning trials and stage 2 at the choices the launch ``launch_id`` (the newest) recorded; else what that launch
    recorded. None where it recorded no grid, or a tuned launch no choice yet: every run of the generation counts."""
    tuning = tracker.load_json(launch_id, "tuning.json")
    if experiment is not None and not (experiment.tune and tuning is None):
        choices = {n: c["values"] for n, c in (tuning or {}).get("choices", {}).items() if c.get("tuned")}
        trials = [*expand(experiment, every_round=True), *tuning_trials(experiment)]
        return {t.key for t in [*trials, *chosen_trials(experiment, choices, every_round=True)]}
    grid = tracker.load_json(launch_id, "grid.json")
    return None if grid is None else plan_keys(grid, tuning, {r.key: r for r in runs})


def overview(tracking_uri: str | None) -> str:
    """One line per ablation in the store."""
    uri = shown_uri(resolve_uri(tracking_uri))
    names = ablation_names(tracking_uri)
    if not names:
        return f"no ablations in the MLflow store {uri} yet; start one with: ablate run experiments/cartpole.toml"
    rows = [("experiment", "launches", "generations", "newest launch", "", "trials of the newest generation")]
    for name in names:
        tracker = RunReader(tracking_uri, name)
        launches = tracker.launches()
        newest = launches[0]
        runs = tracker.trial_runs(_generation(newest))
        counted = current_plan(tracker, newest.info.run_id, runs)
        counts = Counter(run.status for key, run in answers(runs).items() if counted is None or key in counted)
        generations = len({_generation(launch) for launch in launches})
        when = _when(newest.info.start_time)
        rows.append((name, str(len(launches)), str(generations), when, newest.info.status, describe(counts)))
    return f"MLflow store: {uri}\n" + _table(rows, right=(1, 2))


def detail(tracking_uri: str | None, name: str, experiment: Experiment | None = None) -> str:
    """An ablation's generations (newest first), each with its launches and trials by state; the newest
    generation per variant. With ``experiment`` (its file), trials of the file with no run count as pending."""
    uri = shown_uri(resolve_uri(tracking_uri))
    known = ablation_names(tracking_uri)
    if storage_name(name) not in known:  # the name as written or its storage form (``experiment.storage_name``)
        valid = f"valid: {', '.join(known)}" if known else "the store holds no ablation yet"
        raise ConfigError(f"{name!r} is not an ablation in the MLflow store {uri}; {valid}")
    tracker = RunReader(tracking_uri, name)
    launches = tracker.launches()  # newest first
    by_generation: dict[str, list[Any]] = defaultdict(list)
    for launch in reversed(launches):
        by_generation[_generation(launch)].append(launch)
    runs = tracker.trial_runs()
    counts = f"{_count(len(launches), 'launch')} in {_count(len(by_generation), 'generation')}"
    lines = [
        f"{name}: {counts} (MLflow store: {uri})",
        f"MLflow, the variants compared (the last report's): {tracker.ui_link()}{ui_hint(tracker.serves_ui)}",
    ]
    newest_generation = _generation(launches[0])
    for generation in sorted(by_generation, key=lambda g: by_generation[g][-1].info.start_time, reverse=True):
        in_generation = [r for r in runs if r.tags.get(TAG_GENERATION) == generation]
        states = {key: (run.variant, run.status) for key, run in answers(in_generation).items()}
        newest = generation == newest_generation
        tuning = {r.key for r in in_generation if r.tags.get(TAG_STAGE) == TUNE}
        earlier: dict[str, int] = {}
        counted = current_plan(tracker, launches[0].info.run_id, in_generation, experiment) if newest else None
        if counted is not None:  # an edited variant's earlier keys: in the store, not counted
            names = list(dict.fromkeys(r.variant for r in in_generation))
            earlier = earlier_trials(in_generation, counted, names)
            states = {key: state for key, state in states.items() if key in counted}
            tuning &= counted
        if newest and experiment is not None:
            # Stage 2's trials at the chosen values are known only after tuning: not counted until they run.
            for trial in [*tuning_trials(experiment), *expand(experiment)]:
                states.setdefault(trial.key, (trial.variant, "PENDING"))
                if trial.stage == TUNE:
                    tuning.add(trial.key)
        counts = Counter(s for _, s in states.values())
        lines.append("")
        lines.append(f"generation {generation}{' (newest)' if newest else ''}: {describe(counts)}")
        if tuning:
            stage_counts = Counter(s for key, (_, s) in states.items() if key in tuning)
            lines.append(f"  of which tuning (stage 1): {describe(stage_counts)}")
        if earlier:
            listed = ", ".join(f"{n} of {variant}" for variant, n in earlier.items())
            lines.append(
                f"  not counted: {_count(sum(earlier.values()), 'earlier trial')} ({listed}): an earlier version "
                "of the settings or code"
            )
        for launch in by_generation[generation]:
            command = launch.data.tags.get("ablate.command", "")
            lines.append(f"  launch {_when(launch.info.start_time)}  {launch.info.status:<8}  {command}".rstrip())
        if newest:
            order = [v.name for v in experiment.variants] if experiment is not None else []
            lines.append(_variant_table(states, order, _seeds(in_generation, experiment)))
    return "\n".join(lines)


def _natural(name: str) -> list:
    """``depth=2`` after ``depth=1`` and ``width=16`` after ``width=8``: digits compared as numbers."""
    return [(0, int(part), "") if part.isdigit() else (1, 0, part) for part in re.split(r"(\d+)", name) if part]


def _seeds(runs: Iterable[TrialRun], experiment: Experiment | None) -> dict[str, str]:
    """Per variant of an experiment with seeds in rounds, the evaluation seeds with a finished trial (``10 of
    40``: rounds up to 40; ``3``: its own fixed seeds); ``{}`` without rounds."""
    if experiment is None or not any(experiment.rounds_of(v) for v in experiment.variants):
        return {}  # fixed seeds: every variant has the same, the states say how many
    finished: dict[str, set[int]] = defaultdict(set)
    for run in runs:
        if run.status == "FINISHED" and run.tags.get(TAG_STAGE) != TUNE:
            finished[run.variant].add(run.seed)
    most = {v.name: len(experiment.max_seeds_of(v)) for v in experiment.variants if experiment.rounds_of(v)}
    return {v: f"{len(seeds)}{f' of {most[v]}' if v in most else ''}" for v, seeds in finished.items()}


def _variant_table(
    states: dict[str, tuple[str, str]], order: list[str] | None = None, seeds: dict[str, str] | None = None
) -> str:
    """Trials by state per variant, in the experiment file's order (``order``), else by name with numbers as
    numbers; never in the order the trials happened to finish. ``seeds``: a last column, the evaluation seeds
    each variant has finished (``_seeds``)."""
    per_variant: dict[str, Counter] = defaultdict(Counter)
    for variant, state in states.values():
        per_variant[variant][state] += 1
    place = {name: i for i, name in enumerate(order or [])}
    names = sorted(per_variant, key=lambda v: (place.get(v, len(place)), _natural(v)))
    shown = [s for s in STATES if any(c[s] for c in per_variant.values())] or ["FINISHED"]
    rows = [("variant", *(s.lower() for s in shown), *(["seeds"] if seeds else []))]
    rows += [(v, *(str(per_variant[v][s]) for s in shown), *([seeds.get(v, "0")] if seeds else [])) for v in names]
    return _table(rows, right=tuple(range(1, len(shown) + 1 + bool(seeds))), indent="  ")


def _table(rows: list[tuple[str, ...]], right: tuple[int, ...] = (), indent: str = "") -> str:
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return "\n".join(
        indent
        + "  ".join(
            cell.rjust(w) if i in right else cell.ljust(w) for i, (cell, w) in enumerate(zip(row, widths, strict=True))
        ).rstrip()
        for row in rows
    )
