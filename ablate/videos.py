"""Video files: an H.264 writer every browser plays, and the videos of a member's sampling policy taken while it
trains (``TrainingVideos``, fed frame by frame by the trainer's env slots).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np


def as_frame(image: np.ndarray) -> np.ndarray:
    """An env's rendered image as the 8-bit RGB frame a video holds: floats (MinAtar renders 0-1 floats) scaled to
    0-255, so the encoder has nothing to convert (imageio printed "Lossy conversion from float64 to uint8" once a
    frame)."""
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    if image.dtype.kind == "f":
        peak = 1.0 if image.size == 0 or float(np.nanmax(image)) <= 1.0 else 255.0
        return np.clip(np.nan_to_num(image) * (255.0 / peak), 0, 255).round().astype(np.uint8)
    return np.clip(image, 0, 255).astype(np.uint8)


RENDER_WARNINGS = ("No render fps was declared", "RGB-array rendering should return a numpy array with dtype uint8")
"""What Gymnasium's checker prints at an env's first render that ablate answers itself (a video has its own fps,
``as_frame`` makes 8-bit frames): MinAtar's, printed in every trial that records a video, nothing a user can do."""


def rendered(render: Callable[[], np.ndarray]) -> np.ndarray:
    """``render()``'s image as a video frame (``as_frame``), without ``RENDER_WARNINGS``."""
    with warnings.catch_warnings():
        for message in RENDER_WARNINGS:
            warnings.filterwarnings("ignore", f".*{message}", UserWarning)
        return as_frame(render())


def video_writer(path: Path, fps: int):
    import imageio.v2 as imageio  # a worker pays for ffmpeg only when it records

    # yuv420p H.264 plays in every browser, MLflow's artifact viewer included. One encoder thread at x264's
    # fastest preset: ffmpeg runs beside the trial's own process, on CPUs its neighbours are training on.
    return imageio.get_writer(
        path,
        fps=fps,
        codec="libx264",
        pixelformat="yuv420p",
        macro_block_size=2,
        output_params=["-threads", "1", "-preset", "ultrafast"],
    )


class TrainingVideos:
    """Videos of the sampling policy as it trains: every ``every`` episodes, the member's first env's next episode,
    up to ``max_frames`` frames, into ``folder/videos/episode_NNNNN.mp4`` (NNNNN: the episode's number)."""

    def __init__(self, folder: Path | None, every: int, max_frames: int, fps: int) -> None:
        self.folder = folder / "videos" if folder is not None else None
        self.every = every if folder is not None else 0
        self.max_frames = max_frames
        self.fps = fps
        self.next_at = 0
        self.writer = None
        self.frames = 0
        self.paths: list[Path] = []

    def episode_started(self, completed: int, frame: Callable[[], np.ndarray]) -> None:
        """The first env began an episode; ``completed`` episodes have finished in the trial so far."""
        if not self.every or self.writer is not None or completed < self.next_at:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / f"episode_{completed + 1:05d}.mp4"
        self.writer = video_writer(path, self.fps)
        self.paths.append(path)
        self.frames = 0
        self.next_at = (completed // self.every + 1) * self.every
        self.frame(frame, done=False)

    def frame(self, frame: Callable[[], np.ndarray], done: bool) -> None:
        if self.writer is None:
            return
        self.writer.append_data(rendered(frame))
        self.frames += 1
        if done or self.frames >= self.max_frames:
            self.close()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None
