"""Figures shared by a single trial and the report: the course's ``plot_progress`` learning curve.

Matplotlib with the non-interactive Agg backend, so it works on a headless machine or a Ray worker.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_progress(
    returns: Sequence[float],
    rolling_means: Sequence[float],
    path: str | Path,
    threshold: float | None = None,
    title: str = "",
) -> Path:
    """Per-episode return and its rolling mean against episodes, with the solve threshold, saved to ``path``."""
    path = Path(path)
    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    episodes = range(1, len(returns) + 1)
    ax.plot(episodes, returns, color="tab:blue", alpha=0.35, linewidth=0.8, label="episode return")
    ax.plot(episodes, rolling_means, color="tab:blue", linewidth=2, label="rolling mean")
    if threshold is not None:
        ax.axhline(threshold, color="tab:green", linestyle="--", linewidth=1, label=f"solved ({threshold:g})")
    ax.set_xlabel("episode")
    ax.set_ylabel("return")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_pong_observation(previous: np.ndarray, frame: np.ndarray, path: str | Path) -> Path:
    """One Pong observation three ways, side by side: the raw RGB frame, ``pre_process``-ed (80x80, 0/1),
    and the frame difference the policy sees (current - previous pre-processed frame: -1/0/+1)."""
    from ablate.envs import frame_difference, pre_process

    path = Path(path)
    fig, axes = plt.subplots(1, 3, figsize=(9, 3.4), dpi=100)
    panels = [
        (frame, "raw frame 210x160x3", {}),
        (pre_process(frame), "pre_process: 80x80, 0/1", {"cmap": "gray", "vmin": 0, "vmax": 1}),
        (frame_difference(frame, previous), "frame difference: -1/0/+1", {"cmap": "coolwarm", "vmin": -1, "vmax": 1}),
    ]
    for ax, (image, title, style) in zip(axes, panels, strict=True):
        ax.imshow(image, interpolation="nearest", **style)
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
