"""A population's state: its members (each a learner with its own streams), their networks stacked as one
(``stacking.Members``) with each member's Adam, their env slots; what ``trainer``'s loop steps, updates and lets
leave, and a member's checkpoint of it. No Ray and no MLflow here.
"""

from __future__ import annotations

import io
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ablate.agent.policies import build_model, history
from ablate.agent.records import Batch, EpisodeMetrics
from ablate.agent.reinforce import choose_action, discount_rewards, normalize, train_step
from ablate.agent.slots import CartPoleSlots, EnvSlots, Episode
from ablate.agent.stacking import Adam, Members, dropout_seed
from ablate.config import TrialConfig
from ablate.env_spec import solve_threshold
from ablate.envs import Described, make_trial_env
from ablate.videos import TrainingVideos

UNIFORM_BLOCK = 64
"""Steps of action uniforms drawn from each member's stream at a time."""

PACK_SHARE = 0.25
"""Members that left keep their rows (slots, parameters, action stream; stepped and acted for nothing) until they
hold this share of the population's rows; then the rows of the members still training are packed into new arrays.
Packing at every departure copied every slot's ring of steps each time (a departure O(members), a run
O(members^2): with 256 episodes each, 256 members ran at 0.47x the env steps/s of 16 and 1,024 at 0.22x); at a
fixed share each row is copied O(1) times over a run, and the idle rows cost at most this share of a step."""

IMAGE_TRAIN_CHUNK = 256
"""Observations per forward/backward in an update on images (Pong): bounds its activations (~33 MB for the CNN)
and keeps them in cache (the CNN's forward and backward, one core: 90 ms a 1,024 frames at 256, 106 at 1,024)."""


@dataclass
class Member:
    """One member's learner and its place in the loop."""

    index: int
    """Position in ``run_population``'s ``configs``."""
    config: TrialConfig
    threshold: float | None
    started: float
    actions_rng: np.random.Generator
    videos: TrainingVideos
    history: list[EpisodeMetrics] = field(default_factory=list)
    window: deque = field(default_factory=deque)
    env_steps: int = 0
    updates: int = 0
    episodes_to_solve: int | None = None
    counting: np.ndarray | None = None
    """Its slots whose episodes go into its next update (from a reset), or that still play (continuous)."""
    episodes: dict[int, int] = field(default_factory=dict)
    """Lengths of the collection's ended episodes, by slot (from a reset): the slots hold them until ``batch``."""
    finished: deque = field(default_factory=deque)
    """Finished episodes in the order they ended (continuous)."""
    completed: int = 0
    block_origin: dict | None = None
    """Its action stream's state before the population's current block of uniforms was drawn."""

    @property
    def done(self) -> bool:
        return len(self.history) >= self.config.max_episodes or self.episodes_to_solve is not None

    @property
    def wanted(self) -> int:
        return min(self.config.episodes_per_update, self.config.max_episodes - len(self.history))


