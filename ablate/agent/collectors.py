"""Episode collection for one trial: CartPole's vectorised episodes, Pong's emulators stepped together, and the
videos a trial records (of the sampling policy as it trains, of the trained policy at its end).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import gymnasium as gym
import numpy as np

from ablate.agent.envs import PongEnv, env_info, make_env, make_vec_env, observation_adapter
from ablate.agent.policies import Policy
from ablate.agent.reinforce import choose_action
from ablate.config import TrialConfig


class Episode(NamedTuple):
    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray


def collect_episodes(
    env: gym.vector.VectorEnv,
    adapter,
    model: Policy,
    rng: np.random.Generator,
    count: int,
    seed: int | None = None,
) -> list[Episode]:
    """Run the first ``count`` sub-envs of ``env`` for one complete episode each, all stepped together.

    Every collection starts from a reset, so each episode is sampled from the current policy only.
    Sub-envs that finish early are stepped on (a vectorised step costs the same) and their steps ignored.
    """
    raw, _ = env.reset(seed=seed)
    observations = adapter.reset(raw)
    active = np.zeros(env.num_envs, dtype=bool)
    active[:count] = True
    lengths = np.zeros(env.num_envs, dtype=np.int64)
    obs_steps, action_steps, reward_steps = [], [], []
    while active.any():
        actions = choose_action(model, observations, rng)
        raw, rewards, terminated, truncated, _ = env.step(actions)
        obs_steps.append(observations)
        action_steps.append(actions)
        reward_steps.append(rewards)
        finished = active & (terminated | truncated)
        lengths[finished] = len(action_steps)
        active &= ~finished
        observations = adapter.step(raw)
    obs = np.stack(obs_steps, axis=1)
    acts = np.stack(action_steps, axis=1)
    rews = np.stack(reward_steps, axis=1)
    return [Episode(obs[i, : lengths[i]], acts[i, : lengths[i]], rews[i, : lengths[i]]) for i in range(count)]


class VectorCollector:
    """CartPole: each update's episodes collected together from a reset (``collect_episodes``)."""

    def __init__(self, config: TrialConfig) -> None:
        self.env = make_vec_env(config.env_id, config.episodes_per_update)
        self.adapter = observation_adapter(config.env_id, config.model)
        self.reset_seed: int | None = config.seed

    def collect(self, model: Policy, rng: np.random.Generator, count: int, budget: int | None = None) -> list[Episode]:
        episodes = collect_episodes(self.env, self.adapter, model, rng, count, seed=self.reset_seed)
        self.reset_seed = None  # seed the envs once; later resets continue their random streams
        return episodes

    def state(self, episodes_done: int) -> dict:
        # Gymnasium's vector envs do not expose their RNGs to restore; a resumed CartPole trial re-seeds them
        # from the episode count instead, so it continues deterministically but not as the unbroken run would.
        return {"reset_seed": None}

    def set_state(self, state: dict, config: TrialConfig, episodes_done: int) -> None:
        self.reset_seed = config.seed + 7919 * episodes_done

    def close(self) -> None:
        self.env.close()


class _EpisodeBuffer:
    """One sub-env's episode so far, in preallocated arrays that grow by doubling and are reused."""

    def __init__(self, capacity: int = 1024) -> None:
        self.observations = np.zeros((capacity, 80, 80), np.int8)
        self.actions = np.zeros(capacity, np.int64)
        self.rewards = np.zeros(capacity, np.float32)
        self.length = 0

    def add(self, observation: np.ndarray, action: int, reward: float) -> None:
        if self.length == len(self.actions):
            self.observations = np.concatenate([self.observations, np.zeros_like(self.observations)])
            self.actions = np.concatenate([self.actions, np.zeros_like(self.actions)])
            self.rewards = np.concatenate([self.rewards, np.zeros_like(self.rewards)])
        self.observations[self.length] = observation
        self.actions[self.length] = action
        self.rewards[self.length] = reward
        self.length += 1

    def episode(self) -> Episode:
        n = self.length
        return Episode(self.observations[:n, None].copy(), self.actions[:n].copy(), self.rewards[:n].copy())


