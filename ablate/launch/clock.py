"""Clocks for a terminal: ``m:ss``, and a line with a running clock while a slow step runs (Ray's start, the
report)."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

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
