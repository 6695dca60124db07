"""Every change ablate makes to an env's internals lives here: Gymnasium's ``CartPoleVectorEnv``'s ``state``,
``steps``, ``prev_done`` and ``action_space``, and ``TimeLimit``'s step count, which no public API lets one set.

Why: a vector env resets all its envs from one stream, so a member's start states would depend on which other
members share its process; ablate draws each member's start states from that member's own stream and writes
them in (``set_start_states``). A population that drops members goes on with a smaller vector env holding the
survivors' episodes exactly as they were (``copy_slots``). A checkpoint taken mid-episode resumes exactly only
if the episode's step count, which ``TimeLimit`` truncates at, comes back with it (``set_episode_steps``).
``tests/test_env_internals.py`` fails when Gymnasium changes any of what these functions assume.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np


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
    """The ``TimeLimit`` among ``env``'s wrappers, if any."""
    while isinstance(env, gym.Wrapper):
        if isinstance(env, gym.wrappers.TimeLimit):
            return env
        env = env.env
    return None


def episode_steps(env) -> int | None:
    """Steps of ``env``'s episode so far as its ``TimeLimit`` counts them (``None``: no limit, or no reset yet)."""
    limit = _time_limit(env)
    return None if limit is None else limit._elapsed_steps


def set_episode_steps(env, steps: int | None) -> None:
    """``env``'s ``TimeLimit`` counts ``steps`` steps of its episode so far (``episode_steps``'s value)."""
    limit = _time_limit(env)
    if limit is not None:
        limit._elapsed_steps = steps
