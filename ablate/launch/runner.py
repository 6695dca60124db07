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
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ablate.config import ConfigError
from ablate.experiment import Experiment
from ablate.launch.grid import GridTrial, plotted_seeds, schedule_order
from ablate.launch.mlflow_store import (
    TAG_HOST,
    TAG_PID,
    TAG_ROLE,
)
from ablate.launch.plan import LaunchPlan, plan_populations
from ablate.launch.progress import ProgressView, total_words
from ablate.launch.recorder import Recorder
from ablate.launch.records import TorchKernels, environment_document, git_commit, grid_document
from ablate.launch.rounds import Rounds
from ablate.launch.state import LaunchState
from ablate.launch.tracking import START_METRIC, Tracker
from ablate.launch.tuning import tuning_document, unique

# ``ablate.launch.scheduler`` (Ray: seconds to import) is imported only once there is a trial to run, so a
# re-run with nothing left answers from the store alone.


signals_received: list[int] = []
"""Signals ``raise_interrupted`` turned into a ``KeyboardInterrupt`` (Tune re-raises a plain one): which stopped
the launch, cleanly (workers stopped, running trials marked KILLED)."""


def raise_interrupted(signum: int, frame: object) -> None:
    signals_received.append(signum)
    raise KeyboardInterrupt(signal.Signals(signum).name)


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
    """The MLflow UI's comparison of this experiment's variants (``Tracker.ui_link``)."""
    ui_served: bool = False
    """The store is a tracking server, which serves that UI itself (else: ``make mlflow-ui``)."""
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
    report: Any = field(default=None, repr=False)
    """That report (``reporting.document.ReportResult``, from ``api.launch``); ``report_note``: why none;
    ``report_seconds``: its time."""
    report_note: str = ""
    report_seconds: float | None = None
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


def tune_run_name(experiment: str, launch_id: str) -> str:
    """Tune's folder for one launch, ``<storage_path>/<this>``: removed when the launch ends, or by the next
    launch if this one died. ``experiment``: its storage name (``experiment.storage_name``)."""
    return f"{experiment}-{launch_id[:8]}"


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
    its Tune folder; returns how many runs. Called with the launch lock held (``lock.held_launch``), so no other
    launch of this experiment is alive on this store, from any machine: every RUNNING launch of it is a dead one's."""
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


def run_plan(plan: LaunchPlan) -> RunOutcome:
    """Run every trial of ``plan`` that has no finished run in the current generation.

    Every check that can fail without Ray (the grid, the CPUs, the store, another launch) fails first. Holds
    the experiment's launch lock throughout (``LaunchLocked`` if another launch has it)."""
    check_resources(plan.experiment, plan.address)
    kernels = TorchKernels()  # the machine record's one torch question, beside the store's opening
    try:
        tracker = Tracker(plan.tracking_uri, plan.experiment.name)
        with tracker.hold_launch(f"experiment {plan.experiment.name!r}", plan.command):
            reaped = reap_stale_runs(tracker, plan.storage_path)
            outcome = _Launch(plan, tracker, kernels).run()
            outcome.reaped = reaped
            return outcome
    finally:
        kernels.close()


