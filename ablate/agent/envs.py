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
    if "ALE/Pong-v5" in gym.registry:
        return  # registering again costs ~0.1 s (some 100 envs)
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


_FOREGROUND = np.ones(256, np.int8)
_FOREGROUND[[0, 109, 144]] = 0  # red-channel value -> 1 for paddles and ball, 0 for background (and black)


def pre_process_int8(frame: np.ndarray) -> np.ndarray:
    """``pre_process`` as int8 (the same 0/1 values, a quarter of the bytes): what trials store per step.
    One table look-up per pixel instead of three comparisons (11 us instead of 30 per frame)."""
    return np.take(_FOREGROUND, frame[35:195:2, ::2, 0])


class _PaletteForeground:
    """``pre_process_int8`` straight from ALE's screen of palette indices (``getScreen``: 1 us, where the RGB
    screen costs ~21 us of a ~240 us step): a table from palette index to 0/1, filled from the RGB screen the
    first time an index shows up, so the result is ``pre_process_int8`` of the RGB frame by construction."""

    _UNKNOWN = 2

    def __init__(self) -> None:
        self.table = np.full(256, self._UNKNOWN, np.int8)

    def __call__(self, ale, screen: np.ndarray) -> np.ndarray:
        ale.getScreen(screen)
        indices = screen[35:195:2, ::2]
        image = np.take(self.table, indices)
        if (image == self._UNKNOWN).any():  # a colour not seen yet: learn it from the RGB screen
            image = pre_process_int8(ale.getScreenRGB())
            self.table[indices] = image
        return image


def frame_difference(frame: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
    """``pre_process(frame) - pre_process(previous)`` (zeros for the first frame), float32 (80, 80)."""
    current = pre_process(frame)
    return current - (current if previous is None else pre_process(previous))


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


# --- Pong for trials (issue 9): a lean env with the experiment's knobs, int8 frame differences ---
PONG_ACTIONS = {"all": (0, 1, 2, 3, 4, 5), "move": (2, 3)}
"""Policy action index -> ALE action. ``move``: 2 (RIGHT, the paddle goes up) and 3 (LEFT, down)."""


class PongEnv:
    """One Pong emulator (ALE itself, without Gymnasium's env and wrappers) giving int8 (80, 80) frame
    differences of ``pre_process``-ed frames; actions are indices into ``PONG_ACTIONS[action_set]``;
    ``max_episode_steps`` (0: none) truncates. Same emulator settings and seeding as ``ALE/Pong-v5``
    (``ale_py.env.AtariEnv``), but the ROM is loaded once (AtariEnv loads it at construction and again at a
    seeded reset: 0.15 s each) and a step skips AtariEnv's extras (an info dict, a second game-over query).
    ``frame`` is the last raw RGB screen (for videos). ``state``/``set_state``: the whole state, emulator
    RNG included (for checkpoints)."""

    def __init__(
        self,
        env_id: str = "ALE/Pong-v5",
        action_set: str = "all",
        frameskip: int = 4,
        repeat_action_probability: float = 0.25,
        max_episode_steps: int = 0,
    ) -> None:
        import ale_py

        if not is_pong(env_id):
            raise ValueError(f"PongEnv plays ALE/Pong only, not {env_id}")
        self.ale = ale_py.ALEInterface()
        self.ale.setLoggerMode(ale_py.LoggerMode.Error)
        self.ale.setFloat("repeat_action_probability", repeat_action_probability)
        self.ale.setInt("max_num_frames_per_episode", 108_000)  # v5's limit (30 min of play)
        # One act() emulates frameskip frames (sticky actions drawn per frame, rewards summed), as AtariEnv's
        # Python loop of frameskip act() calls does.
        self.ale.setInt("frame_skip", frameskip)
        self._rom = ale_py.roms.get_rom_path("pong")
        self._loaded = False
        self.actions = PONG_ACTIONS[action_set]
        self.ale_actions: list = []
        self.frameskip = frameskip
        self.max_episode_steps = max_episode_steps
        self.steps = 0
        self._frame: np.ndarray | None = None
        self._previous: np.ndarray | None = None
        self._screen = np.zeros((210, 160), np.uint8)
        self._foreground = _PaletteForeground()

    @property
    def frame(self) -> np.ndarray:
        """The last raw RGB screen, read from the emulator only when asked for (videos, figures)."""
        if self._frame is None:
            self._frame = self.ale.getScreenRGB()
        return self._frame

    def reset(self, seed: int | None = None) -> np.ndarray:
        if seed is not None or not self._loaded:
            # As AtariEnv.seed_game: the emulator's seed is the second word drawn from SeedSequence(seed).
            _, ale_seed = np.random.SeedSequence(seed).generate_state(n_words=2)
            self.ale.setInt("random_seed", np.int32(ale_seed))
            self.ale.loadROM(self._rom)
            minimal = self.ale.getMinimalActionSet()
            self.ale_actions = [minimal[a] for a in self.actions]
            self._loaded = True
        self.ale.reset_game()
        self._frame = None
        self.steps = 0
        self._previous = self._foreground(self.ale, self._screen)
        return np.zeros((80, 80), np.int8)

    def step(self, action: int) -> tuple[np.ndarray, float, bool]:
        """(observation, reward, episode over)."""
        ale = self.ale
        reward = ale.act(self.ale_actions[action])
        self._frame = None
        self.steps += 1
        current = self._foreground(ale, self._screen)
        observation = current - self._previous
        self._previous = current
        done = ale.game_over() or (self.max_episode_steps > 0 and self.steps >= self.max_episode_steps)
        return observation, float(reward), bool(done)

    def state(self) -> dict:
        return {
            "ale": self.ale.cloneState(include_rng=True),
            "steps": self.steps,
            "frame": self.frame,
            "previous": self._previous,
        }

    def set_state(self, state: dict) -> None:
        self.ale.restoreState(state["ale"])
        self.steps = state["steps"]
        self._frame = state["frame"]
        self._previous = state["previous"]

    def close(self) -> None:
        pass


def sample_pong_frames(env_id: str = "ALE/Pong-v5", seed: int = 0, steps: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Two consecutive raw RGB frames of a Pong game ``steps`` agent steps in (the ball in play), for figures."""
    env = PongEnv(env_id, repeat_action_probability=0.0)
    try:
        env.reset(seed=seed)
        previous = env.frame
        for _ in range(steps):
            previous = env.frame
            env.step(0)
        return previous, env.frame
    finally:
        env.close()
