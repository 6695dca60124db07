"""The tracking layer's shared part: an MLflow store opened (every check that can fail, in one line), its
experiment, its trial runs read back, and the tags both sides use. The writer (``ablate.launch.tracking``),
the report's variant runs (``ablate.launch.variant_runs``) and the reader (``ablate.reporting.reader``) build on
it; only it, the writer and ``launch.patches`` import MLflow.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
import time
import unicodedata
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import urlparse
from urllib.request import url2pathname

from ablate.experiment import storage_name
from ablate.launch.lock import held_launch
from ablate.launch.secrets import shown as redact
from ablate.launch.store import (
    TrackingError,
    check_sqlite,
    download_folder,
    fail_fast_http,
    first_line,
    is_database,
    lock_file,
    open_uri,
    probe_database,
    probe_server,
    resolve_uri,
    sqlite_path,
    store_problem,
    store_setup_lock,
)

T = TypeVar("T")

TAG_ROLE, TAG_GENERATION, TAG_KEY = "ablate.role", "ablate.generation", "ablate.trial_key"
TAG_VARIANT, TAG_SEED, TAG_ERROR, TAG_ATTEMPT = "ablate.variant", "ablate.seed", "ablate.error", "ablate.attempt"
TAG_COMMIT, TAG_PARENT, TAG_NOTE = "mlflow.source.git.commit", "mlflow.parentRunId", "mlflow.note.content"
TAG_HOST, TAG_PID = "ablate.host", "ablate.pid"
TAG_NODE = "ablate.node"
TAG_POPULATION = "ablate.population"
"""The population (``launch.plan.Population.key``) a trial trained in: members of one share a process."""
TAG_POPULATION_SIZE = "ablate.population_size"
"""Its members, ``1`` for a trial alone: what a run is, as a tag (a reader never parses it out of a key)."""
TAG_NAME = "ablate.name"
"""On an MLflow experiment whose name is a storage name (``experiment.storage_name``): the name as written."""
TAG_STAGE = "ablate.stage"
"""``tune`` (a tuning trial, stage 1 of a ``[tune]`` experiment) or ``eval``; runs without it are ``eval``."""
TAG_ROUND = "ablate.round"
"""The round of seeds its launch ran it in (``1``: the first, its tuning stage included)."""
ROLE_VARIANT = "variant"
"""``ablate.role`` of a report's variant run (``variant_runs``)."""
VARIANTS_FILTER = f'tags.`{TAG_ROLE}` = "{ROLE_VARIANT}"'
"""The MLflow search that shows the variant runs alone: the launch's link (``Store.ui_link``), docs/mlflow-ui.md."""


def ui_hint(served: bool) -> str:
    """What follows a store's UI link where the store serves no UI of its own (``Store.serves_ui``)."""
    return "" if served else "   (start the UI with: make mlflow-ui)"


def ui_port() -> int:
    """The port ``make mlflow-ui`` serves on: ``PORT`` (the Makefile passes it through), else 5000."""
    try:
        return int(os.environ.get("PORT", "5000"))
    except ValueError:
        return 5000


def quiet_mlflow() -> None:
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
    os.environ["MLFLOW_SUPPRESS_PRINTING_URL_TO_STDOUT"] = "true"  # its "View run ... at: URI" lines
    for name in ("mlflow", "alembic"):
        logging.getLogger(name).setLevel(logging.WARNING)


@dataclass
class TrialRun:
    """A tracked trial run, as the results module needs it."""

    run_id: str
    key: str
    variant: str
    seed: int
    status: str
    """MLflow status: FINISHED, FAILED, KILLED, RUNNING."""
    params: dict[str, str]
    metrics: dict[str, float]
    tags: dict[str, str]
    start_time_ms: int
    artifact_uri: str = ""
    """Where its artifacts are (``download`` reads them from here without looking the run up again)."""


