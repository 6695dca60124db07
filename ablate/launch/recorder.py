"""Scheduler events -> the tracker's MLflow writes and the launch's state, then the view redrawn: the one place a
trial's events land (on the driver: one MLflow writer)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ablate.launch.curve import CurvePoint
from ablate.launch.grid import GridTrial
from ablate.launch.mlflow_store import TAG_NODE, TAG_POPULATION, TAG_POPULATION_SIZE, TAG_ROUND
from ablate.launch.plan import Population
from ablate.launch.progress import ProgressView
from ablate.launch.records import tracked_params
from ablate.launch.state import LaunchState
from ablate.launch.tracking import Tracker

if TYPE_CHECKING:
    from ablate.launch.runner import RunOutcome


class Recorder:
    """The scheduler's one receiver of trial events (``scheduler.run_trials``)."""

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
        self,
        key: str,
        summary: dict[str, float],
        artifacts: Path | None,
        node: str,
        population: str = "",
        env: dict[str, str] | None = None,
    ) -> None:
        """``env``: what the trial ran against (``envs.record``), kept as its run's ``env.*`` params."""
        if not self._open(key):
            return
        size = str(self.members.get(key, 1))
        tags = {TAG_NODE: node, TAG_POPULATION: population or key, TAG_POPULATION_SIZE: size}
        tags[TAG_ROUND] = str(self.state.round)  # what a run is, as tags: never parsed back out of its key
        self.tracker.finish_trial(key, summary, artifacts, tags=tags, params=env)
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
