"""The only module that talks to Ray: run a list of trials with Ray Tune, locally or on any Ray cluster.

Trials run in Ray workers; events reach the caller on the driver process (the single tracking writer)
through the ``TrialEvents`` it passes in. Nothing assumes a disk that two machines share: everything a
trial produces travels inside Ray's own results, through the object store, to the driver:

- its curve, reduced in the worker to a bounded number of points (``ablate.launch.curve``), every few seconds;
- its artifacts (``episodes.csv``, weights, curve, videos), as file bytes in its last result;
- its checkpoints (an opaque blob from ``run_trial``'s ``on_checkpoint``), as they are taken. The driver
  keeps the latest one per trial in a small actor on its own node, where a retried trial fetches it.

Why through Ray rather than straight from workers to the tracking store: the driver already is the one
writer (an SQLite store must never see two), so the path is the same for ``sqlite:///`` and a tracking
server; workers need neither the store's address nor its credentials; and a trial that dies mid-way
leaves nothing half-written in the store. The cost is that artifacts cross the driver once: they are
small here (tens of KB to a few MB per trial). ``storage_path`` is Tune's own bookkeeping, kept on the
driver; a user with NFS or ``s3://`` can still point it there.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import ray
from ray import tune
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from ablate.agent.trial import run_trial
from ablate.launch.curve import CurvePoint, CurveReducer
from ablate.launch.grid import GridTrial
from ablate.launch.secrets import shown

REPORT_EVERY_S = 2.0
"""Seconds between metric reports from a trial: each ``tune.report`` costs ~2 ms, so never per episode."""
MAX_PROCESS_FAILURES = 2
"""Times a trial whose process died (OOM kill, segfault, lost node) is restarted before it counts as failed."""
CONNECT_TIMEOUT_S = 10.0
"""Seconds to reach a cluster's address before ``ablate run`` gives up (Ray itself retries for minutes)."""


class ClusterUnavailable(RuntimeError):
    """The Ray cluster named by ``--address`` or ``RAY_ADDRESS`` cannot be reached (one line, exit 1)."""


class TrialEvents(Protocol):
    """What the scheduler tells its caller, on the driver, in order per trial."""

    def started(self, key: str) -> None: ...
    def episodes(self, key: str, points: list[CurvePoint]) -> None: ...
    def checkpoint(self, key: str, blob: bytes) -> None: ...
    def restarted(self, key: str, reason: str) -> None: ...
    def finished(self, key: str, summary: dict[str, float], artifacts: Path | None, node: str) -> None: ...
    def failed(self, key: str, message: str) -> None: ...


@dataclass(frozen=True)
class ClusterOptions:
    address: str | None = None
    """``None``: ``RAY_ADDRESS`` if set, else a fresh local Ray with this machine's cores. Else ``auto``,
    ``host:port`` of a head node's GCS, or ``ray://host:port``."""
    max_concurrent: int | None = None
    """Trials at once; ``None``: as many as the cluster's CPUs allow."""
    cpus_per_trial: float = 1.0
    gpus_per_trial: float = 0.0
    """GPUs Ray reserves per trial (fractions pack trials on one GPU); 0: none."""
    storage_path: str = "ray_results"
    """Tune's bookkeeping, on the driver; artifacts and checkpoints never go through it."""


@ray.remote(num_cpus=0, max_restarts=0)
class _Checkpoints:
    """The latest checkpoint blob per trial key, on the driver's node: a retried trial resumes from it."""

    def __init__(self, blobs: Mapping[str, bytes]) -> None:
        self.blobs = dict(blobs)

    def put(self, key: str, blob: bytes) -> None:
        self.blobs[key] = blob

    def get(self, key: str) -> bytes | None:
        return self.blobs.get(key)


def _read_folder(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _write_folder(files: Mapping[str, bytes], folder: Path) -> None:
    for name, data in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)


