"""A finished trial's files (``trial_files``): what ``write_artifacts`` writes from a result, the video
``replay_video`` records again from them, Pong's observation figure beside the training videos."""

from dataclasses import replace

import numpy as np
import pytest
from test_trial import PONG, SHORT

from ablate.agent.trainer import run_trial
from ablate.config import ModelConfig
from ablate.trial_files import replay_video, write_artifacts


def test_artifacts_written(tmp_path):
    result = run_trial(replace(SHORT, max_episodes=16, record_video=True, video_max_frames=40))
    write_artifacts(result, tmp_path)
    assert set(result.artifacts) == {"episodes", "weights", "config", "learning_curve", "video"}
    names = {p.name for p in tmp_path.iterdir()}
    assert names == {"episodes.csv", "weights.pt", "config.json", "learning_curve.png", "video.mp4"}
    assert len((tmp_path / "episodes.csv").read_text().splitlines()) == 1 + 16
    assert (tmp_path / "video.mp4").stat().st_size > 1000
    assert result.greedy_return is not None and 1 <= result.greedy_return <= 2 * 40  # every 2nd step is a frame


@pytest.mark.parametrize("kind", ["mlp with dropout", "cnn", "pong"])
def test_a_replayed_video_is_the_one_the_trial_would_have_recorded(tmp_path, kind):
    """A launch leaves each trial's video to the report (``replay_video``, from ``config.json`` and ``weights.pt``):
    the same frames and the same greedy return as the trial's own, byte for byte."""
    import imageio.v2 as imageio

    config = {
        "mlp with dropout": replace(SHORT, model=ModelConfig(hidden_sizes=(16, 16), dropout=0.2)),
        "cnn": replace(SHORT, model=ModelConfig(architecture="cnn", history=4, kernel_size=2, hidden_sizes=(16,))),
        "pong": replace(PONG, checkpoint_every=0),
    }[kind]
    config = replace(config, max_episodes=4 if kind == "pong" else 16, record_video=True, video_max_frames=40)
    result = run_trial(config)
    write_artifacts(result, tmp_path / "trial")
    played = replay_video(tmp_path / "trial" / "config.json", tmp_path / "trial" / "weights.pt", tmp_path / "again.mp4")
    assert played == result.greedy_return and (played is None) == (kind == "pong")
    ours, theirs = (imageio.mimread(p) for p in (tmp_path / "again.mp4", tmp_path / "trial" / "video.mp4"))
    assert len(ours) == len(theirs) > 1 and all((a == b).all() for a, b in zip(ours, theirs, strict=True))


def test_pong_trial_artifacts_training_videos_and_observation_figure(tmp_path):
    config = replace(PONG, max_episodes=4, video_every=1, video_max_frames=30, record_video=True, checkpoint_every=0)
    result = run_trial(config, artifacts_dir=tmp_path)  # the training videos, as it trains
    assert {p.name for p in tmp_path.iterdir()} == {"videos"}
    write_artifacts(result, tmp_path)
    names = {p.name for p in tmp_path.iterdir()}
    expected = {"episodes.csv", "weights.pt", "config.json", "learning_curve.png", "video.mp4", "observation.png"}
    assert names == expected | {"videos"}
    videos = sorted(p.name for p in (tmp_path / "videos").iterdir())
    assert videos[:2] == ["episode_00001.mp4", "episode_00002.mp4"]  # the untrained policy, then each of sub-env 0
    assert all((tmp_path / "videos" / v).stat().st_size > 1000 for v in videos)
    assert result.greedy_return is None  # Pong's video is of the sampling policy: no greedy return to report


def test_a_float_rendering_env_is_written_as_8_bit_frames_without_warnings(tmp_path, caplog, capfd):
    """MinAtar renders 0-1 floats: imageio printed "Lossy conversion from float64 to uint8" for each of 34 frames
    (3e01923). The frames are 8-bit before the encoder sees them."""
    import warnings

    from ablate.videos import as_frame, video_writer

    rendered = np.random.default_rng(0).random((20, 20, 3))  # float64 in [0, 1]
    frame = as_frame(rendered)
    assert frame.dtype == np.uint8 and frame.max() > 200 and np.array_equal(frame, (rendered * 255).round())
    assert as_frame(rendered * 255).tolist() == frame.tolist() and as_frame(frame) is frame

    def written(frames) -> str:
        """What writing ``frames`` printed: imageio's logger, Python's warnings, the process's stderr."""
        caplog.clear()
        capfd.readouterr()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with video_writer(tmp_path / "v.mp4", 10) as writer:
                for frame in frames:
                    writer.append_data(frame)
        return caplog.text + capfd.readouterr().err + " ".join(str(w.message) for w in caught)

    assert "Lossy conversion" in written([rendered] * 3)  # what a float frame printed, so the check can fail
    assert "Lossy conversion" not in written([as_frame(rendered)] * 3)


def test_a_minatar_like_envs_render_warnings_are_not_printed(recwarn):
    """MinAtar declares no ``render_fps`` and renders float64 RGB: Gymnasium's checker warned of both at each trial's
    first render (issue 56), nothing a user can act on (a video has its own fps; ``as_frame`` makes 8-bit frames)."""
    import gymnasium as gym

    from ablate.videos import RENDER_WARNINGS, rendered

    class FloatRender(gym.Env):  # MinAtar's metadata and rendering, without MinAtar
        metadata = {"render_modes": ["rgb_array"]}
        observation_space = gym.spaces.Box(0, 1, (2,))
        action_space = gym.spaces.Discrete(2)

        def __init__(self, render_mode=None):
            self.render_mode = render_mode

        def reset(self, *, seed=None, options=None):
            return np.zeros(2, np.float32), {}

        def render(self):
            return np.random.default_rng(0).random((10, 10, 3))

    gym.register("FloatRender-v0", entry_point=FloatRender)
    try:
        env = gym.make("FloatRender-v0", render_mode="rgb_array")
        env.reset(seed=0)
        env.render()  # as a trial rendered before: both warnings, so the check can fail
        assert all(any(m in str(w.message) for w in recwarn) for m in RENDER_WARNINGS), [str(w) for w in recwarn]
        recwarn.clear()
        env = gym.make("FloatRender-v0", render_mode="rgb_array")
        env.reset(seed=0)
        frame = rendered(env.render)
        assert frame.dtype == np.uint8 and frame.shape == (10, 10, 3)
        assert not [str(w.message) for w in recwarn]
    finally:
        gym.registry.pop("FloatRender-v0")
