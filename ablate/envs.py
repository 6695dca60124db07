"""Environments: any Gymnasium env with discrete actions, as the trainer makes and describes it, through its
profile (``env_spec.PROFILES``); an env's state for a checkpoint; fenced at the end, every write to an env's
internals that no public API offers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from ablate.config import ENV_COLUMNS, TrialConfig
from ablate.env_spec import EnvError, Profile, profile_of, register, versions  # noqa: F401 - EnvError: what describe raises

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


class _PaletteForeground:
    """``pre_process`` as int8 (a quarter of the bytes: what trials store per step), straight from ALE's screen of
    palette indices (``getScreen``: 1 us, where the RGB screen costs ~21 us of a ~240 us step): a table from
    palette index to 0/1, filled from ``pre_process`` of the RGB screen the first time an index shows up, so the
    result is ``pre_process`` of the RGB frame by construction."""

    _UNKNOWN = 2

    def __init__(self) -> None:
        self.table = np.full(256, self._UNKNOWN, np.int8)

    def __call__(self, ale, screen: np.ndarray) -> np.ndarray:
        ale.getScreen(screen)
        indices = screen[35:195:2, ::2]
        image = np.take(self.table, indices)
        if (image == self._UNKNOWN).any():  # a colour not seen yet: learn it from the RGB screen
            image = pre_process(ale.getScreenRGB()).astype(np.int8)
            self.table[indices] = image
        return image


def frame_difference(frame: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
    """``pre_process(frame) - pre_process(previous)`` (zeros for the first frame), float32 (80, 80)."""
    current = pre_process(frame)
    return current - (current if previous is None else pre_process(previous))


# --- the Pong profile (issue 9): ale-py's own env through Gymnasium, with the course's observation and actions ---
MOVES = (("RIGHT", "LEFT"), ("UP", "DOWN"))
"""``action_set = "move"``: the first of these pairs of actions the game's minimal set has (Pong's RIGHT and LEFT
move the paddle up and down, as in Karpathy's pg-pong); ``all``: the whole minimal set."""


class ActionSubset(gym.ActionWrapper):
    """The policy's actions, ``range(len(actions))``, as the game's minimal-set actions ``action_set`` picks;
    ``names``: ALE's names of them."""

    def __init__(self, env: gym.Env, action_set: str = "all") -> None:
        super().__init__(env)
        meanings = env.unwrapped.get_action_meanings()
        pairs = [pair for pair in MOVES if set(pair) <= set(meanings)] if action_set == "move" else []
        if action_set == "move" and not pairs:
            raise EnvError(f"action_set = {action_set!r}: {env.spec.id} has no RIGHT/LEFT or UP/DOWN actions")
        self.actions = tuple(meanings.index(name) for name in pairs[0]) if pairs else tuple(range(len(meanings)))
        self.names = tuple(meanings[a] for a in self.actions)
        self.action_space = gym.spaces.Discrete(len(self.actions))

    def action(self, action: int) -> int:
        return self.actions[action]


class PongFrameDifference(gym.Wrapper):
    """int8 (1, 80, 80) frame differences of ``pre_process``-ed frames (zeros at a reset: no motion yet), read
    from the emulator's screen of palette indices (``_PaletteForeground``) through ale-py's public ``ALEInterface``
    (``env.unwrapped.ale``). ``state``/``set_state``: the previous frame, which a checkpoint needs beside the
    emulator's state to resume an episode exactly."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Box(-1, 1, (1, 80, 80), np.int8)
        self._ale = env.unwrapped.ale
        self._screen = np.zeros((210, 160), np.uint8)
        self._foreground = _PaletteForeground()
        self._previous = np.zeros((80, 80), np.int8)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        _, info = self.env.reset(seed=seed, options=options)
        self._previous = self._foreground(self._ale, self._screen)
        return np.zeros((1, 80, 80), np.int8), info

    def step(self, action: int):
        _, reward, terminated, truncated, info = self.env.step(action)
        current = self._foreground(self._ale, self._screen)
        difference = current - self._previous
        self._previous = current
        return difference[None], reward, terminated, truncated, info

    def state(self) -> dict:
        """What the next observation depends on beside the emulator: the last ``pre_process``-ed frame."""
        return {"previous": self._previous.copy()}

    def set_state(self, state: dict) -> None:
        self._previous = state["previous"].copy()


def make_pong(config: TrialConfig, render: bool = False) -> gym.Env:
    """The Pong profile's env of a trial: ale-py's ``AtariEnv`` of ``env_id`` (Pong, or any other game) giving
    ``PongFrameDifference``'s observations. ``render``: ``env.render()`` gives the RGB screen (videos)."""
    register(config)
    kwargs = {"max_episode_steps": config.max_episode_steps} if config.max_episode_steps > 0 else {}
    env = gym.make(
        config.env_id,
        # The observation is read from the palette screen: RAM is the cheapest one for AtariEnv to copy out.
        obs_type="ram",
        frameskip=config.frameskip,
        repeat_action_probability=config.repeat_action_probability,
        full_action_space=False,
        render_mode="rgb_array" if render else None,
        **kwargs,
        **dict(config.env_args),
    )
    return PongFrameDifference(ActionSubset(env, config.action_set))


