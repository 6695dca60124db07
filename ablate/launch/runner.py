"""Run an ablation: experiment file -> grid -> scheduler, every trial event written by the tracker.

The glue of ``ablate run``; it imports neither Ray nor MLflow (``scheduler`` and ``tracking`` do).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

from ablate.config import DEFAULT_POPULATION, ConfigError
from ablate.experiment import Experiment
from ablate.launch.curve import CurvePoint
from ablate.launch.grid import GridTrial, expand, schedule_order, tuning_trials
from ablate.launch.mlflow_store import (
    TAG_HOST,
    TAG_NODE,
    TAG_PID,
    TAG_POPULATION,
    TAG_POPULATION_SIZE,
    TAG_ROLE,
    TAG_ROUND,
)
from ablate.launch.plan import Population, plan_populations
from ablate.launch.progress import ProgressView
from ablate.launch.records import environment_document, git_commit, grid_document, tracked_params
from ablate.launch.rounds import Judge, Rounds
from ablate.launch.state import LaunchState
from ablate.launch.tracking import Tracker
from ablate.launch.tuning import StagePlan, tuning_document, unique

# ``ablate.launch.scheduler`` (Ray: seconds to import) is imported only once there is a trial to run, so a
# re-run with nothing left answers from the store alone.


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM: the launch stops cleanly (workers stopped, running trials marked KILLED).
    ``exit_code`` is the shell's convention for death by that signal: 130 for SIGINT, 143 for SIGTERM."""

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.exit_code = 128 + signum


signals_received: list[int] = []
"""Signals ``raise_interrupted`` turned into ``Interrupted``: Tune re-raises a plain ``KeyboardInterrupt``."""


def raise_interrupted(signum: int, frame: object) -> None:
    signals_received.append(signum)
    raise Interrupted(signum)


@contextlib.contextmanager
def _signals_deferred() -> Iterator[None]:
    """Cleanup that must finish (closing runs) is not cut short by a second Ctrl-C or SIGTERM."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s in saved:
        signal.signal(s, signal.SIG_IGN)
    try:
        yield
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)


@dataclass
class RunOutcome:
    experiment: str
    generation: str
    launch_run_id: str | None
    skipped: int
    """Trials finished by an earlier launch of this generation, not run again."""
    total: int
    """Trials in the experiment's grid."""
    ui_link: str
    """The MLflow runs table of this experiment."""
    finished: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    killed: list[str] = field(default_factory=list)
    interrupted: bool = False
    signal_name: str = ""
    """``SIGINT`` or ``SIGTERM`` when ``interrupted``."""
    error: str = ""
    """Why the scheduler stopped before the grid was done (a Ray error, say): the launch is FAILED."""
    reaped: int = 0
    """Runs a dead launch (kill -9, power loss) left RUNNING, marked KILLED by this one."""
    view: ProgressView | None = field(default=None, repr=False)
    """The launch's progress view (its clock and stage times), when trials ran."""
    report_folder: Path | None = None
    """Where ``ablate.run`` wrote the report afterwards (``None``: no report)."""
    rounds: dict | None = None
    """With seeds in rounds: ``rounds.json`` (``Rounds.document``): the rounds, why they stopped, seeds per variant."""

    @property
    def exit_code(self) -> int:
        if self.interrupted:
            return 128 + signal.Signals[self.signal_name or "SIGINT"].value
        return 1 if self.failed or self.error or self.killed else 0

    def note(self) -> str:
        """One line for the launch run: what happened."""
        counts = f"{len(self.finished)} finished, {len(self.failed)} failed, {len(self.killed)} killed"
        if self.interrupted:
            return f"Interrupted by {self.signal_name}: {counts}; run the same command again to finish the rest."
        if self.error:
            return f"The scheduler failed ({self.error}): {counts}."
        return f"{counts} (of {self.total - self.skipped} to run; {self.skipped} finished before)."


