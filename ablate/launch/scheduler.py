"""The only module that talks to Ray: run a list of trials with Ray Tune, locally or on any Ray cluster.

Trials run in Ray workers; their events (curve points every few seconds, checkpoints as taken, artifacts as file
bytes in their last result) travel through Ray's object store to the driver, the single tracking writer, which
hands them to the ``recorder.Recorder`` it was given: why through Ray is in ``docs/cluster.md`` ("How trials
reach the store"). ``storage_path`` is Tune's own bookkeeping, kept on the driver.
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
from typing import TYPE_CHECKING, Any

import ray
from ray import tune
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from ablate.launch.curve import CurvePoint, CurveReducer
from ablate.launch.event_writer import EventWriter
from ablate.launch.patches import ray_entrypoint_shown, ray_lean_local_start, ray_loopback_only, ray_raylet_errors_to
from ablate.launch.plan import Population
from ablate.launch.ray_logs import log_raylet_errors, one_line, tune_logs_to
from ablate.launch.secrets import shown

if TYPE_CHECKING:
    from ablate.launch.recorder import Recorder  # the events' one receiver (``bench_launch`` times a stand-in)

REPORT_EVERY_S = 2.0
"""Seconds between metric reports from a trial: each ``tune.report`` costs ~2 ms, so never per episode."""
MAX_PROCESS_FAILURES = 2
"""Times a trial whose process died (OOM kill, segfault, lost node) is restarted before it counts as failed."""
CONNECT_TIMEOUT_S = 10.0
"""Seconds to reach a cluster's address before ``ablate run`` gives up (Ray itself retries for minutes)."""


class ClusterUnavailable(RuntimeError):
    """The Ray cluster named by ``--address`` or ``RAY_ADDRESS`` cannot be reached (one line, exit 1)."""


@dataclass(frozen=True)
class ClusterOptions:
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


def _train(params: dict[str, Any], populations: dict[str, Population], checkpoints: Any) -> None:
    """The Tune trainable: runs one population in a Ray worker, on any node. Each member's events travel in
    the population's reports, under its own key: its curve points, and once it ended, its outcome, in the next
    report (every ``REPORT_EVERY_S``, a checkpoint's, or the last): Tune holds the worker at each report until the
    driver has recorded it, so members that end together are recorded together. A member's exception (a NaN
    loss) becomes its ``failed`` report and the others go on; an exception of the whole population fails every
    member still running. Only a dead process is retried: a seeded trial that raises would raise again."""
    population = populations[params["key"]]
    keys = population.keys
    reducers = [CurveReducer(t.config.max_episodes) for t in population.members]
    pending: dict[str, list[CurvePoint]] = {}
    ended: dict[str, dict[str, Any]] = {}
    """Outcomes not reported yet."""
    outcome_of: dict[str, dict[str, Any]] = {}
    last = time.monotonic()
    node = ray.get_runtime_context().get_node_id()

    def report(**extra: Any) -> None:
        nonlocal last
        outcomes = {"ablate_outcomes": dict(ended)} if ended else {}
        tune.report({"ablate_points": dict(pending), "ablate_node": node, **outcomes, **extra})
        pending.clear()
        ended.clear()
        last = time.monotonic()

    def on_episodes(i: int, rows: list) -> None:
        pending.setdefault(keys[i], []).extend(reducers[i].add(rows))
        if time.monotonic() - last >= REPORT_EVERY_S:
            report()

    def on_checkpoint(i: int, blob: bytes) -> None:
        report(ablate_checkpoint={keys[i]: blob})  # the points up to the checkpoint go with it

    with tempfile.TemporaryDirectory(prefix="ablate-") as folder:
        folders = [Path(folder) / str(i) for i in range(len(keys))]

        def on_outcome(i: int, outcome: Any) -> None:
            pending.setdefault(keys[i], []).extend(reducers[i].flush())
            if isinstance(outcome, Exception):
                outcome_of[keys[i]] = {"failed": f"{type(outcome).__name__}: {outcome}"}
            else:
                curve = population.plotted is None or keys[i] in population.plotted
                write_artifacts(outcome, folders[i], video=False, curve=curve)
                files = _read_folder(folders[i])
                outcome_of[keys[i]] = {"summary": outcome.summary(), "artifacts": files, "env": outcome.env}
            ended[keys[i]] = outcome_of[keys[i]]

        resume = {}
        if checkpoints is not None:
            blobs = ray.get([checkpoints.get.remote(k) for k in keys])
            resume = {"resume_from": blobs, "on_checkpoint": on_checkpoint}
        # Here, in the worker: the driver never imports torch for them.
        from ablate.agent.trainer import run_population
        from ablate.trial_files import write_artifacts

        try:
            run_population(
                [t.config for t in population.members],
                on_episodes=on_episodes,
                artifacts_dirs=folders,
                on_outcome=on_outcome,
                **resume,
            )
        except Exception as error:  # noqa: BLE001 - every error is recorded on the runs, with its type
            for i, key in enumerate(keys):
                if key not in outcome_of:
                    pending.setdefault(key, []).extend(reducers[i].flush())
                    ended[key] = {"failed": f"{type(error).__name__}: {error}"}
        report()


