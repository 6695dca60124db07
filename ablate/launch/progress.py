"""The live terminal view of an ablation: it draws a launch's state (``launch.state``) and its estimate
(``launch.estimate``), and renders only: the runner hands events to the state, then tells the view (``update``).
"""

from __future__ import annotations

import statistics
import sys
import time

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table

from ablate.launch.clock import clock
from ablate.launch.estimate import estimate
from ablate.launch.state import LaunchState

MAX_RUNNING_ROWS = 16
"""Rows of running trials shown; more are summarised in one line."""


class ProgressView:
    """Draws ``state``: a panel redrawn four times a second on a terminal (its clock runs while Ray starts), a
    line every 10 s otherwise."""

    def __init__(self, state: LaunchState, enabled: bool = True, log_estimates: bool = False) -> None:
        """``log_estimates``: keep every estimate in ``estimates`` (``make bench``)."""
        self.state = state
        self.enabled = enabled
        self.tty = sys.stdout.isatty()
        self.console = Console()
        self.live: Live | None = None
        self.last_line = 0.0
        self.log_estimates = log_estimates
        self.estimates: list[tuple[float, int, float | None, float | None, int]] = []
        """(seconds since the start, trials ended, the round's estimate, the most in all, the phase: an index
        of ``state.phases``) after every event, for ``make bench`` to hold against the time that remained."""
        self.quarter: tuple[float, float | None, float | None, int] | None = None
        """When a quarter of the launch's first trials had ended: (seconds since the start, left in the round, at
        most in all, the round), which the summary holds against the end (``bounds_line``)."""

    def update(self) -> None:
        """After an event: the estimate logged (``log_estimates``) or kept at a quarter, the line printed when due."""
        state = self.state
        quarter_due = self.quarter is None and state.first_start is not None and self._quartered()
        if self.log_estimates or quarter_due:
            now = time.monotonic()
            left, most = estimate(state, now)
            if self.log_estimates:
                self.estimates.append((now - state.start, state.ended, left, most, len(state.phases) - 1))
            if quarter_due:
                self.quarter = (now - state.start, left, most, state.round)
        self.refresh()

    def _quartered(self) -> bool:
        ended, first = self.state.first_ended
        return ended >= first / 4

    # --- rendering --------------------------------------------------------------------------------
    def headline(self) -> str:
        """The one line: counts, the clock, the time left. Called with the state's lock held."""
        state = self.state
        now = time.monotonic()
        counts = {s: state.count(s) for s in ("done", "running", "pending", "failed")}
        if state.first_start is None:
            status = "starting Ray (its workers import torch before the first trial starts)"
        elif state.trials_end is not None and not state.possible:
            status = "all trials ended"
        elif not self._quartered():
            # Until a quarter of the launch's first trials have ended, their costs are guesses (a launch of 36 read
            # ~0:55 where 2:08 remained): say so, not a figure. Later rounds draw on what these taught.
            ended, first = state.first_ended
            status = f"time left: estimating until a quarter of the trials have ended ({ended} of {first})"
        else:
            left, most = estimate(state, now)
            status = time_left_words(left, most, state.round if state.possible or state.round > 1 else None)
        total = total_words(len(state.trials), state.later_most if state.stage_coming else 0, state.at_most_more)
        return (
            f"{state.name}: {counts['done']} done, {counts['running']} running, {counts['pending']} pending, "
            f"{counts['failed']} failed (of {total}; {state.already_done} finished before) | "
            f"{clock(now - state.start)} elapsed, {status}"
        )

    def _running_table(self, now: float) -> Table | str:
        running = sorted(
            (t for t in self.state.trials.values() if t.state == "running"), key=lambda t: t.started_at or 0
        )
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
        for variant in self.state.variants:
            trials = [t for t in self.state.trials.values() if t.trial.variant == variant]
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
        with self.state.lock:
            now = time.monotonic()
            return Group(self.headline(), self._running_table(now), self._variant_table())

    def refresh(self, now: bool = False) -> None:
        """The line, when 10 s have passed since the last (``now``: in any case)."""
        if not self.enabled or self.live is not None:
            return  # the live panel redraws itself four times a second
        if now or time.monotonic() - self.last_line >= 10:
            self.last_line = time.monotonic()
            with self.state.lock:
                line = self.headline()
            print(line, flush=True)

    def total_line(self, report_s: float | None = None) -> str:
        """The whole command's time, split into its stages."""
        state = self.state
        now = time.monotonic()
        parts = []
        if state.first_start is not None:
            parts.append(f"until the first trial started {clock(state.first_start - state.start)}")
            parts.append(f"trials {clock((state.trials_end or now) - state.first_start)}")
        if report_s is not None:
            parts.append(f"report {clock(report_s)}")
        return f"total {clock(now - state.start)}" + (f" ({', '.join(parts)})" if parts else "")

    def bounds_line(self) -> str:
        """Which bound the trials ended near: the figures at a quarter of the launch's first trials against the
        time that then remained ("" before a quarter, or where no round could follow)."""
        if self.quarter is None or self.state.trials_end is None:
            return ""
        at, left, most, round_number = self.quarter
        if left is None or most is None or most <= left:
            return ""
        remained = self.state.trials_end - self.state.start - at
        nearer = "the round's estimate" if abs(remained - left) <= abs(remained - most) else "the upper bound"
        return (
            f"time: at {clock(at)} the estimate said ~{clock(left)} left in round {round_number}, at most "
            f"~{clock(most)} in all; the trials ended {clock(remained)} later, nearer {nearer}"
        )

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
        else:
            self.refresh(now=True)


def time_left_words(left: float | None, most: float | None, round_number: int | None) -> str:
    """``~0:07 left`` alone; with rounds that may follow, ``~0:07 left in round 1, at most ~2:50 in all``."""
    if left is None:
        return "time left: once a trial reports its episodes"
    if round_number is None:
        return f"~{clock(left)} left"
    words = f"~{clock(left)} left in round {round_number}"
    if most is not None and most > left:
        return f"{words}, at most ~{clock(most)} in all"
    return words


def total_words(known: int, stage_most: int, rounds_most: int) -> str:
    """The trials a launch may run, from its first line to its last: those known now, and as "at most" what the
    stage at the chosen values and later rounds can add, so the figure never moves up past what it said."""
    words = f"{known}"
    if stage_most:
        words += f", at most {known + stage_most} with the chosen values' trials"
    if rounds_most:
        words += f", at most {rounds_most} more in later rounds"
    return words
