"""One trial: seed, build env and policy, collect episodes, update, stop when solved or out of budget.

An importable function of a ``TrialConfig``; metrics leave through a callback, artifacts into a folder.
No Ray and no MLflow here: the scheduler and the tracker wrap this.
"""

from __future__ import annotations

import csv
import ctypes
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import torch

from ablate.agent.collectors import (
    record_greedy_episode,
    record_pong_episode,
    video_writer,
)
from ablate.agent.envs import env_info, is_pong
from ablate.agent.policies import Policy
from ablate.config import TrialConfig


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
        if self.episodes:
            # The area under the rolling-mean curve over the whole budget (as ``report.results`` computes it),
            # here so that tuning selects from the summary alone: a trial that stopped when solved keeps its
            # last rolling mean for the rest of the budget.
            rolling = [m.rolling_mean for m in self.episodes][: self.config.max_episodes]
            padding = max(self.config.max_episodes - len(rolling), 0)
            summary["auc"] = (sum(rolling) + padding * rolling[-1]) / (len(rolling) + padding)
        if solve is not None:
            summary |= {
                "episodes_to_solve": float(solve.episode),
                "env_steps_to_solve": float(solve.env_steps),
                "wall_s_to_solve": solve.wall_s,
            }
        if self.greedy_return is not None:
            summary["greedy_return"] = self.greedy_return
        return summary


PONG_TRAIN_CHUNK = 1024
"""Observations per forward/backward in a Pong update: bounds its activations (~130 MB for the CNN)."""


def solve_threshold(config: TrialConfig) -> float | None:
    """The rolling mean over ``solve_window`` episodes at which a trial counts as solved and stops: its own
    ``solve_threshold``, else its env's reward threshold (``None``: Pong has none)."""
    if config.solve_threshold is not None:
        return config.solve_threshold
    return env_info(config.env_id).reward_threshold


def _limit_fragmentation() -> None:
    """Fix glibc's mmap threshold at 256 KB. By default it rises (to 32 MB) each time a large block is freed,
    after which a Pong trial's per-update arrays (MBs each) come from the heap and fragment it: RSS grew
    515 MB -> 4.1 GB over 500 episodes. Mapped blocks go back to the system when freed. No-op off glibc."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 256 * 1024)  # M_MMAP_THRESHOLD; setting it also turns the dynamic threshold off
    except (OSError, AttributeError):
        pass


def _inject_fault(config: TrialConfig) -> None:
    """Test-only faults (``TrialConfig.fault``), to prove the scheduler's retry and failure handling."""
    if config.fault == "crash_once" and config.fault_marker and not Path(config.fault_marker).exists():
        Path(config.fault_marker).write_text("crashed once\n")
        os._exit(17)  # a hard process death, as an OOM kill or a segfault would be
    if config.fault == "block":
        # A trial that is certainly still running when a test interrupts the launch; a file releases it.
        while not Path(config.fault_marker).exists():
            time.sleep(0.05)


def run_trial(
    config: TrialConfig,
    on_episodes: Callable[[list[EpisodeMetrics]], None] | None = None,
    artifacts_dir: str | Path | None = None,
    *,
    resume_from: bytes | None = None,
    on_checkpoint: Callable[[bytes], None] | None = None,
) -> TrialResult:
    """Train one REINFORCE agent as ``config`` says and return its per-episode metrics and weights: a
    population of one (``population.run_population``), so a trial and a population member are one code path.

    ``on_episodes`` receives each update's new episodes as they finish. With ``artifacts_dir``, the trial
    writes ``episodes.csv``, ``weights.pt``, ``learning_curve.png`` and (if ``record_video``) ``video.mp4``;
    a Pong trial also ``observation.png`` and, with ``video_every``, ``videos/episode_NNNNN.mp4``.

    Every ``config.checkpoint_interval`` episodes, ``on_checkpoint`` receives a bytes blob of the whole trial
    state (weights, optimizer, RNGs, envs, episode history). ``resume_from`` = such a blob: the trial
    restores it, hands the saved history to ``on_episodes`` in one call, and goes on from the next episode;
    a resumed trial returns exactly what the unbroken one would have. Raises ``TrialFailed`` (a NaN loss).
    """
    from ablate.agent.population import run_population  # it builds on this module's types

    [outcome] = run_population(
        [config],
        on_episodes=(lambda _, rows: on_episodes(rows)) if on_episodes is not None else None,
        artifacts_dirs=[artifacts_dir],
        resume_from=[resume_from],
        on_checkpoint=(lambda _, blob: on_checkpoint(blob)) if on_checkpoint is not None else None,
    )
    if isinstance(outcome, TrialFailed):
        raise outcome
    return outcome


def write_artifacts(result: TrialResult, model: Policy, folder: Path) -> None:
    """Per-episode table, weights, learning curve and (optionally) a video of the agent into ``folder``; for
    Pong also ``observation.png`` (one observation raw, pre-processed and as a frame difference)."""
    # Imported here: a worker process pays for matplotlib and ffmpeg only when a trial ends.
    from ablate.agent.envs import sample_pong_frames
    from ablate.agent.plots import plot_pong_observation, plot_progress

    folder.mkdir(parents=True, exist_ok=True)
    config = result.config
    table = folder / "episodes.csv"
    with open(table, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(EpisodeMetrics._fields)
        writer.writerows(result.episodes)
    result.artifacts["episodes"] = table
    weights = folder / "weights.pt"
    torch.save(result.state_dict, weights)
    result.artifacts["weights"] = weights
    curve = plot_progress(
        result.returns,
        [m.rolling_mean for m in result.episodes],
        folder / "learning_curve.png",
        threshold=result.solve_threshold,
        title=f"{config.env_id}, seed {config.seed}",
    )
    result.artifacts["learning_curve"] = curve
    if is_pong(config.env_id):
        previous, frame = sample_pong_frames(config.env_id, config.seed)
        result.artifacts["observation"] = plot_pong_observation(previous, frame, folder / "observation.png")
    if config.record_video:
        video = folder / "video.mp4"
        with video_writer(video, env_info(config.env_id).video_fps) as writer:
            if is_pong(config.env_id):
                record_pong_episode(config, model, config.video_max_frames, writer.append_data)
            else:
                result.greedy_return = record_greedy_episode(config, model, config.video_max_frames, writer.append_data)
        result.artifacts["video"] = video
