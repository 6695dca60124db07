"""The report's side of MLflow: read an ablation's launches, trials, curves and artifacts back from a store.

``ablate.launch.tracking`` writes them (the driver), ``ablate.launch.variant_runs`` the report's variant runs;
these and ``mlflow_store`` are the only modules that import MLflow.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ablate.launch.mlflow_store import TAG_ROLE, Store, TrialRun
from ablate.launch.store import StoreNotFound, TrackingError, check_store

__all__ = ["RunReader", "TrackingError", "TrialRun", "ablation_names"]

LAUNCHES = f"tags.`{TAG_ROLE}` = 'launch'"


def ablation_names(tracking_uri: str | None) -> list[str]:
    """Names of the MLflow experiments holding at least one launch of ``ablate run``, sorted; none where a local
    SQLite file does not exist yet (opening one would create it). A store that cannot be read is a one-line
    ``TrackingError`` within seconds: ``Store`` opens it as it opens the writer's."""
    try:
        check_store(tracking_uri)
    except StoreNotFound:
        return []
    client = Store(tracking_uri, None, write=False).client
    experiments = client.search_experiments()
    return sorted(e.name for e in experiments if client.search_runs([e.experiment_id], LAUNCHES, max_results=1))


class RunReader(Store):
    """An ablation's runs as the report, ``ablate status`` and notebooks read them (``trial_runs`` and
    ``download`` come from ``Store``). Its one write is the report attaching itself to the launch it read."""

    def launches(self) -> list[Any]:
        """Every launch (parent) run of this experiment, newest first (the report picks a generation from them)."""
        return self.all_runs(LAUNCHES, "attributes.start_time DESC")

    def load_text(self, run_id: str, filename: str) -> str:
        """A small text artifact of a run (a launch's ``grid.json``, say)."""
        return Path(self.download(run_id, filename)).read_text()

    def load_json(self, run_id: str, filename: str) -> Any:
        """A run's JSON artifact (a launch's ``tuning.json``, ``rounds.json``); None where it has none (a launch
        without ``[tune]``, or one written by hand)."""
        try:
            return json.loads(self.load_text(run_id, filename))
        except Exception:  # noqa: BLE001 - no such artifact
            return None

    def attach_report(self, run_id: str, folder: Path) -> None:
        """Log a written report (``report.md``, ``.html``, ``.pdf``, figures, tables, the videos it recorded) as
        the ``report/`` artifacts of a launch run."""
        self.client.log_artifacts(run_id, str(folder), "report")
