"""Environments: Pong pre-processing and frame difference, the observation window, vectorised CartPole."""

import numpy as np

from ablate.envs import FrameDifference, ObservationWindow, env_info, make_env, make_vec_env, pre_process


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
    env = make_env("ALE/Pong-v5")
    assert isinstance(env, FrameDifference)
    first, _ = env.reset(seed=0)
    assert first.shape == (1, 80, 80) and not first.any()  # no motion at the first frame
    moved = False
    for _ in range(60):
        obs, *_ = env.step(0)
        moved |= bool(obs.any())
        assert set(np.unique(obs)) <= {-1.0, 0.0, 1.0}
    env.close()
    assert moved
    assert env_info("ALE/Pong-v5").n_actions == 6


def test_observation_window_is_oldest_first_and_zero_padded():
    window = ObservationWindow(3)
    first = window.reset(np.array([[1.0, 1.0]]))
    np.testing.assert_array_equal(first[0], [[0, 0], [0, 0], [1, 1]])
    window.step(np.array([[2.0, 2.0]]))
    third = window.step(np.array([[3.0, 3.0]]))
    np.testing.assert_array_equal(third[0], [[1, 1], [2, 2], [3, 3]])


def test_vectorised_cartpole_respects_each_versions_time_limit():
    for env_id, limit in (("CartPole-v0", 200), ("CartPole-v1", 500)):
        assert env_info(env_id).max_episode_steps == limit
        numpy_vectorised = make_vec_env(env_id, 8)
        assert numpy_vectorised.unwrapped.max_episode_steps == limit
        one_by_one = make_vec_env(env_id, 1)
        assert one_by_one.envs[0].spec.max_episode_steps == limit
        for env in (numpy_vectorised, one_by_one):
            observations, _ = env.reset(seed=0)
            assert observations.shape == (env.num_envs, 4) and observations.dtype == np.float32
            env.close()
