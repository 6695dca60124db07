"""CartPole for a population: every member's envs in one set of numpy arrays, all stepped by one call.

The physics, reset distribution and autoreset are Gymnasium's, operation for operation (``CartPoleVectorEnv``
from 3 envs up, a ``SyncVectorEnv`` of ``CartPoleEnv`` below, as ``envs.make_vec_env`` builds them), and each
member's envs draw from the random streams they draw from in a trial of their own, in the same order: a
member's episodes are its single trial's, bit for bit. ``StreamDraws`` is how M streams are drawn from in one
numpy call per step instead of M Python calls.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


class StreamDraws:
    """Uniform doubles of ``len(generators)`` independent PCG64 streams, pre-drawn into one (streams, capacity)
    array: a step reads every stream's next values with one fancy index. Each stream yields exactly the
    sequence its ``Generator.random()`` calls would (one 64-bit draw per double, in order); ``states`` gives
    each stream's state as if only the values taken so far had been drawn."""

    def __init__(self, generators: Sequence[np.random.Generator], capacity: int) -> None:
        self.generators = list(generators)
        self.origins = [g.bit_generator.state for g in self.generators]
        self.taken = np.zeros(len(self.generators), np.int64)
        """Doubles taken from each stream since its origin state."""
        self.capacity = capacity
        self.buffer = np.stack([g.random(capacity) for g in self.generators]) if self.generators else np.zeros((0, 0))
        self.pos = np.zeros(len(self.generators), np.int64)
        self.end = np.full(len(self.generators), capacity, np.int64)
        """Row s holds stream s's next values at ``buffer[s, pos[s]:end[s]]``."""

    def ensure(self, need: np.ndarray) -> None:
        """Room for ``need[s]`` more doubles of each stream ``s`` (refills the few that run short)."""
        if len(need) and int(need.max()) > self.capacity:  # one block of draws longer than a row: widen all
            grown = 2 * int(need.max())
            self.buffer = np.pad(self.buffer, ((0, 0), (0, grown - self.capacity)))
            self.capacity = grown
        for s in np.flatnonzero(self.pos + need > self.end):
            rest = self.buffer[s, self.pos[s] : self.end[s]].copy()
            self.buffer[s, : len(rest)] = rest
            self.buffer[s, len(rest) :] = self.generators[s].random(self.capacity - len(rest))
            self.pos[s], self.end[s] = 0, self.capacity

    def peek(self, count: int) -> np.ndarray:
        """(streams, count): every stream's next ``count`` doubles, not taken yet."""
        self.ensure(np.full(len(self.generators), count, np.int64))
        return self.buffer[np.arange(len(self.generators))[:, None], self.pos[:, None] + np.arange(count)]

    def take(self, counts: np.ndarray) -> None:
        """Streams ``s`` move on by ``counts[s]`` doubles (read at ``buffer[s, pos[s] + j]``, j < counts[s])."""
        self.pos += counts
        self.taken += counts

    def states(self) -> list[dict]:
        result = []
        for origin, taken in zip(self.origins, self.taken, strict=True):
            bit_generator = np.random.PCG64()
            bit_generator.state = origin
            bit_generator.advance(int(taken))
            result.append(bit_generator.state)
        return result

    def set_state(self, row: int, state: dict) -> None:
        """Stream ``row`` goes on from ``state`` (a checkpoint's)."""
        generator = generator_at(state)
        self.generators[row], self.origins[row], self.taken[row] = generator, state, 0
        self.buffer[row] = generator.random(self.capacity)
        self.pos[row], self.end[row] = 0, self.capacity

    def keep(self, rows: np.ndarray) -> None:
        """Only the streams ``rows`` go on (a member left the population)."""
        self.generators = [self.generators[r] for r in rows]
        self.origins = [self.origins[r] for r in rows]
        self.taken, self.pos, self.end, self.buffer = (
            self.taken[rows],
            self.pos[rows],
            self.end[rows],
            self.buffer[rows],
        )


def generator_at(state: dict) -> np.random.Generator:
    bit_generator = np.random.PCG64()
    bit_generator.state = state
    return np.random.Generator(bit_generator)


