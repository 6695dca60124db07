"""Environments: Pong pre-processing and frame difference, any discrete env described, bad envs refused; and what
the fenced internals assume of Gymnasium's ``CartPoleVectorEnv`` and ``TimeLimit``: each of those tests fails when a
Gymnasium release changes it (an attribute renamed or reshaped, the physics or the next-step autoreset reworked)."""

from dataclasses import replace

import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv, CartPoleVectorEnv

from ablate.config import TrialConfig
from ablate.envs import (
    EnvError,
    _PaletteForeground,
    autoresetting,
    copy_slots,
    describe,
    episode_steps,
    frame_difference,
    make_pong,
    make_trial_env,
    pre_process,
    reset_counters,
    set_episode_steps,
    set_start_states,
    skip_action_check,
)

PONG_MOVE = TrialConfig(env_id="ALE/Pong-v5", action_set="move")


def test_pre_process_crops_downsamples_and_binarises():
    frame = np.full((210, 160, 3), 144, dtype=np.uint8)  # background colour everywhere
    frame[35 + 10, 2 * 7, 0] = 236  # a ball pixel at cropped (row 10, col 7) before downsampling
    frame[35 + 20, 2 * 3, 0] = 109  # the other background colour
    frame[20, 20, 0] = 236  # in the score area, cropped away
    image = pre_process(frame)
    assert image.shape == (80, 80) and image.dtype == np.float32
    assert image[5, 7] == 1.0  # row 10 of the crop is row 5 after taking every 2nd row
    assert image.sum() == 1.0


def test_pong_env_gives_frame_differences():
    env = make_trial_env(TrialConfig(env_id="ALE/Pong-v5"))
    first, _ = env.reset(seed=0)
    assert first.shape == (1, 80, 80) and first.dtype == np.int8 and not first.any()  # no motion at first
    moved = False
    for _ in range(60):
        obs, *_ = env.step(0)
        moved |= bool(obs.any())
        assert set(np.unique(obs)) <= {-1, 0, 1}
    env.close()
    assert moved
    assert describe(TrialConfig(env_id="ALE/Pong-v5")).n_actions == 6
    assert describe(TrialConfig(env_id="ALE/Pong-v5", action_set="move")).n_actions == 2


def test_any_discrete_env_is_described_from_its_spaces_and_spec():
    acrobot = describe(TrialConfig(env_id="Acrobot-v1"))
    assert (acrobot.observation_shape, acrobot.n_actions, acrobot.reward_threshold) == ((6,), 3, -100.0)
    assert acrobot.max_episode_steps == 500
    for env_id, limit in (("CartPole-v0", 200), ("CartPole-v1", 500)):
        assert describe(TrialConfig(env_id=env_id)).max_episode_steps == limit
    assert describe(TrialConfig(env_id="CartPole-v1", max_episode_steps=50)).max_episode_steps == 50


def test_another_atari_game_gets_grayscale_84x84_frame_differences():
    config = TrialConfig(env_id="ALE/Breakout-v5")
    assert describe(config).observation_shape == (1, 84, 84)
    env = make_trial_env(config)
    first, _ = env.reset(seed=0)
    assert first.shape == (1, 84, 84) and first.dtype == np.float32 and not first.any()
    env.close()


@pytest.mark.parametrize(
    ("config", "words"),
    [
        (TrialConfig(env_id="NoSuchEnv-v0"), "not a registered Gymnasium env"),
        (TrialConfig(env_id="Pendulum-v1"), "Box actions; valid: Discrete"),
        (TrialConfig(env_id="Blackjack-v1"), "Tuple observation; valid: a Box"),
        (TrialConfig(env_id="Acrobot-v1", env_args=(("wind", 3),)), "env_args"),
        (TrialConfig(env_module="no_such_module_here"), "env_module = 'no_such_module_here'"),
    ],
)
def test_an_env_the_trainer_cannot_run_says_why_in_one_line(config, words):
    with pytest.raises(EnvError, match=words.replace("(", r"\(")) as error:
        describe(config)
    assert "\n" not in str(error.value)


def test_pre_process_known_output_and_raw_frame_untouched():
    frame = np.full((210, 160, 3), 144, dtype=np.uint8)
    frame[35:195:2, ::2, 0][:, 40] = 109  # the second background colour: erased
    frame[35 + 2 * 7, 2 * 3 : 2 * 5, 0] = 236  # ball pixels at (7, 3) and (7, 4) after downsampling
    frame[35 + 2 * 70, 2 * 76, 0] = 92  # a paddle pixel at (70, 76)
    frame[35 + 2 * 7 + 1, 2 * 9, 0] = 236  # on an odd row: dropped by the downsampling
    before = frame.copy()
    expected = np.zeros((80, 80), np.float32)
    expected[7, 3:5] = 1
    expected[70, 76] = 1
    np.testing.assert_array_equal(pre_process(frame), expected)
    np.testing.assert_array_equal(frame, before)


