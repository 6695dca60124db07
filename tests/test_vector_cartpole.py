"""CartPoleBatch against Gymnasium's own envs, step for step and bit for bit; StreamDraws against Generator."""

import numpy as np
import pytest

from ablate.agent.envs import make_vec_env
from ablate.agent.vector_cartpole import CartPoleBatch, StreamDraws


@pytest.mark.parametrize("num_envs", [1, 2, 5, 32])
def test_every_member_steps_as_its_own_gymnasium_env(num_envs):
    """Vector env from 3 envs up, sync env below; members stop at different steps (their collections end),
    and a stopped member's envs draw nothing, so the next reset of each matches Gymnasium's."""
    seeds = [3, 7, 11]
    references = [make_vec_env("CartPole-v1", num_envs) for _ in seeds]
    batch = CartPoleBatch(seeds, num_envs, 500)
    actions_rng = np.random.default_rng(0)
    for collection in range(3):
        expected = [env.reset(seed=s if collection == 0 else None)[0] for env, s in zip(references, seeds, strict=True)]
        observations = batch.reset()
        for i in range(3):
            np.testing.assert_array_equal(observations[i], expected[i])
        stops = [40 + 30 * i + 5 * collection for i in range(3)]
        for t in range(max(stops)):
            actions = actions_rng.integers(0, 2, (3, num_envs))
            counting = np.array([t < stop for stop in stops])
            observations, rewards, terminated, truncated = batch.step(actions, counting)
            for i in np.flatnonzero(counting):
                obs, reward, term, trunc, _ = references[i].step(actions[i])
                np.testing.assert_array_equal(observations[i], obs)
                np.testing.assert_array_equal(rewards[i], reward)
                np.testing.assert_array_equal(terminated[i], term)
                np.testing.assert_array_equal(truncated[i], trunc)
    for i, env in enumerate(references):
        states = batch.stream_states(i)
        streams = [env.np_random] if num_envs > 2 else [e.unwrapped.np_random for e in env.envs]
        assert states == [s.bit_generator.state for s in streams]


def test_members_that_leave_take_their_streams_with_them():
    batch = CartPoleBatch([1, 2, 3], 4, 500)
    batch.reset()
    kept = batch.stream_states(2)
    batch.keep(np.array([0, 2]))
    assert batch.members == 2 and batch.stream_states(1) == kept


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
