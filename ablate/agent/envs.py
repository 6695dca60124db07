"""Environments: any Gymnasium env with discrete actions, as the trainer makes and describes it; Pong's course
pipeline (``pre_process``, the frame difference) and other Atari games' standard one.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from ablate.config import env_facts
from ablate.env_spec import EnvError, is_pong, register, versions  # noqa: F401 - EnvError: what describe raises

# Rendering to RGB arrays needs no window; without this, SDL (pygame, under CartPole's renderer) probes for a
# display and prints "XDG_RUNTIME_DIR is invalid or not set" on a headless machine.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")


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


# --- any Gymnasium env with discrete actions (the one trainer's envs) ---
NATIVE_VECTOR = ("CartPole-v0", "CartPole-v1")
"""Envs whose Gymnasium vector form (``CartPoleVectorEnv``) steps a whole population in one call."""


def is_native_vector(config) -> bool:
    return config.env_id in NATIVE_VECTOR and not config.env_args


def is_atari(env_id: str) -> bool:
    return env_id.startswith("ALE/") and not is_pong(env_id)


class PongGymEnv(PongEnv):
    """``PongEnv`` with Gymnasium's API (``reset`` -> (obs, info), ``step`` -> 5-tuple, spaces, state cloning)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.observation_space = gym.spaces.Box(-1, 1, (1, 80, 80), np.int8)
        self.action_space = gym.spaces.Discrete(len(self.actions))
        self.metadata = {"render_fps": 30}
        self.unwrapped = self

    def reset(self, seed: int | None = None, options=None):  # type: ignore[override]
        return super().reset(seed=seed)[None], {}

    def step(self, action: int):  # type: ignore[override]
        observation, reward, done = super().step(action)
        return observation[None], reward, done, False, {}

    def render(self) -> np.ndarray:
        return self.frame

    def clone_state(self, include_rng: bool = True) -> dict:
        return self.state()

    def restore_state(self, state: dict) -> None:
        if not self._loaded:  # the emulator needs its ROM before a state (RNG included) can be put back
            super().reset(seed=0)
        self.set_state(state)


class AtariFrameDifference(gym.ObservationWrapper):
    """A grayscale 84x84 frame (``AtariPreprocessing``) minus the previous one, scaled to [-1, 1], (1, 84, 84):
    the frame difference the course feeds its Pong CNN, for any other Atari game."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (1, *env.observation_space.shape), np.float32)
        self._previous: np.ndarray | None = None

    def reset(self, **kwargs):  # type: ignore[override]
        self._previous = None
        return super().reset(**kwargs)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        current = observation.astype(np.float32) / 255.0
        previous = current if self._previous is None else self._previous
        self._previous = current
        return (current - previous)[None]


def make_trial_env(config, render: bool = False) -> gym.Env:
    """One env of a trial, its observations what the policy takes: Pong's frame differences of ``pre_process``-ed
    frames; another Atari game's grayscale 84x84 frame differences (``AtariPreprocessing``, ``frameskip`` frames a
    step, sticky actions at ``repeat_action_probability``); any other env as ``gym.make(env_id, **env_args)``."""
    register(config)
    if is_pong(config.env_id) and not config.env_args:
        return PongGymEnv(
            config.env_id,
            config.action_set,
            config.frameskip,
            config.repeat_action_probability,
            config.max_episode_steps,
        )
    kwargs = dict(config.env_args)
    if config.max_episode_steps:
        kwargs["max_episode_steps"] = config.max_episode_steps
    if render:
        kwargs["render_mode"] = "rgb_array"
    try:
        if is_atari(config.env_id):
            kwargs.setdefault("repeat_action_probability", config.repeat_action_probability)
            env = gym.make(config.env_id, frameskip=1, **kwargs)
            return AtariFrameDifference(gym.wrappers.AtariPreprocessing(env, frame_skip=config.frameskip))
        return gym.make(config.env_id, **kwargs)
    except gym.error.Error as error:
        raise EnvError(f"env_id = {config.env_id!r}: {error}") from None
    except TypeError as error:
        raise EnvError(f"env_args = {dict(config.env_args)!r}: {config.env_id} refuses them ({error})") from None


@dataclass(frozen=True)
class Described:
    """What the trainer needs to know of a trial's env."""

    observation_shape: tuple[int, ...]
    n_actions: int
    reward_threshold: float | None
    max_episode_steps: int
    """Steps after which an episode is truncated (0: no limit)."""
    video_fps: int
    video_stride: int = 1
    video_downscale: int = 1
    observation_dtype: str = "float32"


_DESCRIBED: dict[tuple, Described] = {}


def describe(config) -> Described:
    """``config``'s env, described once per process (an env is built to read its spaces); an env the trainer cannot
    run is an ``EnvError`` saying why."""
    key = env_facts(config)
    if key in _DESCRIBED:
        return _DESCRIBED[key]
    register(config)
    if config.env_id not in gym.registry:
        raise EnvError(f"env_id = {config.env_id!r} is not a registered Gymnasium env (e.g. CartPole-v1, Acrobot-v1)")
    spec = gym.spec(config.env_id)
    env = make_trial_env(config)
    try:
        actions, observations = env.action_space, env.observation_space
        if not isinstance(actions, gym.spaces.Discrete):
            raise EnvError(f"env_id = {config.env_id!r} has {type(actions).__name__} actions; valid: Discrete ones")
        if not isinstance(observations, gym.spaces.Box):
            raise EnvError(f"env_id = {config.env_id!r} has a {type(observations).__name__} observation; valid: a Box")
        limit = config.max_episode_steps or spec.max_episode_steps or 0
        if is_pong(config.env_id):
            limit = config.max_episode_steps
        cartpole = config.env_id in NATIVE_VECTOR
        described = Described(
            tuple(observations.shape),
            int(actions.n),
            spec.reward_threshold,
            int(limit),
            int(env.metadata.get("render_fps", 30) or 30) if not cartpole else 25,
            video_stride=2 if cartpole else 1,
            video_downscale=2 if cartpole else 1,
            observation_dtype=str(observations.dtype),
        )
    finally:
        env.close()
    _DESCRIBED[key] = described
    return described


def record(config, described: Described, threshold: float | None) -> dict[str, str]:
    """What a trial ran against, as its run's ``env.*`` params: the env id, its spec's reward threshold and
    episode limit, its observation's shape and dtype, its action count, the solve threshold the trial stopped
    at (``None``: it ran its budget), and the env libraries' versions. The report and the launch read these, not
    the env's name."""
    libraries = versions()
    return {
        "env.id": config.env_id,
        "env.reward_threshold": str(described.reward_threshold),
        "env.max_episode_steps": str(described.max_episode_steps),
        "env.obs_shape": "x".join(map(str, described.observation_shape)),
        "env.obs_dtype": described.observation_dtype,
        "env.n_actions": str(described.n_actions),
        "env.solve_threshold": str(threshold),
        "env.gymnasium_version": libraries["gymnasium"],
        "env.ale_py_version": libraries["ale-py"],
    }
