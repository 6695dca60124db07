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
    sequence its ``Generator.random()`` calls would (one 64-bit draw per double, in order), or with ``scale =
    (low, high)`` its ``Generator.uniform(low, high)`` calls (``low + (high - low) * random()``, as numpy
    computes it); ``states`` gives each stream's state as if only the values taken so far had been drawn."""

    def __init__(
        self, generators: Sequence[np.random.Generator], capacity: int, scale: tuple[float, float] | None = None
    ) -> None:
        self.generators = list(generators)
        self.origins = [g.bit_generator.state for g in self.generators]
        self.taken = np.zeros(len(self.generators), np.int64)
        """Doubles taken from each stream since its origin state."""
        self.capacity = capacity
        self.scale = scale
        self.buffer = (
            np.stack([self._draw(g, capacity) for g in self.generators]) if self.generators else np.zeros((0, 0))
        )
        self.pos = np.zeros(len(self.generators), np.int64)
        self.end = np.full(len(self.generators), capacity, np.int64)
        """Row s holds stream s's next values at ``buffer[s, pos[s]:end[s]]``."""

    def _draw(self, generator: np.random.Generator, count: int) -> np.ndarray:
        values = generator.random(count)
        if self.scale is not None:
            low, high = self.scale
            values = low + (high - low) * values
        return values

    def ensure(self, need: np.ndarray | int) -> None:
        """Room for ``need`` (or ``need[s]``) more doubles of each stream ``s`` (refills the few that run short)."""
        need = np.broadcast_to(need, self.pos.shape)
        if len(need) and int(need.max()) > self.capacity:  # one block of draws longer than a row: widen all
            grown = 2 * int(need.max())
            self.buffer = np.pad(self.buffer, ((0, 0), (0, grown - self.capacity)))
            self.capacity = grown
        for s in np.flatnonzero(self.pos + need > self.end):
            rest = self.buffer[s, self.pos[s] : self.end[s]].copy()
            self.buffer[s, : len(rest)] = rest
            self.buffer[s, len(rest) :] = self._draw(self.generators[s], self.capacity - len(rest))
            self.pos[s], self.end[s] = 0, self.capacity

    def peek(self, count: int) -> np.ndarray:
        """(streams, count): every stream's next ``count`` doubles, not taken yet."""
        self.ensure(count)
        return self.buffer[np.arange(len(self.generators))[:, None], self.pos[:, None] + np.arange(count)]

    def take(self, counts: np.ndarray | int) -> None:
        """Streams ``s`` move on by ``counts[s]`` doubles (read at ``buffer[s, pos[s] + j]``, j < counts[s])."""
        self.pos += counts
        self.taken += counts

    def state(self, row: int) -> dict:
        """Stream ``row``'s state, as if only the values taken so far had been drawn from it."""
        bit_generator = np.random.PCG64()
        bit_generator.state = self.origins[row]
        bit_generator.advance(int(self.taken[row]))
        return bit_generator.state

    def states(self) -> list[dict]:
        return [self.state(row) for row in range(len(self.generators))]

    def set_state(self, row: int, state: dict) -> None:
        """Stream ``row`` goes on from ``state`` (a checkpoint's)."""
        generator = generator_at(state)
        self.generators[row], self.origins[row], self.taken[row] = generator, state, 0
        self.buffer[row] = self._draw(generator, self.capacity)
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


_ROOM_STEPS = 64
"""Steps (and resets) between two checks that every env stream holds the draws a step may take."""

_FEW_RESETS = 8
"""Up to this many envs to reset at one step, ``CartPoleBatch._redraw`` works in Python integers."""


