"""Population trials: M members (seeds, and tuning candidates that differ in optimisation knobs) of one variant
trained together in one process; ``run_trial`` is a population of one.

Every member collects its next batch of episodes and takes one Adam step as soon as its own episodes are in
(no member waits for another's); a member that solves, runs out of budget or fails (a NaN loss) leaves, the
others go on untouched. CartPole's members (dense or ``cnn``) share stacked tensors (``stacked.StackedBackend``:
one env step, one forward, one backward for all); Pong's members act in one stacked forward and update as their
trials (``pong_population.PongPopulationBackend``); any other variant, and a Pong population of one, runs on its
own path (``SingleBackend``). Every member keeps a single trial's metrics callback, checkpoints, exact resume and
artifacts. No Ray and no MLflow here.
"""

from __future__ import annotations

import io
import math
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from ablate.agent.collectors import PongCollector, TrainingVideos, VectorCollector
from ablate.agent.envs import PONG_ACTIONS, env_info, is_pong
from ablate.agent.optim import Adam
from ablate.agent.policies import Policy, create_model, parameter_count
from ablate.agent.pong_population import PongPopulationBackend
from ablate.agent.reinforce import UpdateStats, discount_rewards, normalize, train_step
from ablate.agent.stacked import Batch, StackedBackend, population_group, stackable
from ablate.agent.trial import (
    PONG_TRAIN_CHUNK,
    EpisodeMetrics,
    TrialFailed,
    TrialResult,
    _inject_fault,
    _limit_fragmentation,
    solve_threshold,
    write_artifacts,
)
from ablate.config import TrialConfig

MemberOutcome = TrialResult | TrialFailed
"""What a member ends with: its result, or the error that stopped it alone."""


class SingleBackend:
    """One member on the single-trial path: its ``Policy``, ``Adam``, global torch RNG and collector, exactly as
    ``run_trial`` ran them before populations. ``run_population`` takes it for a Pong population of one; every
    CartPole config stacks, so for CartPole it is the reference that tests/test_population.py holds members to."""

    def __init__(self, config: TrialConfig, device: torch.device, artifacts_dir: Path | None) -> None:
        pong = is_pong(config.env_id)
        if pong:
            _limit_fragmentation()
        torch.manual_seed(config.seed)
        self.config = config
        self.rng = np.random.default_rng(config.seed)
        info = env_info(config.env_id)
        n_actions = len(PONG_ACTIONS[config.action_set]) if pong else info.n_actions
        self.model = create_model(config.env_id, config.model, info.observation_size, n_actions).to(device)
        self.optimizer = Adam(self.model.parameters(), lr=config.learning_rate)
        self.videos = TrainingVideos(
            artifacts_dir if pong else None, config.video_every, config.video_max_frames, info.video_fps
        )
        self.collector = PongCollector(config, self.videos) if pong else VectorCollector(config)
        self.chunk = PONG_TRAIN_CHUNK if pong else None

    def collect(self, counts: Sequence[int], budgets: Sequence[int]) -> dict[int, Batch]:
        config = self.config
        episodes = self.collector.collect(self.model, self.rng, counts[0], budget=budgets[0])
        # Returns are discounted within each episode, then normalised across the whole batch.
        returns = [discount_rewards(e.rewards, config.gamma, config.reset_on_score) for e in episodes]
        lengths = np.array([len(e.actions) for e in episodes], np.int64)
        return {
            0: Batch(
                lengths,
                np.array([float(e.rewards.sum()) for e in episodes]),
                np.concatenate([e.observations for e in episodes]),
                np.concatenate([e.actions for e in episodes]),
                normalize(np.concatenate(returns)),
            )
        }

    def update(self, batches: dict[int, Batch]) -> dict[int, UpdateStats]:
        b = batches[0]
        return {
            0: train_step(
                self.model,
                self.optimizer,
                b.observations,
                b.actions,
                b.weights,
                l2=self.config.l2,
                chunk_size=self.chunk,
            )
        }

    def policy(self, slot: int) -> Policy:
        return self.model

    def state(self, slot: int) -> dict:
        return {
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "torch_rng": torch.get_rng_state(),
            "numpy_rng": self.rng.bit_generator.state,
            "collector": None,  # filled by the caller, which knows the episode count
        }

    def collector_state(self, episodes_done: int) -> dict:
        return self.collector.state(episodes_done)

    def restore(self, slot: int, saved: dict, episodes_done: int) -> None:
        self.model.load_state_dict(saved["model"])
        self.optimizer.load_state_dict(saved["optimizer"])
        torch.set_rng_state(saved["torch_rng"])
        self.rng.bit_generator.state = saved["numpy_rng"]
        self.collector.set_state(saved["collector"], self.config, episodes_done)

    def keep(self, slots: list[int]) -> None:
        pass

    def video_paths(self, slot: int) -> list[Path]:
        self.videos.close()  # the trial is over: its last video ends here
        return list(self.videos.paths)

    def close(self) -> None:
        self.collector.close()


