"""The live terminal view of an ablation: a running clock from the command's start, the time left from the
expected cost of every trial still to run, a row per running trial, per-variant figures over seeds.

A panel redrawn four times a second on a terminal (the clock runs while Ray starts); a line every 10 s otherwise.
"""

from __future__ import annotations

import statistics
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table

from ablate.launch.clock import clock
from ablate.launch.estimate import TimeLeft, TrialProgress
from ablate.launch.grid import GridTrial

MAX_RUNNING_ROWS = 16
"""Rows of running trials shown; more are summarised in one line."""


class ProgressView(TimeLeft):
    """Events in (``started``, ``episodes``, ``finished``, ``failed``), a panel out. Events come on the driver's
    main thread, the panel is drawn on rich's refresh thread: a lock keeps them apart."""

    def __init__(
        self,
        name: str,
        trials: Sequence[GridTrial],
        already_done: int,
        enabled: bool = True,
        slots: int | None = None,
        start: float | None = None,
        prior_costs: Mapping[str, float] | None = None,
        log_estimates: bool = False,
        later: Sequence[GridTrial] = (),
        provisional: Callable[[Mapping[str, Mapping[str, float]]], Sequence[GridTrial]] | None = None,
        prior_episodes: Mapping[str, int] | None = None,
        populations: Callable[[Sequence[GridTrial]], Sequence[Sequence[str]]] | None = None,
    ) -> None:
        """``trials`` in the order they will start. ``slots``: trials (populations) that can run at once
        (``None``: the most seen running at once). ``start``: the ``time.monotonic()`` the command started at,
        so the clock includes imports and Ray's start. ``prior_costs``: seconds by trial key that earlier launches took
        (``Tracker.earlier_runs``). ``log_estimates``: keep every estimate in ``estimates`` (``make bench``).
        ``later``: stand-ins for the trials not known yet that start once every trial here has ended (a tuned
        ablation's trials at the chosen values); ``add_trials`` puts the real ones in when they are known.
        ``provisional``: the later trials as the finished trials' summaries (key -> metrics) say they would
        be if stage 1 ended now (each variant at its best candidate so far), asked again as tuning trials end.
        ``prior_episodes``: episodes by trial key that earlier launches ran (``Tracker.earlier_runs``).
        ``populations``: the launch's plan (``launch.plan``) as member keys: a population holds one of ``slots``
        until its last member ends (``None``: every trial alone)."""
        self.name = name
        self.trials = {t.key: TrialProgress(t) for t in trials}
        self.variants = list(dict.fromkeys(t.variant for t in trials))
        self.already_done = already_done
        self.slots = slots
        self.populations = populations
        self.population_of = self.plan(trials)
        self.start = time.monotonic() if start is None else start
        self.first_start: float | None = None
        self.trials_end: float | None = None
        self.max_running = 0
        self.enabled = enabled
        self.tty = sys.stdout.isatty()
        self.console = Console()
        self.live: Live | None = None
        self.last_line = 0.0
        self.lock = threading.Lock()
        self.prior = dict(prior_costs or {})
        self.prior_episodes = dict(prior_episodes or {})
        self.gaps: list[float] = []
        """Seconds between a slot freeing and the next trial starting, one per start after an end."""
        self._freed: deque[float] = deque()
        """When slots freed that no trial has taken yet."""
        self.log_estimates = log_estimates
        self.later = [TrialProgress(t) for t in later]
        self.provisional = provisional
        self.summaries: dict[str, Mapping[str, float]] = {}
        self.estimates: list[tuple[float, int, float | None]] = []
        """(seconds since ``start``, trials ended, the estimate in seconds) after every event."""
        self._stage_coming = bool(later or provisional)
        """A later stage stands in ``later`` (or ``provisional`` would say it): its trials join this phase."""
        self.phases: list[tuple[int, list[str]]] = [(0, [t.key for t in trials])]
        """(index of its first estimate, its trials' keys) for each set of trials the view knew of together: the
        launch's, with the later stage that replaces its stand-ins; then each round of seeds."""

    # --- events -----------------------------------------------------------------------------------
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
            self._log_estimate(now)
        self.refresh()

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
            self._log_estimate(time.monotonic())
        self.refresh()

    def finished(
        self, key: str, solved: bool, wall_s: float | None = None, summary: Mapping[str, float] | None = None
    ) -> None:
        """``wall_s``: the trial's own training time (its summary's), which tells its worker's start apart.
        ``summary``: its summary metrics (episodes run; a tuning trial's metric for ``provisional``)."""
        trial = self.trials[key]
        trial.wall_s = wall_s
        if summary:
            self.summaries[key] = summary
            if summary.get("episodes_run") is not None:
                trial.episodes_run = int(summary["episodes_run"])
        self._end(key, "done", solved)

    def failed(self, key: str) -> None:
        self._end(key, "failed", False)

    def _end(self, key: str, state: str, solved: bool) -> None:
        with self.lock:
            trial = self.trials[key]
            trial.state, trial.solved, trial.ended_at = state, solved, time.monotonic()
            if not self._count("pending") and not self._count("running") and not self.later:
                self.trials_end = trial.ended_at
            if self._count("pending") and all(self.trials[k].ended_at for k in self.population_of.get(key, (key,))):
                self._freed.append(trial.ended_at)  # its population's slot
            if self.provisional and trial.trial.stage == "tune":
                try:
                    self.later = [TrialProgress(t) for t in self.provisional(dict(self.summaries))]
                except Exception:  # noqa: BLE001 - an estimate never stops a launch: keep the stand-ins
                    self.provisional = None
            self._log_estimate(trial.ended_at)
        self.refresh()

    def add_trials(
        self,
        trials: Sequence[GridTrial],
        prior_costs: Mapping[str, float] | None = None,
        prior_episodes: Mapping[str, int] | None = None,
    ) -> None:
        """The next stage's trials, now known, in the order they will start (none: it has nothing to run), with
        what earlier launches' runs of them took (as the constructor's). They replace the ``later`` guesses;
        what this launch learned of costs carries over."""
        with self.lock:
            self.prior |= prior_costs or {}
            self.prior_episodes |= prior_episodes or {}
            self.population_of |= self.plan(trials)
            if self._stage_coming:  # the stage its stand-ins stood for
                self.phases[-1][1].extend(t.key for t in trials)
            elif trials:  # a round of seeds: the estimate could not see it coming
                self.phases.append((len(self.estimates), [t.key for t in trials]))
            for t in trials:
                self.trials[t.key] = TrialProgress(t)
                if t.variant not in self.variants:
                    self.variants.append(t.variant)
            self.later, self.provisional, self._stage_coming = [], None, False
            self._freed.clear()  # the next stage starts on slots that are all free: no wait to count
            if trials:
                self.trials_end = None
            elif not self._count("pending") and not self._count("running"):
                self.trials_end = max((t.ended_at for t in self.trials.values() if t.ended_at), default=None)
            self._log_estimate(time.monotonic())
        self.refresh()

    def _count(self, state: str) -> int:
        return sum(t.state == state for t in self.trials.values())

    def _log_estimate(self, now: float) -> None:
        """Called with the lock held after every event: (seconds since the command started, trials ended,
        the estimate) for ``make bench`` to hold against the time that actually remained."""
        if self.log_estimates:
            ended = self._count("done") + self._count("failed")
            self.estimates.append((now - self.start, ended, self.seconds_left(now)))

    # --- rendering --------------------------------------------------------------------------------
    def headline(self) -> str:
        now = time.monotonic()
        counts = {s: self._count(s) for s in ("done", "running", "pending", "failed")}
        first = self.phases[0][1]
        if self.first_start is None:
            state = "starting Ray (its workers import torch before the first trial starts)"
        elif self.trials_end is not None:
            state = "all trials ended"
        elif (ended := sum(self.trials[k].ended_at is not None for k in first)) < len(first) / 4:
            # Until a quarter of the launch's first trials have ended, their costs are guesses (a launch of 36 read
            # ~0:55 where 2:08 remained): say so, not a figure. Later rounds draw on what these taught.
            state = f"time left: estimating until a quarter of the trials have ended ({ended} of {len(first)})"
        else:
            left = self.seconds_left(now)
            state = f"~{clock(left)} left" if left is not None else "time left: once a trial reports its episodes"
        return (
            f"{self.name}: {counts['done']} done, {counts['running']} running, {counts['pending']} pending, "
            f"{counts['failed']} failed (of {len(self.trials)}; {self.already_done} finished before) | "
            f"{clock(now - self.start)} elapsed, {state}"
        )

    def _running_table(self, now: float) -> Table | str:
        running = sorted((t for t in self.trials.values() if t.state == "running"), key=lambda t: t.started_at or 0)
        if not running:
            return ""
        table = Table(box=None, pad_edge=False, title="running", title_justify="left")
        for column in ("variant", "seed", "episode", "rolling mean", "running for"):
            table.add_column(column, justify="left" if column == "variant" else "right")
        for t in running[:MAX_RUNNING_ROWS]:
            table.add_row(
                t.trial.variant,
                str(t.trial.seed),
                f"{t.episode:,}/{t.budget:,}" if t.episode else f"-/{t.budget:,}",
                "-" if t.rolling_mean is None else f"{t.rolling_mean:.1f}",
                clock(now - (t.started_at or now)),
            )
        if len(running) > MAX_RUNNING_ROWS:
            table.add_row(f"... and {len(running) - MAX_RUNNING_ROWS} more", "", "", "", "")
        return table

    def _variant_table(self) -> Table:
        table = Table(box=None, pad_edge=False)
        columns = ("variant", "done", "running", "solved", "seeds reporting", "rolling mean: median of seeds", "range")
        for column in columns:
            table.add_column(column, justify="left" if column == "variant" else "right")
        for variant in self.variants:
            trials = [t for t in self.trials.values() if t.trial.variant == variant]
            means = sorted(t.rolling_mean for t in trials if t.rolling_mean is not None and t.state != "failed")
            table.add_row(
                variant,
                f"{sum(t.state == 'done' for t in trials)}/{len(trials)}",
                str(sum(t.state == "running" for t in trials)),
                str(sum(t.solved for t in trials)),
                str(len(means)),
                f"{statistics.median(means):.1f}" if means else "-",
                f"{means[0]:.1f} to {means[-1]:.1f}" if len(means) > 1 else "-",
            )
        return table

    def render(self) -> Group:
        with self.lock:
            now = time.monotonic()
            return Group(self.headline(), self._running_table(now), self._variant_table())

    def refresh(self) -> None:
        if not self.enabled or self.live is not None:
            return  # the live panel redraws itself four times a second
        if time.monotonic() - self.last_line >= 10:
            self.last_line = time.monotonic()
            with self.lock:
                line = self.headline()
            print(line, flush=True)

    def total_line(self, report_s: float | None = None) -> str:
        """The whole command's time, split into its stages."""
        now = time.monotonic()
        parts = []
        if self.first_start is not None:
            parts.append(f"until the first trial started {clock(self.first_start - self.start)}")
            parts.append(f"trials {clock((self.trials_end or now) - self.first_start)}")
        if report_s is not None:
            parts.append(f"report {clock(report_s)}")
        return f"total {clock(now - self.start)}" + (f" ({', '.join(parts)})" if parts else "")

    def __enter__(self) -> ProgressView:
        if self.enabled and self.tty:
            self.live = Live(
                console=self.console, get_renderable=self.render, refresh_per_second=4, redirect_stderr=False
            )
            self.live.__enter__()
        elif self.enabled:
            self.refresh()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.live is not None:
            self.live.refresh()
            self.live.__exit__(None, None, None)
            self.live = None
        elif self.enabled:
            with self.lock:
                line = self.headline()
            print(line, flush=True)