def test_frame_difference_of_a_moving_ball():
    previous = np.full((210, 160, 3), 144, dtype=np.uint8)
    frame = previous.copy()
    previous[35 + 2 * 20, 2 * 30, 0] = 236  # the ball at (20, 30) ...
    frame[35 + 2 * 22, 2 * 31, 0] = 236  # ... moved to (22, 31)
    difference = frame_difference(frame, previous)
    assert difference[22, 31] == 1 and difference[20, 30] == -1 and np.abs(difference).sum() == 2
    assert not frame_difference(frame, None).any()  # the first frame of an episode: no motion yet


def test_pong_env_is_ale_pong_v5_step_for_step():
    import gymnasium as gym

    reference = gym.make("ALE/Pong-v5").unwrapped  # sticky actions on, as in v5; RGB observations
    ours = make_pong(TrialConfig(env_id="ALE/Pong-v5"), render=True)
    frame, _ = reference.reset(seed=3)
    observation, _ = ours.reset(seed=3)
    assert observation.shape == (1, 80, 80) and observation.dtype == np.int8 and not observation.any()
    assert ours.observation_space == gym.spaces.Box(-1, 1, (1, 80, 80), np.int8)
    rng = np.random.default_rng(0)
    previous = frame
    for _ in range(300):
        action = int(rng.integers(6))
        frame, reward, terminated, truncated, _ = reference.step(action)
        observation, our_reward, our_terminated, our_truncated, _ = ours.step(action)
        np.testing.assert_array_equal(ours.render(), frame)
        np.testing.assert_array_equal(observation[0], frame_difference(frame, previous))
        assert (our_reward, our_terminated, our_truncated) == (reward, terminated, truncated)
        previous = frame


