"""One trial: seed, build env and policy, collect episodes, update, stop when solved or out of budget.

An importable function of a ``TrialConfig``; metrics leave through a callback, artifacts into a folder.
No Ray and no MLflow here: the scheduler and the tracker wrap this.
"""

from __future__ import annotations

import csv
import math
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import gymnasium as gym
import numpy as np
import torch

from ablate.config import TrialConfig
from ablate.envs import env_info, make_env, make_vec_env, observation_adapter
from ablate.optim import Adam
from ablate.policies import Policy, create_model, parameter_count
from ablate.reinforce import choose_action, discount_rewards, normalize, train_step


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
    """Return of the recorded greedy episode (None when no video was recorded)."""
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
) -> TrialResult:
    """Train one REINFORCE agent as ``config`` says and return its per-episode metrics and weights.

    ``on_episodes`` receives each update's new episodes as they finish. With ``artifacts_dir``, the trial
    writes ``episodes.csv``, ``weights.pt``, ``learning_curve.png`` and (if ``record_video``) ``video.mp4``.
    """
    _inject_fault(config)
    started = time.perf_counter()
    torch.set_num_threads(1)  # tiny networks: threads cost more than they give, and trials run side by side
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    info = env_info(config.env_id)
    threshold = config.solve_threshold if config.solve_threshold is not None else info.reward_threshold
    model = create_model(config.env_id, config.model, info.observation_size, info.n_actions)
    optimizer = Adam(model.parameters(), lr=config.learning_rate)
    env = make_vec_env(config.env_id, config.episodes_per_update)
    adapter = observation_adapter(config.env_id, config.model)

    history: list[EpisodeMetrics] = []
    window: deque[float] = deque(maxlen=config.solve_window)
    env_steps = 0
    episodes_to_solve: int | None = None
    reset_seed: int | None = config.seed
    updates = 0
    try:
        while len(history) < config.max_episodes and episodes_to_solve is None:
            count = min(config.episodes_per_update, config.max_episodes - len(history))
            episodes = collect_episodes(env, adapter, model, rng, count, seed=reset_seed)
            reset_seed = None  # seed the envs once; later resets continue their random streams
            # Returns are discounted within each episode, then normalised across the whole batch.
            returns = [discount_rewards(e.rewards, config.gamma, config.reset_on_score) for e in episodes]
            stats = train_step(
                model,
                optimizer,
                np.concatenate([e.observations for e in episodes]),
                np.concatenate([e.actions for e in episodes]),
                normalize(np.concatenate(returns)),
                l2=config.l2,
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
            history.extend(new)
            if on_episodes is not None:
                on_episodes(new)
    finally:
        env.close()

    result = TrialResult(
        config=config,
        episodes=history,
        episodes_to_solve=episodes_to_solve,
        solve_threshold=threshold,
        env_steps=env_steps,
        wall_s=time.perf_counter() - started,
        parameter_count=parameter_count(model),
        state_dict={k: v.detach().clone() for k, v in model.state_dict().items()},
    )
    if artifacts_dir is not None:
        write_artifacts(result, model, Path(artifacts_dir))
    return result


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


def write_artifacts(result: TrialResult, model: Policy, folder: Path) -> None:
    """Per-episode table, weights, learning curve and (optionally) a video of the greedy agent into ``folder``."""
    # Imported here: a worker process pays for matplotlib and ffmpeg only when a trial ends.
    import imageio.v2 as imageio

    from ablate.plots import plot_progress

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
    if config.record_video:
        video = folder / "video.mp4"
        fps = env_info(config.env_id).video_fps
        # yuv420p H.264 plays in every browser, MLflow's artifact viewer included. One encoder thread at x264's
        # fastest preset: ffmpeg runs beside the trial's own process, on CPUs its neighbours are training on
        # (measured per 250 frames: 0.18 s of CPU vs 0.30 s at the default preset; ~60 KB instead of ~20 KB).
        with imageio.get_writer(
            video,
            fps=fps,
            codec="libx264",
            pixelformat="yuv420p",
            macro_block_size=2,
            output_params=["-threads", "1", "-preset", "ultrafast"],
        ) as writer:
            result.greedy_return = record_greedy_episode(config, model, config.video_max_frames, writer.append_data)
        result.artifacts["video"] = video