def _train(params: dict[str, Any], trials: dict[str, GridTrial], checkpoints: Any) -> None:
    """The Tune trainable: runs in a Ray worker, on any node. Exceptions become a ``failed`` report, not a
    retry: a seeded trial that raises would raise again. Only a dead process is retried."""
    trial = trials[params["key"]]
    reducer = CurveReducer(trial.config.max_episodes)
    pending: list[CurvePoint] = []
    last = time.monotonic()
    node = ray.get_runtime_context().get_node_id()

    def report(status: str, **extra: Any) -> None:
        nonlocal last
        tune.report({"ablate_status": status, "ablate_points": list(pending), "ablate_node": node, **extra})
        pending.clear()
        last = time.monotonic()

    def on_episodes(rows: list) -> None:
        pending.extend(reducer.add(rows))
        if time.monotonic() - last >= REPORT_EVERY_S:
            report("running")

    def on_checkpoint(blob: bytes) -> None:
        report("running", ablate_checkpoint=blob)  # the points up to the checkpoint go with it

    resume = {}
    if checkpoints is not None:
        resume = {"resume_from": ray.get(checkpoints.get.remote(trial.key)), "on_checkpoint": on_checkpoint}
    with tempfile.TemporaryDirectory(prefix="ablate-") as folder:
        try:
            result = run_trial(trial.config, on_episodes=on_episodes, artifacts_dir=folder, **resume)
        except Exception as error:  # noqa: BLE001 - every error is recorded on the run, with its type
            pending.extend(reducer.flush())
            report("failed", ablate_error=f"{type(error).__name__}: {error}")
            return
        pending.extend(reducer.flush())
        report("finished", ablate_summary=result.summary(), ablate_artifacts=_read_folder(Path(folder)))


