"""What a trial produces: its per-episode metrics, its result, the error that stops it, an update's batch.

Types only (no training here), so the trainer, its artifacts and the launch can all import them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from ablate.config import TrialConfig
from ablate.measures import Curve, recorded


class TrialFailed(RuntimeError):
    """The trial cannot go on (a NaN loss, say); the message says why and what to change."""


class EpisodeMetrics(NamedTuple):
    episode: int
    """1-based index of the episode in the trial."""
    episode_return: float
    length: int
    loss: float
    """Loss of the update this episode took part in."""
    entropy: float
    """Mean policy entropy (nats) over that update's observations."""
    rolling_mean: float
    """Mean return of the last ``solve_window`` episodes (fewer at the start)."""
    env_steps: int
    """Environment steps since the trial started, this episode included."""
    wall_s: float
    """Seconds since the trial started, at the end of this episode's update."""
    update: int
    """1-based index of the update (Adam step) this episode took part in."""


@dataclass
class TrialResult:
    config: TrialConfig
    episodes: list[EpisodeMetrics]
    episodes_to_solve: int | None
    """Episode at which the rolling mean first reached the threshold over a full window; None if never."""
    solve_threshold: float | None
    env_steps: int
    wall_s: float
    parameter_count: int
    greedy_return: float | None = None
    """Return of the recorded greedy episode (None when no video was recorded, and for Pong, whose video is of
    the sampling policy)."""
    state_dict: dict[str, torch.Tensor] = field(default_factory=dict)
    artifacts: dict[str, Path] = field(default_factory=dict)
    env: dict[str, str] = field(default_factory=dict)
    """What it ran against (``envs.record``): its run's ``env.*`` params."""

    @property
    def returns(self) -> list[float]:
        return [m.episode_return for m in self.episodes]

    @property
    def solved(self) -> bool:
        return self.episodes_to_solve is not None

    def summary(self) -> dict[str, float]:
        """Scalar results, with the tracker's metric names."""
        last = self.episodes[-1] if self.episodes else None
        solve = self.episodes[self.episodes_to_solve - 1] if self.episodes_to_solve else None
        summary = {
            "solved": float(self.solved),
            "episodes_run": float(len(self.episodes)),
            "final_rolling_mean": last.rolling_mean if last else float("nan"),
            "env_steps": float(self.env_steps),
            "wall_s": self.wall_s,
            "steps_per_s": self.env_steps / self.wall_s if self.wall_s > 0 else 0.0,
            "parameter_count": float(self.parameter_count),
        }
        # Here, so that tuning selects from the summary alone; the report recomputes them from the same registry.
        rolling = np.asarray([m.rolling_mean for m in self.episodes], float)
        summary |= recorded(Curve(rolling, self.config.max_episodes, self.solve_threshold, self.config.solve_window))
        if solve is not None:
            summary |= {
                "episodes_to_solve": float(solve.episode),
                "env_steps_to_solve": float(solve.env_steps),
                "wall_s_to_solve": solve.wall_s,
            }
        if self.greedy_return is not None:
            summary["greedy_return"] = self.greedy_return
        return summary


class Batch(NamedTuple):
    """One member's episodes of one update."""

    lengths: np.ndarray
    """Steps of each episode, in order."""
    episode_returns: np.ndarray
    observations: np.ndarray
    """Every episode's observations, concatenated in order (the update's batch)."""
    actions: np.ndarray
    weights: np.ndarray
    """Normalised discounted returns: the policy-gradient weights."""
