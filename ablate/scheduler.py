"""The only module that talks to Ray: run a list of trials with Ray Tune, locally or on a cluster.

Trials run in Ray workers and report metrics in chunks; events reach the caller on the driver process
(one writer for the tracker), through the ``TrialEvents`` it passes in.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import ray
from ray import tune

from ablate.grid import GridTrial
from ablate.trial import EpisodeMetrics, run_trial

REPORT_EVERY_S = 2.0
"""Seconds between metric reports from a trial: each ``tune.report`` costs ~2 ms, so never per episode."""
MAX_PROCESS_FAILURES = 2
"""Times a trial whose process died (OOM kill, segfault, lost node) is restarted before it counts as failed."""


class TrialEvents(Protocol):
    """What the scheduler tells its caller, on the driver, in order per trial."""

    def started(self, key: str) -> None: ...
    def episodes(self, key: str, rows: list[EpisodeMetrics]) -> None: ...
    def restarted(self, key: str, reason: str) -> None: ...
    def finished(self, key: str, summary: dict[str, float], artifacts: Path | None) -> None: ...
    def failed(self, key: str, message: str) -> None: ...


@dataclass(frozen=True)
class ClusterOptions:
    address: str | None = None
    """``None``: start a local Ray with this machine's cores. Else ``auto`` or ``ray://host:port``."""
    max_concurrent: int | None = None
    """Trials at once; ``None``: as many as the cluster's CPUs allow."""
    cpus_per_trial: float = 1.0
    storage_path: str = "ray_results"
    """Where Tune keeps trial state and the checkpoints that carry artifacts back (shared storage on a
    multi-node cluster)."""


def _train(params: dict[str, Any], trials: dict[str, GridTrial]) -> None:
    """The Tune trainable: runs in a Ray worker. Exceptions become a ``failed`` report, not a retry:
    a seeded trial that raises would raise again. Only a dead process is retried (``MAX_PROCESS_FAILURES``)."""
    trial = trials[params["key"]]
    pending: list[EpisodeMetrics] = []
    last = time.monotonic()

    def on_episodes(rows: list[EpisodeMetrics]) -> None:
        nonlocal last
        pending.extend(rows)
        if time.monotonic() - last >= REPORT_EVERY_S:
            tune.report({"ablate_status": "running", "ablate_episodes": [tuple(r) for r in pending]})
            pending.clear()
            last = time.monotonic()

    with tempfile.TemporaryDirectory(prefix="ablate-") as folder:
        try:
            result = run_trial(trial.config, on_episodes=on_episodes, artifacts_dir=folder)
        except Exception as error:  # noqa: BLE001 - every error is recorded on the run, with its type
            tune.report(
                {
                    "ablate_status": "failed",
                    "ablate_error": f"{type(error).__name__}: {error}",
                    "ablate_episodes": [tuple(r) for r in pending],
                }
            )
            return
        tune.report(
            {
                "ablate_status": "finished",
                "ablate_episodes": [tuple(r) for r in pending],
                "ablate_summary": result.summary(),
            },
            checkpoint=tune.Checkpoint.from_directory(folder),
        )


def run_trials(trials: Sequence[GridTrial], events: TrialEvents, options: ClusterOptions, run_name: str) -> None:
    """Run ``trials`` to completion with Ray Tune, calling ``events`` on this process as they progress.

    Raises ``KeyboardInterrupt`` on Ctrl-C after Ray's workers are stopped.
    """
    # Before Tune is imported: our tracker records everything, so Tune's own loggers and its SIGINT
    # handler (which would swallow Ctrl-C) stay off.
    os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
    os.environ["TUNE_DISABLE_SIGINT_HANDLER"] = "1"
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    started_here = ensure_ray(options.address)
    by_key = {t.key: t for t in trials}
    bridge = _Bridge(events)
    storage = Path(options.storage_path).resolve()
    tuner = tune.Tuner(
        tune.with_resources(tune.with_parameters(_train, trials=by_key), {"cpu": options.cpus_per_trial}),
        param_space={"key": tune.grid_search(list(by_key))},
        tune_config=tune.TuneConfig(
            reuse_actors=True,  # ~0.5 s per trial instead of ~2 s for a fresh worker process
            max_concurrent_trials=options.max_concurrent,
            trial_name_creator=lambda t: t.config["key"],
            trial_dirname_creator=lambda t: t.config["key"],
        ),
        run_config=tune.RunConfig(
            name=run_name,
            storage_path=str(storage),
            failure_config=tune.FailureConfig(max_failures=MAX_PROCESS_FAILURES),
            callbacks=[bridge],
            verbose=0,
            log_to_file=False,
        ),
    )
    try:
        tuner.fit()
    except KeyboardInterrupt:
        ray.shutdown()  # stops the workers now; the caller marks their runs killed
        raise
    finally:
        shutil.rmtree(storage / run_name, ignore_errors=True)  # artifacts are in the tracker by now
        if started_here and ray.is_initialized():
            ray.shutdown()


