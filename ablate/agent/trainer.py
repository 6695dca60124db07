"""The one trainer: REINFORCE for M members (seeds, tuning candidates) of one variant in one process, any network,
any env with discrete actions; a single trial is a population of one.

One loop: every member acts in one batched forward (``acting``), every slot steps (``slots``), and a member whose
episodes are in takes its own update at once (``reinforce.train_step`` on its own module and Adam), no member
waiting for another. Each member draws its initial weights, dropout, actions and env resets from its own streams,
so its run never depends on who shares its process: on a CPU, with a built-in network, a member is its population
of one bit for bit. No Ray and no MLflow here.
"""

from __future__ import annotations

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

from ablate.agent.acting import stack
from ablate.agent.artifacts import TrainingVideos, write_artifacts
from ablate.agent.checkpoints import checkpoint, restore
from ablate.agent.envs import Described, describe, is_native_vector, is_pong, make_trial_env
from ablate.agent.models import build_model, history
from ablate.agent.optim import Adam
from ablate.agent.records import Batch, EpisodeMetrics, TrialFailed, TrialResult
from ablate.agent.reinforce import choose_action, discount_rewards, normalize, train_step
from ablate.agent.sharing import can_share, population_group
from ablate.agent.slots import CartPoleSlots, EnvSlots, Episode
from ablate.config import TrialConfig

MemberOutcome = TrialResult | TrialFailed
"""What a member ends with: its result, or the error that stopped it alone."""

UNIFORM_BLOCK = 64
"""Steps of action uniforms drawn from each member's stream at a time."""

IMAGE_TRAIN_CHUNK = 1024
"""Observations per forward/backward in an update on images (Pong): bounds its activations (~130 MB for the CNN)."""


@dataclass
class Member:
    """One member's learner and its place in the loop."""

    index: int
    """Position in ``run_population``'s ``configs``."""
    config: TrialConfig
    threshold: float | None
    started: float
    model: torch.nn.Module
    optimizer: Adam
    actions_rng: np.random.Generator
    torch_rng: torch.Tensor
    """Its torch RNG state (after its initial weights): its dropout draws."""
    history: list[EpisodeMetrics] = field(default_factory=list)
    window: deque = field(default_factory=deque)
    env_steps: int = 0
    updates: int = 0
    episodes_to_solve: int | None = None
    next_checkpoint: int | None = None
    counting: np.ndarray | None = None
    """Its slots whose episodes go into its next update (from a reset), or that still play (continuous)."""
    episodes: dict[int, int] = field(default_factory=dict)
    """Lengths of the collection's ended episodes, by slot (from a reset): the slots hold them until ``batch``."""
    finished: deque = field(default_factory=deque)
    """Finished episodes in the order they ended (continuous)."""
    completed: int = 0
    videos: TrainingVideos | None = None
    block_origin: dict | None = None
    """Its action stream's state before the population's current block of uniforms was drawn."""

    @property
    def done(self) -> bool:
        return len(self.history) >= self.config.max_episodes or self.episodes_to_solve is not None

    @property
    def wanted(self) -> int:
        return min(self.config.episodes_per_update, self.config.max_episodes - len(self.history))


def solve_threshold(config: TrialConfig) -> float | None:
    """The rolling mean over ``solve_window`` episodes at which a trial counts as solved and stops: its own
    ``solve_threshold``, else its env's ``reward_threshold`` (``None``: Pong has none)."""
    if config.solve_threshold is not None:
        return config.solve_threshold
    return describe(config).reward_threshold


def _inject_fault(config: TrialConfig) -> None:
    """Test-only faults (``TrialConfig.fault``), to prove the scheduler's retry and failure handling."""
    if config.fault == "crash_once" and config.fault_marker and not Path(config.fault_marker).exists():
        Path(config.fault_marker).write_text("crashed once\n")
        os._exit(17)  # a hard process death, as an OOM kill or a segfault would be
    if config.fault == "block":
        while not Path(config.fault_marker).exists():  # certainly still running when a test interrupts the launch
            time.sleep(0.05)


