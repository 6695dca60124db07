"""Slots: a collection's episodes taken back to back from the ring are the steps the slots played."""

from __future__ import annotations

import numpy as np
import pytest

from ablate.agent.slots import CartPoleSlots, windows


@pytest.mark.parametrize("history", [0, 3])
def test_cartpole_slots_take_every_episode_as_played_even_across_the_rings_end(history):
    # A short episode limit makes the ring (max_episode_steps + 1 rows) come round within the test.
    slots = CartPoleSlots([7, 8], per_member=3, max_episode_steps=20, history=history, env_id="CartPole-v1")
    rng, size = np.random.default_rng(0), 6  # 2 members x 3 slots
    for _ in range(3):  # three collections: the later ones start past the ring's end
        playing = np.arange(size)
        slots.start(playing)
        seen = {s: [] for s in playing.tolist()}
        taken_actions = {s: [] for s in playing.tolist()}
        lengths: dict[int, int] = {}
        stepping = np.ones(size, bool)
        while stepping.any():
            observations = slots.observations().copy()
            actions = rng.integers(0, 2, size)
            for s in np.flatnonzero(stepping).tolist():
                seen[s].append(observations[s])
                taken_actions[s].append(actions[s])
            _, ended = slots.step(actions, stepping)
            for s in np.flatnonzero(ended & stepping).tolist():
                lengths[s] = slots.steps(s)
            stepping &= ~ended
        order = np.array(sorted(lengths), np.int64)
        taken = slots.take(order, np.array([lengths[s] for s in order.tolist()], np.int64))
        expected = np.concatenate([np.stack(seen[s]) for s in order.tolist()])
        np.testing.assert_array_equal(taken.observations, expected)
        np.testing.assert_array_equal(taken.actions, np.concatenate([taken_actions[s] for s in order.tolist()]))
        assert taken.rewards.shape == (sum(lengths.values()),)
        if history:  # the windows are the raw observations' last `history`, zeros before the episode's first
            raw = [np.stack(seen[s])[:, -1] for s in order.tolist()]
            np.testing.assert_array_equal(taken.observations, np.concatenate([windows(r, history) for r in raw]))


def test_cartpole_slots_come_from_gym_make_vec_and_refuse_another_autoreset_mode(monkeypatch):
    import gymnasium as gym

    slots = CartPoleSlots([7], per_member=3, max_episode_steps=20, env_id="CartPole-v0")
    assert type(slots.env).__name__ == "CartPoleVectorEnv" and slots.env.num_envs == 3
    made = gym.make_vec

    def same_step(*args, **kwargs):
        env = made(*args, **kwargs)
        env.metadata = {**env.metadata, "autoreset_mode": gym.vector.AutoresetMode.SAME_STEP}
        return env

    monkeypatch.setattr(gym, "make_vec", same_step)
    with pytest.raises(RuntimeError, match="need NEXT_STEP"):
        CartPoleSlots([7], per_member=3, max_episode_steps=20, env_id="CartPole-v1")