def run_trials(
    plan: Sequence[Population],
    events: Recorder,
    options: ClusterOptions,
    run_name: str,
    resume: Mapping[str, bytes] | None = None,
) -> None:
    """Run the trials of ``plan`` (``launch.plan``: each population one Ray task) to completion with Ray Tune,
    calling ``events`` per trial (member) on this process as they progress. ``resume``: checkpoint blobs by
    trial key (from a killed launch); those trials continue from them. Ray is started or joined (``ensure_ray``)
    before.

    Raises ``KeyboardInterrupt`` on Ctrl-C after Ray's workers are stopped.
    """
    # Before Tune is imported: our tracker records everything, so Tune's own loggers and its SIGINT
    # handler (which would swallow Ctrl-C) stay off.
    os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
    os.environ["TUNE_DISABLE_SIGINT_HANDLER"] = "1"
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    ray_raylet_errors_to(log_raylet_errors)  # a dead worker: one line
    by_key = {p.key: p for p in plan}
    checkpoints = None
    if resume or any(t.config.checkpoint_interval for p in plan for t in p.members):
        # On the driver's node (a worker node may die), holding no CPU. Only where a trial checkpoints: the
        # actor is a process of its own, importing torch and Tune (~2 s of CPU) for nothing otherwise.
        here = ray.get_runtime_context().get_node_id()
        checkpoints = _Checkpoints.options(scheduling_strategy=NodeAffinitySchedulingStrategy(here, soft=False)).remote(
            dict(resume or {})
        )
    writer = EventWriter(events)
    bridge = _Bridge(writer, checkpoints, {p.key: p.keys for p in plan})
    storage = Path(options.storage_path).resolve() if "://" not in options.storage_path else None
    tuner = tune.Tuner(
        tune.with_resources(
            tune.with_parameters(_train, populations=by_key, checkpoints=checkpoints), trial_resources(options)
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
    log_path = (storage or Path.cwd()) / f"{run_name}.log"
    problem: Exception | None = None
    try:
        with tune_logs_to(log_path):
            tuner.fit()
        writer.close()  # every event told before the trials count as ended
    except KeyboardInterrupt:
        writer.close(drop=True)  # the events not told yet are dropped: the caller marks their runs killed
        ray.shutdown()  # stops the workers now
        raise
    except Exception as error:  # noqa: BLE001 - Tune's error, whose text is a traceback: told in one line
        cause: Exception = error
        try:
            writer.close()  # what the trials did before the error is recorded
        except Exception as failed:  # noqa: BLE001 - a write failed: the store's error is the launch's
            cause = failed
        problem = one_line(cause, log_path)
    finally:
        if storage is not None:
            shutil.rmtree(storage / run_name, ignore_errors=True)  # everything is in the tracker by now
    if problem is not None:  # raised outside the except: one line, not the chain of exceptions behind it
        raise problem


def trial_resources(options: ClusterOptions) -> dict[str, float]:
    """What Ray Tune reserves for each trial: ``cpus_per_trial`` CPUs and, when set, ``gpus_per_trial`` GPUs."""
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
    ray_loopback_only(not address or _host(address) in ("127.0.0.1", "localhost"))
    # ray.init installs a SIGTERM handler that calls sys.exit() wherever the driver is, which skips the
    # caller's cleanup and ends in a C++ abort (exit 134); the caller's own handler stays.
    sigterm = signal.getsignal(signal.SIGTERM)
    problem = None
    try:
        # Only a join is refused for a token; a local start's daemons would inherit the kept descriptor.
        with (
            _stderr_kept() if address else contextlib.nullcontext(_Kept()) as kept,
            ray_entrypoint_shown(shown),
            contextlib.nullcontext() if address else ray_lean_local_start(),
        ):
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


class _Bridge(tune.Callback):
    """A Tune callback (runs on the driver) that turns Tune's lifecycle of populations into events
    per member, handed to the ``EventWriter``. A member's end is told as its report arrives; a population whose
    process died is retried whole, and its members that had ended already are not told of again."""

    def __init__(self, writer: EventWriter, checkpoints: Any, members: Mapping[str, list[str]]) -> None:
        self.writer, self.events = writer, writer.events
        self.checkpoints = checkpoints
        self.members = dict(members)
        self.ended: set[str] = set()

    def __getstate__(self) -> dict:
        # Tune pickles its callbacks into its experiment state; the writer and its events (an MLflow client, a terminal
        # view) belong to this process and are no part of that state.
        return {"writer": None, "events": None, "checkpoints": None, "members": {}, "ended": set()}

    def _running(self, trial: Any) -> list[str]:
        return [k for k in self.members[trial.config["key"]] if k not in self.ended]

    def on_trial_start(self, iteration, trials, trial, **info):
        for key in self._running(trial):
            self.writer.put(self.events.started, key)

    def on_trial_result(self, iteration, trials, trial, result, **info):
        # Popped: Tune keeps the last result of every trial in memory and in its experiment state.
        running = set(self._running(trial))
        for key, points in result.pop("ablate_points", {}).items():
            if points and key in running:
                self.writer.put(self.events.episodes, key, [CurvePoint(*p) for p in points])
        for key, blob in result.pop("ablate_checkpoint", {}).items():
            if key in running:
                if self.checkpoints is not None:
                    self.checkpoints.put.remote(key, blob)
                self.writer.put(self.events.checkpoint, key, blob)
        node = result.get("ablate_node", "")
        population = trial.config["key"]
        for key, outcome in result.pop("ablate_outcomes", {}).items():
            if key not in running:
                continue
            self.ended.add(key)
            if "failed" in outcome:
                self.writer.put(self.events.failed, key, outcome["failed"])
            else:
                self.writer.put(_finished, self.events, key, outcome, node, population)

    def on_trial_recover(self, iteration, trials, trial, **info):
        for key in self._running(trial):
            self.writer.put(self.events.restarted, key, _error_text(trial))

    def on_trial_error(self, iteration, trials, trial, **info):
        reason = f"trial process died {MAX_PROCESS_FAILURES + 1} times: {_error_text(trial)}"
        for key in self._running(trial):
            self.ended.add(key)
            self.writer.put(self.events.failed, key, reason)


def _finished(events: Recorder, key: str, outcome: Mapping[str, Any], node: str, population: str) -> None:
    """A member's end told with its files in a folder of their own (the tracker logs the folder)."""
    summary, env = dict(outcome["summary"]), outcome.get("env")
    if not outcome["artifacts"]:
        events.finished(key, summary, None, node, population, env)
        return
    with tempfile.TemporaryDirectory(prefix="ablate-artifacts-") as folder:
        _write_folder(outcome["artifacts"], Path(folder))
        events.finished(key, summary, Path(folder), node, population, env)


def _error_text(trial: Any) -> str:
    path = getattr(trial, "error_file", None) or ""
    try:
        lines = [line for line in Path(path).read_text().splitlines() if line.strip()]
        return lines[-1][:500] if lines else "no error message"
    except OSError:
        return "the worker process exited unexpectedly"