class Population:
    """The members, their slots and their batched acting: ``run_population``'s state."""

    def __init__(self, configs: Sequence[TrialConfig], device: torch.device, folders: Sequence[Path | None]) -> None:
        first = configs[0]
        self.env: Described = describe(first)
        self.continuous = first.num_envs > 0
        """Slots play on into the next update (``num_envs`` set: Pong's emulators never idle); else each update's
        episodes start together from a reset, one per slot, so every one is sampled from the current policy."""
        self.per_member = first.num_envs or first.episodes_per_update
        self.history = history(first)
        self.device = device
        started = time.perf_counter()
        self.members = []
        for i, config in enumerate(configs):
            torch.manual_seed(config.seed)  # initial weights, then dropout's stream
            model = build_model(config, self.env).to(device)
            fps, folder = self.env.video_fps, folders[i]
            self.members.append(
                Member(
                    i,
                    config,
                    solve_threshold(config),
                    started,
                    model,
                    Adam(model.parameters(), lr=config.learning_rate),
                    np.random.default_rng(config.seed),
                    torch.get_rng_state(),
                    window=deque(maxlen=config.solve_window),
                    videos=TrainingVideos(folder, config.video_every, config.video_max_frames, fps),
                )
            )
        seeds = [c.seed for c in configs]
        if is_native_vector(first) and not self.continuous:
            self.slots = CartPoleSlots(seeds, self.per_member, self.env.max_episode_steps, self.history)
        else:

            def make(m: int, j: int):  # a member's first env renders where it records training videos
                return make_trial_env(
                    configs[m], render=j == 0 and configs[m].video_every > 0 and folders[m] is not None
                )

            self.slots = EnvSlots(seeds, self.per_member, make, self.history)
            self.slots.on_frame = self._frame
        self.acting = stack([m.model for m in self.members], device, built_in=not first.model.factory)
        self.chunk = IMAGE_TRAIN_CHUNK if len(self.env.observation_shape) == 3 else None
        self.stepping = np.zeros(len(self.members) * self.per_member, bool)
        """Every member's counting slots, as one mask (what ``step`` steps)."""
        self.block: np.ndarray | None = None
        self.block_used = 0
        self.leaving = True
        """Some member may have ended (solved, out of budget, failed) since ``_finish`` last looked."""

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
        if j != 0 or member.videos is None or not member.videos.every:
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
        actions = choose_action(self.acting, observations, single=False, uniforms=uniforms).reshape(-1)
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
        observations = taken.observations
        if config.model.factory:  # a user's network takes float32 (the built-ins read int8 frames as they are)
            observations = observations.astype(np.float32, copy=False)
        rewards = taken.rewards.astype(np.float64)
        returns = discount_rewards(rewards, config.gamma, config.reset_on_score, lengths=lengths)
        return Batch(
            lengths,
            np.add.reduceat(rewards, np.cumsum(lengths) - lengths),
            observations,
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

    def update(self, position: int, batch: Batch):
        """The member's own Adam step on its own module, its dropout from its own stream."""
        member = self.members[position]
        torch.set_rng_state(member.torch_rng)
        stats = train_step(
            member.model,
            member.optimizer,
            batch.observations,
            batch.actions,
            batch.weights,
            l2=member.config.l2,
            chunk_size=self.chunk,
        )
        member.torch_rng = torch.get_rng_state()
        self.acting.refresh(position)
        return stats

    def keep(self, positions: list[int]) -> None:
        """Only the members at ``positions`` go on (the others left)."""
        self.members = [self.members[p] for p in positions]
        if self.block is not None:
            self.block = self.block[positions]
        self.slots.keep(positions)
        self.acting.keep(positions)
        self.stepping = self.stepping.reshape(-1, self.per_member)[positions].reshape(-1)
        for new, member in enumerate(self.members):
            mine = self.slots_of(new)
            old = member.counting % self.per_member
            member.counting = mine[old]
            member.episodes = {int(mine[s % self.per_member]): e for s, e in member.episodes.items()}

    def close(self) -> None:
        for member in self.members:
            if member.videos is not None:
                member.videos.close()
        self.slots.close()


def _record(member: Member, batch: Batch, loss: float, entropy: float, wall_s: float) -> list[EpisodeMetrics]:
    """The update's episodes as metrics rows, with the rolling mean and the solve rule."""
    config = member.config
    new: list[EpisodeMetrics] = []
    for length, episode_return in zip(batch.lengths, batch.episode_returns, strict=True):
        member.env_steps += int(length)
        member.window.append(float(episode_return))
        # Exactly rounded, so np.mean's value for the integer returns of CartPole and Pong, at a tenth of its cost.
        rolling = math.fsum(member.window) / len(member.window)
        episode = len(member.history) + len(new) + 1
        new.append(
            EpisodeMetrics(
                episode, float(episode_return), int(length), loss, entropy, rolling, member.env_steps, wall_s,
                member.updates,
            )
        )  # fmt: skip
        full = len(member.window) == config.solve_window
        if member.episodes_to_solve is None and member.threshold is not None and full and rolling >= member.threshold:
            member.episodes_to_solve = episode
    member.history.extend(new)
    return new


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
    """Train ``configs`` (``sharing.can_share``) together; member i behaves as ``run_trial(configs[i], ...)``.

    ``on_episodes(i, rows)``: member i's new episodes after each update (a resumed member's saved history first,
    in one call). ``artifacts_dirs[i]``: member i's folder. Every ``checkpoint_interval`` episodes,
    ``on_checkpoint(i, blob)`` gets member i's whole state, which ``resume_from[i]`` restores (the resumed run is
    the unbroken one). ``on_outcome(i, outcome)`` as each member ends. ``device``: where the networks act and
    learn (``None``: CUDA whenever torch sees a device, else the CPU). Returns every member's outcome, in order."""
    if not can_share(configs):
        raise ValueError(
            "these configs cannot share a population: " + ", ".join(map(str, map(population_group, configs)))
        )
    for config in configs:
        _inject_fault(config)
    torch.set_num_threads(1)  # small networks: threads cost more than they give, and trials run side by side
    threadpool_limits(1, user_api="blas")  # the same for numpy's acting (OpenBLAS would spin 2 threads)
    if is_pong(configs[0].env_id):
        _limit_fragmentation()
    torch_device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    folders = [Path(d) if d is not None else None for d in (artifacts_dirs or [None] * len(configs))]
    population = Population(configs, torch_device, folders)
    for position, blob in enumerate(resume_from or [None] * len(configs)):
        member = population.members[position]
        if blob is not None:
            restore(population, position, blob)
            if on_episodes is not None and member.history:
                on_episodes(member.index, list(member.history))
        every = member.config.checkpoint_interval if on_checkpoint is not None else 0
        member.next_checkpoint = (len(member.history) // every + 1) * every if every else None
    outcomes: dict[int, MemberOutcome] = {}
    try:
        for position, member in enumerate(population.members):
            if not member.done and member.counting is None:
                population.start(position)
        while True:
            if population.leaving:
                _finish(population, outcomes, folders, on_outcome)
                population.leaving = False
            if not population.members:
                break
            for position in population.step():
                _learn(population, position, outcomes, on_episodes, on_checkpoint, on_outcome)
    finally:
        population.close()
    return [outcomes[i] for i in range(len(configs))]


def _learn(population: Population, position: int, outcomes: dict, on_episodes, on_checkpoint, on_outcome) -> None:
    """Member ``position``'s updates while its episodes are in (continuous: several may be), then its next
    collection."""
    member = population.members[position]
    while population.has_batch(member):
        batch = population.batch(member)
        stats = population.update(position, batch)
        failure = None
        if not math.isfinite(stats.loss):
            failure = TrialFailed(
                f"loss became {stats.loss} at episode {len(member.history) + len(batch.lengths)}; "
                f"try a smaller learning_rate (now {member.config.learning_rate})"
            )
        elif member.config.fault == "raise":
            failure = TrialFailed("injected fault: raise after the first update (tests only)")
        if failure is not None:
            outcomes[member.index] = failure
            if on_outcome is not None:
                on_outcome(member.index, failure)
            population.set_counting(position, member.counting[:0])
            population.leaving = True
            return
        member.updates += 1
        new = _record(member, batch, stats.loss, stats.entropy, time.perf_counter() - member.started)
        if on_episodes is not None:
            on_episodes(member.index, new)
        _maybe_checkpoint(population, position, on_checkpoint)
    if member.done:
        population.leaving = True
    elif not population.continuous:
        population.start(position)


def _maybe_checkpoint(population: Population, position: int, on_checkpoint) -> None:
    member = population.members[position]
    config, done = member.config, len(member.history)
    if member.next_checkpoint is None or done < member.next_checkpoint or done >= config.max_episodes:
        return
    on_checkpoint(member.index, checkpoint(population, position))
    every = config.checkpoint_interval
    member.next_checkpoint = (done // every + 1) * every
    if config.fault == "crash_after_checkpoint" and not Path(config.fault_marker).exists():
        Path(config.fault_marker).write_text("crashed after a checkpoint\n")
        os._exit(17)  # the process dies with a checkpoint taken: its retry must resume from it


def _finish(population: Population, outcomes: dict, folders, on_outcome) -> None:
    """Members that solved, spent their budget or failed leave: result, artifacts, ``on_outcome``."""
    staying = []
    for position, member in enumerate(population.members):
        if member.index not in outcomes and not member.done:
            staying.append(position)
            continue
        if member.index in outcomes:
            continue
        model = member.model
        result = TrialResult(
            config=member.config,
            episodes=member.history,
            episodes_to_solve=member.episodes_to_solve,
            solve_threshold=member.threshold,
            env_steps=member.env_steps,
            wall_s=time.perf_counter() - member.started,
            parameter_count=sum(p.numel() for p in model.parameters()),
            state_dict={k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        )
        folder = folders[member.index]
        if member.videos is not None:
            member.videos.close()  # the trial is over: its last video ends here
            result.artifacts.update({f"videos/{p.name}": p for p in member.videos.paths if p.exists()})
        if folder is not None:
            write_artifacts(result, model, population.history, folder)
        outcomes[member.index] = result
        if on_outcome is not None:
            on_outcome(member.index, result)
    if not staying:
        population.members = []
    elif len(staying) < len(population.members):
        population.keep(staying)


def run_trial(
    config: TrialConfig,
    on_episodes: Callable[[list[EpisodeMetrics]], None] | None = None,
    artifacts_dir: str | Path | None = None,
    *,
    resume_from: bytes | None = None,
    on_checkpoint: Callable[[bytes], None] | None = None,
) -> TrialResult:
    """Train one REINFORCE agent as ``config`` says: a population of one. ``on_episodes`` receives each update's
    new episodes; with ``artifacts_dir``, the trial writes ``episodes.csv``, ``weights.pt``,
    ``learning_curve.png`` and (``record_video``) ``video.mp4``. ``on_checkpoint`` receives the whole state every
    ``checkpoint_interval`` episodes; ``resume_from`` = such a blob goes on from it. Raises ``TrialFailed``."""
    [outcome] = run_population(
        [config],
        on_episodes=(lambda _, rows: on_episodes(rows)) if on_episodes is not None else None,
        artifacts_dirs=[artifacts_dir],
        resume_from=[resume_from],
        on_checkpoint=(lambda _, blob: on_checkpoint(blob)) if on_checkpoint is not None else None,
    )
    if isinstance(outcome, TrialFailed):
        raise outcome
    return outcome


def _limit_fragmentation() -> None:
    """Fix glibc's mmap threshold at 256 KB. By default it rises (to 32 MB) each time a large block is freed,
    after which a Pong trial's per-update arrays (MBs each) come from the heap and fragment it: RSS grew
    515 MB -> 4.1 GB over 500 episodes. Mapped blocks go back to the system when freed. No-op off glibc."""
    import contextlib
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").mallopt(-3, 256 * 1024)  # M_MMAP_THRESHOLD; setting it turns the dynamic one off
