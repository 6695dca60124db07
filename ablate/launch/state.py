"""What a launch knows now: each trial's progress (``TrialProgress``) and the launch's (``LaunchState``), updated
by the scheduler's events and the runner's plan. Pure state: no estimate, no rendering, no Ray, no MLflow.
Events come on the driver's main thread while the view draws on its own: ``lock`` keeps them apart.
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

from ablate.env_spec import solve_threshold  # the env's threshold: Gymnasium, never torch, in the driver
from ablate.launch.grid import GridTrial, config_hash

RATE_REPORTS = 4
"""Reports (one per ~2 s per trial) that a running trial's recent pace is measured over."""

Groups = Sequence[Sequence[str]]
"""A plan's populations (``launch.plan``) as their members' keys, in the order they start."""


def populations_of(trials: Sequence[GridTrial], groups: Groups | None) -> dict[str, tuple[str, ...]]:
    """Each trial's population, by member key: its members' keys (without ``groups``: each trial alone)."""
    by_key = {key: tuple(group) for group in (groups or ()) for key in group}
    return {t.key: by_key.get(t.key, (t.key,)) for t in trials}


@dataclass
class TrialProgress:
    trial: GridTrial
    started_at: float | None = None
    ended_at: float | None = None
    episode: int = 0
    """Last episode reported."""
    rolling_mean: float | None = None
    """Rolling mean at the last episode reported (the final one once finished)."""
    state: str = "pending"
    """pending, running, done, failed."""
    solved: bool = False
    first_on_worker: bool = False
    """Started before any trial had ended: its time holds its worker's start (imports, the emulator's ROMs),
    which the trials after it on that worker do not pay."""
    wall_s: float | None = None
    """The trial's own training time (its summary's ``wall_s``), once finished."""
    train_s: float | None = None
    """The trial's own clock at the last episode reported (seconds since its training began)."""
    reports: deque[tuple[float, int, float | None]] = field(default_factory=lambda: deque(maxlen=RATE_REPORTS))
    """(time, episode, rolling mean) of the newest reports: the recent pace, which slows as a CartPole agent's
    episodes grow, and the recent climb towards the solve threshold."""

    episodes_run: int | None = None
    """Episodes it ran (its summary's), once finished: fewer than its budget when it stopped early (solved)."""
    profile: list[tuple[int, float, int]] = field(default_factory=list)
    """(episode, its own clock, its env steps) at every report: where its time went. A later trial with the same
    settings is held to it (``TimeLeft._pace``), which sees a machine that got busier or freer since."""

    pace_seen: tuple[tuple[int, int], float | None] | None = None
    """Its last ``TimeLeft._pace`` and what it was computed from (its reports, its finished peers): a pace
    changes only when one of them does, and the estimate runs after every event."""

    def at(self, episode: float) -> tuple[float, float] | None:
        """Its own clock and env steps at ``episode``, interpolated between its reports (0 at episode 0);
        ``None`` past its last report."""
        if not self.profile or episode > self.profile[-1][0]:
            return None
        i = bisect.bisect_left(self.profile, episode, key=lambda point: point[0])
        e1, s1, n1 = self.profile[i]
        e0, s0, n0 = self.profile[i - 1] if i else (0, 0.0, 0)
        f = 1.0 if e1 == e0 else (episode - e0) / (e1 - e0)
        return s0 + (s1 - s0) * f, n0 + (n1 - n0) * f

    @property
    def budget(self) -> int:
        return self.trial.config.max_episodes

    @cached_property
    def settings(self) -> tuple[str, str]:
        """Its variant and everything it trains with but the seed and the episode budget: a tuning trial and
        the evaluation trial at the same values share it."""
        return self.trial.variant, config_hash(replace(self.trial.config, seed=0, max_episodes=0))

    @cached_property
    def threshold(self) -> float | None:
        """The rolling mean at which it stops, solved (``run_trial``'s own rule)."""
        return solve_threshold(self.trial.config)

    @property
    def last_episode_reported(self) -> bool:
        """It reported the last episode it will run: its budget's, or the one that solved it (a trial stops
        there); what is left is writing its artifacts."""
        if self.episode >= self.budget:
            return True
        window = self.trial.config.solve_window
        if self.rolling_mean is None or self.episode < window:
            return False
        return self.threshold is not None and self.rolling_mean >= self.threshold

    def episodes_to_solve(self) -> float | None:
        """Episodes until its rolling mean reaches the solve threshold at its climb over the newest reports;
        ``None`` while it is not climbing (or has no threshold)."""
        if self.threshold is None or len(self.reports) < 2:
            return None
        (_, e0, m0), (_, e1, m1) = self.reports[0], self.reports[-1]
        if m0 is None or m1 is None or e1 <= e0 or m1 <= m0:
            return None
        return max((self.threshold - m1) * (e1 - e0) / (m1 - m0), self.trial.config.solve_window - e1, 0.0)

    def seconds_per_episode(self, now: float) -> float | None:
        """Over the newest reports when there are two, else by the trial's own clock (a worker's start and
        Tune's scheduling are not episodes: in a 4-episode Pong trial they are most of its time), else since
        the trial started."""
        if len(self.reports) >= 2 and self.reports[-1][1] > self.reports[0][1]:
            (t0, e0, _), (t1, e1, _) = self.reports[0], self.reports[-1]
            return (t1 - t0) / (e1 - e0)
        if self.started_at is None or not self.episode:
            return None
        if self.train_s:
            return self.train_s / self.episode
        return ((self.ended_at or now) - self.started_at) / self.episode