class CartPoleBatch:
    """``len(seeds)`` members' ``num_envs`` CartPole envs each. From 3 envs up, a member's envs share one stream
    seeded ``seed`` (``CartPoleVectorEnv``); below, env j has its own, seeded ``seed + j`` (``SyncVectorEnv``).
    Autoreset is Gymnasium's next-step mode: the step after an episode ends resets that env (reward 0).
    Every member steps at every ``step``; ``reset(members)`` starts some members' envs afresh at any time (a
    member's next collection), as its own ``VectorEnv.reset()`` would."""

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
        streams = (
            [np.random.default_rng(s) for s in seeds]
            if self.shared
            else [np.random.default_rng(s + j) for s in seeds for j in range(num_envs)]
        )
        self.draws = StreamDraws(streams, 128 * num_envs, scale=(self.low, self.high))
        # A step or a reset takes at most 4 doubles per env from its stream: room for _ROOM_STEPS of them.
        self._room_need = 4 * (num_envs if self.shared else 1) * _ROOM_STEPS
        self._room = 0
        self._limits = np.array([self.x_threshold, self.theta_threshold_radians])[:, None, None]
        self._allocate(m)

    def _allocate(self, m: int, state: np.ndarray | None = None) -> None:
        """State and preallocated work arrays for ``m`` members (``state``: theirs, else zeros)."""
        shape = (m, self.num_envs)
        self.state = np.zeros((4, *shape)) if state is None else state
        self.steps = np.zeros(shape, np.int32) if state is None else self.steps
        self.prev_done = np.zeros(shape, bool) if state is None else self.prev_done
        self._resetting = bool(self.prev_done.any())
        self._done = np.zeros(shape, bool)
        self._flag = np.zeros(shape, bool)
        self._pair = np.zeros((2, *shape))
        self._acc = np.zeros((2, *shape))
        self._over = np.zeros((2, *shape), bool)
        self._work = [np.zeros(shape) for _ in range(4)]

    @property
    def members(self) -> int:
        return self.state.shape[1]

    def observations(self, out: np.ndarray | None = None) -> np.ndarray:
        """Every env's observation, (M, N, 4) float32 (into ``out`` if given)."""
        if out is None:
            return self.state.transpose(1, 2, 0).astype(np.float32)
        np.copyto(out, self.state.transpose(1, 2, 0), casting="same_kind")
        return out

    def reset(self, members: np.ndarray | None = None) -> np.ndarray:
        """The envs of ``members`` (indices; default all) from a reset, as their ``VectorEnv.reset()``: returns
        every member's observations (M, N, 4) float32."""
        mask = np.zeros((self.members, self.num_envs), bool)
        mask[slice(None) if members is None else members] = True
        self._redraw(mask)
        self.steps[mask] = 0
        self.prev_done[mask] = False
        self._resetting = bool(self.prev_done.any())
        return self.observations()

    def step(self, actions: np.ndarray, observations: np.ndarray | None = None) -> np.ndarray:
        """One step of every env (``CartPoleVectorEnv.step``), ``actions`` (M, N) of 0 and 1 (or bools). Returns
        whether each env's episode ended at this step (terminated or truncated; an env that autoresets at this
        step gets reward 0 and never ends at it); the observations go to ``observations`` (M, N, 4) float32 if
        given, else ``observations()`` reads them. The returned array is reused by the next step."""
        s = self.state
        theta, theta_dot = s[2], s[3]
        cos, sin, temp, work = self._work
        np.cos(theta, out=cos)
        np.sin(theta, out=sin)
        # The same operations, in the same order, as CartPoleVectorEnv.step (rounding included); in place.
        force = np.where(actions, self.force_mag, -self.force_mag)  # np.sign(actions - 0.5) * force_mag
        np.square(theta_dot, out=temp)
        temp *= self.polemass_length
        temp *= sin
        np.add(force, temp, out=temp)
        temp /= self.total_mass
        thetaacc, xacc = self._acc[1], self._acc[0]
        np.multiply(self.gravity, sin, out=thetaacc)
        np.multiply(cos, temp, out=work)
        thetaacc -= work
        np.square(cos, out=work)
        work *= self.masspole
        work /= self.total_mass
        np.subtract(4.0 / 3.0, work, out=work)
        work *= self.length
        thetaacc /= work
        np.multiply(self.polemass_length, thetaacc, out=xacc)
        xacc *= cos
        xacc /= self.total_mass
        np.subtract(temp, xacc, out=xacc)
        # Euler: x += tau * x_dot and theta += tau * theta_dot, then the velocities by tau * acceleration.
        np.multiply(self.tau, s[1::2], out=self._pair)
        s[0::2] += self._pair
        self._acc *= self.tau
        s[1::2] += self._acc
        # x < -t | x > t is |x| > t (negation is exact), for x and theta at once.
        np.abs(s[0::2], out=self._pair)
        np.greater(self._pair, self._limits, out=self._over)
        done = np.logical_or(self._over[0], self._over[1], out=self._done)
        self.steps += 1
        np.greater_equal(self.steps, self.max_episode_steps, out=self._flag)
        done |= self._flag
        if self._resetting:
            reset = self.prev_done
            self._redraw(reset)
            np.copyto(self.steps, 0, where=reset)
            np.greater(done, reset, out=done)  # done & ~reset: an env that resets now does not end now
        self._done, self.prev_done = self.prev_done, done
        self._resetting = bool(done.any())
        if observations is not None:
            np.copyto(observations, s.transpose(1, 2, 0), casting="same_kind")
        return done

    def _redraw(self, mask: np.ndarray) -> None:
        """The envs of ``mask`` (M, N) take a fresh start state: per stream, one ``uniform(size=(4, k))`` over its
        k envs to reset, in env order (vector), or ``uniform(size=(4,))`` per env (sync)."""
        self._room -= 1
        if self._room < 0:
            self.draws.ensure(self._room_need)
            self._room = _ROOM_STEPS - 1
        flat = np.flatnonzero(mask)
        if not len(flat):
            return
        draws = self.draws
        if self.shared and len(flat) <= _FEW_RESETS:
            flat_draws = self._few_shared_draws(flat.tolist())
        elif self.shared:
            members = flat // self.num_envs
            k = np.bincount(members, minlength=self.members)
            rank = np.arange(len(flat)) - (np.cumsum(k) - k)[members]
            # Component c of the r-th env to reset in a member's row is that stream's draw c * k + r.
            start = members * draws.capacity + draws.pos[members] + rank
            flat_draws = start + np.outer(np.arange(4), k[members])
            draws.take(4 * k)
        else:
            flat_draws = (flat * draws.capacity + draws.pos[flat]) + np.arange(4)[:, None]
            draws.pos[flat] += 4
            draws.taken[flat] += 4
        self.state.reshape(4, -1)[:, flat] = draws.buffer.reshape(-1)[flat_draws]

    def _few_shared_draws(self, flat: list[int]) -> list[list[int]]:
        """``_redraw``'s positions in the draws' buffer for a few envs (most steps reset one or two): Python
        integers, cheaper than a dozen array operations on arrays of one or two."""
        draws, n = self.draws, self.num_envs
        groups: dict[int, int] = {}
        for f in flat:
            groups[f // n] = groups.get(f // n, 0) + 1
        columns: list[tuple[int, int]] = []  # (position of the env's first component, its member's k)
        for member, k in groups.items():
            base = member * draws.capacity + int(draws.pos[member])
            columns += [(base + r, k) for r in range(k)]
            draws.pos[member] += 4 * k
            draws.taken[member] += 4 * k
        return [[first + c * k for first, k in columns] for c in range(4)]

    def keep(self, members: np.ndarray) -> None:
        """Only ``members`` (indices, in order) go on."""
        self.steps, self.prev_done = self.steps[members], self.prev_done[members]
        self._allocate(len(members), np.ascontiguousarray(self.state[:, members]))
        rows = members if self.shared else (members[:, None] * self.num_envs + np.arange(self.num_envs)).reshape(-1)
        self.draws.keep(rows)

    def stream_states(self, member: int) -> list[dict]:
        """Member ``member``'s env streams (1, or one per env), for a checkpoint."""
        per = 1 if self.shared else self.num_envs
        return [self.draws.state(row) for row in range(member * per, (member + 1) * per)]

    def set_stream_states(self, member: int, states: list[dict]) -> None:
        per = 1 if self.shared else self.num_envs
        for j, state in enumerate(states):
            self.draws.set_state(member * per + j, state)