def run_trials(
    trials: Sequence[GridTrial],
    events: TrialEvents,
    options: ClusterOptions,
    run_name: str,
    resume: Mapping[str, bytes] | None = None,
) -> None:
    """Run ``trials`` to completion with Ray Tune, calling ``events`` on this process as they progress.
    ``resume``: checkpoint blobs by trial key (from a killed launch); those trials continue from them.

    Raises ``KeyboardInterrupt`` on Ctrl-C after Ray's workers are stopped.
    """
    # Before Tune is imported: our tracker records everything, so Tune's own loggers and its SIGINT
    # handler (which would swallow Ctrl-C) stay off.
    os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
    os.environ["TUNE_DISABLE_SIGINT_HANDLER"] = "1"
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    started_here = ensure_ray(options.address)
    by_key = {t.key: t for t in trials}
    checkpoints = None
    if resume or any(t.config.checkpoint_interval for t in trials):
        # On the driver's node (a worker node may die), holding no CPU. Only where a trial checkpoints: the
        # actor is a process of its own, importing torch and Tune (~2 s of CPU) for nothing otherwise.
        here = ray.get_runtime_context().get_node_id()
        checkpoints = _Checkpoints.options(scheduling_strategy=NodeAffinitySchedulingStrategy(here, soft=False)).remote(
            dict(resume or {})
        )
    bridge = _Bridge(events, checkpoints)
    storage = Path(options.storage_path).resolve() if "://" not in options.storage_path else None
    tuner = tune.Tuner(
        tune.with_resources(
            tune.with_parameters(_train, trials=by_key, checkpoints=checkpoints), trial_resources(options)
        ),
        param_space={"key": tune.grid_search(list(by_key))},
        tune_config=tune.TuneConfig(
            reuse_actors=True,  # ~0.5 s per trial instead of ~2 s for a fresh worker process
            max_concurrent_trials=options.max_concurrent,
            trial_name_creator=lambda t: t.config["key"],
            trial_dirname_creator=lambda t: t.config["key"],
        ),
        run_config=tune.RunConfig(
            name=run_name,
            storage_path=str(storage) if storage else options.storage_path,
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
        if storage is not None:
            shutil.rmtree(storage / run_name, ignore_errors=True)  # everything is in the tracker by now
        if started_here:
            stop_ray()


def trial_resources(options: ClusterOptions) -> dict[str, float]:
    """What Ray Tune reserves for each trial: ``cpus_per_trial`` CPUs and, when set, ``gpus_per_trial`` GPUs
    (the trial puts its policy on CUDA whenever torch sees one)."""
    resources = {"cpu": options.cpus_per_trial}
    if options.gpus_per_trial:
        resources["gpu"] = options.gpus_per_trial
    return resources


def ensure_ray(address: str | None) -> bool:
    """Join ``address`` (or ``RAY_ADDRESS``), else start a fresh, quiet local Ray that listens on 127.0.0.1
    only; returns whether this call started or joined it. With neither, ``ray.init`` would join the newest
    cluster started on this machine (``ray start``) and then refuse our CPU count: a local run must never
    depend on what else runs here. Raises ``ClusterUnavailable`` when the address cannot be reached."""
    if ray.is_initialized():
        return False
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        _check_reachable(address)
    # A head on this machine's loopback (``make cluster-up``): Ray would otherwise swap 127.0.0.1 for the
    # machine's address, where that head does not listen.
    _loopback_only(not address or _host(address) in ("127.0.0.1", "localhost"))
    # ray.init installs a SIGTERM handler that calls sys.exit() wherever the driver is, which skips the
    # caller's cleanup and ends in a C++ abort (exit 134); the caller's own handler stays.
    sigterm = signal.getsignal(signal.SIGTERM)
    problem = None
    try:
        # Only a join is refused for a token; a local start's daemons would inherit the kept descriptor.
        with _stderr_kept() if address else contextlib.nullcontext(_Kept()) as kept, _entrypoint_shown():
            ray.init(
                address=address or "local",
                num_cpus=None if address else os.cpu_count(),
                include_dashboard=False,
                log_to_driver=False,  # workers' prints stay in Ray's log files, not on the progress view
                logging_level=logging.ERROR,
                configure_logging=True,
            )
    except ConnectionError as error:
        problem = f"cannot join the Ray cluster at {address}: {error}".splitlines()[0]
        if "InvalidAuthToken" in kept.text:
            problem = (
                f"the Ray cluster at {address} refused this driver: its token is missing or wrong; set "
                "RAY_AUTH_MODE=token and RAY_AUTH_TOKEN_PATH to the cluster's token file (or RAY_AUTH_TOKEN)"
            )
    except Exception as error:  # noqa: BLE001 - a local start that failed (Ray's 30 s node start-up limit, ...)
        if address:
            raise
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        problem = (
            f"could not start a local Ray: {first} (an overloaded machine makes Ray's start-up time out); "
            "run the same command again"
        )
    if problem:  # raised outside the except: one line, not the chain of exceptions behind it
        raise ClusterUnavailable(problem)
    if callable(sigterm) and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, sigterm)
    return True


class _Kept:
    text = ""


@contextlib.contextmanager
def _entrypoint_shown() -> Iterator[None]:
    """Ray records the driver's command line (``ps``'s, not ``sys.argv``) as its job's entrypoint, which the
    job table shows anyone on the cluster: the shown form instead, a password in ``--tracking-uri`` masked."""
    utils = ray._private.utils
    original = utils.get_entrypoint_name
    utils.get_entrypoint_name = lambda: shown(original())
    try:
        yield
    finally:
        utils.get_entrypoint_name = original


@contextlib.contextmanager
def _stderr_kept() -> Iterator[_Kept]:
    """Ray's C++ client prints a warning a second to file descriptor 2 while a cluster refuses it (a missing
    token: ``InvalidAuthToken``) before ``ray.init`` gives up: keep them aside, to name the cause in one line;
    on success they are passed on as they were."""
    kept = _Kept()
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as buffer:
        os.dup2(buffer.fileno(), 2)
        failed = False
        try:
            yield kept
        except BaseException:
            failed = True
            raise
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            buffer.seek(0)
            kept.text = buffer.read().decode(errors="replace")
            if not failed and kept.text:
                sys.stderr.write(kept.text)


def largest_node_cpus() -> float:
    """CPUs of the biggest live node of the cluster Ray is connected to: a trial needing more never starts."""
    return max((node["Resources"].get("CPU", 0.0) for node in ray.nodes() if node.get("Alive")), default=0.0)


def stop_ray() -> None:
    """Stop the local Ray this process started, or leave the cluster it joined."""
    if ray.is_initialized():
        ray.shutdown()


def _check_reachable(address: str) -> None:
    """``host:port`` (GCS) or ``ray://host:port`` must accept a connection within ``CONNECT_TIMEOUT_S``: Ray
    itself retries an unreachable GCS for many minutes before it says anything."""
    if address == "auto" or address == "local":
        return
    host, port = _host(address), address.rpartition(":")[2]
    if not host or not port.isdigit():
        raise ClusterUnavailable(
            f"--address {address!r} is not a Ray address; valid: auto, host:port or ray://host:port"
        )
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as error:
        raise ClusterUnavailable(
            f"cannot reach the Ray cluster at {address} ({error.strerror or error}); is its head node running?"
        ) from None


def _host(address: str) -> str:
    return address.removeprefix("ray://").rpartition(":")[0]


def _loopback_only(enabled: bool) -> None:
    """A local Ray takes this machine's network address, and its gcs_server, raylet and workers listen on
    every interface without authentication. Ray (2.60) has no bind option, but with clusters disabled (its
    macOS/Windows default) a new node's address is 127.0.0.1 and every server binds to it alone. Only read
    when this process starts a node: joined clusters and ``ray start`` are unaffected; restored for a join."""
    import ray._private.ray_constants as ray_constants

    global _CLUSTERS_DEFAULT
    if _CLUSTERS_DEFAULT is None:
        _CLUSTERS_DEFAULT = ray_constants.ENABLE_RAY_CLUSTER
    ray_constants.ENABLE_RAY_CLUSTER = False if enabled else _CLUSTERS_DEFAULT


_CLUSTERS_DEFAULT: bool | None = None


class _Bridge(tune.Callback):
    """A Tune callback (runs on the driver) that turns Tune's trial lifecycle into ``TrialEvents``."""

    def __init__(self, events: TrialEvents, checkpoints: Any) -> None:
        self.events = events
        self.checkpoints = checkpoints
        self.summaries: dict[str, tuple[dict[str, float], dict[str, bytes], str]] = {}

    def __getstate__(self) -> dict:
        # Tune pickles its callbacks into its experiment state; the events (an MLflow client, a terminal
        # view) belong to this process and are no part of that state.
        return {"events": None, "checkpoints": None, "summaries": {}}

    def on_trial_start(self, iteration, trials, trial, **info):
        self.events.started(trial.config["key"])

    def on_trial_result(self, iteration, trials, trial, result, **info):
        key = trial.config["key"]
        # Popped: Tune keeps the last result of every trial in memory and in its experiment state.
        points = [CurvePoint(*p) for p in result.pop("ablate_points", [])]
        if points:
            self.events.episodes(key, points)
        blob = result.pop("ablate_checkpoint", None)
        if blob is not None:
            if self.checkpoints is not None:
                self.checkpoints.put.remote(key, blob)
            self.events.checkpoint(key, blob)
        artifacts = result.pop("ablate_artifacts", None)
        status = result.get("ablate_status")
        if status == "failed":
            self.events.failed(key, result.get("ablate_error", "unknown error"))
        elif status == "finished":
            self.summaries[key] = (dict(result["ablate_summary"]), artifacts or {}, result.get("ablate_node", ""))

    def on_trial_complete(self, iteration, trials, trial, **info):
        key = trial.config["key"]
        if key not in self.summaries:
            return  # a trial that reported "failed" has been recorded already
        summary, files, node = self.summaries.pop(key)
        if not files:
            self.events.finished(key, summary, None, node)
            return
        with tempfile.TemporaryDirectory(prefix="ablate-artifacts-") as folder:
            _write_folder(files, Path(folder))
            self.events.finished(key, summary, Path(folder), node)

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