class _Recorder:
    """Scheduler events -> tracker writes and the launch's state, then the view redrawn (all on the driver: one
    MLflow writer)."""

    def __init__(
        self,
        tracker: Tracker,
        launch: str,
        generation: str,
        trials: dict[str, GridTrial],
        commit: str,
        state: LaunchState,
        view: ProgressView,
        outcome: RunOutcome,
    ) -> None:
        self.tracker, self.launch, self.generation = tracker, launch, generation
        self.trials, self.commit, self.state, self.view, self.outcome = trials, commit, state, view, outcome
        self.closed = False
        """Set once the launch stops: a late event from the scheduler then opens no run."""
        self.summaries: dict[str, dict[str, float]] = {}
        """Summary metrics of the trials this launch finished (tuning selection reads them)."""
        self.members: dict[str, int] = {}
        """Each trial's population size, from the plans handed to the scheduler (``planned``)."""
        self.tuned: Callable[[], None] | None = None
        """Asked after each tuning trial ends: the runner's stand-ins for stage 2, as the choice would be now."""

    def planned(self, populations: list[Population]) -> list[Population]:
        """``populations``, as the scheduler will run them: each member's size is kept for its run's tag."""
        self.members |= {key: len(p.members) for p in populations for key in p.keys}
        return populations

    def _open(self, key: str) -> bool:
        """Open the trial's run if needed; ``False`` once the launch has stopped (the event is dropped)."""
        if self.closed:
            return False
        if key not in self.tracker.open_runs:
            trial = self.trials[key]
            params = tracked_params(trial.variant, trial.config)
            self.tracker.start_trial(
                self.launch, self.generation, key, trial.variant, trial.seed, params, self.commit, trial.stage
            )
        return True

    def started(self, key: str) -> None:
        if self._open(key):
            self.state.started(key)
            self.view.update()

    def episodes(self, key: str, points: list[CurvePoint]) -> None:
        if not self._open(key):
            return
        self.tracker.log_points(key, points)
        self.state.episodes(key, points)
        self.view.update()

    def checkpoint(self, key: str, blob: bytes) -> None:
        if not self._open(key):
            return
        self.tracker.log_checkpoint(key, blob)

    def restarted(self, key: str, reason: str) -> None:
        if not self.closed:
            self.tracker.discard_trial(key, reason)

    def finished(
        self, key: str, summary: dict[str, float], artifacts: Path | None, node: str, population: str = ""
    ) -> None:
        if not self._open(key):
            return
        size = str(self.members.get(key, 1))
        tags = {TAG_NODE: node, TAG_POPULATION: population or key, TAG_POPULATION_SIZE: size}
        tags[TAG_ROUND] = str(self.state.round)  # what a run is, as tags: never parsed back out of its key
        self.tracker.finish_trial(key, summary, artifacts, tags=tags)
        self.outcome.finished.append(key)
        self.summaries[key] = dict(summary)
        self.state.finished(key, bool(summary.get("solved")), summary.get("wall_s"), summary)
        if self.tuned is not None and self.trials[key].stage == "tune":
            self.tuned()
        self.view.update()

    def failed(self, key: str, message: str) -> None:
        if not self._open(key):
            return
        self.tracker.fail_trial(key, message)
        self.outcome.failed[key] = message
        self.state.failed(key)
        self.view.update()


def tune_run_name(experiment: str, launch_id: str) -> str:
    """Tune's folder for one launch, ``<storage_path>/<this>``: removed when the launch ends, or by the next
    launch if this one died. ``experiment``: its storage name (``experiment.storage_name``)."""
    return f"{experiment}-{launch_id[:8]}"


def ui_port() -> int:
    """The port ``make mlflow-ui`` serves on: ``PORT`` (the Makefile passes it through), else 5000."""
    try:
        return int(os.environ.get("PORT", "5000"))
    except ValueError:
        return 5000


def check_resources(experiment: Experiment, address: str | None) -> None:
    """A local run whose trial needs more CPUs than the machine has would wait forever ("pending")."""
    cpus = os.cpu_count() or 1
    if address is None and experiment.resources_per_trial > cpus:
        raise ConfigError(
            f"{experiment.path}: cpus_per_trial = {experiment.resources_per_trial:g} is more than this machine's "
            f"{cpus} CPUs, so no trial could start; valid: at most {cpus} (or --address a cluster with bigger nodes)"
        )


