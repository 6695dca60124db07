"""The driver's side of MLflow: write launches and trials as runs in a store ``mlflow_store.Store`` opened.

One writer: the driver process owns every write (trials run elsewhere and send their metrics through
the scheduler), so an SQLite store never sees two writers; a tracking server works the same way.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ablate.launch.mlflow_store import (
    TAG_ATTEMPT,
    TAG_COMMIT,
    TAG_ERROR,
    TAG_GENERATION,
    TAG_KEY,
    TAG_NOTE,
    TAG_PARENT,
    TAG_ROLE,
    TAG_SEED,
    TAG_STAGE,
    TAG_VARIANT,
    Store,
)
from ablate.launch.patches import mlflow_answers_kept, mlflow_insert_metrics, mlflow_log_artifacts, mlflow_sql_store
from ablate.launch.secrets import shown as redact
from ablate.launch.store_writes import RetryingClient, fail_fast_writes

# A trial's curve: one point per bin of episodes (``curve.CURVE_POINTS``: why at most ~100), step = the bin's last
# episode; a value per episode capped the one writer at ~10 concurrent trials.
POINT_METRICS = {
    "episode/return": "episode_return",  # mean over the bin
    "episode/rolling_mean": "rolling_mean",  # at the bin's last episode
    "episode/loss": "loss",  # mean over the bin's updates
    "episode/entropy": "entropy",
    "episode/length": "length",  # mean over the bin
    "episode/wall_s": "wall_s",
    "episode/env_steps": "env_steps",
}
CHECKPOINT_ARTIFACT = "checkpoint.pt"
"""A trial's latest checkpoint blob, kept on its run so a killed launch's next launch resumes from it."""
FLUSH_EVERY_S = 10.0
"""Seconds curve points wait to be written together: every open trial's in one write (one transaction on an SQL
store, ``patches.mlflow_insert_metrics``; a ``log_batch`` per run on a server), as one MLflow call costs ~4 ms;
a trial's end writes its own."""


START_METRIC, REPORT_METRIC = "start_s", "report_s"
"""On a launch's run: seconds until its first trial started, and spent writing its report (``ablate run``)."""


@dataclass
class OpenRun:
    """A trial's run while it is open."""

    run_id: str
    start_ms: int
    artifact_uri: str
    """From the run's creation, for ``patches.mlflow_log_artifacts`` (which says why)."""
    points: list[Any] = field(default_factory=list)
    """Its curve points not written yet."""