class TrainingVideos:
    """Videos of the sampling policy as it trains: every ``every`` episodes, sub-env 0's next episode, up to
    ``max_frames`` raw frames, into ``folder/videos/episode_NNNNN.mp4`` (NNNNN: the episode's number)."""

    def __init__(self, folder: Path | None, every: int, max_frames: int, fps: int, completed: int = 0) -> None:
        self.folder = folder / "videos" if folder is not None else None
        self.every = every if folder is not None else 0
        self.max_frames = max_frames
        self.fps = fps
        self.next_at = -(-completed // self.every) * self.every if self.every else 0
        self.writer = None
        self.frames = 0
        self.paths: list[Path] = []

    def episode_started(self, completed: int, frame: np.ndarray) -> None:
        """Sub-env 0 began an episode; ``completed`` episodes have finished in the trial so far."""
        if not self.every or self.writer is not None or completed < self.next_at:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / f"episode_{completed + 1:05d}.mp4"
        self.writer = video_writer(path, self.fps)
        self.paths.append(path)
        self.frames = 0
        self.next_at = (completed // self.every + 1) * self.every
        self.frame(frame, done=False)

    @property
    def recording(self) -> bool:
        return self.writer is not None

    def frame(self, frame: np.ndarray, done: bool) -> None:
        if self.writer is None:
            return
        self.writer.append_data(frame)
        self.frames += 1
        if done or self.frames >= self.max_frames:
            self.close()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


class PongCollector:
    """Pong: ``config.vector_envs`` emulators stepped together, one batched forward per step for all of them.
    A sub-env whose episode ends starts the next one at once (no idle steps); finished episodes queue up and
    each update takes the oldest ``count``. An episode that straddles an update was partly sampled under the
    previous weights (at most a few updates old): the price of never idling an emulator."""

    def __init__(self, config: TrialConfig, videos: TrainingVideos) -> None:
        n = config.vector_envs
        self.envs = [
            PongEnv(
                config.env_id,
                config.action_set,
                config.frameskip,
                config.repeat_action_probability,
                config.max_episode_steps,
            )
            for _ in range(n)
        ]
        self.observations = np.zeros((n, 1, 80, 80), np.int8)
        self.buffers = [_EpisodeBuffer() for _ in range(n)]
        self.finished: deque[Episode] = deque()
        self.playing = np.ones(n, bool)
        """Sub-envs playing an episode the trial may still use; the others sit idle once the trial's budget of
        episodes is finished or under way (no steps spent on episodes that would be thrown away)."""
        self.completed = 0
        self.videos = videos
        for i, env in enumerate(self.envs):
            self.observations[i, 0] = env.reset(seed=config.seed * 1000 + i)
        self.videos.episode_started(0, self.envs[0].frame)

    def collect(self, model: Policy, rng: np.random.Generator, count: int, budget: int | None = None) -> list[Episode]:
        """The oldest ``count`` finished episodes. ``budget``: episodes the trial still needs, these included
        (None: no end in sight); a sub-env that finishes when enough episodes are finished or under way for
        the budget stops instead of starting an episode nobody would train on."""
        while len(self.finished) < count:
            playing, observations = self.playing_observations()
            self.advance(playing, choose_action(model, observations, rng), budget)
        return self.take(count)

    def playing_observations(self) -> tuple[np.ndarray, np.ndarray]:
        """The sub-envs that step next and their observations, (playing, 1, 80, 80) int8: what to act on."""
        playing = np.flatnonzero(self.playing)
        return playing, self.observations if len(playing) == len(self.envs) else self.observations[playing]

    def advance(self, playing: np.ndarray, actions: np.ndarray, budget: int | None) -> None:
        """Step the ``playing`` sub-envs with ``actions``: one step of ``collect`` (a population acts for all
        its members' emulators in one forward, then advances each member's)."""
        for i, action in zip(playing, actions, strict=True):
            env = self.envs[i]
            observation, reward, done = env.step(int(action))
            self.buffers[i].add(self.observations[i, 0], action, reward)
            if i == 0 and self.videos.recording:
                self.videos.frame(env.frame, done)
            if done:
                self.finished.append(self.buffers[i].episode())
                self.buffers[i].length = 0
                self.completed += 1
                if budget is not None and len(self.finished) + int(self.playing.sum()) - 1 >= budget:
                    self.playing[i] = False
                    continue
                observation = env.reset()
                if i == 0:
                    self.videos.episode_started(self.completed, env.frame)
            self.observations[i, 0] = observation

    def take(self, count: int) -> list[Episode]:
        """The oldest ``count`` finished episodes, out of the queue."""
        return [self.finished.popleft() for _ in range(count)]

    def state(self, episodes_done: int) -> dict:
        return {
            "envs": [env.state() for env in self.envs],
            "observations": self.observations.copy(),
            "buffers": [
                (b.observations[: b.length].copy(), b.actions[: b.length].copy(), b.rewards[: b.length].copy())
                for b in self.buffers
            ],
            "finished": list(self.finished),
            "playing": self.playing.copy(),
            "completed": self.completed,
        }

    def set_state(self, state: dict, config: TrialConfig, episodes_done: int) -> None:
        for env, saved in zip(self.envs, state["envs"], strict=True):
            env.set_state(saved)
        self.observations[:] = state["observations"]
        for buffer, (observations, actions, rewards) in zip(self.buffers, state["buffers"], strict=True):
            buffer.length = 0
            for t in range(len(actions)):
                buffer.add(observations[t], actions[t], rewards[t])
        self.finished = deque(Episode(*e) for e in state["finished"])
        self.playing[:] = state.get("playing", True)
        self.completed = state["completed"]
        self.videos.close()
        self.videos.next_at = -(-self.completed // self.videos.every) * self.videos.every if self.videos.every else 0

    def close(self) -> None:
        self.videos.close()
        for env in self.envs:
            env.close()


def video_writer(path: Path, fps: int):
    import imageio.v2 as imageio  # a worker pays for ffmpeg only when it records

    # yuv420p H.264 plays in every browser, MLflow's artifact viewer included. One encoder thread at x264's
    # fastest preset: ffmpeg runs beside the trial's own process, on CPUs its neighbours are training on
    # (measured per 250 frames: 0.18 s of CPU vs 0.30 s at the default preset; ~60 KB instead of ~20 KB).
    return imageio.get_writer(
        path,
        fps=fps,
        codec="libx264",
        pixelformat="yuv420p",
        macro_block_size=2,
        output_params=["-threads", "1", "-preset", "ultrafast"],
    )


def record_greedy_episode(
    config: TrialConfig, model: Policy, max_frames: int, on_frame: Callable[[np.ndarray], None]
) -> float:
    """Play one greedy (argmax) episode of ``model`` on a seed training never used, passing rendered frames
    to ``on_frame`` as they come (every ``video_stride``-th step, downscaled; a list of 500 full CartPole
    frames would hold 360 MB); returns the episode's return."""
    info = env_info(config.env_id)
    env = make_env(config.env_id, render=True)
    adapter = observation_adapter(config.env_id, config.model)
    scale = info.video_downscale

    def frame() -> None:
        on_frame(np.ascontiguousarray(env.render()[::scale, ::scale]))

    try:
        raw, _ = env.reset(seed=config.seed + 1_000_003)
        observation = adapter.reset(np.asarray(raw)[None])[0]
        frame()
        frames, steps, total, done = 1, 0, 0.0, False
        while not done and frames < max_frames:
            raw, reward, terminated, truncated, _ = env.step(choose_action(model, observation, greedy=True))
            total += float(reward)
            steps += 1
            done = terminated or truncated
            observation = adapter.step(np.asarray(raw)[None])[0]
            if steps % info.video_stride == 0 or done:
                frame()
                frames += 1
        return total
    finally:
        env.close()


def record_pong_episode(
    config: TrialConfig, model: Policy, max_frames: int, on_frame: Callable[[np.ndarray], None]
) -> float:
    """Pong's end-of-trial video: the *sampling* policy (a greedy Pong agent that has not learnt much presses
    one button for the whole video) on a seed training never used, raw frames, up to ``max_frames``; returns
    the points won minus lost over those frames."""
    env = PongEnv(config.env_id, config.action_set, config.frameskip, config.repeat_action_probability)
    rng = np.random.default_rng(config.seed + 1_000_003)
    try:
        observation = env.reset(seed=config.seed + 1_000_003)
        on_frame(env.frame)
        total, frames, done = 0.0, 1, False
        while not done and frames < max_frames:
            observation, reward, done = env.step(choose_action(model, observation[None], rng))
            total += reward
            on_frame(env.frame)
            frames += 1
        return total
    finally:
        env.close()