def sample_frames(env_id: str = "ALE/Pong-v5", seed: int = 0, steps: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Two consecutive raw RGB frames of an Atari game ``steps`` agent steps in (Pong's ball in play), for figures."""
    env = make_pong(TrialConfig(env_id=env_id, repeat_action_probability=0.0), render=True)
    try:
        env.reset(seed=seed)
        previous = frame = env.render()
        for _ in range(steps):
            previous = frame
            env.step(0)
            frame = env.render()
        return previous, frame
    finally:
        env.close()


# --- any Gymnasium env with discrete actions (the one trainer's envs) ---
NATIVE_VECTOR = ("CartPole-v0", "CartPole-v1")
"""Envs whose Gymnasium vector form (``CartPoleVectorEnv``) steps a whole population in one call."""


def make_native_vector(env_id: str, num_envs: int, max_episode_steps: int) -> gym.vector.VectorEnv:
    """Gymnasium's own vector form of ``env_id`` (one of ``NATIVE_VECTOR``), through ``gym.make_vec``. CartPole's
    slots read an episode's end as its next step's autoreset, so another autoreset mode is an error, not a wrong
    result."""
    env = gym.make_vec(env_id, num_envs, vectorization_mode="vector_entry_point", max_episode_steps=max_episode_steps)
    mode = env.metadata.get("autoreset_mode")
    if mode != gym.vector.AutoresetMode.NEXT_STEP:
        raise RuntimeError(f"{env_id}'s vector env autoresets {mode}; ablate's CartPole slots need NEXT_STEP")
    return env


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
    """One env of a trial, its observations what the policy takes, as its profile makes it (``env_spec.PROFILES``),
    ``config``'s env registered first (``env_spec.register``)."""
    make = profile_of(config).maker()
    register(config)
    try:
        return make(config, render)
    except gym.error.Error as error:
        raise EnvError(f"env_id = {config.env_id!r}: {error}") from None
    except TypeError as error:
        raise EnvError(f"env_args = {dict(config.env_args)!r}: {config.env_id} refuses them ({error})") from None


def _gym_kwargs(config, render: bool) -> dict[str, Any]:
    kwargs = dict(config.env_args)
    if config.max_episode_steps:
        kwargs["max_episode_steps"] = config.max_episode_steps
    if render:
        kwargs["render_mode"] = "rgb_array"
    return kwargs


def make_atari_trial_env(config, render: bool = False) -> gym.Env:
    """The Atari profile's env: ``AtariPreprocessing``, its frames differenced."""
    kwargs = _gym_kwargs(config, render)
    kwargs.setdefault("repeat_action_probability", config.repeat_action_probability)
    env = gym.make(config.env_id, frameskip=1, **kwargs)
    return AtariFrameDifference(gym.wrappers.AtariPreprocessing(env, frame_skip=config.frameskip))


def make_gym_trial_env(config, render: bool = False) -> gym.Env:
    """The plain profile's env: ``gym.make(env_id, **env_args)``."""
    return gym.make(config.env_id, **_gym_kwargs(config, render))


@dataclass(frozen=True)
class Described:
    """What the trainer needs to know of a trial's env, read once from its config (``describe``)."""

    env_id: str
    profile: Profile
    """Its family: how its env is made, its return rule, its arrays' size (``env_spec.PROFILES``)."""
    native_vector: bool
    """Gymnasium's own vector form steps every slot in one call (one of ``NATIVE_VECTOR``, no ``env_args``)."""
    observation_shape: tuple[int, ...]
    n_actions: int
    reward_threshold: float | None
    max_episode_steps: int
    """Steps after which an episode is truncated (0: no limit)."""
    video_fps: int
    video_stride: int = 1
    video_downscale: int = 1
    observation_dtype: str = "float32"
    action_names: tuple[str, ...] = ()
    """The env's names of the policy's actions, where it names them (ALE's ``get_action_meanings``)."""


_DESCRIBED: dict[tuple, Described] = {}


def env_facts(config) -> tuple:
    """The values of the fields that make ``config``'s env (``config.ENV_COLUMNS``, top-level fields): configs with
    equal facts share one env, described once (``describe``)."""
    return tuple(getattr(config, column) for column in ENV_COLUMNS)


def describe(config) -> Described:
    """``config``'s env, described once per process (an env is built to read its spaces); an env the trainer cannot
    run is an ``EnvError`` saying why."""
    key = env_facts(config)
    if key in _DESCRIBED:
        return _DESCRIBED[key]
    env = make_trial_env(config)
    spec = gym.spec(config.env_id)
    try:
        actions, observations = env.action_space, env.observation_space
        if not isinstance(actions, gym.spaces.Discrete):
            raise EnvError(f"env_id = {config.env_id!r} has {type(actions).__name__} actions; valid: Discrete ones")
        if not isinstance(observations, gym.spaces.Box):
            raise EnvError(f"env_id = {config.env_id!r} has a {type(observations).__name__} observation; valid: a Box")
        profile = profile_of(config)
        limit = config.max_episode_steps or (spec.max_episode_steps or 0 if profile.episode_limit_from_spec else 0)
        cartpole = config.env_id in NATIVE_VECTOR
        described = Described(
            config.env_id,
            profile,
            cartpole and not config.env_args,
            tuple(observations.shape),
            int(actions.n),
            spec.reward_threshold,
            int(limit),
            int(env.metadata.get("render_fps", 30) or 30) if not cartpole else 25,
            video_stride=2 if cartpole else 1,
            video_downscale=2 if cartpole else 1,
            observation_dtype=str(observations.dtype),
            action_names=_action_names(env),
        )
    finally:
        env.close()
    _DESCRIBED[key] = described
    return described


def _wrappers(env):
    """``env``'s wrappers, outermost first."""
    while isinstance(env, gym.Wrapper):
        yield env
        env = env.env


def _action_names(env: gym.Env) -> tuple[str, ...]:
    subset = next((w for w in _wrappers(env) if isinstance(w, ActionSubset)), None)
    if subset is not None:
        return subset.names
    meanings = getattr(env.unwrapped, "get_action_meanings", None)
    return tuple(meanings()) if meanings else ()


def record(described: Described, threshold: float | None) -> dict[str, str]:
    """What a trial ran against, as its run's ``env.*`` params, ``threshold`` the solve threshold it stopped at
    (``None``: it ran its budget). The report and the launch read these, not the env's name."""
    libraries = versions()
    return {
        "env.id": described.env_id,
        "env.reward_threshold": str(described.reward_threshold),
        "env.max_episode_steps": str(described.max_episode_steps),
        "env.obs_shape": "x".join(map(str, described.observation_shape)),
        "env.obs_dtype": described.observation_dtype,
        "env.n_actions": str(described.n_actions),
        **({"env.actions": ", ".join(described.action_names)} if described.action_names else {}),
        "env.solve_threshold": str(threshold),
        "env.gymnasium_version": libraries["gymnasium"],
        "env.ale_py_version": libraries["ale-py"],
    }


def env_state(env) -> dict:
    """What ``env``'s next steps and resets draw from (a checkpointed slot's, restored by ``set_env_state``): the
    emulator's state, RNG included, where it has one (ALE), its wrappers' own (``state()``: Pong's previous frame)
    and its ``TimeLimit``'s step count; else its np_random."""
    base = env.unwrapped
    if hasattr(base, "clone_state"):
        return {
            "emulator": base.clone_state(include_rng=True),
            "wrappers": [w.state() for w in _stateful_wrappers(env)],
            "episode_steps": episode_steps(env),
        }
    return {"np_random": base.np_random.bit_generator.state}


def set_env_state(env, saved: dict) -> None:
    base = env.unwrapped
    if "emulator" in saved:
        env.reset()  # Gymnasium's OrderEnforcing refuses a step before a reset; the state below replaces its effects
        base.restore_state(saved["emulator"])
        for wrapper, state in zip(_stateful_wrappers(env), saved["wrappers"], strict=True):
            wrapper.set_state(state)
        set_episode_steps(env, saved["episode_steps"])
    else:
        base.np_random.bit_generator.state = saved["np_random"]


def _stateful_wrappers(env) -> list:
    return [w for w in _wrappers(env) if callable(getattr(type(w), "set_state", None))]


# --- an env's internals, fenced: every write ablate makes to what no public API lets one set ---
# Why: a vector env resets all its envs from one stream, so a member's start states would depend on which other
# members share its process; ablate draws each member's start states from that member's own stream and writes
# them in (``set_start_states``). A population that drops members goes on with a smaller vector env holding the
# survivors' episodes exactly as they were (``copy_slots``). A checkpoint taken mid-episode resumes exactly only
# if the episode's step count, which ``TimeLimit`` truncates at, comes back with it (``set_episode_steps``).
# ``tests/test_envs.py`` fails when Gymnasium changes any of what these functions assume.


def set_start_states(env, slots: np.ndarray, states: np.ndarray) -> None:
    """Slots ``slots`` of a ``CartPoleVectorEnv`` are in states ``states`` (4, len(slots)): x, x_dot, theta,
    theta_dot, one column a slot; its next step moves them by the physics."""
    env.state[:, slots] = states


def reset_counters(env, slots: np.ndarray) -> None:
    """``slots`` begin an episode: no steps taken, no autoreset pending (what ``reset`` does to every slot)."""
    env.steps[slots] = 0
    env.prev_done[slots] = False


def autoresetting(env) -> np.ndarray | None:
    """The slots whose next step is the next-step autoreset (their episode ended at the last step), or ``None``:
    that step draws their start states from the vector env's own stream, which the caller overwrites."""
    done = env.prev_done
    return np.flatnonzero(done) if done.any() else None


def copy_slots(old, new, slots: np.ndarray) -> None:
    """``new`` (a reset ``CartPoleVectorEnv`` of ``len(slots)`` envs) holds ``old``'s ``slots``, in this order, as
    they are: their states, step counts and pending autoresets."""
    new.state = np.ascontiguousarray(old.state[:, slots])
    new.steps, new.prev_done = old.steps[slots].copy(), old.prev_done[slots].copy()


class _SampledActions:
    """A vector env's action space whose ``contains`` checks the shape only. ``CartPoleVectorEnv.step`` asserts
    that its actions lie in its space, which cost a fifth of its step; the trainer's actions are sampled in
    ``range(n_actions)`` by construction (``reinforce.sample_actions``), so only their shape can be wrong."""

    def __init__(self, space) -> None:
        self.space = space

    def contains(self, actions) -> bool:
        return isinstance(actions, np.ndarray) and actions.shape == self.space.shape

    def __getattr__(self, name: str):
        return getattr(self.space, name)


def skip_action_check(env):
    """``env`` (a ``CartPoleVectorEnv``) checks its actions' shape only, not each value; returns it."""
    env.action_space = _SampledActions(env.action_space)
    return env


def _time_limit(env) -> gym.wrappers.TimeLimit | None:
    return next((w for w in _wrappers(env) if isinstance(w, gym.wrappers.TimeLimit)), None)


def episode_steps(env) -> int | None:
    """Steps of ``env``'s episode so far as its ``TimeLimit`` counts them (``None``: no limit, or no reset yet)."""
    limit = _time_limit(env)
    return None if limit is None else limit._elapsed_steps


def set_episode_steps(env, steps: int | None) -> None:
    """``env``'s ``TimeLimit`` counts ``steps`` steps of its episode so far (``episode_steps``'s value)."""
    limit = _time_limit(env)
    if limit is not None:
        limit._elapsed_steps = steps
