"""A stacked population's episodes: each member's collection in flight, all members stepped together, and a
member's batch handed over the moment its own episodes have ended (no member waits for another's).

A member collects exactly as ``collectors.collect_episodes`` does in its single trial: from a reset, its first
``count`` sub-envs each play one episode, sub-envs that end early are stepped on (their steps ignored), its
actions sampled as ``reinforce.choose_action`` samples them from its own stream of uniforms.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from ablate.agent.reinforce import normalize
from ablate.agent.vector_cartpole import CartPoleBatch, StreamDraws

_BLOCK_STEPS = 64
"""Steps of action uniforms read from the streams at a time."""


class Batch(NamedTuple):
    """One member's episodes of one update."""

    lengths: np.ndarray
    """Steps of each episode, in order."""
    episode_returns: np.ndarray
    observations: np.ndarray
    """Every episode's observations, concatenated in order (the update's batch)."""
    actions: np.ndarray
    weights: np.ndarray
    """Normalised discounted returns: the policy-gradient weights."""


def sample_actions(logits: np.ndarray, u: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``reinforce.choose_action``'s inverse-CDF sampling for every row of (M, N, actions) ``logits`` with
    uniforms ``u`` (M, N): the same float operations, so the same actions, written into ``out`` (M, N) int8."""
    if logits.shape[2] == 2:
        # Its cumulative sums are [e0, e0 + e1]; u * (e0 + e1) never exceeds e0 + e1 (u < 1), so the action is
        # whether e0 falls below it: six array operations instead of its reductions along a 2-wide axis.
        exps = logits - np.maximum(logits[:, :, 0], logits[:, :, 1])[:, :, None]
        np.exp(exps, out=exps)
        scaled = u * (exps[:, :, 0] + exps[:, :, 1])
        np.less(exps[:, :, 0], scaled, out=out.view(bool))
        return out
    cumulative = np.cumsum(np.exp(logits - logits.max(axis=2, keepdims=True)), axis=2)
    scaled = u[:, :, None] * cumulative[:, :, -1:]
    out[...] = np.minimum((cumulative < scaled).sum(axis=2), logits.shape[2] - 1)
    return out


def discounted_steps(gamma: float, steps: int) -> np.ndarray:
    """``reinforce.discount_rewards`` of CartPole's 1.0 a step, indexed by steps left: ``[d]`` is the return
    of a step with ``d`` steps after it in its episode (the same operations, so the same values)."""
    table = np.zeros(max(steps, 1))
    running = 0.0
    for d in range(len(table)):
        running = 1.0 + gamma * running
        table[d] = running
    return table


class StackedEpisodes:
    """Every member's CartPole envs (``CartPoleBatch``), action streams and collection in flight. Slots are
    the members' positions; ``keep`` drops those that left, their collections with them."""

    def __init__(
        self, seeds: Sequence[int], gammas: Sequence[float], num_envs: int, max_episode_steps: int, history: int = 0
    ) -> None:
        m, n = len(seeds), num_envs
        self.num_envs = n
        self.env = CartPoleBatch(seeds, n, max_episode_steps)
        self.draws = StreamDraws([np.random.default_rng(s) for s in seeds], 4 * _BLOCK_STEPS * n)
        self.returns = [discounted_steps(g, max_episode_steps) for g in gammas]
        # A collection lasts at most max_episode_steps (every episode is truncated there): a ring of that many
        # steps (plus the next observation) holds every collection in flight.
        self.capacity = max_episode_steps + 1
        self.iteration = 0
        """Steps taken by the population so far; step g's observations and actions sit in ring slot g % capacity."""
        self.observations = np.zeros((self.capacity, m, n, 4), np.float32)
        self.actions = np.zeros((self.capacity, m, n), np.int8)
        self.history = history
        self.window = np.zeros((m, n, history, 4), np.float32) if history else None
        """With ``history`` (CartPole's ``cnn``): each env's last ``history`` observations, oldest first, zeros
        before its collection's reset, as ``envs.ObservationWindow`` keeps them (across the autoresets of envs
        that are stepped on): what members act on."""
        self.collecting = np.zeros(m, bool)
        self.started = np.zeros(m, np.int64)
        """The step at which each member's collection began."""
        self.counts = np.zeros(m, np.int64)
        self.active = np.zeros((m, n), bool)
        """Sub-envs whose episode is still running and counts (its first ``count``)."""
        self.lengths = np.zeros((m, n), np.int64)
        self._ended = np.zeros((m, n), bool)
        self._block: np.ndarray | None = None
        self._block_used = 0

    @property
    def members(self) -> int:
        return len(self.collecting)

    def collect(self, act_logits: Callable[[np.ndarray], np.ndarray], counts: Sequence[int]) -> dict[int, Batch]:
        """Step every member until at least one has all its episodes; those members' batches, by slot. A member
        with no collection in flight starts its next one (``counts[slot]`` episodes) from a reset first;
        the others go on with theirs."""
        starting = np.flatnonzero(~self.collecting)
        if len(starting):
            self._start(starting, np.asarray(counts)[starting])
        capacity = self.capacity
        ended, active, window = self._ended, self.active, self.window
        while True:
            slot = self.iteration % capacity
            if self._block is None or self._block_used == _BLOCK_STEPS:
                self._next_block()
            u = self._block[:, self._block_used]
            self._block_used += 1
            inputs = self.observations[slot] if window is None else window
            actions = sample_actions(act_logits(inputs), u, self.actions[slot])
            done = self.env.step(actions, self.observations[(slot + 1) % capacity])
            if window is not None:
                window[:, :, :-1] = window[:, :, 1:]
                window[:, :, -1] = self.observations[(slot + 1) % capacity]
            self.iteration += 1
            np.logical_and(active, done, out=ended)
            if not ended.any():
                continue
            np.copyto(self.lengths, self.env.steps, where=ended)  # an active env's steps are its episode's
            np.greater(active, ended, out=active)  # active & ~ended
            running = active.any(axis=1)
            if not running.all():
                ready = np.flatnonzero(~running)
                self.collecting[ready] = False
                return {int(i): self._batch(int(i)) for i in ready}

    def _start(self, members: np.ndarray, counts: np.ndarray) -> None:
        """``members`` begin a collection of ``counts`` episodes at this step, from a reset."""
        observations = self.env.reset(members)
        self.observations[self.iteration % self.capacity, members] = observations[members]
        if self.window is not None:
            self.window[members] = 0
            self.window[members, :, -1] = observations[members]
        self.active[members] = np.arange(self.num_envs)[None, :] < counts[:, None]
        self.lengths[members] = 0
        self.counts[members] = counts
        self.started[members] = self.iteration
        self.collecting[members] = True

    def _next_block(self) -> None:
        """Every member takes ``num_envs`` uniforms a step, whichever collection it is in: the next block's."""
        if self._block is not None:
            self.draws.take(self._block_used * self.num_envs)
        self._block = self.draws.peek(_BLOCK_STEPS * self.num_envs).reshape(self.members, _BLOCK_STEPS, -1)
        self._block_used = 0

    def _settle(self) -> None:
        """The action streams' positions as the steps taken so far left them (before a checkpoint or a change)."""
        if self._block is not None:
            self.draws.take(self._block_used * self.num_envs)
        self._block, self._block_used = None, 0

    def _batch(self, member: int) -> Batch:
        """Member ``member``'s finished collection: its first ``count`` sub-envs' episodes, in order."""
        count = int(self.counts[member])
        steps = self.iteration - int(self.started[member])
        ring = (self.started[member] + np.arange(steps)) % self.capacity
        lengths = self.lengths[member, :count].copy()
        valid = np.arange(steps)[None, :] < lengths[:, None]  # (episode, step)
        observations = self.observations[ring, member, :count]  # (step, episode, 4)
        if self.history:  # each step's window: the observations of the last `history` steps, zeros before the reset
            padded = np.concatenate([np.zeros((self.history - 1, *observations.shape[1:]), np.float32), observations])
            observations = np.swapaxes(np.lib.stride_tricks.sliding_window_view(padded, self.history, axis=0), -1, -2)
        observations = np.swapaxes(observations, 0, 1)[valid]
        actions = self.actions[ring, member, :count].T[valid].astype(np.int64)
        steps_left = (lengths[:, None] - 1 - np.arange(steps)[None, :])[valid]
        weights = normalize(self.returns[member][steps_left])
        return Batch(lengths, lengths.astype(np.float64), observations, actions, weights)

    def action_state(self, member: int) -> dict:
        """Member ``member``'s action stream (its single trial's ``numpy_rng``), as the steps taken left it."""
        self._settle()
        return self.draws.state(member)

    def set_action_state(self, member: int, state: dict) -> None:
        self._settle()
        self.draws.set_state(member, state)
        self.collecting[member] = False

    def keep(self, slots: list[int]) -> None:
        """Only ``slots`` go on, in this order, each with its collection in flight."""
        self._settle()
        index = np.asarray(slots, np.int64)
        self.env.keep(index)
        self.draws.keep(index)
        self.returns = [self.returns[s] for s in slots]
        # Contiguous: indexing an inner axis can hand back a transposed layout, and a step's rows are read as one.
        self.observations = np.ascontiguousarray(self.observations[:, index])
        self.actions = np.ascontiguousarray(self.actions[:, index])
        self.collecting, self.started, self.counts = self.collecting[index], self.started[index], self.counts[index]
        self.active, self.lengths = self.active[index], self.lengths[index]
        if self.window is not None:
            self.window = np.ascontiguousarray(self.window[index])
        self._ended = np.zeros_like(self.active)
