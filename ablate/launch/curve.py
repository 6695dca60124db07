"""A trial's learning curve at a bounded number of points, however many episodes it runs.

Pure: the scheduler reduces each trial's episodes to points in the trial's own process, so what crosses
the network and what the single tracking writer stores per trial does not grow with its episode count.
The exact per-episode table stays complete in the trial's ``episodes.csv`` artifact.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import NamedTuple

CURVE_POINTS = 100
"""Points per curve at most (+1 for a last, partial bin). MLflow's SQLite store costs ~4 ms per call and
~55 us per value of the writer's CPU; 100 points x 7 metrics keep a 1,500-episode CartPole trial at ~40 ms
of writer CPU, so one core writes for hundreds of trials at once (``make bench``, section ``tracking``)."""


class CurvePoint(NamedTuple):
    """``bin`` consecutive episodes of a trial, ending at ``episode``."""

    episode: int
    """1-based index of the bin's last episode: the point's step."""
    episode_return: float
    """Mean return of the bin's episodes."""
    length: float
    """Mean length of the bin's episodes."""
    loss: float
    """Mean loss of the updates the bin's episodes took part in."""
    entropy: float
    """Mean policy entropy of those updates."""
    rolling_mean: float
    """The trial's rolling mean at the bin's last episode."""
    env_steps: int
    """Environment steps up to the bin's last episode."""
    wall_s: float
    """Seconds since the trial started, at the end of the update of the bin's last episode."""


class CurveReducer:
    """Feed a trial's episode rows (``EpisodeMetrics``) in order; get ``CurvePoint`` s back as bins fill.
    Bins are fixed by episode index, so a resumed trial that replays its history yields the same points."""

    def __init__(self, max_episodes: int, points: int = CURVE_POINTS) -> None:
        self.size = max(1, math.ceil(max_episodes / points))
        """Episodes per point: the budget over ``points``, at least 1."""
        self.pending: list = []

    def add(self, rows: Iterable) -> list[CurvePoint]:
        out = []
        for row in rows:
            self.pending.append(row)
            if row.episode % self.size == 0:
                out.append(self._point())
        return out

    def flush(self) -> list[CurvePoint]:
        """The last, partial bin (when the trial ends)."""
        return [self._point()] if self.pending else []

    def _point(self) -> CurvePoint:
        rows, self.pending = self.pending, []
        last = rows[-1]
        updates = list({row.update: row for row in rows}.values())  # a row carries its update's loss, entropy
        return CurvePoint(
            last.episode,
            sum(r.episode_return for r in rows) / len(rows),
            sum(r.length for r in rows) / len(rows),
            sum(u.loss for u in updates) / len(updates),
            sum(u.entropy for u in updates) / len(updates),
            float(last.rolling_mean),
            int(last.env_steps),
            float(last.wall_s),
        )