class CartPoleBatch:
    """``len(seeds)`` members' ``num_envs`` CartPole envs each. From 3 envs up, a member's envs share one stream
    seeded ``seed`` (``CartPoleVectorEnv``); below, env j has its own, seeded ``seed + j`` (``SyncVectorEnv``).
    Autoreset is Gymnasium's next-step mode: the step after an episode ends resets that env (reward 0)."""

    # CartPoleVectorEnv's constants, computed as it computes them.
    gravity, masscart, masspole, length, force_mag, tau = 9.8, 1.0, 0.1, 0.5, 10.0, 0.02
    total_mass = masspole + masscart
    polemass_length = masspole * length
    theta_threshold_radians = 12 * 2 * math.pi / 360
    x_threshold = 2.4
    low, high = -0.05, 0.05

    def __init__(self, seeds: Sequence[int], num_envs: int, max_episode_steps: int) -> None:
        self.num_envs = num_envs
        self.shared = num_envs > 2
        """One stream per member (vector env) rather than one per env (sync env)."""
        self.max_episode_steps = max_episode_steps
        m = len(seeds)
        self.state = np.zeros((4, m, num_envs))
        self.steps = np.zeros((m, num_envs), np.int32)
        self.prev_done = np.zeros((m, num_envs), bool)
        streams = (
            [np.random.default_rng(s) for s in seeds]
            if self.shared
            else [np.random.default_rng(s + j) for s in seeds for j in range(num_envs)]
        )
        self.draws = StreamDraws(streams, 64 * num_envs)

    @property
    def members(self) -> int:
        return self.state.shape[1]

    def reset(self) -> np.ndarray:
        """Every env of every member from a reset (``VectorEnv.reset()``): observations (M, N, 4) float32."""
        self._redraw(np.ones((self.members, self.num_envs), bool))
        self.steps[:] = 0
        self.prev_done[:] = False
        return self.state.transpose(1, 2, 0).astype(np.float32)

    def step(self, actions: np.ndarray, counting: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One step of every env (``CartPoleVectorEnv.step``): (observations, rewards, terminated, truncated).
        ``counting`` (M,): members whose trial takes this step; an env of any other member that autoresets
        draws nothing from its stream (its single trial has stopped stepping)."""
        x, x_dot, theta, theta_dot = self.state
        force = np.sign(actions - 0.5) * self.force_mag
        costheta = np.cos(theta)
        sintheta = np.sin(theta)
        temp = (force + self.polemass_length * np.square(theta_dot) * sintheta) / self.total_mass
        thetaacc = (self.gravity * sintheta - costheta * temp) / (
            self.length * (4.0 / 3.0 - self.masspole * np.square(costheta) / self.total_mass)
        )
        xacc = temp - self.polemass_length * thetaacc * costheta / self.total_mass
        x = x + self.tau * x_dot
        x_dot = x_dot + self.tau * xacc
        theta = theta + self.tau * theta_dot
        theta_dot = theta_dot + self.tau * thetaacc
        state = np.empty_like(self.state)  # np.stack's checks cost more than these four copies
        state[0], state[1], state[2], state[3] = x, x_dot, theta, theta_dot
        self.state = state
        terminated = (
            (x < -self.x_threshold)
            | (x > self.x_threshold)
            | (theta < -self.theta_threshold_radians)
            | (theta > self.theta_threshold_radians)
        )
        self.steps += 1
        truncated = self.steps >= self.max_episode_steps
        reset = self.prev_done
        if reset.any():
            drawing = reset if counting.all() else reset & counting[:, None]
            self._redraw(drawing)
            if drawing is not reset:
                self.state[:, reset & ~drawing] = 0.0  # never observed: the member's next collection resets it
            kept = ~reset
            self.steps *= kept
            reward = kept.astype(np.float32)  # 1.0 a step, 0.0 on the step that resets
            terminated &= kept
            truncated &= kept
        else:
            reward = np.ones(terminated.shape, np.float32)
        self.prev_done = terminated | truncated
        return self.state.transpose(1, 2, 0).astype(np.float32), reward, terminated, truncated

    def _redraw(self, mask: np.ndarray) -> None:
        """The envs of ``mask`` (M, N) take a fresh start state: per stream, one ``uniform(size=(4, k))`` over its
        k envs to reset, in env order (vector), or ``uniform(size=(4,))`` per env (sync)."""
        members, envs = np.nonzero(mask)
        if not len(members):
            return
        if self.shared:
            k = mask.sum(axis=1)
            self.draws.ensure(4 * k)
            rank = (np.cumsum(mask, axis=1) - 1)[members, envs]
            streams, stride = members, k[members]
            start = self.draws.pos[streams] + rank
            counts = 4 * k
        else:
            streams = members * self.num_envs + envs
            counts = 4 * mask.reshape(-1).astype(np.int64)
            self.draws.ensure(counts)
            stride = np.ones(len(streams), np.int64)
            start = self.draws.pos[streams]
        # One gather of the 4 components' draws (component c of an env at start + c * stride), one scatter.
        flat = (streams * self.draws.capacity + start)[None, :] + np.arange(4)[:, None] * stride[None, :]
        self.state[:, members, envs] = self.low + (self.high - self.low) * self.draws.buffer.reshape(-1)[flat]
        self.draws.take(counts)

    def keep(self, members: np.ndarray) -> None:
        """Only ``members`` (indices, in order) go on."""
        self.state = self.state[:, members]
        self.steps, self.prev_done = self.steps[members], self.prev_done[members]
        rows = members if self.shared else (members[:, None] * self.num_envs + np.arange(self.num_envs)).reshape(-1)
        self.draws.keep(rows)

    def stream_states(self, member: int) -> list[dict]:
        """Member ``member``'s env streams (1, or one per env), for a checkpoint."""
        per = 1 if self.shared else self.num_envs
        return self.draws.states()[member * per : (member + 1) * per]

    def set_stream_states(self, member: int, states: list[dict]) -> None:
        per = 1 if self.shared else self.num_envs
        for j, state in enumerate(states):
            self.draws.set_state(member * per + j, state)
