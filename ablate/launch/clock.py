"""Clocks for a terminal: ``m:ss``, a line with a running clock while a slow step runs (Ray's start, the
report), and one trial's episode line (``ablate train``)."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from rich.live import Live


def clock(seconds: float) -> str:
    """``m:ss`` (``h:mm:ss`` past an hour)."""
    seconds = int(max(seconds, 0))
    hours, rest = divmod(seconds, 3600)
    if hours:
        return f"{hours}:{rest // 60:02d}:{rest % 60:02d}"
    return f"{seconds // 60}:{seconds % 60:02d}"


@contextmanager
def stage(text: str, enabled: bool = True) -> Iterator[list[float]]:
    """A line with a running clock while a slow step runs (``text ... 0:04``), then ``text: done in 6.8 s``.
    Yields a list that holds the step's seconds once it ends."""
    began = time.monotonic()
    seconds: list[float] = []
    live = None
    if enabled and sys.stdout.isatty():
        live = Live(get_renderable=lambda: f"{text} ... {clock(time.monotonic() - began)}", transient=True)
        live.__enter__()
    elif enabled:
        print(f"{text} ...", flush=True)
    try:
        yield seconds
    finally:
        seconds.append(time.monotonic() - began)
        if live is not None:
            live.__exit__(None, None, None)
        if enabled:
            print(f"{text}: done in {seconds[0]:.1f} s", flush=True)


class EpisodeLine:
    """``ablate train``'s progress: one refreshing line on a terminal; a line every few seconds when output is a
    file or a pipe."""

    def __init__(self) -> None:
        self.tty = sys.stdout.isatty()
        self.last_print = 0.0

    def update(self, episodes: list[Any]) -> None:
        now = time.monotonic()
        if not self.tty and now - self.last_print < 2.0:
            return
        self.last_print = now
        m = episodes[-1]
        line = (
            f"episode {m.episode:>6} | return {m.episode_return:7.1f} | rolling mean {m.rolling_mean:7.1f}"
            f" | {m.env_steps / max(m.wall_s, 1e-9):>9,.0f} steps/s"
        )
        print(f"\r{line}" if self.tty else line, end="" if self.tty else "\n", flush=True)

    def close(self) -> None:
        if self.tty:
            print()