class Store:
    """One MLflow experiment (one per ablation) in one store, opened: what the writer (``Tracker``, below) and
    the report's reader (``ablate.reporting.reader``) share: the checks that open it, its experiment, its runs."""

    def __init__(self, tracking_uri: str | None, experiment_name: str | None, write: bool = True) -> None:
        """Opens the store and reads the experiment once, so every reason the store cannot be used surfaces
        here as a one-line ``TrackingError``, before anything is written or started. ``write=False`` (a
        report) accepts a read-only store and refuses to create one; ``experiment_name=None`` opens the store
        alone (``ablate status`` lists its ablations)."""
        self.uri = open_uri(resolve_uri(tracking_uri))
        """The URI MLflow is given (``store.open_uri``: a tracking server's login moved to the environment)."""
        self.shown_uri = redact(self.uri)
        """The URI as messages and records show it: its password masked."""
        self.display_name = unicodedata.normalize("NFC", experiment_name or "")
        # The MLflow experiment, its artifact folder and its lock file: the name's safe form (the name itself
        # for every name valid before names in any script were), whichever form the caller gave.
        self.experiment_name = storage_name(experiment_name) if experiment_name is not None else ""
        self._experiment_id: str | None = None
        db = sqlite_path(self.uri)
        if db is not None:
            check_sqlite(db, write)
        if is_database(self.uri):
            probe_database(self.uri)
        elif self.uri.startswith(("http://", "https://")):
            probe_server(self.uri)

        from mlflow.tracking import MlflowClient

        quiet_mlflow()
        try:
            with store_setup_lock(db), fail_fast_http():
                self.client = MlflowClient(self.uri)
                existing = None
                if experiment_name is None:  # the store alone: one read, so a login it refuses is refused here
                    self.client.search_experiments(max_results=1)
                else:
                    existing = self.client.get_experiment_by_name(self.experiment_name)
        except Exception as error:  # noqa: BLE001 - MLflow, SQLAlchemy and requests errors alike end here
            raise TrackingError(store_problem(self.uri, error)) from None
        if existing is not None and existing.lifecycle_stage == "deleted":
            raise TrackingError(
                f"MLflow experiment {self.experiment_name!r} (id {existing.experiment_id}) at {self.shown_uri} "
                "is deleted; "
                f"restore it with `MLFLOW_TRACKING_URI={self.shown_uri} mlflow experiments restore --experiment-id "
                f"{existing.experiment_id}`, or give the experiment another name"
            )
        if existing is not None:
            self._experiment_id = existing.experiment_id

    # --- experiment -------------------------------------------------------------------------------
    def hold_launch(self, what: str, command: str) -> contextlib.AbstractContextManager[None]:
        """One launch of this experiment at a time on this store (``lock.held_launch``): this machine's lock,
        and for a store other machines reach (not an SQLite file) the store's own lease."""
        shared = sqlite_path(self.uri) is None
        lock = lock_file(self.uri, self.experiment_name)
        return held_launch(lock, what, command, self.client if shared else None, self.experiment_name)

    def ui_link(self, port: int | None = None) -> str:
        """The MLflow UI's comparison of this experiment's variants: its variant runs (one per variant, the last
        report's), their curves in the chart view (docs/mlflow-ui.md). On a tracking server, its own address."""
        from urllib.parse import urlencode

        base = self.shown_uri if self.serves_ui else f"http://127.0.0.1:{port or ui_port()}"
        # MLflow 3 opens an experiment in its GenAI view unless told this is a machine-learning one.
        query = urlencode(
            {"workflowType": "machine_learning", "searchFilter": VARIANTS_FILTER, "compareRunsMode": "CHART"}
        )
        return f"{base.rstrip('/')}/#/experiments/{self.experiment_id()}/runs?{query}"

    @property
    def serves_ui(self) -> bool:
        """A tracking server serves its own UI; a local store needs ``make mlflow-ui``."""
        return self.uri.startswith("http")

    def experiment_id(self, create: bool = True) -> str | None:
        if self._experiment_id is None:
            existing = self.client.get_experiment_by_name(self.experiment_name)
            if existing is not None:
                self._experiment_id = existing.experiment_id
            elif create:
                # The name as written, on the experiment, where MLflow's name is its storage form.
                tags = {TAG_NAME: self.display_name} if self.display_name != self.experiment_name else None
                self._experiment_id = self.client.create_experiment(
                    self.experiment_name, artifact_location=self._artifact_location(), tags=tags
                )
        return self._experiment_id

    def _artifact_location(self) -> str | None:
        """Beside the SQLite file for a local store; a server chooses its own."""
        db = sqlite_path(self.uri)
        return None if db is None else (db.resolve().parent / "mlartifacts" / self.experiment_name).as_uri()

    # --- reading back (the writer resumes from what it wrote) -----------------------------------------
    def all_runs(self, query: str, order_by: str = "attributes.start_time ASC") -> list[Any]:
        """Every run of this experiment that ``query`` matches, page by page (MLflow returns at most 1,000 a call);
        none where the experiment does not exist yet."""
        experiment_id = self.experiment_id(create=False)
        if experiment_id is None:
            return []
        runs, token = [], None
        while True:
            page = self.client.search_runs(
                [experiment_id], query, order_by=[order_by], max_results=1000, page_token=token
            )
            runs.extend(page)
            token = page.token
            if not token:
                return runs

    def trial_runs(self, generation: str | None = None) -> list[TrialRun]:
        """Trial runs of this experiment (of one generation, if given), oldest first."""
        query = f"tags.`{TAG_ROLE}` = 'trial'"
        if generation is not None:
            query += f" and tags.`{TAG_GENERATION}` = '{generation}'"
        runs = self.all_runs(query)
        return [
            TrialRun(
                run_id=r.info.run_id,
                key=r.data.tags.get(TAG_KEY, ""),
                variant=r.data.tags.get(TAG_VARIANT, ""),
                seed=int(r.data.tags.get(TAG_SEED, "-1")),
                status=r.info.status,
                params=dict(r.data.params),
                metrics=dict(r.data.metrics),
                tags=dict(r.data.tags),
                start_time_ms=r.info.start_time,
                artifact_uri=r.info.artifact_uri or "",
            )
            for r in runs
        ]

    def log_values(
        self,
        run_id: str,
        metrics: dict[str, float] | None = None,
        params: dict[str, Any] | None = None,
        tags: dict[str, str] | None = None,
        series: dict[str, list[tuple[int, float]]] | None = None,
    ) -> None:
        """One ``log_batch`` on a run (MLflow splits it into calls its store takes): ``metrics`` at step 0 and
        ``series`` (``(step, value)`` points) stamped now, ``params`` as ``param_text``, ``tags`` as given."""
        from mlflow.entities import Metric, Param, RunTag

        now = int(time.time() * 1000)
        values = [Metric(k, float(v), now, 0) for k, v in (metrics or {}).items()]
        values += [Metric(k, float(v), now, int(step)) for k, points in (series or {}).items() for step, v in points]
        self.client.log_batch(
            run_id,
            metrics=values,
            params=[Param(k, param_text(v)) for k, v in (params or {}).items()],
            tags=[RunTag(k, v) for k, v in (tags or {}).items()],
        )

    def download(self, run_id: str, path: str, destination: str | Path | None = None, artifact_uri: str = "") -> str:
        """An artifact of a run, into ``destination`` or a folder of its own removed when the process ends; a
        one-line ``TrackingError`` naming the run and the artifact when the store cannot give it (its artifact
        folder moved or removed: MLflow's own error is a 40-line traceback). ``artifact_uri``: the run's (from
        its search, ``TrialRun.artifact_uri``), read from directly: MLflow's own download looks the run up twice
        first (~65 ms of a store's CPU each time; a report of 1,000 trials spent a minute there)."""
        target = str(destination or download_folder())
        try:
            if artifact_uri:
                from mlflow.artifacts import download_artifacts

                return download_artifacts(f"{artifact_uri.rstrip('/')}/{path}", dst_path=target, tracking_uri=self.uri)
            return self.client.download_artifacts(run_id, path, target)
        except Exception as error:  # noqa: BLE001 - MLflow's, the artifact store's and the file system's alike
            problem = f"MLflow store {self.shown_uri}: artifact {path!r} of run {run_id} cannot be read"
            problem += f" ({first_line(error)}); was its artifact folder moved or removed?"
        raise TrackingError(problem)

    def read_artifact(self, run: TrialRun, path: str, read: Callable[[Path], T]) -> T:
        """``read`` of a run's artifact: the file itself where the run's artifacts are on this machine (a local
        store's ``mlartifacts/``), else a download into a folder removed afterwards. ``TrackingError`` as
        ``download`` where the store cannot give it."""
        if run.artifact_uri.startswith("file:"):
            local = Path(url2pathname(urlparse(run.artifact_uri).path)) / path
            if local.is_file():
                return read(local)
        with tempfile.TemporaryDirectory(prefix="ablate-artifact-") as folder:
            return read(Path(self.download(run.run_id, path, folder, run.artifact_uri)))


def param_text(value: Any) -> str:
    """A knob's value as an MLflow param: a list or tuple as JSON (``[16]``, as the experiment file writes it)."""
    if isinstance(value, tuple | list):
        return json.dumps(list(value))
    return str(value)