class Population:
    """The members, their slots and their batched acting: ``run_population``'s state."""

    def __init__(
        self, configs: Sequence[TrialConfig], env: Described, device: torch.device, folders: Sequence[Path | None]
    ) -> None:
        first = configs[0]
        self.env = env
        self.continuous = first.num_envs > 0
        """Slots play on into the next update (``num_envs`` set: Pong's emulators never idle); else each update's
        episodes start together from a reset, one per slot, so every one is sampled from the current policy."""
        self.per_member = first.num_envs or first.episodes_per_update
        self.history = history(first.model, env)
        self.device = device
        started = time.perf_counter()
        self.members = []
        models = []
        for i, config in enumerate(configs):
            torch.manual_seed(config.seed)  # each member's initial weights from its own seed
            models.append(build_model(config, self.env))
            videos = TrainingVideos(folders[i], config.video_every, config.video_max_frames, env.video_fps)
            rng = np.random.default_rng(config.seed)
            window = deque(maxlen=config.solve_window)
            self.members.append(Member(i, config, solve_threshold(config), started, rng, videos, window=window))
        self.network = Members(models, device, [dropout_seed(c.seed) for c in configs])
        shape = (self.history, *self.env.observation_shape) if self.history else self.env.observation_shape
        self.network.check(models, shape)
        self.optimizer = Adam(self.network.flat, lr=[c.learning_rate for c in configs])
        self.l2 = np.array([c.l2 for c in configs], np.float32)
        seeds = [c.seed for c in configs]
        if env.native_vector and not self.continuous:
            self.slots = CartPoleSlots(seeds, self.per_member, env.max_episode_steps, self.history, env_id=env.env_id)
        else:  # a member's first env renders where it records training videos
            envs = [
                make_trial_env(c, render=j == 0 and c.video_every > 0 and folder is not None)
                for c, folder in zip(configs, folders, strict=True)
                for j in range(self.per_member)
            ]
            self.slots = EnvSlots(seeds, self.per_member, envs, self.history)
            self.slots.on_frame = self._frame
        self.chunk = IMAGE_TRAIN_CHUNK if len(self.env.observation_shape) == 3 else None
        self.stepping = np.zeros(len(self.members) * self.per_member, bool)
        """Every member's counting slots, as one mask (what ``step`` steps)."""
        self.block: np.ndarray | None = None
        self.block_used = 0
        self.leaving: set[int] = set(range(len(self.members)))
        """Positions of the members that may have ended (solved, out of budget, failed) since ``_finish`` looked."""
        self.left: set[int] = set()
        """Positions of the members that left but still hold their rows (``leave``)."""

    @property
    def training(self) -> int:
        """How many members are still training."""
        return len(self.members) - len(self.left)

    def slots_of(self, position: int) -> np.ndarray:
        return position * self.per_member + np.arange(self.per_member)

    def start(self, position: int) -> None:
        """Member ``position`` begins its next collection (from a reset; continuous: its slots begin playing)."""
        member, slots = self.members[position], self.slots_of(position)
        self.slots.start(slots)
        # Continuous: every slot plays from the start, a budget smaller than the slots included (its rest rule, in
        # _ended, stops the slots that would play for nothing as their episodes end).
        count = member.wanted if not self.continuous else self.per_member
        self.set_counting(position, slots[:count])
        member.episodes = {}

    def set_counting(self, position: int, slots: np.ndarray) -> None:
        """Member ``position``'s counting slots become ``slots`` (its others rest)."""
        self.members[position].counting = slots
        self.stepping[self.slots_of(position)] = False
        self.stepping[slots] = True

    def _frame(self, slot: int, over: bool) -> None:
        """A slot stepped or reset: the member's first slot feeds its training videos."""
        position, j = divmod(slot, self.per_member)
        member = self.members[position]
        if j != 0 or not member.videos.every:
            return
        frame = self.slots.envs[slot].render
        if len(self.slots.memories[slot]) == 0 and not over:
            member.videos.episode_started(member.completed, frame)
        else:
            member.videos.frame(frame, over)

    def step(self) -> list[int]:
        """One step of every member; the positions of the members whose next batch is complete."""
        m, n = len(self.members), self.per_member
        observations = self.slots.observations()
        observations = observations.reshape(m, n, *observations.shape[1:])
        uniforms = self._uniforms()
        actions = choose_action(self.network, observations, single=False, uniforms=uniforms).reshape(-1)
        _, ended = self.slots.step(actions, self.stepping)
        over = np.flatnonzero(ended & self.stepping)  # counting slots whose episode ended (most steps: none or a few)
        self.stepping[over] = False
        ready = []
        for position in np.unique(over // n).tolist() if len(over) else ():
            member = self.members[position]
            counting = member.counting
            if not self.continuous:
                member.counting = counting[~ended[counting]]
            for slot in counting[ended[counting]].tolist():  # in slot order, as if each env stepped in turn
                self._ended(position, member, slot)
            if self.has_batch(member):
                ready.append(position)
        return ready

    def _uniforms(self) -> np.ndarray:
        """(M, N): each member's next N uniforms from its own stream, drawn ``UNIFORM_BLOCK`` steps at a time (the
        same doubles one draw a step would give: every member takes N at every step). Continuous: one per playing
        slot, in slot order (a resting emulator draws none, as in a loop over the emulators that still play)."""
        if self.continuous:
            uniforms = np.zeros((len(self.members), self.per_member))
            for position, member in enumerate(self.members):
                playing = member.counting - position * self.per_member
                uniforms[position, playing] = member.actions_rng.random(len(playing))
            return uniforms
        if self.block is None or self.block_used == UNIFORM_BLOCK:
            for member in self.members:
                member.block_origin = member.actions_rng.bit_generator.state
            self.block = np.stack([m.actions_rng.random((UNIFORM_BLOCK, self.per_member)) for m in self.members])
            self.block_used = 0
        self.block_used += 1
        return self.block[:, self.block_used - 1]

    def actions_state(self, position: int) -> dict:
        """Member ``position``'s action stream as if only the uniforms used so far had been drawn (a checkpoint's)."""
        member = self.members[position]
        if self.block is None:
            return member.actions_rng.bit_generator.state
        stream = np.random.PCG64()
        stream.state = member.block_origin
        stream.advance(self.block_used * self.per_member)  # one 64-bit draw per double
        return stream.state

    def _ended(self, position: int, member: Member, slot: int) -> None:
        member.completed += 1
        if not self.continuous:
            member.episodes[slot] = self.slots.steps(slot)
            return
        member.finished.append(self.slots.episode(slot))
        member.counting = member.counting[member.counting != slot]  # the slots that ended after it still count
        budget = member.config.max_episodes - len(member.history)
        if len(member.finished) + len(member.counting) >= budget:
            return  # enough episodes finished or under way for the budget: this slot rests
        self.slots.start(np.array([slot]))
        member.counting = np.sort(np.append(member.counting, slot))
        self.stepping[slot] = True

    def batch(self, member: Member) -> Batch:
        """The member's episodes of this update: returns discounted within each episode, normalised across all."""
        if self.continuous:
            episodes = [member.finished.popleft() for _ in range(member.wanted)]
            lengths = np.array([len(e.actions) for e in episodes], np.int64)
            taken = Episode(*(np.concatenate(parts) for parts in zip(*episodes, strict=True)))
        else:
            slots = np.array(sorted(member.episodes), np.int64)
            lengths = np.array([member.episodes[s] for s in slots.tolist()], np.int64)
            taken = self.slots.take(slots, lengths)
            member.episodes = {}
        config = member.config
        rewards = taken.rewards.astype(np.float64)
        returns = discount_rewards(rewards, config.gamma, self.env.profile.resets_on_score, lengths=lengths)
        return Batch(
            lengths,
            np.add.reduceat(rewards, np.cumsum(lengths) - lengths),
            taken.observations,
            taken.actions,
            normalize(returns),
        )

    def has_batch(self, member: Member) -> bool:
        """Whether the member's next update's episodes are all in."""
        if member.done:
            return False
        if self.continuous:
            return len(member.finished) >= member.wanted
        return bool(member.episodes) and not len(member.counting)

    def update_groups(self, positions: list[int]) -> list[list[int]]:
        """Which of the members ready at one step update together. On a GPU, all of them in one batched pass
        (kernel launches dominate there). On a CPU, each in its own pass: a member's gradient then never depends on
        who else is ready (a batched pass pads each member to the longest batch, which moves float rounding), so
        a member is bit for bit its population of one and a resumed run is its unbroken one; members rarely end
        their collections on one step (CartPole: 247 passes for 256 updates), so batching gains little there."""
        return [positions] if self.device.type == "cuda" else [[p] for p in positions]

    def update(self, batches: dict[int, Batch]) -> dict[int, tuple[float, float]]:
        """Each member at ``batches``' positions takes its own step (``reinforce.train_step``): (loss, entropy)."""
        positions = sorted(batches)
        lengths = np.array([len(batches[p].actions) for p in positions], np.int64)
        steps = int(lengths.max())
        first = batches[positions[0]]
        if len(positions) == 1:  # one member (a CPU's update): its batch as it is, nothing to pad
            observations, actions, weights = first.observations[None], first.actions[None], first.weights[None]
        else:
            observations = np.zeros((len(positions), steps, *first.observations.shape[1:]), first.observations.dtype)
            actions = np.zeros((len(positions), steps), np.int64)
            weights = np.zeros((len(positions), steps), np.float32)
            for row, position in enumerate(positions):
                batch, n = batches[position], lengths[row]
                observations[row, :n], actions[row, :n], weights[row, :n] = (
                    batch.observations,
                    batch.actions,
                    batch.weights,
                )
        serving = torch.tensor(positions, device=self.device)
        stats = train_step(
            self.network,
            self.optimizer,
            observations,
            actions,
            weights,
            l2=self.l2[positions],
            chunk_size=self.chunk,
            lengths=lengths,
            serving=serving,
        )
        return {p: (float(stats.loss[row]), float(stats.entropy[row])) for row, p in enumerate(positions)}

    def leave(self, positions: list[int]) -> None:
        """The members at ``positions`` leave (their outcomes are taken). Their slots rest and their parameters become
        zeros (a NaN member's acting stays finite), in their rows until those who left hold ``PACK_SHARE`` of the
        rows; then only the members still training go on, packed (positions change)."""
        for position in positions:
            self.set_counting(position, self.slots_of(position)[:0])
            self.members[position].episodes = {}
        with torch.no_grad():
            self.network.flat[positions] = 0
        self.left.update(positions)
        if self.training and len(self.left) >= PACK_SHARE * len(self.members):
            self._pack([p for p in range(len(self.members)) if p not in self.left])

    def _pack(self, positions: list[int]) -> None:
        """Only the members at ``positions`` go on (the others left)."""
        self.members = [self.members[p] for p in positions]
        self.left = set()
        if self.block is not None:
            self.block = self.block[positions]
        self.slots.keep(positions)
        self.network.keep(positions)
        self.optimizer.keep(positions, self.network.flat)
        self.l2 = self.l2[positions]
        self.stepping = self.stepping.reshape(-1, self.per_member)[positions].reshape(-1)
        for new, member in enumerate(self.members):
            mine = self.slots_of(new)
            old = member.counting % self.per_member
            member.counting = mine[old]
            member.episodes = {int(mine[s % self.per_member]): e for s, e in member.episodes.items()}

    def close(self) -> None:
        for member in self.members:
            member.videos.close()
        self.slots.close()


# --- a member's checkpoint: everything its run depends on, so a resumed member is its unbroken run ---
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
            "dropout_rng": population.network.stack.generators[position].get_state(),
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
    population.network.stack.generators[position].set_state(saved["dropout_rng"])
    member.actions_rng.bit_generator.state = saved["numpy_rng"]
    population.slots.set_member_state(position, saved["slots"])
    member.started -= saved["wall_s"]
    if member.videos.every:
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