class LaunchState:
    """The launch's trials and what is known of them, as events and the runner's plan update it."""

    def __init__(
        self,
        name: str,
        trials: Sequence[GridTrial],
        already_done: int,
        slots: int | None = None,
        start: float | None = None,
        prior_costs: Mapping[str, float] | None = None,
        prior_episodes: Mapping[str, int] | None = None,
        groups: Groups | None = None,
        later: Sequence[GridTrial] = (),
        later_groups: Groups | None = None,
        stage_coming: bool = False,
        later_most: int | None = None,
    ) -> None:
        """``trials`` in the order they will start. ``slots``: populations that can run at once (``None``: the
        most seen running at once). ``start``: the ``time.monotonic()`` the command started at, so the clock
        includes imports and Ray's start. ``prior_costs``, ``prior_episodes``: seconds and episodes by trial key
        that earlier launches took (``Tracker.earlier_runs``). ``groups``: the populations the trials run in
        (a population holds a slot until its last member ends). ``later``: stand-ins for the trials of a stage
        not known yet, which start once every trial here has ended (a tuned ablation's trials at the chosen
        values), in ``later_groups``; ``stage_coming``, ``later_most``: as the attributes of those names."""
        self.name = name
        self.trials = {t.key: TrialProgress(t) for t in trials}
        self.variants = list(dict.fromkeys(t.variant for t in trials))
        self.already_done = already_done
        self.slots = slots
        self.population_of = populations_of(trials, groups)
        self.start = time.monotonic() if start is None else start
        self.first_start: float | None = None
        self.trials_end: float | None = None
        self.max_running = 0
        self.lock = threading.RLock()
        self.prior = dict(prior_costs or {})
        self.prior_episodes = dict(prior_episodes or {})
        self.gaps: list[float] = []
        """Seconds between a slot freeing and the next trial starting, one per start after an end."""
        self._freed: deque[float] = deque()
        """When slots freed that no trial has taken yet."""
        self.later: list[TrialProgress] = []
        self.later_population_of: dict[str, tuple[str, ...]] = {}
        self.set_later(later, later_groups)
        self.stage_coming = stage_coming or bool(later)
        """A later stage stands in ``later`` (or will, even while no stand-in stands for it): its trials join
        this phase."""
        self.later_most = len(later) if later_most is None else later_most
        """The most trials the later stage can add: the progress line's bound, which stand-ins never move."""
        self.phases: list[list[str]] = [[t.key for t in trials]]
        """The keys of each set of trials known together: the launch's, with the later stage that replaces its
        stand-ins; then each round of seeds."""
        self.possible: list[list[TrialProgress]] = []
        """Stand-ins for the trials later rounds may still add, round by round (``set_possible``)."""
        self.possible_population_of: dict[str, tuple[str, ...]] = {}
        self.round = 1
        """The round of seeds the trials running now belong to (1 without rounds)."""

    # --- events from the scheduler ------------------------------------------------------------------
    def started(self, key: str) -> None:
        with self.lock:
            now = time.monotonic()
            trial = self.trials[key]
            trial.state, trial.started_at, trial.episode, trial.rolling_mean = "running", now, 0, None
            trial.reports.clear()
            trial.profile.clear()
            trial.pace_seen = None
            self.first_start = self.first_start or now
            trial.first_on_worker = not any(t.ended_at for t in self.trials.values())
            running = {self.population_of.get(k, (k,)) for k, t in self.trials.items() if t.state == "running"}
            self.max_running = max(self.max_running, len(running))
            mates = [k for k in self.population_of.get(key, (key,)) if k != key]
            if self._freed and not any(self.trials[k].started_at for k in mates if k in self.trials):
                self.gaps.append(now - self._freed.popleft())  # its population's first member takes the slot

    def episodes(self, key: str, rows: Sequence[Any]) -> None:
        """``rows``: the trial's newest episodes (``EpisodeMetrics``), oldest first."""
        if not rows:
            return
        with self.lock:
            trial = self.trials[key]
            trial.episode, trial.rolling_mean = rows[-1].episode, rows[-1].rolling_mean
            trial.train_s = getattr(rows[-1], "wall_s", None)
            steps = getattr(rows[-1], "env_steps", None)
            if trial.train_s is not None and steps is not None:
                trial.profile.append((trial.episode, trial.train_s, steps))
            trial.reports.append((time.monotonic(), trial.episode, trial.rolling_mean))

    def finished(
        self, key: str, solved: bool, wall_s: float | None = None, summary: Mapping[str, float] | None = None
    ) -> None:
        """``wall_s``, ``summary``: its summary's training time and metrics (``TrialProgress`` keeps what it reads)."""
        trial = self.trials[key]
        trial.wall_s = wall_s
        if summary and summary.get("episodes_run") is not None:
            trial.episodes_run = int(summary["episodes_run"])
        self._end(key, "done", solved)

    def failed(self, key: str) -> None:
        self._end(key, "failed", False)

    def _end(self, key: str, state: str, solved: bool) -> None:
        with self.lock:
            trial = self.trials[key]
            trial.state, trial.solved, trial.ended_at = state, solved, time.monotonic()
            if not self.count("pending") and not self.count("running") and not self.later and not self.stage_coming:
                self.trials_end = trial.ended_at
            if self.count("pending") and all(self.trials[k].ended_at for k in self.population_of.get(key, (key,))):
                self._freed.append(trial.ended_at)  # its population's slot

    # --- the runner's plan ----------------------------------------------------------------------------
    def set_later(self, trials: Sequence[GridTrial], groups: Groups | None = None) -> None:
        """The stand-ins of the later stage, as the finished tuning trials would choose now."""
        with self.lock:
            self.later = [TrialProgress(t) for t in trials]
            self.later_population_of = populations_of(trials, groups)

    def set_possible(self, rounds: Sequence[Sequence[GridTrial]], groups: Groups | None = None) -> None:
        """The trials later rounds may still add, round by round (``Rounds.possible``), in ``groups``."""
        with self.lock:
            self.possible = [[TrialProgress(t) for t in trials] for trials in rounds if trials]
            self.possible_population_of = populations_of([t for ts in rounds for t in ts], groups)

    def add_trials(
        self,
        trials: Sequence[GridTrial],
        prior_costs: Mapping[str, float] | None = None,
        prior_episodes: Mapping[str, int] | None = None,
        groups: Groups | None = None,
    ) -> None:
        """The next stage's trials, now known, in the order they will start (none: it has nothing to run), with
        what earlier launches' runs of them took (as the constructor's). They replace the ``later`` stand-ins;
        what this launch learned of costs carries over."""
        with self.lock:
            self.prior |= prior_costs or {}
            self.prior_episodes |= prior_episodes or {}
            self.population_of |= populations_of(trials, groups)
            if self.stage_coming:  # the stage its stand-ins stood for
                self.phases[-1].extend(t.key for t in trials)
            elif trials:  # a round of seeds: the estimate could not see it coming
                self.phases.append([t.key for t in trials])
            for t in trials:
                self.trials[t.key] = TrialProgress(t)
                if t.variant not in self.variants:
                    self.variants.append(t.variant)
            self.later, self.later_population_of, self.stage_coming = [], {}, False
            self._freed.clear()  # the next stage starts on slots that are all free: no wait to count
            if trials:
                self.trials_end = None
            elif not self.count("pending") and not self.count("running"):
                self.trials_end = max((t.ended_at for t in self.trials.values() if t.ended_at), default=None)

    # --- reading --------------------------------------------------------------------------------------
    def count(self, state: str) -> int:
        return sum(t.state == state for t in self.trials.values())

    @property
    def ended(self) -> int:
        return self.count("done") + self.count("failed")

    @property
    def first_ended(self) -> tuple[int, int]:
        """(trials ended, trials) of the launch's first phase: until a quarter have ended, costs are guesses."""
        first = self.phases[0]
        return sum(self.trials[k].ended_at is not None for k in first), len(first)

    @property
    def at_most_more(self) -> int:
        """Trials later rounds may still add (0 without rounds, or once every comparison is decided)."""
        return sum(len(r) for r in self.possible)
