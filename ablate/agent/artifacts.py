"""What a finished trial leaves in its folder: ``episodes.csv``, ``weights.pt``, ``config.json``, the learning
curve, a video of the trained policy, Pong's observation figure, and the videos of the sampling policy taken while
it trained. ``replay_video`` records the trained policy's video later, from ``weights.pt`` and ``config.json``:
a launch leaves each trial's video to the report, which records only the seeds it shows.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ablate.agent.models import build_model
from ablate.agent.models import history as window_of
from ablate.agent.records import EpisodeMetrics, TrialResult
from ablate.agent.reinforce import choose_action
from ablate.agent.slots import windows
from ablate.config import TrialConfig, config_document, config_from_document
from ablate.envs import describe, is_pong, make_trial_env


def video_writer(path: Path, fps: int):
    import imageio.v2 as imageio  # a worker pays for ffmpeg only when it records

    # yuv420p H.264 plays in every browser, MLflow's artifact viewer included. One encoder thread at x264's
    # fastest preset: ffmpeg runs beside the trial's own process, on CPUs its neighbours are training on.
    return imageio.get_writer(
        path,
        fps=fps,
        codec="libx264",
        pixelformat="yuv420p",
        macro_block_size=2,
        output_params=["-threads", "1", "-preset", "ultrafast"],
    )


class TrainingVideos:
    """Videos of the sampling policy as it trains: every ``every`` episodes, the member's first env's next episode,
    up to ``max_frames`` frames, into ``folder/videos/episode_NNNNN.mp4`` (NNNNN: the episode's number)."""

    def __init__(self, folder: Path | None, every: int, max_frames: int, fps: int, completed: int = 0) -> None:
        self.folder = folder / "videos" if folder is not None else None
        self.every = every if folder is not None else 0
        self.max_frames = max_frames
        self.fps = fps
        self.next_at = -(-completed // self.every) * self.every if self.every else 0
        self.writer = None
        self.frames = 0
        self.paths: list[Path] = []

    def episode_started(self, completed: int, frame: Callable[[], np.ndarray]) -> None:
        """The first env began an episode; ``completed`` episodes have finished in the trial so far."""
        if not self.every or self.writer is not None or completed < self.next_at:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / f"episode_{completed + 1:05d}.mp4"
        self.writer = video_writer(path, self.fps)
        self.paths.append(path)
        self.frames = 0
        self.next_at = (completed // self.every + 1) * self.every
        self.frame(frame, done=False)

    def frame(self, frame: Callable[[], np.ndarray], done: bool) -> None:
        if self.writer is None:
            return
        self.writer.append_data(frame())
        self.frames += 1
        if done or self.frames >= self.max_frames:
            self.close()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


def record_episode(
    config, model: nn.Module, history: int, max_frames: int, on_frame: Callable[[np.ndarray], None]
) -> float:
    """Play one episode of ``model`` on a seed training never used, frames to ``on_frame`` as they come (every
    ``video_stride``-th step, downscaled); returns its return. Greedy (argmax), except on Pong, where a greedy agent
    that has not learnt much presses one button for the whole video: there the sampling policy plays."""
    info = describe(config)
    env = make_trial_env(config, render=True)
    greedy = not is_pong(config.env_id)
    rng = np.random.default_rng(config.seed + 1_000_003)
    scale = info.video_downscale
    seen: list[np.ndarray] = []

    def frame() -> None:
        on_frame(np.ascontiguousarray(np.asarray(env.render())[::scale, ::scale]))

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


def write_artifacts(result: TrialResult, model: nn.Module, history: int, folder: Path, video: bool = True) -> None:
    """Per-episode table, weights, config, learning curve and (``record_video`` and ``video``) a video of the agent
    into ``folder``; for Pong also ``observation.png`` (one observation raw, pre-processed and as a frame
    difference). ``video=False``: the video is left to ``replay_video`` (a launch's report records its picks')."""
    from ablate.agent.plots import plot_pong_observation, plot_progress
    from ablate.envs import sample_pong_frames

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
    settings.write_text(json.dumps(config_document(config), indent=1), encoding="utf-8")
    result.artifacts["config"] = settings
    result.artifacts["learning_curve"] = plot_progress(
        result.returns,
        [m.rolling_mean for m in result.episodes],
        folder / "learning_curve.png",
        threshold=result.solve_threshold,
        title=f"{config.env_id}, seed {config.seed}",
    )
    if is_pong(config.env_id):
        previous, frame = sample_pong_frames(config.env_id, config.seed)
        result.artifacts["observation"] = plot_pong_observation(previous, frame, folder / "observation.png")
    if config.model.factory_source:
        source = folder / "model.py"
        source.write_text(config.model.factory_source[0][1], encoding="utf-8")  # the factory's own file
        result.artifacts["model_source"] = source
    if config.record_video and video:
        path = folder / "video.mp4"
        played = _write_video(config, model, history, path)
        if not is_pong(config.env_id):
            result.greedy_return = played
        result.artifacts["video"] = path


def _write_video(config: TrialConfig, model: nn.Module, history: int, path: Path) -> float:
    with video_writer(path, describe(config).video_fps) as writer:
        return record_episode(config, model, history, config.video_max_frames, writer.append_data)


def replay_video(config_json: Path, weights: Path, path: Path) -> float | None:
    """The video ``write_artifacts`` would have recorded at the trial's end, from the ``config.json`` and
    ``weights.pt`` it left: the same network, weights, env seed and frames. Returns the greedy return it played
    (``None`` on Pong, whose video is of the sampling policy). Raises what building the network or the env
    raises (a user's factory or env module that this machine cannot import)."""
    config = config_from_document(json.loads(config_json.read_text(encoding="utf-8")))
    model = build_model(config, describe(config))
    model.load_state_dict(torch.load(weights, map_location="cpu", weights_only=True))
    played = _write_video(config, model, window_of(config), path)
    return None if is_pong(config.env_id) else played
