"""One trial: seed, build env and policy, collect episodes, update, stop when solved or out of budget.

An importable function of a ``TrialConfig``; metrics leave through a callback, artifacts into a folder.
No Ray and no MLflow here: the scheduler and the tracker wrap this.
"""

from __future__ import annotations

import csv
import ctypes
import io
import math
import os
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import gymnasium as gym
import numpy as np
import torch
from threadpoolctl import threadpool_limits

from ablate.config import TrialConfig
from ablate.agent.envs import PONG_ACTIONS, PongEnv, env_info, is_pong, make_env, make_vec_env, observation_adapter
from ablate.agent.optim import Adam
from ablate.agent.policies import Policy, create_model, parameter_count
from ablate.agent.reinforce import choose_action, discount_rewards, normalize, train_step


class TrialFailed(RuntimeError):
    """The trial cannot go on (a NaN loss, say); the message says why and what to change."""


class EpisodeMetrics(NamedTuple):
    episode: int
    """1-based index of the episode in the trial."""
    episode_return: float
    length: int
    loss: float
    """Loss of the update this episode took part in."""
    entropy: float
    """Mean policy entropy (nats) over that update's observations."""
    rolling_mean: float
    """Mean return of the last ``solve_window`` episodes (fewer at the start)."""
    env_steps: int
    """Environment steps since the trial started, this episode included."""
    wall_s: float
    """Seconds since the trial started, at the end of this episode's update."""
    update: int
    """1-based index of the update (Adam step) this episode took part in."""


class Episode(NamedTuple):
    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray


@dataclass
class TrialResult:
    config: TrialConfig
    episodes: list[EpisodeMetrics]
    episodes_to_solve: int | None
    """Episode at which the rolling mean first reached the threshold over a full window; None if never."""
    solve_threshold: float | None
    env_steps: int
    wall_s: float
    parameter_count: int
    greedy_return: float | None = None
    """Return of the recorded greedy episode (None when no video was recorded, and for Pong, whose video is of
    the sampling policy)."""
    state_dict: dict[str, torch.Tensor] = field(default_factory=dict)
    artifacts: dict[str, Path] = field(default_factory=dict)

    @property
    def returns(self) -> list[float]:
        return [m.episode_return for m in self.episodes]

    @property
    def solved(self) -> bool:
        return self.episodes_to_solve is not None

    def summary(self) -> dict[str, float]:
        """Scalar results, with the tracker's metric names."""
        last = self.episodes[-1] if self.episodes else None
        solve = self.episodes[self.episodes_to_solve - 1] if self.episodes_to_solve else None
        summary = {
            "solved": float(self.solved),
            "episodes_run": float(len(self.episodes)),
            "final_rolling_mean": last.rolling_mean if last else float("nan"),
            "env_steps": float(self.env_steps),
            "wall_s": self.wall_s,
            "steps_per_s": self.env_steps / self.wall_s if self.wall_s > 0 else 0.0,
            "parameter_count": float(self.parameter_count),
        }
        if self.episodes:
            # The area under the rolling-mean curve over the whole budget (as ``report.results`` computes it),
            # here so that tuning selects from the summary alone: a trial that stopped when solved keeps its
            # last rolling mean for the rest of the budget.
            rolling = [m.rolling_mean for m in self.episodes][: self.config.max_episodes]
            padding = max(self.config.max_episodes - len(rolling), 0)
            summary["auc"] = (sum(rolling) + padding * rolling[-1]) / (len(rolling) + padding)
        if solve is not None:
            summary |= {
                "episodes_to_solve": float(solve.episode),
                "env_steps_to_solve": float(solve.env_steps),
                "wall_s_to_solve": solve.wall_s,
            }
        if self.greedy_return is not None:
            summary["greedy_return"] = self.greedy_return
        return summary


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


PONG_TRAIN_CHUNK = 1024
"""Observations per forward/backward in a Pong update: bounds its activations (~130 MB for the CNN)."""


class _VectorCollector:
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
        self.writer = _video_writer(path, self.fps)
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


class _PongCollector:
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
            playing = np.flatnonzero(self.playing)
            observations = self.observations if len(playing) == len(self.envs) else self.observations[playing]
            actions = choose_action(model, observations, rng)
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


def _video_writer(path: Path, fps: int):
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