def ensure_ray(address: str | None) -> bool:
    """Join ``address`` (or ``RAY_ADDRESS``), else start a fresh, quiet local Ray; returns whether this call
    started or joined it. With neither, ``ray.init`` would join the newest cluster started on this machine
    (``ray start``) and then refuse our CPU count: a local run must never depend on what else runs here."""
    if ray.is_initialized():
        return False
    address = address or os.environ.get("RAY_ADDRESS") or None
    # ray.init installs a SIGTERM handler that calls sys.exit() wherever the driver is, which skips the
    # caller's cleanup and ends in a C++ abort (exit 134); the caller's own handler stays.
    sigterm = signal.getsignal(signal.SIGTERM)
    ray.init(
        address=address or "local",
        num_cpus=None if address else os.cpu_count(),
        include_dashboard=False,
        log_to_driver=False,  # workers' prints stay in Ray's log files, not on the progress view
        logging_level=logging.ERROR,
        configure_logging=True,
    )
    if callable(sigterm) and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, sigterm)
    return True


class _Bridge(tune.Callback):
    """A Tune callback (runs on the driver) that turns Tune's trial lifecycle into ``TrialEvents``."""

    def __init__(self, events: TrialEvents) -> None:
        self.events = events
        self.summaries: dict[str, dict[str, float]] = {}

    def __getstate__(self) -> dict:
        # Tune pickles its callbacks into its experiment state; the events (an MLflow client, a terminal
        # view) belong to this process and are no part of that state.
        return {"events": None, "summaries": {}}

    def on_trial_start(self, iteration, trials, trial, **info):
        self.events.started(trial.config["key"])

    def on_trial_result(self, iteration, trials, trial, result, **info):
        key = trial.config["key"]
        rows = [EpisodeMetrics(*row) for row in result.get("ablate_episodes", [])]
        if rows:
            self.events.episodes(key, rows)
        status = result.get("ablate_status")
        if status == "failed":
            self.events.failed(key, result.get("ablate_error", "unknown error"))
        elif status == "finished":
            self.summaries[key] = dict(result["ablate_summary"])

    def on_trial_complete(self, iteration, trials, trial, **info):
        key = trial.config["key"]
        if key not in self.summaries:
            return  # a trial that reported "failed" has been recorded already
        summary = self.summaries.pop(key)
        checkpoint = trial.checkpoint
        if checkpoint is None:
            self.events.finished(key, summary, None)
            return
        with checkpoint.as_directory() as folder:
            self.events.finished(key, summary, Path(folder))
        shutil.rmtree(checkpoint.path, ignore_errors=True)

    def on_trial_recover(self, iteration, trials, trial, **info):
        self.events.restarted(trial.config["key"], _error_text(trial))

    def on_trial_error(self, iteration, trials, trial, **info):
        reason = f"trial process died {MAX_PROCESS_FAILURES + 1} times: {_error_text(trial)}"
        self.events.failed(trial.config["key"], reason)


def _error_text(trial: Any) -> str:
    path = getattr(trial, "error_file", None) or ""
    try:
        lines = [line for line in Path(path).read_text().splitlines() if line.strip()]
        return lines[-1][:500] if lines else "no error message"
    except OSError:
        return "the worker process exited unexpectedly"