@dataclass
class _Member:
    index: int
    """Position in ``run_population``'s ``configs``."""
    config: TrialConfig
    threshold: float | None
    started: float
    history: list[EpisodeMetrics] = field(default_factory=list)
    window: deque = field(default_factory=deque)
    env_steps: int = 0
    updates: int = 0
    episodes_to_solve: int | None = None
    next_checkpoint: int | None = None

    @property
    def done(self) -> bool:
        return len(self.history) >= self.config.max_episodes or self.episodes_to_solve is not None


def can_share(configs: Sequence[TrialConfig]) -> bool:
    """Whether ``configs`` can train as one population (one is always a population)."""
    groups = {population_group(c) for c in configs}
    return len(configs) <= 1 or (len(groups) == 1 and None not in groups)


def run_population(
    configs: Sequence[TrialConfig],
    on_episodes: Callable[[int, list[EpisodeMetrics]], None] | None = None,
    artifacts_dirs: Sequence[str | Path | None] | None = None,
    *,
    resume_from: Sequence[bytes | None] | None = None,
    on_checkpoint: Callable[[int, bytes], None] | None = None,
    on_outcome: Callable[[int, MemberOutcome], None] | None = None,
    device: str | None = None,
) -> list[MemberOutcome]:
    """Train ``configs`` (``can_share``) together; member i behaves as ``run_trial(configs[i], ...)``.

    ``on_episodes(i, rows)``: member i's new episodes after each update (a resumed member's saved history
    first, in one call). ``artifacts_dirs[i]``: member i's folder (``run_trial``'s artifacts). Every
    ``checkpoint_interval`` episodes, ``on_checkpoint(i, blob)`` gets member i's whole state, which
    ``resume_from[i]`` restores. ``on_outcome(i, outcome)`` as each member ends (its ``TrialResult``, or the
    ``TrialFailed`` that stopped it alone). ``device``: where the networks learn (``None``: CUDA whenever torch
    sees a device, else the CPU). Returns every member's outcome, in order."""
    if not can_share(configs):
        raise ValueError(
            "these configs cannot share a population: " + ", ".join(str(population_group(c)) for c in configs)
        )
    for config in configs:
        _inject_fault(config)
    started = time.perf_counter()
    torch.set_num_threads(1)  # tiny networks: threads cost more than they give, and trials run side by side
    threadpool_limits(1, user_api="blas")  # the same for numpy's acting path (OpenBLAS would spin 2 threads)
    device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    folders = [Path(d) if d is not None else None for d in (artifacts_dirs or [None] * len(configs))]
    if stackable(configs[0]):
        backend: StackedBackend | PongPopulationBackend | SingleBackend = StackedBackend(configs, device)
    elif len(configs) > 1 and is_pong(configs[0].env_id):
        backend = PongPopulationBackend(configs, device, folders)
    else:
        backend = SingleBackend(configs[0], device, folders[0])
    members = [
        _Member(i, c, solve_threshold(c), started, window=deque(maxlen=c.solve_window)) for i, c in enumerate(configs)
    ]
    for slot, (member, blob) in enumerate(zip(members, resume_from or [None] * len(configs), strict=True)):
        if blob is not None:
            _restore(backend, slot, member, blob, on_episodes)
        every = member.config.checkpoint_interval if on_checkpoint is not None else 0
        member.next_checkpoint = (len(member.history) // every + 1) * every if every else None
    outcomes: dict[int, MemberOutcome] = {}
    try:
        while True:
            _finish_done(backend, members, outcomes, folders, on_outcome)
            staying = [slot for slot, m in enumerate(members) if m.index not in outcomes]
            if len(staying) < len(members):
                members = [members[slot] for slot in staying]
                if members:
                    backend.keep(staying)
            if not members:
                break
            counts = [min(m.config.episodes_per_update, m.config.max_episodes - len(m.history)) for m in members]
            # The members whose batch is complete (at least one): each updates as soon as its episodes are in,
            # so no member waits for another's (a member's run is its single trial's, whoever is beside it).
            batches = backend.collect(counts, [m.config.max_episodes - len(m.history) for m in members])
            stats = backend.update(batches)
            for slot, batch in batches.items():
                member, stat = members[slot], stats[slot]
                failure = None
                if not math.isfinite(stat.loss):
                    failure = TrialFailed(
                        f"loss became {stat.loss} at episode {len(member.history) + len(batch.lengths)}; "
                        f"try a smaller learning_rate (now {member.config.learning_rate})"
                    )
                elif member.config.fault == "raise":
                    failure = TrialFailed("injected fault: raise after the first update (tests only)")
                if failure is not None:
                    outcomes[member.index] = failure
                    if on_outcome is not None:
                        on_outcome(member.index, failure)
                    continue
                member.updates += 1
                new = _record(member, batch, stat, time.perf_counter() - member.started)
                if on_episodes is not None:
                    on_episodes(member.index, new)
                _maybe_checkpoint(backend, slot, member, on_checkpoint)
    finally:
        backend.close()
    return [outcomes[i] for i in range(len(configs))]


def _record(member: _Member, batch: Batch, stat: UpdateStats, wall_s: float) -> list[EpisodeMetrics]:
    """The update's episodes as metrics rows, with the rolling mean and the solve rule (``run_trial``'s)."""
    config = member.config
    new: list[EpisodeMetrics] = []
    for length, episode_return in zip(batch.lengths, batch.episode_returns, strict=True):
        member.env_steps += int(length)
        member.window.append(float(episode_return))
        # Exactly rounded, so np.mean's value for the integer returns of CartPole and Pong, at a tenth of its cost.
        rolling = math.fsum(member.window) / len(member.window)
        new.append(
            EpisodeMetrics(
                len(member.history) + len(new) + 1,
                float(episode_return),
                int(length),
                stat.loss,
                stat.entropy,
                rolling,
                member.env_steps,
                wall_s,
                member.updates,
            )
        )
        if (
            member.episodes_to_solve is None
            and member.threshold is not None
            and len(member.window) == config.solve_window
            and rolling >= member.threshold
        ):
            member.episodes_to_solve = new[-1].episode
    member.history.extend(new)
    return new


def _maybe_checkpoint(backend, slot: int, member: _Member, on_checkpoint) -> None:
    config, history = member.config, member.history
    if member.next_checkpoint is None or len(history) < member.next_checkpoint or len(history) >= config.max_episodes:
        return
    on_checkpoint(member.index, _checkpoint(backend, slot, member))
    every = config.checkpoint_interval
    member.next_checkpoint = (len(history) // every + 1) * every
    if config.fault == "crash_after_checkpoint" and not Path(config.fault_marker).exists():
        Path(config.fault_marker).write_text("crashed after a checkpoint\n")
        os._exit(17)  # the process dies with a checkpoint taken: its retry must resume from it


def _checkpoint(backend, slot: int, member: _Member) -> bytes:
    state = backend.state(slot)
    if state["collector"] is None:
        state["collector"] = backend.collector_state(len(member.history))
    buffer = io.BytesIO()
    torch.save(
        {
            "version": 1,
            **state,
            "history": [tuple(m) for m in member.history],
            "env_steps": member.env_steps,
            "updates": member.updates,
            "episodes_to_solve": member.episodes_to_solve,
            "wall_s": time.perf_counter() - member.started,
        },
        buffer,
    )
    return buffer.getvalue()


def _restore(backend, slot: int, member: _Member, blob: bytes, on_episodes) -> None:
    saved = torch.load(io.BytesIO(blob), weights_only=False)
    member.history = [EpisodeMetrics(*row) for row in saved["history"]]
    member.window.extend(m.episode_return for m in member.history[-member.config.solve_window :])
    member.env_steps, member.updates = saved["env_steps"], saved["updates"]
    member.episodes_to_solve = saved["episodes_to_solve"]
    backend.restore(slot, saved, len(member.history))
    member.started -= saved["wall_s"]
    if on_episodes is not None and member.history:
        on_episodes(member.index, list(member.history))


def _finish_done(backend, members, outcomes, folders, on_outcome) -> None:
    """Members that solved or spent their budget end: result, artifacts, ``on_outcome``."""
    for slot, member in enumerate(members):
        if member.index in outcomes or not member.done:
            continue
        policy = backend.policy(slot)
        result = TrialResult(
            config=member.config,
            episodes=member.history,
            episodes_to_solve=member.episodes_to_solve,
            solve_threshold=member.threshold,
            env_steps=member.env_steps,
            wall_s=time.perf_counter() - member.started,
            parameter_count=parameter_count(policy),
            state_dict={k: v.detach().cpu().clone() for k, v in policy.state_dict().items()},
        )
        folder = folders[member.index]
        if folder is not None:
            result.artifacts.update({f"videos/{p.name}": p for p in backend.video_paths(slot) if p.exists()})
            write_artifacts(result, policy, folder)
        outcomes[member.index] = result
        if on_outcome is not None:
            on_outcome(member.index, result)
