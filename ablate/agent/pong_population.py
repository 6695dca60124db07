"""A population of Pong members in one process: each member's own emulators stepped in turn, one stacked forward
to act for every member's frames (``pong_acting``), each member's own update as its single trial's.

Every member keeps its single trial's streams: emulator seeds, numpy RNG for actions, torch seed for its initial
weights and dropout, Adam, checkpoints and videos. Acting is its trial's function to float rounding, so a
member plays its trial's episodes until a float difference first flips a sampled action; its updates are its
trial's own ``train_step``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ablate.agent.collectors import Episode, PongCollector, TrainingVideos
from ablate.agent.envs import PONG_ACTIONS, env_info
from ablate.agent.optim import Adam
from ablate.agent.policies import Policy, create_model
from ablate.agent.pong_acting import StackedPongActor, stackable_policy
from ablate.agent.reinforce import UpdateStats, actions_from_uniforms, discount_rewards, normalize, train_step
from ablate.agent.stacked_episodes import Batch
from ablate.agent.trial import PONG_TRAIN_CHUNK, _limit_fragmentation
from ablate.config import TrialConfig


def episodes_batch(episodes: Sequence[Episode], config: TrialConfig) -> Batch:
    """An update's episodes as one ``Batch``: returns discounted within each episode, then normalised across
    the batch (``SingleBackend``'s)."""
    returns = [discount_rewards(e.rewards, config.gamma, config.reset_on_score) for e in episodes]
    return Batch(
        np.array([len(e.actions) for e in episodes], np.int64),
        np.array([float(e.rewards.sum()) for e in episodes]),
        np.concatenate([e.observations for e in episodes]),
        np.concatenate([e.actions for e in episodes]),
        normalize(np.concatenate(returns)),
    )


@dataclass
class _PongMember:
    config: TrialConfig
    model: Policy
    optimizer: Adam
    rng: np.random.Generator
    torch_rng: torch.Tensor
    """Its single trial's global torch RNG state (after its initial weights; dropout draws from it)."""
    videos: TrainingVideos
    collector: PongCollector
    episodes_done: int = 0
    """Episodes its updates have taken (its checkpoints' count)."""


class PongPopulationBackend:
    """Members of one ``pong_population_group``; the backend interface of ``population.SingleBackend``."""

    def __init__(self, configs: Sequence[TrialConfig], device: torch.device, artifacts_dirs: Sequence[Path | None]):
        _limit_fragmentation()
        info = env_info(configs[0].env_id)
        self.members: list[_PongMember] = []
        for config, folder in zip(configs, artifacts_dirs, strict=True):
            torch.manual_seed(config.seed)  # the initial weights of its single trial
            n_actions = len(PONG_ACTIONS[config.action_set])
            model = create_model(config.env_id, config.model, info.observation_size, n_actions).to(device)
            videos = TrainingVideos(folder, config.video_every, config.video_max_frames, info.video_fps)
            self.members.append(
                _PongMember(
                    config,
                    model,
                    Adam(model.parameters(), lr=config.learning_rate),
                    np.random.default_rng(config.seed),
                    torch.get_rng_state(),
                    videos,
                    PongCollector(config, videos),
                )
            )
        # On a GPU, or for a network the stacked forward does not cover, each member acts as its trial does.
        stacked = device.type == "cpu" and all(stackable_policy(m.model) for m in self.members)
        self.actor = StackedPongActor([m.model for m in self.members]) if stacked else None

    def collect(self, counts: Sequence[int], budgets: Sequence[int]) -> dict[int, Batch]:
        """Step every member whose batch of ``counts[slot]`` episodes is not finished, one stacked forward per
        step, until at least one member's is; those members' batches. A finished member steps no more until
        its update, so it plays under the weights its single trial would."""
        members = self.members
        while True:
            ready = [s for s, m in enumerate(members) if len(m.collector.finished) >= counts[s]]
            if ready:
                for s in ready:
                    members[s].episodes_done += counts[s]
                return {s: episodes_batch(members[s].collector.take(counts[s]), members[s].config) for s in ready}
            playing, observations = zip(*(m.collector.playing_observations() for m in members), strict=True)
            if self.actor is not None:
                logits = self.actor.logits(np.concatenate(observations), [len(p) for p in playing])
            else:
                logits = np.concatenate([m.model.act_logits(o) for m, o in zip(members, observations, strict=True)])
            # Each member's uniforms from its own RNG, drawn as choose_action draws them for its single trial.
            uniforms = np.concatenate([m.rng.random((len(p), 1)) for m, p in zip(members, playing, strict=True)])
            actions = actions_from_uniforms(logits, uniforms).astype(np.int64)
            start = 0
            for slot, (member, these) in enumerate(zip(members, playing, strict=True)):
                member.collector.advance(these, actions[start : start + len(these)], budgets[slot])
                start += len(these)

    def update(self, ready: dict[int, Batch]) -> dict[int, UpdateStats]:
        """Each ready member's single-trial ``train_step`` on its batch, under its own torch RNG. (A batched
        update would save nothing here: at 1,024 frames a chunk the CNN's update is arithmetic, not calls.)"""
        stats = {}
        for slot, batch in ready.items():
            member = self.members[slot]
            torch.set_rng_state(member.torch_rng)
            stats[slot] = train_step(
                member.model,
                member.optimizer,
                batch.observations,
                batch.actions,
                batch.weights,
                l2=member.config.l2,
                chunk_size=PONG_TRAIN_CHUNK,
            )
            member.torch_rng = torch.get_rng_state()
        return stats

    def policy(self, slot: int) -> Policy:
        return self.members[slot].model

    def state(self, slot: int) -> dict:
        member = self.members[slot]
        return {
            "model": member.model.state_dict(),
            "optimizer": member.optimizer.state_dict(),
            "torch_rng": member.torch_rng.clone(),
            "numpy_rng": member.rng.bit_generator.state,
            "collector": member.collector.state(member.episodes_done),
        }

    def collector_state(self, episodes_done: int) -> dict:
        raise NotImplementedError("a Pong population's state(slot) carries each member's collector")

    def restore(self, slot: int, saved: dict, episodes_done: int) -> None:
        member = self.members[slot]
        member.model.load_state_dict(saved["model"])
        member.optimizer.load_state_dict(saved["optimizer"])
        member.torch_rng = saved["torch_rng"]
        member.rng.bit_generator.state = saved["numpy_rng"]
        member.episodes_done = episodes_done
        member.collector.set_state(saved["collector"], member.config, episodes_done)

    def keep(self, slots: list[int]) -> None:
        """Only the members at ``slots`` go on; the others' emulators close (their results are taken)."""
        for slot, member in enumerate(self.members):
            if slot not in slots:
                member.collector.close()
        self.members = [self.members[s] for s in slots]
        if self.actor is not None:
            self.actor.keep(slots)

    def video_paths(self, slot: int) -> list[Path]:
        videos = self.members[slot].videos
        videos.close()  # the member is over: its last video ends here
        return list(videos.paths)

    def close(self) -> None:
        for member in self.members:
            member.collector.close()
