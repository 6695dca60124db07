"""The one trainer: REINFORCE for M members (seeds, tuning candidates) of one variant in one process, any network,
any env with discrete actions; a single trial is a population of one.

One loop over a ``population.Population``: every member acts in one batched forward of the members' stacked
parameters (``stacking.Members``, any network), every slot steps (``slots``), and the members whose episodes are
in take their own Adam steps at once (``reinforce.train_step`` on the stack), no member waiting for another. Each
member draws its initial weights, dropout, actions and env resets from its own streams, so its run never depends
on who shares its process: on a CPU a member is its population of one bit for bit (tests/test_trainer.py), on a
GPU to float rounding. No Ray and no MLflow here.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import torch
from threadpoolctl import threadpool_limits

from ablate.agent.population import Member, Population, checkpoint, restore
from ablate.agent.records import Batch, EpisodeMetrics, TrialFailed, TrialResult
from ablate.config import TrialConfig, can_share, population_group
from ablate.envs import describe, record
from ablate.measures import reaches_threshold

MemberOutcome = TrialResult | TrialFailed
"""What a member ends with: its result, or the error that stopped it alone."""


def _inject_fault(config: TrialConfig) -> None:
    """Test-only faults (``TrialConfig.fault``), to prove the scheduler's retry and failure handling."""
    if config.fault == "crash_once" and config.fault_marker and not Path(config.fault_marker).exists():
        Path(config.fault_marker).write_text("crashed once\n")
        os._exit(17)  # a hard process death, as an OOM kill or a segfault would be
    if config.fault == "block":
        while not Path(config.fault_marker).exists():  # certainly still running when a test interrupts the launch
            time.sleep(0.05)


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
        if member.episodes_to_solve is None and reaches_threshold(rolling, full, member.threshold):
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
    """Train ``configs`` (``config.can_share``) together; member i behaves as ``run_trial(configs[i], ...)``.

    ``on_episodes(i, rows)``: member i's new episodes after each update (a resumed member's saved history first,
    in one call). ``artifacts_dirs[i]``: member i's folder, for the videos it records as it trains (``video_every``).
    Every ``checkpoint_interval`` episodes, ``on_checkpoint(i, blob)`` gets member i's whole state, which
    ``resume_from[i]`` restores. ``on_outcome(i, outcome)`` as each member ends. ``device``: where the networks act
    and learn (``None``: CUDA whenever torch sees a device, else the CPU). Returns every member's outcome, in order."""
    for config in configs:
        _inject_fault(config)
    if not can_share(configs):
        raise ValueError(
            "these configs cannot share a population: " + ", ".join(map(str, map(population_group, configs)))
        )
    torch.set_num_threads(1)  # small networks: threads cost more than they give, and trials run side by side
    threadpool_limits(1, user_api="blas")  # the same for numpy's (OpenBLAS would spin 2 threads)
    env = describe(configs[0])  # the population's env, read once: every layer below is handed this
    _set_malloc(large_frames=env.profile.large_frames)
    torch_device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    folders = [Path(d) if d is not None else None for d in (artifacts_dirs or [None] * len(configs))]
    population = Population(configs, env, torch_device, folders)
    for position, blob in enumerate(resume_from or [None] * len(configs)):
        member = population.members[position]
        if blob is not None:
            restore(population, position, blob)
            if on_episodes is not None and member.history:
                on_episodes(member.index, list(member.history))
    outcomes: dict[int, MemberOutcome] = {}
    try:
        for position, member in enumerate(population.members):
            if not member.done and member.counting is None:
                population.start(position)
        while True:
            if population.leaving:
                _finish(population, outcomes, on_outcome)
            if not population.training:
                break
            ready = population.step()
            if ready:
                _learn(population, ready, outcomes, on_episodes, on_checkpoint, on_outcome)
    finally:
        population.close()
    return [outcomes[i] for i in range(len(configs))]


