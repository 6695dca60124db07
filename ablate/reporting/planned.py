"""Which runs of a generation a launch's plan counts, by key: its grid's trials, its tuning trials and stage 2 at
each variant's chosen values. A run of any other key is an earlier trial (an earlier version of a variant's settings
or code, an edited network say): it stays in the store and is counted under no variant's name."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any

from ablate.launch.mlflow_store import TAG_STAGE

TUNE = "tune"
"""A stage-1 run's ``TAG_STAGE`` (``GridTrial.stage``). This module stays free of pandas: ``ablate status`` reads it."""


def answers(runs: Iterable[Any]) -> dict[str, Any]:
    """Each key's run that answers it (``runs`` oldest first): its newest finished run, else its newest run of any
    status (a re-run after Ctrl-C or a failure opens a new run under the same key)."""
    best: dict[str, Any] = {}
    for run in runs:
        current = best.get(run.key)
        if current is None or run.status == "FINISHED" or current.status != "FINISHED":
            best[run.key] = run
    return best


def planned_trials(grid: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The trials ``grid.json`` lists: the evaluation trials (later rounds' too), then a tuned launch's stage 1."""
    return [*grid["trials"], *grid.get("tune_trials", [])]


def stage_two(tuning: Mapping[str, Any], grid: Mapping[str, Any], runs: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Stage 2 of a tuned launch, the evaluation trials at the chosen values, known only once tuning ended (so not in
    ``grid.json``): the keys ``tuning.json`` records. A launch written before it recorded them has them recognised
    among ``runs`` (key -> run): an evaluation run outside the plan with the settings of its variant's planned
    evaluation runs but for the tuned knobs and the seed (another network's source hash, another gamma: not it)."""
    if "trials" in tuning:
        return list(tuning["trials"])
    ignored = {"seed", *tuning.get("knobs", {})}

    def settings(run: Any) -> dict[str, str]:
        return {k: v for k, v in run.params.items() if k not in ignored}

    planned = {trial["key"] for trial in planned_trials(grid)}
    references: dict[str, list[dict[str, str]]] = {}
    for trial in grid["trials"]:
        run = runs.get(trial["key"])
        if run is not None and run.tags.get(TAG_STAGE) != TUNE:
            references.setdefault(trial["variant"], []).append(settings(run))
    return [
        {"key": run.key, "variant": run.variant, "seed": run.seed}
        for run in runs.values()
        if run.key not in planned
        and run.tags.get(TAG_STAGE) != TUNE
        and settings(run) in references.get(run.variant, [])
    ]


def plan_keys(grid: Mapping[str, Any], tuning: Mapping[str, Any] | None, runs: Mapping[str, Any]) -> set[str] | None:
    """Every key the plan holds: the grid's and stage 2's (``stage_two``); None where a tuned launch has not recorded
    its choice yet (interrupted in stage 1): its stage 2 is unknown, so no run of the generation can be called
    earlier."""
    if tuning is None:
        return None if grid.get("tune_trials") else {trial["key"] for trial in grid["trials"]}
    return {trial["key"] for trial in [*planned_trials(grid), *stage_two(tuning, grid, runs)]}


def earlier_trials(runs: Iterable[Any], counted: set[str], variants: list[str]) -> dict[str, int]:
    """Per variant (of ``variants``, in their order), how many trials of the generation have a key the plan does not
    hold (``counted``): ``runs`` may hold several runs of one key (a re-run), counted once."""
    keys = {run.key: run.variant for run in runs if run.key not in counted}
    per_variant = Counter(keys.values())
    return {variant: per_variant[variant] for variant in variants if per_variant[variant]}
