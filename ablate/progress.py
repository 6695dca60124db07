"""The live terminal view of an ablation: trials done / running / pending / failed, best rolling mean per
variant, elapsed and estimated time left. A refreshing panel on a terminal, a line every 10 s otherwise."""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from collections.abc import Sequence

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table

from ablate.grid import GridTrial


def _clock(seconds: float) -> str:
    seconds = int(max(seconds, 0))
    return f"{seconds // 60}:{seconds % 60:02d}"


class ProgressView:
    def __init__(self, name: str, trials: Sequence[GridTrial], already_done: int, enabled: bool = True) -> None:
        self.name = name
        self.variant_of = {t.key: t.variant for t in trials}
        self.variants = list(dict.fromkeys(t.variant for t in trials))
        self.total = len(trials)
        self.already_done = already_done
        self.pending = set(self.variant_of)
        self.running: set[str] = set()
        self.done_keys: set[str] = set()
        self.failed_keys: set[str] = set()
        self.best: dict[str, float] = defaultdict(lambda: float("-inf"))
        self.solved: dict[str, int] = defaultdict(int)
        self.durations: list[float] = []
        self.started_at: dict[str, float] = {}
        self.start = time.monotonic()
        self.max_running = 1
        self.enabled = enabled
        self.tty = sys.stdout.isatty()
        self.console = Console()
        self.live: Live | None = None
        self.last_line = 0.0

    # --- events -----------------------------------------------------------------------------------
    def started(self, key: str) -> None:
        self.pending.discard(key)
        self.running.add(key)
        self.started_at.setdefault(key, time.monotonic())
        self.max_running = max(self.max_running, len(self.running))
        self.refresh()

    def episodes(self, key: str, rolling_mean: float) -> None:
        variant = self.variant_of[key]
        self.best[variant] = max(self.best[variant], rolling_mean)
        self.refresh()

    def finished(self, key: str, solved: bool) -> None:
        self.running.discard(key)
        self.done_keys.add(key)
        self.solved[self.variant_of[key]] += int(solved)
        self.durations.append(time.monotonic() - self.started_at.get(key, self.start))
        self.refresh()

    def failed(self, key: str) -> None:
        self.running.discard(key)
        self.pending.discard(key)
        self.failed_keys.add(key)
        self.refresh()

    # --- rendering --------------------------------------------------------------------------------
    def headline(self) -> str:
        elapsed = time.monotonic() - self.start
        remaining = len(self.pending) + len(self.running)
        if self.durations:
            mean = sum(self.durations) / len(self.durations)
            eta = f"~{_clock(mean * remaining / self.max_running)} left"
        else:
            eta = "time left: after the first trial"
        return (
            f"{self.name}: {len(self.done_keys)} done, {len(self.running)} running, {len(self.pending)} pending, "
            f"{len(self.failed_keys)} failed (of {self.total}; {self.already_done} finished before) | "
            f"{_clock(elapsed)} elapsed, {eta}"
        )

    def render(self) -> Group:
        table = Table(box=None, pad_edge=False)
        for column in ("variant", "done", "solved", "best rolling mean"):
            table.add_column(column, justify="left" if column == "variant" else "right")
        for variant in self.variants:
            keys = [k for k, v in self.variant_of.items() if v == variant]
            done = sum(k in self.done_keys for k in keys)
            best = self.best[variant]
            table.add_row(
                variant,
                f"{done}/{len(keys)}",
                str(self.solved[variant]),
                "-" if best == float("-inf") else f"{best:.1f}",
            )
        return Group(self.headline(), table)

    def refresh(self) -> None:
        if not self.enabled:
            return
        if self.live is not None:
            self.live.update(self.render())
        elif time.monotonic() - self.last_line >= 10:
            self.last_line = time.monotonic()
            print(self.headline(), flush=True)

    def __enter__(self) -> ProgressView:
        if self.enabled and self.tty:
            self.live = Live(self.render(), console=self.console, refresh_per_second=4, transient=False)
            self.live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.live is not None:
            self.live.update(self.render())
            self.live.__exit__(None, None, None)
            self.live = None
        elif self.enabled:
            print(self.headline(), flush=True)