class _Launch:
    """One launch, with the experiment's lock held, as its plan runs: its methods are the plan's steps, in
    the order ``run`` takes them."""

    recorder: Recorder | None = None
    state: LaunchState | None = None
    """Both set by ``watch``; ``close`` runs whatever step failed before it."""

    def __init__(self, plan: LaunchPlan, tracker: Tracker, kernels: TorchKernels) -> None:
        self.experiment, self.plan, self.tracker, self.kernels = plan.experiment, plan, tracker, kernels
        self.generation = (None if plan.fresh else tracker.latest_generation()) or uuid.uuid4().hex[:12]
        evaluation = plan.trials
        self.wanted = {t.variant for t in evaluation}
        # Selection on resume reads the tuning trials finished by earlier launches back from the store.
        self.finished_runs = {r.key: r.metrics for r in tracker.trial_runs(self.generation) if r.status == "FINISHED"}
        self.choices = self.plan.choices(self.finished_runs)
        self.unchosen = {t.variant for t in self.plan.tuning} - set(self.choices)
        self.known = unique([*self.plan.tuning, *evaluation, *self.plan.chosen(self.choices)], set())
        judge, rounds = plan.judge, plan.experiment.rounds
        self.rounds = Rounds(plan.experiment, self.wanted, judge, plan.started_at) if rounds and judge else None

    def run(self) -> RunOutcome:
        todo = self.todo()
        self.outcome = RunOutcome(
            self.experiment.name,
            self.generation,
            None,
            skipped=len(self.known) - len(todo),
            total=len(self.known),
            ui_link=self.tracker.ui_link(),
            ui_served=self.tracker.serves_ui,
        )
        if not todo:
            self.outcome.rounds = self.rounds.document() if self.rounds else None
            return self.outcome
        self.start(todo)
        try:
            self.stages(self.watch(todo))
        except KeyboardInterrupt:
            self.outcome.interrupted = True
            self.outcome.signal_name = signal.Signals(signals_received[-1] if signals_received else signal.SIGINT).name
        except Exception as error:  # noqa: BLE001 - any scheduler or Ray error: the launch is recorded FAILED
            first = str(error).strip().splitlines()[0] if str(error).strip() else ""
            self.outcome.error = f"{type(error).__name__}: {first}"
        finally:
            self.close()
        return self.outcome

    def todo(self) -> list[GridTrial]:
        """What this launch runs first: every known trial without a finished run; on a resume after round 1,
        the next round the open comparisons ask for (none: all decided)."""
        todo = [t for t in self.known if t.key not in self.finished_runs]
        if self.rounds and not todo:
            todo = self.rounds.next_round(self.choices, self.finished_runs)
            self.known += todo
        return todo

    def start(self, todo: list[GridTrial]) -> None:
        """Ray (an unreachable cluster fails here, in seconds, before a launch is recorded), then the launch's
        MLflow run with the files the report reads: the experiment, the grid, the machine."""
        from ablate.launch import scheduler

        experiment, plan = self.experiment, self.plan
        if plan.show_progress:
            print(f"trials to run: {total_words(len(todo), *self.most(todo))}; starting Ray ...", flush=True)
        # The machine's record (its torch kernels asked of a child since the launch began) and git: while Ray starts.
        with ThreadPoolExecutor(1, thread_name_prefix="ablate-record") as pool:
            machine, commit = pool.submit(environment_document, self.kernels), pool.submit(git_commit)
            self.started_ray = scheduler.ensure_ray(plan.address)
            environment, self.commit = machine.result(), commit.result()
        self.biggest = scheduler.largest_node_cpus()
        if experiment.resources_per_trial > self.biggest:  # a joined cluster: no node could ever start a trial
            if self.started_ray:
                scheduler.stop_ray()
            raise ConfigError(
                f"{experiment.path}: cpus_per_trial = {experiment.resources_per_trial:g} is more than the largest "
                f"node of the Ray cluster has ({self.biggest:g} CPUs), so no trial could start; valid: at most "
                f"{self.biggest:g}"
            )
        extra = self.rounds.finished_trials(self.choices, self.finished_runs) if self.rounds else []  # later rounds'
        self.grid = grid_document(experiment, unique([*plan.grid, *extra], set()))
        self.launch = self.tracker.start_launch(
            self.generation,
            name=f"{experiment.name} {time.strftime('%Y-%m-%d %H:%M:%S')}",
            tags={
                "mlflow.source.git.commit": self.commit,
                "ablate.command": plan.command,
                "ablate.experiment_file": experiment.path,
                TAG_HOST: socket.gethostname(),
                TAG_PID: str(os.getpid()),
            },
            files={
                "experiment.toml": Path(experiment.path).read_text(encoding="utf-8-sig"),
                "grid.json": json.dumps(self.grid, indent=1),
                "environment.json": json.dumps(environment, indent=1),
            },
        )
        self.outcome.launch_run_id = self.launch

    def watch(self, todo: list[GridTrial]) -> list[GridTrial]:
        """The launch's state (stage 2's stand-ins and later rounds counted from the start), its view and the
        recorder that turns scheduler events into MLflow writes and state updates; ``todo`` in start order."""
        experiment, plan = self.experiment, self.plan
        cpus = max(int((os.cpu_count() or 1) / experiment.resources_per_trial), 1)
        slots = plan.max_concurrent or (None if plan.address else cpus)
        prior, prior_episodes = self.tracker.earlier_runs(t.key for t in todo)
        todo = schedule_order(todo, prior)
        self.cores = slots or max(int(self.biggest), 1)
        self.known_keys = {t.key for t in self.known}  # what stage 2 adds is what is not among them
        self.state = LaunchState(
            experiment.name, todo, self.outcome.skipped, slots, plan.started_at, prior, prior_episodes,
            self.groups(todo), stage_coming=bool(self.unchosen), later_most=self.most(todo)[0],
        )  # fmt: skip
        self.view = ProgressView(self.state, plan.show_progress, plan.log_estimates)
        self.outcome.view = self.view
        trials = {t.key: t for t in todo}
        self.recorder = Recorder(
            self.tracker, self.launch, self.generation, trials, self.commit, self.state, self.view, self.outcome
        )
        self.recorder.tuned = self.restage if self.unchosen else None
        self.restage()
        self.may_follow()
        return todo

    def most(self, todo: list[GridTrial]) -> tuple[int, int]:
        """The most trials stage 2 and later rounds can add to ``todo``: a tuned variant not chosen yet runs at
        most one trial per evaluation seed at its chosen values; rounds, every open comparison to ``max`` seeds."""
        stage = sum(t.variant in self.unchosen for t in self.plan.trials)
        rounds = 0
        if self.rounds is not None:
            seen = {t.key for t in todo} | self.finished_runs.keys()
            rounds = sum(len(ts) for ts in self.rounds.possible(self.choices, seen))
        return stage, rounds

    def groups(self, trials: Sequence[GridTrial]) -> list[list[str]]:
        """The keys of each population ``trials`` will run in: how the estimate sees them."""
        return [p.keys for p in plan_populations(trials, self.plan.population, self.cores)]

    def restage(self) -> None:
        """The launch began or a tuning trial ended: stage 2's stand-ins (``LaunchPlan.provisional``) for the
        estimate."""
        try:
            finished = {**self.finished_runs, **self.recorder.summaries}
            trials = self.plan.provisional(finished, self.known_keys) if self.state.stage_coming else []
        except Exception:  # noqa: BLE001 - an estimate never stops a launch: keep the stand-ins
            return
        later = [t for t in trials if t.variant in self.unchosen]
        self.state.set_later(later, self.groups(later))

    def may_follow(self) -> None:
        """The rounds that may still follow: the most the launch can still run."""
        if self.rounds is not None:
            possible = self.rounds.possible(self.choices, set(self.state.trials) | self.finished_runs.keys())
            self.state.set_possible(possible, self.groups([t for ts in possible for t in ts]))

    def stages(self, todo: list[GridTrial]) -> None:
        """Stage 1 (tuning, or the grid); stage 2 at each variant's chosen values; then rounds of seeds until the
        primary comparisons are decided."""
        plan, rounds = self.plan, self.rounds
        if plan.tuning and self.wanted <= set(self.choices):
            self.log_json("tuning.json", tuning_document(self.experiment, self.choices))
        if rounds and rounds.ran:  # a resumed launch starts in a later round
            self.state.name, self.state.round = rounds.announce(self.plan.show_progress)
        self.stage(todo)
        if plan.tuning and not self.wanted <= set(self.choices):
            self.choices = plan.choices(self.finished_runs | self.recorder.summaries)
            self.log_json("tuning.json", tuning_document(self.experiment, self.choices))
            self.later(unique(plan.chosen(self.choices), self.known_keys))
        while rounds is not None:
            later = rounds.next_round(self.choices, self.finished_runs | self.recorder.summaries)
            self.log_json("rounds.json", rounds.document())
            if not later:
                self.may_follow()  # none: the upper figure is the launch's end
                break
            self.grid["trials"] += [{"key": t.key, "variant": t.variant, "seed": t.seed} for t in later]
            self.log_json("grid.json", self.grid)
            self.state.name, self.state.round = rounds.announce(self.plan.show_progress)
            self.later(later)
        self.outcome.rounds = rounds.document() if rounds else None

    def log_json(self, name: str, document: object) -> None:
        self.tracker.log_file(self.launch, name, json.dumps(document, indent=1))

    def stage(self, todo: list[GridTrial]) -> None:
        """Run ``todo`` as populations; trials a killed launch left with a checkpoint continue from it."""
        self.recorder.trials |= {t.key: t for t in todo}
        resume = self.tracker.latest_checkpoints(self.generation, (t.key for t in todo))
        from ablate.launch import scheduler

        seeds = plotted_seeds(self.experiment)
        plotted = {t.key for t in todo if t.seed in seeds.get(t.variant, ())}
        populations = self.recorder.planned(plan_populations(todo, self.plan.population, self.cores, plotted))
        with self.view:
            plan, experiment = self.plan, self.experiment
            cluster = scheduler.ClusterOptions(
                plan.max_concurrent, experiment.resources_per_trial, experiment.gpus_per_trial, plan.storage_path
            )  # fmt: skip
            run_name = tune_run_name(self.tracker.experiment_name, self.launch)
            scheduler.run_trials(populations, self.recorder, cluster, run_name=run_name, resume=resume)

    def later(self, trials: list[GridTrial]) -> None:
        """Stage 2, or a round of seeds, after what ran before: seeds interleaved as in stage 1, in the same
        state, so what stage 1 taught of costs carries over."""
        todo = [t for t in trials if t.key not in self.finished_runs]
        self.outcome.total += len(trials)
        self.outcome.skipped += len(trials) - len(todo)
        self.state.already_done = self.outcome.skipped  # the summary's count: this launch's trials run before
        costs, episodes = self.tracker.earlier_runs(t.key for t in todo)  # earlier launches' runs of them
        todo = schedule_order(todo, costs)
        self.state.add_trials(todo, costs, episodes, self.groups(todo))
        self.may_follow()
        self.view.update()
        if todo:
            self.stage(todo)

    def close(self) -> None:
        """Mark what did not finish, close the launch's run with what happened, stop the Ray this launch
        started: uninterrupted by a second Ctrl-C."""
        outcome, tracker = self.outcome, self.tracker
        with _signals_deferred():
            if self.recorder is not None:
                self.recorder.closed = True
            if outcome.interrupted:
                reason = f"interrupted ({outcome.signal_name}); a re-run starts it again"
            elif outcome.error:
                reason = f"the launch failed ({outcome.error}); a re-run starts it again"
            else:
                reason = "the scheduler ended without a result for this trial; a re-run starts it again"
            outcome.killed = tracker.kill_running_trials(self.launch, reason)
            failed = outcome.error or outcome.failed or outcome.killed
            status = "KILLED" if outcome.interrupted else "FAILED" if failed else "FINISHED"
            counts = {
                "trials_finished": len(outcome.finished),
                "trials_failed": len(outcome.failed),
                "trials_killed": len(outcome.killed),
            }
            if self.state is not None and self.state.first_start is not None:  # the next --dry-run's start cost
                counts[START_METRIC] = round(self.state.first_start - self.state.start, 3)
            tracker.finish_launch(self.launch, status, counts, note=outcome.note())
            if self.started_ray:
                from ablate.launch import scheduler

                scheduler.stop_ray()
