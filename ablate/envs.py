"""Environments: CartPole and Pong factories, Pong's ``pre_process`` and frame difference, observation windows.

Everything here turns a Gymnasium env into the observations a policy from ``policies`` expects.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from ablate.config import ModelConfig

# Rendering to RGB arrays needs no window; without this, SDL (pygame, under CartPole's renderer) probes for a
# display and prints "XDG_RUNTIME_DIR is invalid or not set" on a headless machine.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")


@dataclass(frozen=True)
class EnvInfo:
    observation_size: int
    n_actions: int
    reward_threshold: float | None
    max_episode_steps: int | None
    video_fps: int
    """Frames per second of a recorded video (real time for CartPole, whose physics step is 20 ms)."""
    video_stride: int = 1
    """Record every n-th step: CartPole at 25 fps of its 50 steps a second looks the same and costs half."""
    video_downscale: int = 1
    """Keep every n-th pixel: CartPole renders 600x400; 300x200 encodes ~4x faster and plays the same."""


def is_pong(env_id: str) -> bool:
    return env_id.startswith("ALE/Pong")


def _register_ale() -> None:
    import ale_py  # imported lazily: CartPole-only users never pay for the emulator

    gym.register_envs(ale_py)


def env_info(env_id: str) -> EnvInfo:
    if is_pong(env_id):
        _register_ale()
    spec = gym.spec(env_id)
    if is_pong(env_id):
        return EnvInfo(80 * 80, 6, spec.reward_threshold, spec.max_episode_steps, 30)
    return EnvInfo(4, 2, spec.reward_threshold, spec.max_episode_steps, 25, video_stride=2, video_downscale=2)


def make_env(env_id: str, render: bool = False) -> gym.Env:
    """One env whose observations are policy inputs (Pong: frame differences), optionally rendering RGB."""
    if is_pong(env_id):
        _register_ale()
        return FrameDifference(gym.make(env_id, render_mode="rgb_array" if render else None))
    return gym.make(env_id, render_mode="rgb_array" if render else None)


def make_vec_env(env_id: str, num_envs: int) -> gym.vector.VectorEnv:
    """``num_envs`` copies stepped together. CartPole uses Gymnasium's numpy-vectorised implementation
    (one call steps all of them, ~70 us whatever their number) from 3 copies up; below that, and for Pong,
    copies step one after another in this process (~27 us per CartPole copy)."""
    if is_pong(env_id):
        return gym.vector.SyncVectorEnv([lambda: make_env(env_id) for _ in range(num_envs)])
    if num_envs <= 2:
        return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="sync")
    spec = gym.spec(env_id)
    return gym.make_vec(
        env_id,
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        max_episode_steps=spec.max_episode_steps,
    )


def pre_process(frame: np.ndarray) -> np.ndarray:
    """210x160x3 Pong frame -> 80x80 float32 of 0/1: crop rows 35:195 (the playing field), keep every
    2nd pixel of one colour channel, erase the two background colours (144, 109), paddles and ball -> 1."""
    image = frame[35:195:2, ::2, 0].astype(np.float32)
    image[(image == 144) | (image == 109)] = 0
    image[image != 0] = 1
    return image


class FrameDifference(gym.ObservationWrapper):
    """Pong observation = pre_process(frame) - pre_process(previous frame), shape (1, 80, 80): motion is
    what the policy needs, and one difference image carries the ball's direction."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (1, 80, 80), np.float32)
        self._previous: np.ndarray | None = None

    def reset(self, **kwargs):  # type: ignore[override]
        self._previous = None
        return super().reset(**kwargs)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        current = pre_process(observation)
        previous = current if self._previous is None else self._previous
        self._previous = current
        return (current - previous)[None]


class ObservationWindow:
    """The last ``history`` observations of each of a batch of envs, oldest first, zero-padded after reset.
    CartPole's ``cnn`` policy reads this window instead of the single current observation."""

    def __init__(self, history: int) -> None:
        self.history = history
        self._window: np.ndarray | None = None

    def reset(self, observations: np.ndarray) -> np.ndarray:
        self._window = np.zeros((len(observations), self.history, *observations.shape[1:]), np.float32)
        return self.step(observations)

    def step(self, observations: np.ndarray) -> np.ndarray:
        assert self._window is not None, "reset() first"
        self._window[:, :-1] = self._window[:, 1:]
        self._window[:, -1] = observations
        return self._window.copy()


class _Identity:
    def reset(self, observations: np.ndarray) -> np.ndarray:
        return np.asarray(observations, dtype=np.float32)

    step = reset


def observation_adapter(env_id: str, model: ModelConfig) -> ObservationWindow | _Identity:
    """What turns raw (batched) env observations into the policy's input for this env and model."""
    if model.architecture == "cnn" and not is_pong(env_id):
        return ObservationWindow(model.history)
    return _Identity()