def _limit_fragmentation() -> None:
    """Fix glibc's mmap threshold at 256 KB. By default it rises (to 32 MB) each time a large block is freed,
    after which a Pong trial's per-update arrays (MBs each) come from the heap and fragment it: RSS grew
    515 MB -> 4.1 GB over 500 episodes. Mapped blocks go back to the system when freed. No-op off glibc."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 256 * 1024)  # M_MMAP_THRESHOLD; setting it also turns the dynamic threshold off
    except (OSError, AttributeError):
        pass


def _inject_fault(config: TrialConfig) -> None:
    """Test-only faults (``TrialConfig.fault``), to prove the scheduler's retry and failure handling."""
    if config.fault == "crash_once" and config.fault_marker and not Path(config.fault_marker).exists():
        Path(config.fault_marker).write_text("crashed once\n")
        os._exit(17)  # a hard process death, as an OOM kill or a segfault would be
    if config.fault == "block":
        # A trial that is certainly still running when a test interrupts the launch; a file releases it.
        while not Path(config.fault_marker).exists():
            time.sleep(0.05)


def run_trial(
    config: TrialConfig,
    on_episodes: Callable[[list[EpisodeMetrics]], None] | None = None,
    artifacts_dir: str | Path | None = None,
    *,
    resume_from: bytes | None = None,
    on_checkpoint: Callable[[bytes], None] | None = None,
) -> TrialResult:
    """Train one REINFORCE agent as ``config`` says and return its per-episode metrics and weights.

    ``on_episodes`` receives each update's new episodes as they finish. With ``artifacts_dir``, the trial
    writes ``episodes.csv``, ``weights.pt``, ``learning_curve.png`` and (if ``record_video``) ``video.mp4``;
    a Pong trial also ``observation.png`` and, with ``video_every``, ``videos/episode_NNNNN.mp4``.

    Every ``config.checkpoint_interval`` episodes, ``on_checkpoint`` receives a bytes blob of the whole trial
    state (weights, optimizer, RNGs, emulators, episode history). ``resume_from`` = such a blob: the trial
    restores it, hands the saved history to ``on_episodes`` in one call, and goes on from the next episode;
    a resumed Pong trial returns exactly what the unbroken one would have.
    """
    _inject_fault(config)
    started = time.perf_counter()
    torch.set_num_threads(1)  # tiny networks: threads cost more than they give, and trials run side by side
    threadpool_limits(1, user_api="blas")  # the same for numpy's acting path (OpenBLAS would spin 2 threads)
    pong = is_pong(config.env_id)
    if pong:
        _limit_fragmentation()
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    info = env_info(config.env_id)
    threshold = config.solve_threshold if config.solve_threshold is not None else info.reward_threshold
    n_actions = len(PONG_ACTIONS[config.action_set]) if pong else info.n_actions
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    model = create_model(config.env_id, config.model, info.observation_size, n_actions).to(device)
    optimizer = Adam(model.parameters(), lr=config.learning_rate)
    videos = TrainingVideos(
        Path(artifacts_dir) if artifacts_dir is not None and pong else None,
        config.video_every,
        config.video_max_frames,
        info.video_fps,
    )
    collector = _PongCollector(config, videos) if pong else _VectorCollector(config)

    history: list[EpisodeMetrics] = []
    window: deque[float] = deque(maxlen=config.solve_window)
    env_steps = 0
    episodes_to_solve: int | None = None
    updates = 0
    if resume_from is not None:
        saved = torch.load(io.BytesIO(resume_from), weights_only=False)
        model.load_state_dict(saved["model"])
        optimizer.load_state_dict(saved["optimizer"])
        torch.set_rng_state(saved["torch_rng"])
        rng.bit_generator.state = saved["numpy_rng"]
        history = [EpisodeMetrics(*row) for row in saved["history"]]
        window.extend(m.episode_return for m in history[-config.solve_window :])
        env_steps, updates, episodes_to_solve = saved["env_steps"], saved["updates"], saved["episodes_to_solve"]
        collector.set_state(saved["collector"], config, len(history))
        started -= saved["wall_s"]
        if on_episodes is not None and history:
            on_episodes(list(history))
    every = config.checkpoint_interval if on_checkpoint is not None else 0
    next_checkpoint = (len(history) // every + 1) * every if every else None
    chunk = PONG_TRAIN_CHUNK if pong else None
    try:
        while len(history) < config.max_episodes and episodes_to_solve is None:
            count = min(config.episodes_per_update, config.max_episodes - len(history))
            episodes = collector.collect(model, rng, count, budget=config.max_episodes - len(history))
            # Returns are discounted within each episode, then normalised across the whole batch.
            returns = [discount_rewards(e.rewards, config.gamma, config.reset_on_score) for e in episodes]
            stats = train_step(
                model,
                optimizer,
                np.concatenate([e.observations for e in episodes]),
                np.concatenate([e.actions for e in episodes]),
                normalize(np.concatenate(returns)),
                l2=config.l2,
                chunk_size=chunk,
            )
            if not math.isfinite(stats.loss):
                raise TrialFailed(
                    f"loss became {stats.loss} at episode {len(history) + count}; "
                    f"try a smaller learning_rate (now {config.learning_rate})"
                )
            updates += 1
            if config.fault == "raise":
                raise TrialFailed("injected fault: raise after the first update (tests only)")
            wall_s = time.perf_counter() - started
            new: list[EpisodeMetrics] = []
            for e in episodes:
                env_steps += len(e.actions)
                episode_return = float(e.rewards.sum())
                window.append(episode_return)
                rolling = float(np.mean(window))
                new.append(
                    EpisodeMetrics(
                        len(history) + len(new) + 1,
                        episode_return,
                        len(e.actions),
                        stats.loss,
                        stats.entropy,
                        rolling,
                        env_steps,
                        wall_s,
                        updates,
                    )
                )
                if (
                    episodes_to_solve is None
                    and threshold is not None
                    and len(window) == config.solve_window
                    and rolling >= threshold
                ):
                    episodes_to_solve = new[-1].episode
            del episodes, returns
            history.extend(new)
            if on_episodes is not None:
                on_episodes(new)
            if next_checkpoint is not None and len(history) >= next_checkpoint and len(history) < config.max_episodes:
                on_checkpoint(
                    _checkpoint(
                        model, optimizer, rng, collector, history, env_steps, updates, episodes_to_solve, wall_s
                    )
                )
                next_checkpoint = (len(history) // every + 1) * every
                if config.fault == "crash_after_checkpoint" and not Path(config.fault_marker).exists():
                    Path(config.fault_marker).write_text("crashed after a checkpoint\n")
                    os._exit(17)  # the process dies with a checkpoint taken: its retry must resume from it
    finally:
        collector.close()

    result = TrialResult(
        config=config,
        episodes=history,
        episodes_to_solve=episodes_to_solve,
        solve_threshold=threshold,
        env_steps=env_steps,
        wall_s=time.perf_counter() - started,
        parameter_count=parameter_count(model),
        state_dict={k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
    )
    if artifacts_dir is not None:
        result.artifacts.update({f"videos/{p.name}": p for p in videos.paths if p.exists()})
        write_artifacts(result, model, Path(artifacts_dir))
    return result


def _checkpoint(model, optimizer, rng, collector, history, env_steps, updates, episodes_to_solve, wall_s) -> bytes:
    buffer = io.BytesIO()
    torch.save(
        {
            "version": 1,
            "model": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "torch_rng": torch.get_rng_state(),
            "numpy_rng": rng.bit_generator.state,
            "collector": collector.state(len(history)),
            "history": [tuple(m) for m in history],
            "env_steps": env_steps,
            "updates": updates,
            "episodes_to_solve": episodes_to_solve,
            "wall_s": wall_s,
        },
        buffer,
    )
    return buffer.getvalue()


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


def write_artifacts(result: TrialResult, model: Policy, folder: Path) -> None:
    """Per-episode table, weights, learning curve and (optionally) a video of the agent into ``folder``; for
    Pong also ``observation.png`` (one observation raw, pre-processed and as a frame difference)."""
    # Imported here: a worker process pays for matplotlib and ffmpeg only when a trial ends.
    from ablate.agent.envs import sample_pong_frames
    from ablate.agent.plots import plot_pong_observation, plot_progress

    folder.mkdir(parents=True, exist_ok=True)
    config = result.config
    table = folder / "episodes.csv"
    with open(table, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(EpisodeMetrics._fields)
        writer.writerows(result.episodes)
    result.artifacts["episodes"] = table
    weights = folder / "weights.pt"
    torch.save(result.state_dict, weights)
    result.artifacts["weights"] = weights
    curve = plot_progress(
        result.returns,
        [m.rolling_mean for m in result.episodes],
        folder / "learning_curve.png",
        threshold=result.solve_threshold,
        title=f"{config.env_id}, seed {config.seed}",
    )
    result.artifacts["learning_curve"] = curve
    if is_pong(config.env_id):
        previous, frame = sample_pong_frames(config.env_id, config.seed)
        result.artifacts["observation"] = plot_pong_observation(previous, frame, folder / "observation.png")
    if config.record_video:
        video = folder / "video.mp4"
        with _video_writer(video, env_info(config.env_id).video_fps) as writer:
            if is_pong(config.env_id):
                record_pong_episode(config, model, config.video_max_frames, writer.append_data)
            else:
                result.greedy_return = record_greedy_episode(config, model, config.video_max_frames, writer.append_data)
        result.artifacts["video"] = video
