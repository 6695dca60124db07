"""The experiment file a launch ran (its copy in the store) against the file at the same path now. Where they differ
only in what no trial key holds (the description, a comment, a knob written at its default value, the order of the
variants), every trial the launch ran is the trial the file now describes: the report reads the file as it is now.
Where a key differs, the report describes the launch's copy and says the file has changed (``provenance``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ablate.config import ConfigError
from ablate.experiment import load_experiment
from ablate.launch.grid import expand, tuning_trials
from ablate.launch.records import grid_document


def edited(path: str, ran: str | None, cwd: str | Path | None = None) -> tuple[Path, str] | None:
    """The file at ``path`` (relative to ``cwd``) and its text where it differs from ``ran`` (the launch's copy);
    None where they match, or where either is missing."""
    file = Path(cwd or ".") / path
    try:
        text = file.read_text() if path and ran is not None else None
    except OSError:
        return None
    return None if text is None or text.strip() == ran.strip() else (file, text)


def read_from_disk(
    grid: dict[str, Any], path: str, ran: str | None, cwd: str | Path | None = None
) -> tuple[dict, str] | None:
    """The launch's grid as the file at ``path`` now describes it, and that file's text, where it differs from
    ``ran`` (the launch's copy) and still gives every trial the launch ran the same key; None otherwise. The trials
    stay the launch's (what ran, round after round); the variants, baseline, description and base come from the
    file."""
    found = edited(path, ran, cwd)
    if found is None:
        return None
    try:
        experiment = load_experiment(found[0])
        every_round = {t.key for t in expand(experiment, every_round=True)}
        first = {t.key for t in expand(experiment)}
        tuning = {t.key for t in tuning_trials(experiment)} if experiment.tune else set()
    except (ConfigError, OSError, ValueError):
        return None  # a file that no longer loads: the launch's copy it is
    ran_keys = {t["key"] for t in grid["trials"]}
    ran_tuning = {t["key"] for t in grid.get("tune_trials", [])}
    if not (first <= ran_keys <= every_round) or tuning != ran_tuning:
        return None
    now = grid_document(experiment, [])
    tune = {"tune_trials": grid["tune_trials"]} if "tune_trials" in grid else {}
    return now | {"trials": grid["trials"]} | tune, found[1]