def reap_stale_runs(tracker: Tracker, storage_path: str) -> int:
    """Mark KILLED the runs a dead launch of this experiment left RUNNING (kill -9, a power cut) and remove
    its Tune folder; returns how many runs. Called with the launch lock held (the file beside an SQLite store,
    the store's own lease for a server or a database: ``lock.held_launch``), so no other launch of this
    experiment is alive on this store, from any machine: every RUNNING launch of it is a dead one's."""
    running = tracker.running_runs()
    launches = [r for r in running if r.data.tags.get(TAG_ROLE) == "launch"]
    stale = {r.info.run_id for r in launches}
    trials = [r.info.run_id for r in running if r.data.tags.get(TAG_ROLE) == "trial"]
    reason = "its launch's process died (found RUNNING by the next launch)"
    tracker.kill_runs(trials, reason)
    tracker.kill_runs(stale, "the launch's process died without closing it (found RUNNING by the next launch)")
    for launch_id in stale:
        shutil.rmtree(Path(storage_path) / tune_run_name(tracker.experiment_name, launch_id), ignore_errors=True)
    return len(trials) + len(stale)


def run_experiment(
    experiment: Experiment,
    tracking_uri: str | None = None,
    address: str | None = None,
    fresh: bool = False,
    max_concurrent: int | None = None,
    storage_path: str = "ray_results",
    show_progress: bool = True,
    command: str = "",
    only: Sequence[GridTrial] | None = None,
    started_at: float | None = None,
    log_estimates: bool = False,
    population: int = DEFAULT_POPULATION,
    judge: Judge | None = None,
) -> RunOutcome:
    """Run every trial of ``experiment`` (or of ``only``, a part of its grid) that has no finished run in the
    current generation. ``started_at``: the command's ``time.monotonic()`` start, for the progress view's clock.
    ``log_estimates``: keep every time-left estimate in ``outcome.view.estimates`` (``make bench``).
    ``population``: at most this many trials train together as one population (``launch.plan``); 1: each alone.
    ``judge``: with seeds in rounds (``experiment.rounds``), the sequential rule that decides after each round who
    gets more seeds (``reporting.rounds.judge_for``); ``None``: round 1 only.

    Every check that can fail without Ray (the grid, the CPUs, the store, another launch) fails first. Holds
    the experiment's launch lock throughout (``LaunchLocked`` if another launch has it)."""
    trials = expand(experiment)
    check_resources(experiment, address)
    tracker = Tracker(tracking_uri, experiment.name)
    with tracker.hold_launch(f"experiment {experiment.name!r}", command):
        reaped = reap_stale_runs(tracker, storage_path)
        outcome = _run_locked(
            experiment, trials, tracker, address, fresh, max_concurrent, storage_path, show_progress, command,
            only, started_at, log_estimates, population, judge,
        )  # fmt: skip
        outcome.reaped = reaped
        return outcome


