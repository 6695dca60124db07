"""What a finished trial leaves in its folder (``write_artifacts``), and its video recorded later from those files
(``replay_video``). Matplotlib with the Agg backend: it draws on a headless machine or a Ray worker.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path

import matplotlib
import numpy as np
import torch
from torch import nn

from ablate.agent.policies import build_model
from ablate.agent.policies import history as window_of
from ablate.agent.records import EpisodeMetrics, TrialResult
from ablate.agent.reinforce import choose_action
from ablate.agent.slots import windows
from ablate.config import TrialConfig, config_from_document
from ablate.envs import describe, frame_difference, make_trial_env, pre_process, profile_of, sample_frames
from ablate.videos import rendered, video_writer

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def record_episode(config: TrialConfig, model: nn.Module, on_frame: Callable[[np.ndarray], None]) -> float:
    """Play one episode of ``model`` on a seed training never used, frames to ``on_frame`` as they come (every
    ``video_stride``-th step, downscaled, up to ``video_max_frames``); returns its return. Greedy (argmax), except
    where the env's profile plays the sampling policy (``Profile.sampling_video``)."""
    info, max_frames = describe(config), config.video_max_frames
    history = window_of(config.model, info)
    env = make_trial_env(config, render=True)
    greedy = not profile_of(config).sampling_video
    rng = np.random.default_rng(config.seed + 1_000_003)
    scale = info.video_downscale
    seen: list[np.ndarray] = []

    def frame() -> None:
        on_frame(np.ascontiguousarray(rendered(env.render)[::scale, ::scale]))

    def policy_input(observation: np.ndarray) -> np.ndarray:
        if not history:
            return np.asarray(observation)
        seen.append(np.asarray(observation))
        del seen[:-history]  # the window needs the last `history` only (zeros before the episode's first)
        return windows(np.stack(seen).astype(np.float32), history)[-1]

    try:
        observation, _ = env.reset(seed=config.seed + 1_000_003)
        frame()
        frames, steps, total, done = 1, 0, 0.0, False
        while not done and frames < max_frames:
            action = choose_action(model, policy_input(observation), rng, greedy=greedy)
            observation, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            steps += 1
            done = terminated or truncated
            if steps % info.video_stride == 0 or done:
                frame()
                frames += 1
        return total
    finally:
        env.close()


def write_artifacts(result: TrialResult, folder: Path, video: bool = True, curve: bool = True) -> None:
    """Per-episode table, weights, config, learning curve and (``record_video`` and ``video``) a video of the agent
    into ``folder``, each added to ``result.artifacts``; for Pong also ``observation.png`` (one observation raw,
    pre-processed and as a frame difference). ``video=False``: the video is left to ``replay_video`` (a launch's
    report records its picks'). ``curve=False``: no ``learning_curve.png`` (why: ``launch.grid.PLOTTED_SEEDS``)."""
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
    settings = folder / "config.json"
    settings.write_text(json.dumps(dataclasses.asdict(config), indent=1), encoding="utf-8")
    result.artifacts["config"] = settings
    if curve:
        result.artifacts["learning_curve"] = plot_progress(
            result.returns,
            [m.rolling_mean for m in result.episodes],
            folder / "learning_curve.png",
            threshold=result.solve_threshold,
            title=f"{config.env_id}, seed {config.seed}",
        )
    if profile_of(config).observation_figure:
        previous, frame = sample_frames(config.env_id, config.seed)
        result.artifacts["observation"] = plot_pong_observation(previous, frame, folder / "observation.png")
    if config.model.factory_source:
        source = folder / "model.py"
        source.write_text(config.model.factory_source[0][1], encoding="utf-8")  # the factory's own file
        result.artifacts["model_source"] = source
    if config.record_video and video:
        path = folder / "video.mp4"
        played = _write_video(config, _network(config, result.state_dict), path)
        if not profile_of(config).sampling_video:
            result.greedy_return = played
        result.artifacts["video"] = path


def _network(config: TrialConfig, state_dict: dict[str, torch.Tensor]) -> nn.Module:
    """The trial's network with its trained weights (the global RNG left as it was: members may still train)."""
    with torch.random.fork_rng(devices=[]):
        model = build_model(config, describe(config))
    model.load_state_dict(state_dict)
    return model


def _write_video(config: TrialConfig, model: nn.Module, path: Path) -> float:
    with video_writer(path, describe(config).video_fps) as writer:
        return record_episode(config, model, writer.append_data)


def replay_video(config_json: Path, weights: Path, path: Path) -> float | None:
    """The video ``write_artifacts`` would have recorded at the trial's end, from the ``config.json`` and
    ``weights.pt`` it left: the same network, weights, env seed and frames. Returns the greedy return it played
    (``None`` on Pong, whose video is of the sampling policy). Raises what building the network or the env
    raises (a user's factory or env module that this machine cannot import)."""
    config = config_from_document(json.loads(config_json.read_text(encoding="utf-8")))
    played = _write_video(config, _network(config, torch.load(weights, map_location="cpu", weights_only=True)), path)
    return None if profile_of(config).sampling_video else played


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
