"""CartPoleBatch against Gymnasium's own envs, step for step and bit for bit; StreamDraws against Generator."""

import numpy as np
import pytest

from ablate.agent.envs import make_vec_env
from ablate.agent.vector_cartpole import CartPoleBatch, StreamDraws


@pytest.mark.parametrize("num_envs", [1, 2, 5, 32])
def test_every_member_steps_as_its_own_gymnasium_env(num_envs):
    """Vector env from 3 envs up, sync env below. Every member steps at every step and resets at its own times
    (its collections end at different steps, as in an asynchronous population): each member's observations,
    rewards, ends and streams are those of its own Gymnasium env, reset and stepped the same way."""
    seeds = [3, 7, 11]
    references = [make_vec_env("CartPole-v1", num_envs) for _ in seeds]
    batch = CartPoleBatch(seeds, num_envs, 500)
    actions_rng = np.random.default_rng(0)
    observations = batch.reset()
    for i, (env, seed) in enumerate(zip(references, seeds, strict=True)):
        np.testing.assert_array_equal(observations[i], env.reset(seed=seed)[0])
    lasts = [40 + 30 * i for i in range(3)]  # each member's collections last 40, 70, 100 steps, then it resets
    ended = np.zeros((3, num_envs), bool)
    out = np.zeros((3, num_envs, 4), np.float32)
    for t in range(1, 260):
        actions = actions_rng.integers(0, 2, (3, num_envs))
        done = batch.step(actions, out)
        for i, env in enumerate(references):
            obs, reward, term, trunc, _ = env.step(actions[i])
            np.testing.assert_array_equal(out[i], obs)
            np.testing.assert_array_equal(reward, ~ended[i])  # 0 on the step that autoresets
            np.testing.assert_array_equal(done[i], term | trunc)
        ended = done.copy()
        restarting = [i for i, last in enumerate(lasts) if t % last == 0]
        if restarting:
            observations = batch.reset(np.array(restarting))
            ended[restarting] = False
            for i in restarting:
                np.testing.assert_array_equal(observations[i], references[i].reset()[0])
    for i, env in enumerate(references):
        states = batch.stream_states(i)
        streams = [env.np_random] if num_envs > 2 else [e.unwrapped.np_random for e in env.envs]
        assert states == [s.bit_generator.state for s in streams]


def test_members_that_leave_take_their_streams_with_them():
    """The members that stay step on as a batch that never held the one that left (autoresets included)."""
    batch, without = CartPoleBatch([1, 2, 3], 4, 500), CartPoleBatch([1, 3], 4, 500)
    batch.reset(), without.reset()
    rng = np.random.default_rng(0)
    for t in range(120):
        if t == 7:
            kept = batch.stream_states(2)
            batch.keep(np.array([0, 2]))
            assert batch.members == 2 and batch.stream_states(1) == kept
        actions = rng.integers(0, 2, (3, 4))
        done = batch.step(actions if t < 7 else actions[[0, 2]]).copy()
        np.testing.assert_array_equal(without.step(actions[[0, 2]]), done if t >= 7 else done[[0, 2]])
        np.testing.assert_array_equal(without.observations(), batch.observations()[[0, 2] if t < 7 else [0, 1]])


def test_stream_draws_are_each_generators_own_sequence():
    draws = StreamDraws([np.random.default_rng(s) for s in (5, 6)], capacity=8)
    taken = [[], []]
    for count in (3, 7, 0, 20, 2):  # 20: longer than a row, which widens
        need = np.array([count, 1])
        draws.ensure(need)
        for s in range(2):
            taken[s] += list(draws.buffer[s, draws.pos[s] : draws.pos[s] + need[s]])
        draws.take(need)
    for s, seed in enumerate((5, 6)):
        generator = np.random.default_rng(seed)
        assert taken[s] == list(generator.random(len(taken[s])))
        assert draws.states()[s] == generator.bit_generator.state
