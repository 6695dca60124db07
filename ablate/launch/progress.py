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
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table

from ablate.launch.clock import clock
from ablate.launch.estimate import at_budget, makespan
from ablate.launch.grid import GridTrial, config_hash

RATE_REPORTS = 4
"""Reports (one per ~2 s per trial) that a running trial's recent pace is measured over."""
MAX_RUNNING_ROWS = 16
"""Rows of running trials shown; more are summarised in one line."""


@dataclass
class _Trial:
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
        from ablate.agent.trial import solve_threshold  # the driver has it loaded once trials run

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


@dataclass(frozen=True)
class _CostsSeen:
    means: dict[tuple[str, int], float]
    """Mean seconds of the finished trials per (variant, episode budget)."""
    peers: dict[tuple[str, str], list[tuple[float, int, int, float | None]]]
    """The finished trials per ``settings``: (seconds, episodes run, budget, recent seconds per episode)."""
    rates: dict[str | None, float]
    """Mean seconds per episode per variant (``None``: over every variant)."""
    prior_scale: float
    """This launch's seconds over the earlier runs' seconds, for the trials both finished; 1 before one has."""
    overhead_s: float
    """What a trial costs beside its training (median over the finished trials that paid no worker start)."""


class ProgressView:
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
    ) -> None:
        """``trials`` in the order they will start. ``slots``: trials that can run at once (``None``: the most
        seen running at once). ``start``: the ``time.monotonic()`` the command started at, so the clock
        includes imports and Ray's start. ``prior_costs``: seconds by trial key that earlier launches took
        (``Tracker.earlier_runs``). ``log_estimates``: keep every estimate in ``estimates`` (``make bench``).
        ``later``: stand-ins for the trials not known yet that start once every trial here has ended (a tuned
        ablation's trials at the chosen values); ``add_trials`` puts the real ones in when they are known.
        ``provisional``: the later trials as the finished trials' summaries (key -> metrics) say they would
        be if stage 1 ended now (each variant at its best candidate so far), asked again as tuning trials end.
        ``prior_episodes``: episodes by trial key that earlier launches ran (``Tracker.earlier_runs``)."""
        self.name = name
        self.trials = {t.key: _Trial(t) for t in trials}
        self.variants = list(dict.fromkeys(t.variant for t in trials))
        self.already_done = already_done
        self.slots = slots
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
        self.later = [_Trial(t) for t in later]
        self.provisional = provisional
        self.summaries: dict[str, Mapping[str, float]] = {}
        self.estimates: list[tuple[float, int, float | None]] = []
        """(seconds since ``start``, trials ended, the estimate in seconds) after every event."""

    # --- events -----------------------------------------------------------------------------------
    def started(self, key: str) -> None:
        with self.lock:
            now = time.monotonic()
            trial = self.trials[key]
            trial.state, trial.started_at, trial.episode, trial.rolling_mean = "running", now, 0, None
            trial.reports.clear()
            self.first_start = self.first_start or now
            trial.first_on_worker = not any(t.ended_at for t in self.trials.values())
            self.max_running = max(self.max_running, self._count("running"))
            if self._freed:
                self.gaps.append(now - self._freed.popleft())
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
            if self._count("pending"):
                self._freed.append(trial.ended_at)
            if self.provisional and trial.trial.stage == "tune":
                try:
                    self.later = [_Trial(t) for t in self.provisional(dict(self.summaries))]
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
            for t in trials:
                self.trials[t.key] = _Trial(t)
                if t.variant not in self.variants:
                    self.variants.append(t.variant)
            self.later, self.provisional = [], None
            self._freed.clear()  # the next stage starts on slots that are all free: no wait to count
            if trials:
                self.trials_end = None
            elif not self._count("pending") and not self._count("running"):
                self.trials_end = max((t.ended_at for t in self.trials.values() if t.ended_at), default=None)
            self._log_estimate(time.monotonic())
        self.refresh()

    def _count(self, state: str) -> int:
        return sum(t.state == state for t in self.trials.values())

    # --- the estimate -----------------------------------------------------------------------------
    def _costs_seen(self, now: float) -> _CostsSeen:
        """What this launch has shown so far of its trials' costs (once per estimate: the trials are many)."""
        by_group: dict[tuple[str, int], list[float]] = {}
        peers: dict[tuple[str, str], list[tuple[float, int, int, float | None]]] = {}
        rates: dict[str | None, list[float]] = {}
        observed = earlier = 0.0
        done = [t for t in self.trials.values() if t.state == "done" and t.started_at and t.ended_at]
        # What a trial costs beside its training (Tune, the driver's writes), from the trials that paid no
        # worker start; a trial that did pay one counts as its training time plus that.
        beside = [t.ended_at - t.started_at - t.wall_s for t in done if not t.first_on_worker and t.wall_s is not None]
        overhead = statistics.median(beside) if beside else 0.0
        for t in done:
            cost = t.ended_at - t.started_at  # type: ignore[operator]
            if t.first_on_worker and t.wall_s is not None:
                cost = min(cost, t.wall_s + max(overhead, 0.0))
            by_group.setdefault((t.trial.variant, t.budget), []).append(cost)
            ran = t.episodes_run if t.episodes_run is not None else t.episode
            if ran:  # a trial that reported no episode says nothing of a budget's cost
                peers.setdefault(t.settings, []).append((cost, ran, t.budget, t.seconds_per_episode(now)))
            if t.trial.key in self.prior:  # as the earlier launch measured it: start to end, a worker start too
                observed, earlier = observed + t.ended_at - t.started_at, earlier + self.prior[t.trial.key]  # type: ignore[operator]
        for t in self.trials.values():
            if (rate := t.seconds_per_episode(now)) is not None:
                rates.setdefault(t.trial.variant, []).append(rate)
                rates.setdefault(None, []).append(rate)
        return _CostsSeen(
            means={group: statistics.fmean(costs) for group, costs in by_group.items()},
            peers=peers,
            rates={variant: statistics.fmean(r) for variant, r in rates.items()},
            # How this launch's trials compare with their earlier runs (a busier machine, another CPU).
            prior_scale=observed / earlier if earlier > 0 else 1.0,
            overhead_s=max(overhead, 0.0),
        )

    def _peer_cost(self, trial: _Trial, seen: _CostsSeen) -> float | None:
        """What finished trials say a trial costs: its earlier run's (scaled to this launch's pace); else the
        mean of its finished peers with the same settings, at its budget; else their cost carried over to its
        budget (a tuned variant's evaluation trial from its tuning trials at the same values), halfway to the
        mean of its variant's finished trials at its budget once there are some: the value won on the tuning
        seeds, so its tuning trials are an optimistic guide (an evaluation seed may solve later, or never),
        and the variant's evaluation seeds at the base value ran the whole budget; else that mean alone."""
        if trial.trial.key in self.prior:
            return self.prior[trial.trial.key] * seen.prior_scale
        peers = seen.peers.get(trial.settings, [])
        same = [cost for cost, _, budget, _ in peers if budget == trial.budget]
        if same:
            return statistics.fmean(same)
        variant_mean = seen.means.get((trial.trial.variant, trial.budget))
        if peers:
            carried = statistics.fmean(at_budget(*peer, trial.budget) for peer in peers)
            return carried if variant_mean is None else (carried + variant_mean) / 2
        return variant_mean

    def _trial_cost(self, trial: _Trial, seen: _CostsSeen) -> float | None:
        """Expected seconds of a trial that has not started: what its finished peers say (``_peer_cost``), else
        its whole budget at the seconds per episode seen so far (its variant's own, else every variant's);
        ``None`` before any trial has reported an episode."""
        cost = self._peer_cost(trial, seen)
        if cost is not None:
            return cost
        rate = seen.rates.get(trial.trial.variant) or seen.rates.get(None)
        return None if rate is None else rate * trial.budget + seen.overhead_s

    def expected_cost(self, variant: str, now: float | None = None) -> float | None:
        """Expected seconds of a trial of ``variant`` that has not started (its first pending one)."""
        now = time.monotonic() if now is None else now
        trials = [t for t in self.trials.values() if t.trial.variant == variant]
        trial = next((t for t in trials if t.state == "pending"), trials[0])
        return self._trial_cost(trial, self._costs_seen(now))

    def dispatch_s(self) -> float:
        """Mean seconds a slot stays idle between one trial's end and the next trial's start (Tune's loop, the
        driver writing the ended trial's artifacts): with trials of a second or two, a third of the time."""
        return statistics.fmean(self.gaps) if self.gaps else 0.0

    def _left_of_running(self, trial: _Trial, now: float, seen: _CostsSeen) -> float | None:
        elapsed = now - (trial.started_at or now)
        expected = self._peer_cost(trial, seen)
        if expected is not None and expected > elapsed:
            return expected - elapsed
        if trial.last_episode_reported:  # not the rest of its budget: a solved trial stops where it solved
            return 0.0
        # Past what its peers took (or none has ended): at its own recent pace, to where its earlier run (the
        # same seed) stopped, a slower machine's being no reason to run longer; past that, the rest of its budget;
        # sooner where its rolling mean climbs to the solve threshold first (a CartPole agent near it plays
        # 500-step episodes: the rest of its budget at that pace would be many times what is left).
        rate = trial.seconds_per_episode(now) or seen.rates.get(None)
        if rate is None:
            return None
        stop = self.prior_episodes.get(trial.trial.key, trial.budget)
        left = (stop if trial.episode < stop else trial.budget) - trial.episode
        # An earlier run of the same seed that ran its whole budget says no climb now reaches the threshold.
        never_solved = trial.trial.key in self.prior_episodes and stop >= trial.budget
        climb = None if never_solved else trial.episodes_to_solve()
        return rate * max(left if climb is None else min(left, climb), 0)

    def seconds_left(self, now: float | None = None) -> float | None:
        """Seconds until the last trial ends, or ``None`` while nothing is known of any trial's cost."""
        now = time.monotonic() if now is None else now
        running = [t for t in self.trials.values() if t.state == "running"]
        pending = [t for t in self.trials.values() if t.state == "pending"]
        if not running and not pending and not self.later:
            return 0.0
        seen = self._costs_seen(now)
        running_left = [self._left_of_running(t, now, seen) for t in running]
        costs = [self._trial_cost(t, seen) for t in pending]
        later = [self._trial_cost(t, seen) for t in self.later]
        if any(x is None for x in [*running_left, *costs, *later]):
            return None
        slots = self.slots or max(self.max_running, 1)
        gap = self.dispatch_s()
        # Pending trials start in the order the scheduler was given them (``grid.schedule_order``); the later
        # stage once every one of them has ended.
        now_stage = makespan(running_left, [c + gap for c in costs], slots)  # type: ignore[misc, operator]
        return now_stage + (makespan([], [c + gap for c in later], slots) if later else 0.0)  # type: ignore[misc, operator]

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
        if self.first_start is None:
            state = "starting Ray (its workers import torch before the first trial starts)"
        elif self.trials_end is not None:
            state = "all trials ended"
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
