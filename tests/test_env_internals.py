"""What ``env_internals`` assumes of Gymnasium's ``CartPoleVectorEnv``: each test fails when a Gymnasium release
changes it (an attribute renamed or reshaped, the physics or the next-step autoreset reworked)."""

import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv, CartPoleVectorEnv

from ablate import env_internals


def _env(n: int = 3, max_episode_steps: int = 500) -> CartPoleVectorEnv:
    env = CartPoleVectorEnv(num_envs=n, max_episode_steps=max_episode_steps)
    env.reset(seed=0)
    return env


def _next_state(state: np.ndarray, action: int) -> np.ndarray:
    """CartPole's Euler step, by hand (Florian's equations, Gymnasium's constants)."""
    x, x_dot, theta, theta_dot = state
    force = 10.0 if action == 1 else -10.0
    total_mass, polemass_length = 1.1, 0.05
    temp = (force + polemass_length * theta_dot**2 * np.sin(theta)) / total_mass
    half_length = 0.5
    thetaacc = (9.8 * np.sin(theta) - np.cos(theta) * temp) / (
        half_length * (4.0 / 3.0 - 0.1 * np.cos(theta) ** 2 / total_mass)
    )
    xacc = temp - polemass_length * thetaacc * np.cos(theta) / total_mass
    return np.array([x + 0.02 * x_dot, x_dot + 0.02 * xacc, theta + 0.02 * theta_dot, theta_dot + 0.02 * thetaacc])


def test_the_internals_exist_with_the_shapes_and_dtypes_written():
    env = _env(5)
    assert env.state.shape == (4, 5) and env.state.dtype == np.float64
    assert env.steps.shape == (5,) and np.issubdtype(env.steps.dtype, np.integer)
    assert env.prev_done.shape == (5,) and env.prev_done.dtype == np.bool_
    assert (env.low, env.high) == (-0.05, 0.05)  # CartPoleSlots draws start states from the same bounds


def test_a_written_start_state_is_stepped_by_the_physics():
    env = _env(3)
    states = np.array([[0.01, -0.02, 0.03], [0.0, 0.1, -0.1], [0.02, -0.01, 0.04], [-0.03, 0.2, 0.0]])
    env_internals.set_start_states(env, np.array([0, 2]), states[:, [0, 2]])
    env_internals.set_start_states(env, np.array([1]), states[:, [1]])
    actions = np.array([1, 0, 1])
    observations, rewards, terminated, truncated, _ = env.step(actions)
    expected = np.stack([_next_state(states[:, k], int(actions[k])) for k in range(3)], axis=1)
    np.testing.assert_allclose(env.state, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(observations, env.state.T.astype(np.float32))  # what CartPoleSlots stores
    assert rewards.tolist() == [1.0] * 3 and not terminated.any() and not truncated.any()
    single = CartPoleEnv()  # the single env agrees with the vector env from the same state
    single.reset(seed=0)
    single.state = tuple(states[:, 0])
    np.testing.assert_allclose(single.step(1)[0], observations[0], rtol=1e-6)


def test_the_next_step_autoresets_an_ended_slot_unless_its_counters_are_reset():
    env = _env(2, max_episode_steps=500)
    falling = np.array([[0.0, 0.0], [0.0, 0.0], [0.2, 0.0], [2.0, 0.0]])  # slot 0 past 12 degrees after a step
    env_internals.set_start_states(env, np.array([0, 1]), falling)
    assert env_internals.autoresetting(env) is None
    _, rewards, terminated, _, _ = env.step(np.array([0, 0]))
    assert terminated.tolist() == [True, False] and rewards.tolist() == [1.0, 1.0]
    assert env_internals.autoresetting(env).tolist() == [0]
    _, rewards, terminated, truncated, _ = env.step(np.array([0, 0]))  # the autoreset step: a fresh start state
    assert rewards.tolist() == [0.0, 1.0] and not terminated[0] and not truncated[0]
    assert (np.abs(env.state[:, 0]) <= 0.05).all() and env.steps.tolist() == [0, 2]
    assert env_internals.autoresetting(env) is None
    # A slot whose counters are reset is stepped by the physics, not autoreset, whatever ended before.
    env_internals.set_start_states(env, np.array([0]), falling[:, [0]])
    env.step(np.array([0, 0]))
    assert env_internals.autoresetting(env).tolist() == [0]
    start = np.array([[0.01], [0.0], [0.0], [0.0]])
    env_internals.set_start_states(env, np.array([0]), start)
    env_internals.reset_counters(env, np.array([0]))
    _, rewards, _, _, _ = env.step(np.array([1, 0]))
    assert rewards[0] == 1.0 and env.steps[0] == 1
    np.testing.assert_allclose(env.state[:, 0], _next_state(start[:, 0], 1), rtol=1e-12, atol=1e-15)


def test_an_episode_is_truncated_at_max_episode_steps_counted_by_steps():
    env = _env(1, max_episode_steps=3)
    env_internals.set_start_states(env, np.array([0]), np.zeros((4, 1)))
    truncations = [bool(env.step(np.array([t % 2]))[3][0]) for t in range(3)]
    assert truncations == [False, False, True] and env.steps.tolist() == [3]
    assert env_internals.autoresetting(env).tolist() == [0]


def test_copied_slots_go_on_as_they_would_have_in_the_old_env():
    old, new = _env(4), CartPoleVectorEnv(num_envs=2, max_episode_steps=500)
    new.reset(seed=1)
    for t in range(3):
        old.step(np.array([t % 2, 1, 0, 1]))
    env_internals.copy_slots(old, new, np.array([3, 1]))
    assert new.steps.tolist() == [3, 3]
    after_old = old.step(np.array([0, 1, 0, 0]))[0]
    after_new = new.step(np.array([0, 1]))[0]
    np.testing.assert_array_equal(after_new, after_old[[3, 1]])


def test_skipping_the_action_check_still_refuses_a_wrong_shape():
    env = env_internals.skip_action_check(_env(3))
    assert env.action_space.shape == (3,) and env.action_space.nvec.tolist() == [2, 2, 2]  # the space as it was
    env.step(np.array([0, 1, 1]))
    with pytest.raises(AssertionError):  # the vector env's step still asks its action space: the check is ours
        env.step(np.array([0, 1]))


def test_a_time_limits_step_count_is_read_and_written_back():
    import gymnasium as gym

    env = gym.make("CartPole-v1", max_episode_steps=5)
    assert env_internals.episode_steps(env) is None  # no reset yet
    env.reset(seed=0)
    env.step(0)
    env.step(1)
    assert env_internals.episode_steps(env) == 2
    env_internals.set_episode_steps(env, 4)
    assert env.step(0)[3]  # the 5th step counted: truncated
    unlimited = gym.make("CartPole-v1", max_episode_steps=None).env  # below its TimeLimit: none to count
    assert env_internals.episode_steps(unlimited) is None