def _run_locked(
    experiment: Experiment,
    trials: list[GridTrial],
    tracker: Tracker,
    address: str | None,
    fresh: bool,
    max_concurrent: int | None,
    storage_path: str,
    show_progress: bool,
    command: str,
    only: Sequence[GridTrial] | None,
    started_at: float | None,
    log_estimates: bool = False,
    population: int = DEFAULT_POPULATION,
    judge: Judge | None = None,
) -> RunOutcome:
    generation = (None if fresh else tracker.latest_generation()) or uuid.uuid4().hex[:12]
    evaluation = trials if only is None else list(only)
    wanted = {t.variant for t in evaluation}
    plan = StagePlan(experiment, evaluation, [t for t in tuning_trials(experiment) if t.variant in wanted])
    # Selection on resume reads the tuning trials finished by earlier launches back from the store.
    finished_runs = {r.key: r.metrics for r in tracker.trial_runs(generation) if r.status == "FINISHED"}
    finished_before = set(finished_runs)
    choices = plan.choices(finished_runs)
    known = unique([*plan.tuning, *evaluation, *plan.chosen(choices)], set())
    todo = [t for t in known if t.key not in finished_before]
    rounds = Rounds(experiment, wanted, judge, started_at) if experiment.rounds and judge else None
    if rounds and not todo:  # round 1 is done: the next round open comparisons ask for (none: all decided)
        todo = rounds.next_round(choices, finished_runs)
        known += todo
    outcome = RunOutcome(
        experiment.name,
        generation,
        None,
        skipped=len(known) - len(todo),
        total=len(known),
        ui_link=tracker.ui_link(ui_port()),
    )
    if not todo:
        outcome.rounds = rounds.document() if rounds else None
        return outcome
    from ablate.launch.scheduler import ClusterOptions, ensure_ray, largest_node_cpus, run_trials, stop_ray

    if show_progress:
        print(f"{len(todo)} trial(s) to run; starting Ray ...", flush=True)
    started_ray = ensure_ray(address)  # an unreachable cluster fails here, in seconds, before a launch is recorded
    biggest = largest_node_cpus()
    if experiment.resources_per_trial > biggest:  # a joined cluster: no node could ever start a trial
        if started_ray:
            stop_ray()
        raise ConfigError(
            f"{experiment.path}: cpus_per_trial = {experiment.resources_per_trial:g} is more than the largest node "
            f"of the Ray cluster has ({biggest:g} CPUs), so no trial could start; valid: at most {biggest:g}"
        )
    # Trials a killed launch left with a checkpoint continue from it.
    resume = tracker.latest_checkpoints(generation, (t.key for t in todo))
    commit = git_commit()
    extra = rounds.finished_trials(choices, finished_runs) if rounds else []  # later rounds' seeds
    grid = grid_document(experiment, unique([*trials, *extra], set()))
    launch = tracker.start_launch(
        generation,
        name=f"{experiment.name} {time.strftime('%Y-%m-%d %H:%M:%S')}",
        tags={
            "mlflow.source.git.commit": commit,
            "ablate.command": command,
            "ablate.experiment_file": experiment.path,
            TAG_HOST: socket.gethostname(),
            TAG_PID: str(os.getpid()),
        },
        files={
            "experiment.toml": Path(experiment.path).read_text(encoding="utf-8-sig"),
            "grid.json": json.dumps(grid, indent=1),
            "environment.json": json.dumps(environment_document(), indent=1),
        },
    )
    outcome.launch_run_id = launch
    slots = max_concurrent or (None if address else max(int((os.cpu_count() or 1) / experiment.resources_per_trial), 1))
    # What each trial took when an earlier launch ran it: the estimate's first guess, and the order's.
    prior, prior_episodes = tracker.earlier_runs(t.key for t in todo)
    todo = schedule_order(todo, prior)
    # Populations: each holds a slot until its last member ends, which the estimate sees through their groups.
    cores = slots or max(int(biggest), 1)
    populations = partial(plan_populations, cap=population, slots=cores)

    def groups(trials: Sequence[GridTrial]) -> list[list[str]]:
        return [p.keys for p in populations(trials)]

    # Stage 2 of the tuned variants not chosen yet, for the estimate: as the finished tuning trials would
    # choose now (each variant's best candidate so far), asked again as each one ends.
    unchosen = {t.variant for t in plan.tuning} - set(choices)
    known_keys = {t.key for t in known}

    def provisional(summaries: Mapping[str, Mapping[str, float]]) -> list[GridTrial]:
        trials = plan.provisional({**finished_runs, **summaries}, known_keys)
        return [t for t in trials if t.variant in unchosen]

    stand_ins = provisional({}) if unchosen else []
    state = LaunchState(
        experiment.name, todo, len(finished_before), slots, started_at, prior, prior_episodes, groups(todo),
        stand_ins, groups(stand_ins), stage_coming=bool(unchosen),
    )  # fmt: skip
    view = ProgressView(state, show_progress, log_estimates)
    outcome.view = view
    recorder = _Recorder(tracker, launch, generation, {t.key: t for t in todo}, commit, state, view, outcome)

    def may_follow() -> None:  # the rounds that may still follow: the most the launch can still run
        if rounds is not None:
            possible = rounds.possible(choices, set(state.trials) | finished_before)
            state.set_possible(possible, groups([t for ts in possible for t in ts]))

    def restage() -> None:  # a tuning trial ended: stage 2's stand-ins as the choice would be now
        try:
            later = provisional(recorder.summaries) if state.stage_coming else []
        except Exception:  # noqa: BLE001 - an estimate never stops a launch: keep the stand-ins
            return
        state.set_later(later, groups(later))

    recorder.tuned = restage if unchosen else None
    may_follow()
    options = ClusterOptions(
        address,
        max_concurrent,
        experiment.resources_per_trial,
        experiment.gpus_per_trial,
        storage_path,
    )
    run_name = tune_run_name(tracker.experiment_name, launch)
    try:
        if plan.tuning and wanted <= set(choices):
            tracker.log_file(launch, "tuning.json", json.dumps(tuning_document(experiment, choices), indent=1))
        if rounds and rounds.ran:  # a resumed launch starts in a later round
            state.name, state.round = rounds.announce(show_progress), rounds.ran[-1]["round"]
        with view:
            run_trials(recorder.planned(populations(todo)), recorder, options, run_name=run_name, resume=resume)

        def run_later(later: list[GridTrial]) -> None:  # stage 2, a round of seeds: after what ran before
            todo_after = [t for t in later if t.key not in finished_before]
            outcome.total += len(later)
            outcome.skipped += len(later) - len(todo_after)
            # Seeds interleaved, as in stage 1; the same state, so what stage 1 taught of costs carries over.
            costs, episodes = tracker.earlier_runs(t.key for t in todo_after)  # earlier launches' runs of them
            todo_after = schedule_order(todo_after, costs)
            state.add_trials(todo_after, costs, episodes, groups(todo_after))
            may_follow()
            view.update()
            if todo_after:
                recorder.trials |= {t.key: t for t in todo_after}
                with view:
                    resume = tracker.latest_checkpoints(generation, (t.key for t in todo_after))
                    run_trials(
                        recorder.planned(populations(todo_after)), recorder, options, run_name=run_name, resume=resume
                    )

        if plan.tuning and not wanted <= set(choices):
            # Stage 2: every variant whose tuning trials all finished, at its chosen values.
            choices = plan.choices(finished_runs | recorder.summaries)
            tracker.log_file(launch, "tuning.json", json.dumps(tuning_document(experiment, choices), indent=1))
            run_later(unique(plan.chosen(choices), {t.key for t in known}))
        while rounds is not None:  # then rounds of seeds, until the primary comparisons are decided
            later = rounds.next_round(choices, finished_runs | recorder.summaries)
            tracker.log_file(launch, "rounds.json", json.dumps(rounds.document(), indent=1))
            if not later:
                may_follow()  # none: the upper figure is the launch's end
                break
            grid["trials"] += [{"key": t.key, "variant": t.variant, "seed": t.seed} for t in later]
            tracker.log_file(launch, "grid.json", json.dumps(grid, indent=1))
            state.name, state.round = rounds.announce(show_progress), rounds.ran[-1]["round"]
            run_later(later)
        outcome.rounds = rounds.document() if rounds else None
    except KeyboardInterrupt as interrupt:
        outcome.interrupted = True
        signum = getattr(interrupt, "signum", None) or (signals_received[-1] if signals_received else signal.SIGINT)
        outcome.signal_name = signal.Signals(signum).name
    except Exception as error:  # noqa: BLE001 - any scheduler or Ray error: the launch is recorded FAILED, with it
        outcome.error = f"{type(error).__name__}: {str(error).strip().splitlines()[0] if str(error).strip() else ''}"
    finally:
        with _signals_deferred():
            recorder.closed = True
            if outcome.interrupted:
                reason = f"interrupted ({outcome.signal_name}); a re-run starts it again"
            elif outcome.error:
                reason = f"the launch failed ({outcome.error}); a re-run starts it again"
            else:
                reason = "the scheduler ended without a result for this trial; a re-run starts it again"
            outcome.killed = tracker.kill_running_trials(launch, reason)
            failed = outcome.error or outcome.failed or outcome.killed
            status = "KILLED" if outcome.interrupted else "FAILED" if failed else "FINISHED"
            tracker.finish_launch(
                launch,
                status,
                {
                    "trials_finished": len(outcome.finished),
                    "trials_failed": len(outcome.failed),
                    "trials_killed": len(outcome.killed),
                },
                note=outcome.note(),
            )
            if started_ray:
                stop_ray()
    return outcome