def _continues_exactly(saved_after: int, repeat_action_probability: float) -> bool:
    """A fresh env given a slot's saved state (``EnvSlots``'s checkpoint) plays on as the saved one does."""
    from ablate.envs import env_state, set_env_state

    def make():
        return make_pong(replace(PONG_MOVE, max_episode_steps=60, repeat_action_probability=repeat_action_probability))

    env = make()
    env.reset(seed=0)
    for t in range(saved_after):
        env.step(t % 2)
    saved = env_state(env)
    fresh = make()
    set_env_state(fresh, saved)
    for t in range(60 - saved_after):
        a, b = env.step((t // 3) % 2), fresh.step((t // 3) % 2)
        if not (np.array_equal(a[0], b[0]) and a[1:4] == b[1:4]):
            return False
    return a[3]  # both truncated at step 60: the step count came back too


def test_pong_env_restores_its_state_into_a_fresh_env():
    assert _continues_exactly(25, repeat_action_probability=0.0)  # mid-episode: emulator, previous frame, steps
    # With sticky actions, ALE's last applied action is not in its saved state (ale-py has no API for it): a
    # restore is exact where that action is known, at an episode's start (a reset makes it NOOP), as checkpoints
    # of episodes in lockstep are (tests/test_trial.py); mid-episode its first frames may repeat another action.
    assert _continues_exactly(0, repeat_action_probability=0.25)


def test_pong_env_action_sets_and_step_cap():
    moving = make_pong(replace(PONG_MOVE, max_episode_steps=25))
    moving.reset(seed=0)
    meanings = moving.unwrapped.get_action_meanings()
    assert [meanings[a] for a in moving.get_wrapper_attr("actions")] == [
        "RIGHT",
        "LEFT",
    ]  # ALE 2 and 3: the paddle up and down
    assert moving.action_space.n == 2
    dones = [any(moving.step(t % 2)[2:4]) for t in range(25)]
    assert dones == [False] * 24 + [True]


# --- the fenced internals ---


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
    set_start_states(env, np.array([0, 2]), states[:, [0, 2]])
    set_start_states(env, np.array([1]), states[:, [1]])
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
    set_start_states(env, np.array([0, 1]), falling)
    assert autoresetting(env) is None
    _, rewards, terminated, _, _ = env.step(np.array([0, 0]))
    assert terminated.tolist() == [True, False] and rewards.tolist() == [1.0, 1.0]
    assert autoresetting(env).tolist() == [0]
    _, rewards, terminated, truncated, _ = env.step(np.array([0, 0]))  # the autoreset step: a fresh start state
    assert rewards.tolist() == [0.0, 1.0] and not terminated[0] and not truncated[0]
    assert (np.abs(env.state[:, 0]) <= 0.05).all() and env.steps.tolist() == [0, 2]
    assert autoresetting(env) is None
    # A slot whose counters are reset is stepped by the physics, not autoreset, whatever ended before.
    set_start_states(env, np.array([0]), falling[:, [0]])
    env.step(np.array([0, 0]))
    assert autoresetting(env).tolist() == [0]
    start = np.array([[0.01], [0.0], [0.0], [0.0]])
    set_start_states(env, np.array([0]), start)
    reset_counters(env, np.array([0]))
    _, rewards, _, _, _ = env.step(np.array([1, 0]))
    assert rewards[0] == 1.0 and env.steps[0] == 1
    np.testing.assert_allclose(env.state[:, 0], _next_state(start[:, 0], 1), rtol=1e-12, atol=1e-15)


def test_an_episode_is_truncated_at_max_episode_steps_counted_by_steps():
    env = _env(1, max_episode_steps=3)
    set_start_states(env, np.array([0]), np.zeros((4, 1)))
    truncations = [bool(env.step(np.array([t % 2]))[3][0]) for t in range(3)]
    assert truncations == [False, False, True] and env.steps.tolist() == [3]
    assert autoresetting(env).tolist() == [0]


def test_copied_slots_go_on_as_they_would_have_in_the_old_env():
    old, new = _env(4), CartPoleVectorEnv(num_envs=2, max_episode_steps=500)
    new.reset(seed=1)
    for t in range(3):
        old.step(np.array([t % 2, 1, 0, 1]))
    copy_slots(old, new, np.array([3, 1]))
    assert new.steps.tolist() == [3, 3]
    after_old = old.step(np.array([0, 1, 0, 0]))[0]
    after_new = new.step(np.array([0, 1]))[0]
    np.testing.assert_array_equal(after_new, after_old[[3, 1]])


def test_skipping_the_action_check_still_refuses_a_wrong_shape():
    env = skip_action_check(_env(3))
    assert env.action_space.shape == (3,) and env.action_space.nvec.tolist() == [2, 2, 2]  # the space as it was
    env.step(np.array([0, 1, 1]))
    with pytest.raises(AssertionError):  # the vector env's step still asks its action space: the check is ours
        env.step(np.array([0, 1]))


def test_a_time_limits_step_count_is_read_and_written_back():
    import gymnasium as gym

    env = gym.make("CartPole-v1", max_episode_steps=5)
    assert episode_steps(env) is None  # no reset yet
    env.reset(seed=0)
    env.step(0)
    env.step(1)
    assert episode_steps(env) == 2
    set_episode_steps(env, 4)
    assert env.step(0)[3]  # the 5th step counted: truncated
    unlimited = gym.make("CartPole-v1", max_episode_steps=None).env  # below its TimeLimit: none to count
    assert episode_steps(unlimited) is None


def test_pongs_palette_table_is_pre_process_of_the_rgb_screen_learnt_and_then_looked_up():
    """What Pong trials store per step, read from ALE's palette indices through a table that ``pre_process`` of
    the RGB screen fills: the same 0/1 on the first frame (learnt) and on a second frame of the same colours
    (looked up, no RGB read)."""
    rng = np.random.default_rng(0)
    palette = rng.integers(0, 256, (256, 3), dtype=np.uint8)
    palette[[3, 5, 7]] = [[144, 72, 17], [109, 118, 43], [0, 0, 0]]  # the two background colours, and black
    indices = rng.choice([3, 5, 7, 11, 200], size=(210, 160)).astype(np.uint8)

    class FakeALE:
        rgb_reads = 0

        def getScreen(self, out):  # noqa: N802 - ALE's names
            out[...] = indices

        def getScreenRGB(self):  # noqa: N802
            self.rgb_reads += 1
            return palette[indices]

    ale, table, screen = FakeALE(), _PaletteForeground(), np.empty((210, 160), np.uint8)
    expected = pre_process(palette[indices]).astype(np.int8)
    assert np.array_equal(table(ale, screen), expected) and ale.rgb_reads == 1
    assert np.array_equal(table(ale, screen), expected) and ale.rgb_reads == 1
    assert set(np.unique(expected)) == {0, 1}