def _learn(population: Population, ready: list[int], outcomes: dict, on_episodes, on_checkpoint, on_outcome) -> None:
    """The ``ready`` members' updates, in one batched step each round while their episodes are in (continuous:
    several may be), then their next collections."""
    learning = list(ready)
    while learning:
        batches = {p: population.batch(population.members[p]) for p in learning}
        stats = {}
        for group in population.update_groups(list(batches)):
            stats.update(population.update({p: batches[p] for p in group}))
        learning = []
        for position, batch in batches.items():
            member = population.members[position]
            loss, entropy = stats[position]
            failure = None
            if not math.isfinite(loss):
                failure = TrialFailed(
                    f"loss became {loss} at episode {len(member.history) + len(batch.lengths)}; "
                    f"try a smaller learning_rate (now {member.config.learning_rate})"
                )
            elif member.config.fault == "raise":
                failure = TrialFailed("injected fault: raise after the first update (tests only)")
            if failure is not None:
                outcomes[member.index] = failure
                if on_outcome is not None:
                    on_outcome(member.index, failure)
                population.set_counting(position, member.counting[:0])
                population.leaving.add(position)
                continue
            member.updates += 1
            new = _record(member, batch, loss, entropy, time.perf_counter() - member.started)
            if on_episodes is not None:
                on_episodes(member.index, new)
            _maybe_checkpoint(population, position, len(new), on_checkpoint)
            if population.has_batch(member):
                learning.append(position)
    for position in ready:
        member = population.members[position]
        if member.index in outcomes:
            continue
        if member.done:
            population.leaving.add(position)
        elif not population.continuous:
            population.start(position)


def _maybe_checkpoint(population: Population, position: int, new: int, on_checkpoint) -> None:
    """A checkpoint where the update's ``new`` episodes crossed a multiple of ``checkpoint_interval``."""
    member = population.members[position]
    config, done, every = member.config, len(member.history), member.config.checkpoint_interval
    if on_checkpoint is None or not every or done // every == (done - new) // every or done >= config.max_episodes:
        return
    on_checkpoint(member.index, checkpoint(population, position))
    if config.fault == "crash_after_checkpoint" and not Path(config.fault_marker).exists():
        Path(config.fault_marker).write_text("crashed after a checkpoint\n")
        os._exit(17)  # the process dies with a checkpoint taken: its retry must resume from it


def _finish(population: Population, outcomes: dict, on_outcome) -> None:
    """Members that solved, spent their budget or failed leave: their results, ``on_outcome``. Only the members
    flagged ``leaving`` are looked at, in position order (a scan of every member at each departure grew as
    members squared)."""
    leaving = []
    for position in sorted(population.leaving):
        member = population.members[position]
        if position in population.left or (member.index not in outcomes and not member.done):
            continue
        leaving.append(position)
        if member.index in outcomes:
            continue
        result = TrialResult(
            config=member.config,
            episodes=member.history,
            episodes_to_solve=member.episodes_to_solve,
            solve_threshold=member.threshold,
            env_steps=member.env_steps,
            wall_s=time.perf_counter() - member.started,
            parameter_count=population.network.flat.shape[1],  # a member's row: each of its parameters once
            state_dict=population.network.state_dict(position),
            env=record(population.env, member.threshold),
        )
        member.videos.close()  # the trial is over: its last video ends here
        result.artifacts.update({f"videos/{p.name}": p for p in member.videos.paths if p.exists()})
        outcomes[member.index] = result
        if on_outcome is not None:
            on_outcome(member.index, result)
    population.leaving = set()
    if leaving:
        population.leave(leaving)


def run_trial(
    config: TrialConfig,
    on_episodes: Callable[[list[EpisodeMetrics]], None] | None = None,
    artifacts_dir: str | Path | None = None,
    *,
    resume_from: bytes | None = None,
    on_checkpoint: Callable[[bytes], None] | None = None,
) -> TrialResult:
    """Train one REINFORCE agent as ``config`` says: ``run_population`` of one, its callbacks without the member's
    index. Raises ``TrialFailed``."""
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


def _set_malloc(large_frames: bool) -> None:
    """glibc's thresholds for this population (no-op off glibc). By default its mmap threshold rises, up to 32 MB,
    each time a large block is freed, and it trims its heap's free top. CartPole: an update's activations (a
    5,000-step batch through a 32-wide layer: 640 KB a tensor) come from a heap that keeps what it frees (mmap
    threshold 32 MB, trim threshold 128 MB), not page-faulted in anew at every update (``make bench trainer``:
    the default's 16 x 1,024-episode updates 0.61 s -> 0.47 s). Pong: 256 KB, so its per-update arrays (MBs each)
    are mapped and go back to the system when freed; from the heap they fragmented it (RSS 515 MB -> 4.1 GB over
    500 episodes)."""
    import ctypes

    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        mallopt = ctypes.CDLL("libc.so.6").mallopt
        mallopt(-3, 256 * 1024 if large_frames else 32 << 20)  # M_MMAP_THRESHOLD; setting it turns the dynamic one off
        if not large_frames:
            mallopt(-1, 128 << 20)  # M_TRIM_THRESHOLD