class Tracker(Store):
    """The driver's writer: a parent run per launch, a child run per trial (and what resuming reads back)."""

    def __init__(self, tracking_uri: str | None, experiment_name: str, write: bool = True) -> None:
        super().__init__(tracking_uri, experiment_name, write)
        self._sql = mlflow_sql_store(self.client)
        """The SQL store the client writes to (``None``: a server): curve points go to it in bulk."""
        self.client = RetryingClient(self.client, self.shown_uri)
        fail_fast_writes()
        mlflow_answers_kept()
        self.open_runs: dict[str, OpenRun] = {}
        self.attempts: dict[str, int] = {}
        self._flushed_at = time.monotonic()
        """When the open trials' points were last written."""

    # --- launches ---------------------------------------------------------------------------------
    def latest_generation(self) -> str | None:
        """The generation of the newest launch: re-runs continue it, ``--fresh`` starts a new one."""
        launch = self.latest_launch()
        return launch.data.tags.get(TAG_GENERATION) if launch else None

    def latest_launch(self) -> Any | None:
        experiment_id = self.experiment_id(create=False)
        if experiment_id is None:
            return None
        runs = self.client.search_runs(
            [experiment_id], f"tags.`{TAG_ROLE}` = 'launch'", order_by=["attributes.start_time DESC"], max_results=1
        )
        return runs[0] if runs else None

    def earlier_runs(self, keys: Iterable[str]) -> tuple[dict[str, float], dict[str, int]]:
        """Seconds each of ``keys`` took (its run's start to end) and the episodes it ran, when an earlier
        launch, of any generation, finished it (the newest such run): the time-left estimate starts from these."""
        wanted, runs = set(keys), {}
        if not wanted:
            return {}, {}
        query = f"tags.`{TAG_ROLE}` = 'trial' and attributes.status = 'FINISHED'"
        for r in self.all_runs(query, order_by="attributes.start_time DESC"):
            key = r.data.tags.get(TAG_KEY, "")
            if key in wanted and key not in runs and r.info.end_time and r.info.start_time:
                runs[key] = r
        costs = {key: max(r.info.end_time - r.info.start_time, 0) / 1000 for key, r in runs.items()}
        return costs, {
            key: int(r.data.metrics["episodes_run"]) for key, r in runs.items() if "episodes_run" in r.data.metrics
        }

    def start_launch(self, generation: str, name: str, tags: dict[str, str], files: dict[str, str]) -> str:
        """Open the parent run of one launch; ``files`` are small text artifacts (the experiment, the grid).
        A store that refuses the files leaves the run FAILED, not RUNNING."""
        run = self.client.create_run(
            self.experiment_id(),
            run_name=name,
            tags={TAG_ROLE: "launch", TAG_GENERATION: generation, **{k: redact(v) for k, v in tags.items()}},
        )
        try:
            for filename, text in files.items():
                self.client.log_text(run.info.run_id, redact(text), filename)
        except Exception as error:
            with contextlib.suppress(Exception):  # a store that stopped answering cannot be told
                self.kill_runs([run.info.run_id], str(error), "FAILED")
            raise
        return run.info.run_id

    def log_file(self, run_id: str, filename: str, text: str) -> None:
        """A small text artifact on a run (a launch's ``tuning.json``, written once its choices are known)."""
        self.client.log_text(run_id, text, filename)

    def finish_launch(self, run_id: str, status: str, summary: dict[str, float], note: str = "") -> None:
        """Close the launch's run; ``note`` (the run's description in MLflow) says what happened."""
        note = redact(note)[:5000]
        tags = ({TAG_NOTE: note} if note else {}) | ({TAG_ERROR: note} if status != "FINISHED" else {})
        self.log_values(run_id, summary, tags=tags)
        self.client.set_terminated(run_id, status)

    def record_report_time(self, run_id: str, seconds: float) -> None:
        """The seconds ``ablate run`` spent writing the report after launch ``run_id``: what the next ``--dry-run``
        says a report costs (``launch_times``)."""
        self.log_values(run_id, {REPORT_METRIC: round(seconds, 3)})

    def launch_times(self) -> tuple[float | None, float | None]:
        """(start, report) seconds the newest launch took: until its first trial started, and writing its report
        (None where it recorded none: an older store, a launch without a report)."""
        launch = self.latest_launch()
        if launch is None:
            return None, None
        metrics = launch.data.metrics
        return metrics.get(START_METRIC), metrics.get(REPORT_METRIC)

    # --- trials -----------------------------------------------------------------------------------
    def start_trial(
        self,
        parent_id: str,
        generation: str,
        key: str,
        variant: str,
        seed: int,
        params: dict[str, Any],
        commit: str,
        stage: str = "eval",
    ) -> str:
        self.attempts[key] = self.attempts.get(key, 0) + 1
        run = self.client.create_run(
            self.experiment_id(),
            run_name=key,
            tags={
                TAG_PARENT: parent_id,
                TAG_ROLE: "trial",
                TAG_GENERATION: generation,
                TAG_KEY: key,
                TAG_VARIANT: variant,
                TAG_SEED: str(seed),
                TAG_ATTEMPT: str(self.attempts[key]),
                TAG_COMMIT: commit,
                TAG_STAGE: stage,
            },
        )
        self.log_values(run.info.run_id, params=params)
        self.open_runs[key] = OpenRun(run.info.run_id, run.info.start_time, run.info.artifact_uri)
        return run.info.run_id

    def log_points(self, key: str, points: Sequence[Any]) -> None:
        """``POINT_METRICS`` of each curve point (``ablate.launch.curve.CurvePoint``) of an open trial, written as
        ``FLUSH_EVERY_S`` says."""
        self.open_runs[key].points.extend(points)
        if time.monotonic() - self._flushed_at >= FLUSH_EVERY_S:
            self._flush_points(list(self.open_runs))
            self._flushed_at = time.monotonic()

    def _flush_points(self, keys: Sequence[str], extra: dict[str, list[Any]] | None = None) -> None:
        """Write the pending points of the open trials ``keys`` (and ``extra``: more metrics by key) in one write,
        each point stamped run start + its ``wall_s``, so MLflow's time axes show when it happened, not when the
        driver wrote the batch."""
        from mlflow.entities import Metric

        batches: dict[str, list[Any]] = {}
        for key in keys:
            run, more = self.open_runs[key], (extra or {}).get(key, [])
            if run.points or more:
                pending, run.points = run.points, []
                batches[run.run_id] = [
                    Metric(metric, float(getattr(p, attr)), run.start_ms + int(1000 * p.wall_s), int(p.episode))
                    for p in pending
                    for metric, attr in POINT_METRICS.items()
                ] + more
        if not batches:
            return
        if self._sql is not None:
            self.client.retried(mlflow_insert_metrics, self._sql, batches)
            return
        for run_id, metrics in batches.items():  # 1,000 a call (MLflow's limit): a retry re-sends only its own
            for i in range(0, len(metrics), 1000):
                self.client.log_batch(run_id, metrics=metrics[i : i + 1000])

    def log_checkpoint(self, key: str, blob: bytes) -> None:
        """Keep ``blob`` as the open trial's ``checkpoint.pt`` (replacing the previous one): whatever ends the
        launch (Ctrl-C, a killed driver), the next launch finds the latest one (``latest_checkpoints``)."""
        import tempfile

        with tempfile.TemporaryDirectory(prefix="ablate-checkpoint-") as folder:
            path = Path(folder) / CHECKPOINT_ARTIFACT
            path.write_bytes(blob)
            self.client.log_artifact(self.open_runs[key].run_id, str(path))

    def latest_checkpoints(self, generation: str, keys: Iterable[str]) -> dict[str, bytes]:
        """Per key, the checkpoint of its newest interrupted (KILLED) run in ``generation`` that has one."""
        wanted, found = set(keys), {}
        runs = [r for r in self.trial_runs(generation) if r.key in wanted and r.status == "KILLED"]
        for run in reversed(runs):  # newest first
            paths = [] if run.key in found else [a.path for a in self.client.list_artifacts(run.run_id)]
            if CHECKPOINT_ARTIFACT in paths:
                found[run.key] = self.read_artifact(run, CHECKPOINT_ARTIFACT, Path.read_bytes)
        return found

    def finish_trial(
        self,
        key: str,
        summary: dict[str, float],
        artifacts: Path | None,
        tags: dict[str, str] | None = None,
        params: dict[str, str] | None = None,
    ) -> None:
        """Close the trial's run: its summary metrics, ``tags``, and ``params`` known only once it ran (the env
        it ran against)."""
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        run = self._close(key, [Metric(k, float(v), now, 0) for k, v in summary.items()])
        if params or tags:
            self.log_values(run.run_id, params=params, tags={k: redact(v) for k, v in (tags or {}).items()})
        if artifacts is not None:
            self.client.retried(mlflow_log_artifacts, run.artifact_uri, self.uri, artifacts)  # as the client's calls
        self.client.set_terminated(run.run_id, "FINISHED")

    def _close(self, key: str, last: Sequence[Any] = ()) -> OpenRun:
        """Write the trial's pending points (and ``last``: its summary metrics, in the same write) and forget it as
        open."""
        self._flush_points([key], {key: list(last)})
        return self.open_runs.pop(key)

    def fail_trial(self, key: str, message: str) -> None:
        self.kill_runs([self._close(key).run_id], message, "FAILED")

    def discard_trial(self, key: str, reason: str) -> None:
        """A trial whose process died restarts from scratch: its partial run is closed and soft-deleted so
        no metric is counted twice; the restart opens a new run (``ablate.attempt`` counts them)."""
        run = self.open_runs.pop(key, None)
        if run is not None:
            self.kill_runs([run.run_id], f"process died, retried: {reason}")
            self.client.delete_run(run.run_id)

    def kill_running_trials(self, launch_id: str, reason: str) -> list[str]:
        """Mark every trial run of ``launch_id`` still RUNNING in the store KILLED; returns their keys. Read
        from the store, not from ``open_runs``: an interrupt can land between MLflow creating a run and this
        object recording it, and such a run must not stay RUNNING."""
        with contextlib.suppress(Exception):  # marking the runs KILLED matters more than their last points
            self._flush_points(list(self.open_runs))  # their curves so far (written every FLUSH_EVERY_S)
        self.open_runs.clear()
        runs = self.running_runs(f" and tags.`{TAG_PARENT}` = '{launch_id}'")
        self.kill_runs([r.info.run_id for r in runs], reason)
        return [r.data.tags.get(TAG_KEY, r.info.run_id) for r in runs]

    def running_runs(self, query: str = "") -> list[Any]:
        """Runs of this experiment MLflow has as RUNNING (``query``: more of a filter, `` and ...``)."""
        return self.all_runs("attributes.status = 'RUNNING'" + query, order_by="attributes.start_time DESC")

    def kill_runs(self, run_ids: Iterable[str], reason: str, status: str = "KILLED") -> None:
        """End ``run_ids`` as ``status``, with ``reason`` as their error and their note ("Killed: reason")."""
        reason = redact(reason)[:5000]
        for run_id in run_ids:
            self.log_values(run_id, tags={TAG_ERROR: reason, TAG_NOTE: f"{status.capitalize()}: {reason}"})
            self.client.set_terminated(run_id, status)
