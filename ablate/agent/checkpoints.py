"""A trainer member's checkpoint: everything its run depends on, so a resumed member is its unbroken run."""

from __future__ import annotations

import io
import time
from collections import deque

import torch

from ablate.agent.records import EpisodeMetrics
from ablate.agent.slots import Episode

CHECKPOINT_VERSION = 3
"""The stacked members' checkpoints (1, 2: earlier trainers', which a trial starts afresh from)."""


def checkpoint(population, position: int) -> bytes:
    """Member ``position``'s whole state: weights, Adam, RNGs, its envs' streams, its episodes in flight."""
    member = population.members[position]
    buffer = io.BytesIO()
    torch.save(
        {
            "version": CHECKPOINT_VERSION,
            "model": population.network.state_dict(position),
            "optimizer": population.optimizer.state_dict(position),
            "dropout_rng": population.network.generator_state(position),
            "numpy_rng": population.actions_state(position),
            "slots": population.slots.member_state(position),
            "collection": _collection_state(population, position),
            "history": [tuple(m) for m in member.history],
            "env_steps": member.env_steps,
            "updates": member.updates,
            "episodes_to_solve": member.episodes_to_solve,
            "completed": member.completed,
            "wall_s": time.perf_counter() - member.started,
        },
        buffer,
    )
    return buffer.getvalue()


def _collection_state(population, position: int) -> dict | None:
    """Continuous slots' episodes in flight (taken with their emulators' states); from a reset, none."""
    if not population.continuous:
        return None
    member, slots = population.members[position], population.slots_of(position)
    return {
        "finished": list(member.finished),
        "playing": [int(s - slots[0]) for s in member.counting],
        "memories": [(list(population.slots.memories[s].observations), list(population.slots.memories[s].actions),
                      list(population.slots.memories[s].rewards)) for s in slots],
        "raw": population.slots.raw[slots].copy(),
    }  # fmt: skip


def restore(population, position: int, blob: bytes) -> None:
    """Member ``position`` goes on from ``blob`` (``checkpoint``'s) exactly as its unbroken run."""
    member = population.members[position]
    saved = torch.load(io.BytesIO(blob), weights_only=False)
    if saved.get("version") != CHECKPOINT_VERSION:
        return  # an earlier trainer's checkpoint (no slots to restore): the trial starts afresh
    member.history = [EpisodeMetrics(*row) for row in saved["history"]]
    member.window.extend(m.episode_return for m in member.history[-member.config.solve_window :])
    member.env_steps, member.updates = saved["env_steps"], saved["updates"]
    member.episodes_to_solve, member.completed = saved["episodes_to_solve"], saved["completed"]
    population.network.load_state_dict(position, saved["model"])
    population.optimizer.load_state_dict(position, saved["optimizer"])
    population.network.set_generator_state(position, saved["dropout_rng"])
    member.actions_rng.bit_generator.state = saved["numpy_rng"]
    population.slots.set_member_state(position, saved["slots"])
    member.started -= saved["wall_s"]
    if member.videos is not None and member.videos.every:
        member.videos.next_at = -(-member.completed // member.videos.every) * member.videos.every
    collection = saved["collection"]
    if collection is None or member.done:
        return
    slots = population.slots_of(position)
    member.finished = deque(Episode(*e) for e in collection["finished"])
    population.set_counting(position, slots[collection["playing"]])
    for s, (observations, actions, rewards) in zip(slots, collection["memories"], strict=True):
        memory = population.slots.memories[s]
        memory.observations, memory.actions, memory.rewards = observations, actions, rewards
    population.slots.raw[slots] = collection["raw"]
