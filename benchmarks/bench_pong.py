"""`make bench` sections on Pong: `pong` and `pong-memory` (Pong trials against the raw emulator; RSS over a
long trial), `pong-population` (Pong populations of 8 per member against the raw emulator; RSS per member),
`pong-seeds` (30 seeds of each arm one at a time and in populations: the same runs, the same distribution)."""

from __future__ import annotations

import statistics
import time
from dataclasses import replace

import torch
from bench_results import RESULTS

from ablate.agent.trainer import run_trial

# --- Pong (issue 9) ---
PONG_EXPERIMENT = "experiments/pong.toml"
PONG_BENCH_EPISODES = {"mlp": 200, "cnn": 50}
"""Episodes per bench trial, fixed (not pong.toml's budget, which is sized for learning): a speed measurement.
Steps cost the same early and late in a trial; 200 MLP episodes (~200,000 steps) make setup (4 ROM loads,
~0.6 s) weigh under 1%."""


def _pong_config(variant: str, **overrides):
    """The trial config of ``variant`` in experiments/pong.toml, seed 0, with ``overrides``."""
    from ablate.experiment import load_experiment

    config = next(v.config for v in load_experiment(PONG_EXPERIMENT).variants if v.name == variant)
    return replace(config, record_video=False, video_every=0, checkpoint_every=0, **overrides)


def _raw_pong_steps_per_cpu_s(steps: int = 8000) -> float:
    """Agent steps per CPU second of the raw emulator: ``gym.make("ALE/Pong-v5")`` (frameskip 4, sticky
    actions, RGB observations) stepped with uniformly random actions, nothing else."""
    import gymnasium as gym
    import numpy as np

    from ablate.config import TrialConfig
    from ablate.env_spec import register

    register(TrialConfig(env_id="ALE/Pong-v5"))
    env = gym.make("ALE/Pong-v5")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 6, steps)
    started = time.process_time()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(int(action))
        if terminated or truncated:
            env.reset()
    spent = time.process_time() - started
    env.close()
    return steps / spent


def _cnn_compute_ms_per_step(batch: int = 1024, acting_batch: int = 4) -> float:
    """CPU ms per agent step that the pong.toml `cnn` network alone costs, with nothing else running in the
    process: one forward at the acting batch (``num_envs`` frames) divided by that batch, plus forward and
    backward of a training chunk of ``batch`` frames divided by the chunk (real frame differences)."""
    import numpy as np

    from ablate.agent.policies import create_pong_model
    from ablate.config import TrialConfig
    from ablate.envs import make_pong

    env = make_pong(TrialConfig(env_id="ALE/Pong-v5", action_set="move"))
    env.reset(seed=0)
    frames = np.stack([env.step(i % 2)[0] for i in range(batch)])
    model = create_pong_model(2, (64,), architecture="cnn")
    x = torch.from_numpy(frames)
    acting = frames[:acting_batch]

    def median_ms(f, n: int) -> float:
        f()
        times = []
        for _ in range(n):
            started = time.process_time()
            f()
            times.append(time.process_time() - started)
        return statistics.median(times) * 1000

    def train() -> None:
        model.zero_grad()
        model(x).sum().backward()

    model.eval()
    acting_t = torch.from_numpy(acting)

    def act() -> None:
        with torch.inference_mode():
            model(acting_t)

    act_ms = median_ms(act, 200) / acting_batch
    model.train()
    return act_ms + median_ms(train, 5) / batch


def bench_pong(repeats: int = 3) -> None:
    """Agent steps per CPU second (= per core: one thread each) of the raw ALE/Pong-v5 emulator, and of whole
    Pong trials (acting, pre-processing, updates; setup included) of the pong.toml `mlp` and `cnn` variants,
    interleaved in one process; the raw emulator is measured before and after each repeat's trials (their
    mean is the repeat's baseline); ratios per repeat, medians. The trials run ``PONG_BENCH_EPISODES``
    episodes, a fixed short budget whatever pong.toml's. CPU time, not wall:
    on a machine shared with other work, wall time measures the neighbours. Also the CNN's floor: its network alone
    (acting forward + training forward and backward per step) against the emulator's step, which caps the
    CNN trial's ratio at emulator / (emulator + network) whatever the rest costs."""
    torch.set_num_threads(1)
    rows: dict[str, list[float]] = {"raw": [], "mlp": [], "cnn": [], "mlp_ratio": [], "cnn_ratio": []}
    rows |= {"cnn_network_ms": [], "cnn_ceiling": []}
    for i in range(repeats):
        before = _raw_pong_steps_per_cpu_s()
        trials = {}
        for variant, episodes in PONG_BENCH_EPISODES.items():
            started = time.process_time()
            result = run_trial(_pong_config(variant, max_episodes=episodes, seed=i))
            trials[variant] = result.env_steps / (time.process_time() - started)
        raw = (before + _raw_pong_steps_per_cpu_s()) / 2
        network_ms = _cnn_compute_ms_per_step()
        rows["raw"].append(raw)
        for variant, sps in trials.items():
            rows[variant].append(sps)
            rows[f"{variant}_ratio"].append(sps / raw)
        rows["cnn_network_ms"].append(network_ms)
        rows["cnn_ceiling"].append((1000 / raw) / (1000 / raw + network_ms))
        print(
            f"  repeat {i}: raw emulator {raw:,.0f} steps/s/core | mlp trial {rows['mlp'][-1]:,.0f} "
            f"({rows['mlp_ratio'][-1]:.2f}x) | cnn trial {rows['cnn'][-1]:,.0f} ({rows['cnn_ratio'][-1]:.2f}x) "
            f"| cnn network alone {network_ms:.3f} ms/step -> ceiling {rows['cnn_ceiling'][-1]:.2f}x",
            flush=True,
        )
    medians = {k: statistics.median(v) for k, v in rows.items()}
    print(
        f"pong: raw ALE/Pong-v5 median {medians['raw']:,.0f} agent steps/s/core; mlp trial "
        f"{medians['mlp']:,.0f} ({medians['mlp_ratio']:.2f}x raw); cnn trial {medians['cnn']:,.0f} "
        f"({medians['cnn_ratio']:.2f}x raw); the cnn network alone {medians['cnn_network_ms']:.3f} ms per step "
        f"caps a cnn trial at {medians['cnn_ceiling']:.2f}x"
    )
    RESULTS["pong"] = {"medians": medians, "runs": rows}


def bench_pong_memory(episodes: int = 0, variant: str = "cnn", max_episode_steps: int = 0) -> None:
    """Resident memory of one Pong trial at pong.toml's settings (the `cnn` variant, seed 0) over ``episodes``
    episodes (`--pong-memory-episodes`; 0: pong.toml's budget; ~20 min of CPU for 1,000): RSS after episode
    100, every 100 after, and the process's peak, outside Ray.
    ``max_episode_steps`` (`--pong-memory-cap`) cuts episodes short: as many updates in less time."""
    import resource

    import psutil

    process = psutil.Process()
    samples: dict[int, float] = {}

    def sample(rows) -> None:
        for row in rows:
            if row.episode % 100 == 0:
                samples[row.episode] = process.memory_info().rss / 2**20
                print(f"  episode {row.episode}: RSS {samples[row.episode]:,.0f} MB", flush=True)

    config = _pong_config(variant, max_episode_steps=max_episode_steps)
    episodes = episodes or config.max_episodes
    run_trial(replace(config, max_episodes=episodes), on_episodes=sample)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    first, last = samples.get(100, float("nan")), samples.get(episodes, float("nan"))
    print(
        f"pong-memory: {variant} trial, {episodes} episodes (step cap {max_episode_steps or 'none'}): RSS "
        f"{first:,.0f} MB at episode 100, {last:,.0f} MB at episode {episodes}; peak RSS {peak_mb:,.0f} MB"
    )
    RESULTS["pong-memory"] = {"variant": variant, "rss_mb": samples, "peak_rss_mb": peak_mb}


PONG_POPULATION_EPISODES = {"mlp": 16, "cnn": 8}
"""Episodes per member in the `pong-population` section's populations of 8 (twice as many in its population of
one): ~100,000 MLP and ~60,000 CNN agent steps in all, a few minutes on one core."""


def _pong_population_child(variant: str, members: int, episodes: int, queue) -> None:
    """In a fresh process (its peak RSS is the population's own): ``members`` seeds of pong.toml's ``variant``
    as one population; puts (agent steps, CPU seconds, of them in setup, peak RSS in MB) on ``queue``. Setup:
    building the backend (4 ROM loads a member, ~0.15 s each idle), a one-off cost over a 400-episode trial."""
    import resource

    from ablate.agent import trainer

    setup = [0.0]

    class Timed(trainer.Population):
        def __init__(self, *args, **kwargs) -> None:
            started = time.process_time()
            super().__init__(*args, **kwargs)
            setup[0] += time.process_time() - started

    trainer.Population = Timed
    configs = [_pong_config(variant, max_episodes=episodes, seed=seed) for seed in range(members)]
    started = time.process_time()
    outcomes = trainer.run_population(configs, device="cpu")
    spent = time.process_time() - started
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    queue.put((sum(o.env_steps for o in outcomes), spent, setup[0], peak_mb))


def bench_pong_population(members: int = 8) -> None:
    """Pong populations (issue 26): agent steps per CPU second of a population of ``members`` seeds of the
    pong.toml `mlp` and `cnn` variants, per member (the population's steps over its CPU time: what one
    member's steps cost a core; after setup, and with it), against the raw emulator per core
    measured before and after; a population of one (the single trial) for reference; peak RSS of each
    population's process over its members. Each population in a fresh process, one thread, CPU time (not
    wall: the neighbours' load on a shared machine does not count)."""
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    before = _raw_pong_steps_per_cpu_s()
    rows = []
    for variant, episodes in PONG_POPULATION_EPISODES.items():
        for size, per_member in ((members, episodes), (1, 2 * episodes)):
            queue = context.Queue()
            child = context.Process(target=_pong_population_child, args=(variant, size, per_member, queue))
            child.start()
            steps, cpu_s, setup_s, peak_mb = _result_of(child, queue)
            steady = steps / (cpu_s - setup_s)
            rows.append(
                {"variant": variant, "members": size, "steps": steps, "cpu_s": cpu_s, "setup_s": setup_s}
                | {"steady": steady, "peak_rss_mb": peak_mb}
            )
            print(
                f"  {variant} population of {size}: {steps:,} agent steps in {cpu_s:,.1f} CPU s, "
                f"{setup_s:,.1f} of them setup ({steady:,.0f} per CPU s after setup, {steps / cpu_s:,.0f} with it); "
                f"peak RSS {peak_mb:,.0f} MB ({peak_mb / size:,.0f} MB per member)",
                flush=True,
            )
    raw = (before + _raw_pong_steps_per_cpu_s()) / 2
    for row in rows:
        row["ratio"], row["steady_ratio"] = row["steps"] / row["cpu_s"] / raw, row["steady"] / raw
    summary = "; ".join(
        f"{r['variant']} x{r['members']} {r['steady_ratio']:.2f}x ({r['ratio']:.2f}x with setup; "
        f"{r['peak_rss_mb'] / r['members']:,.0f} MB/member)"
        for r in rows
    )
    print(f"pong-population: raw ALE/Pong-v5 {raw:,.0f} agent steps/s/core; per member against it: {summary}")
    RESULTS["pong-population"] = {"raw": raw, "runs": rows}


def _pong_seeds_child(variant: str, seeds: int, episodes: int, members: int, queue) -> None:
    """In a fresh process: ``seeds`` seeds of pong.toml's ``variant`` at ``episodes`` each, one at a time (the
    single trial) and as populations of ``members``; puts each seed's (alone, together) episode rows
    (return, length) and AUC on ``queue``."""
    torch.set_num_threads(1)
    from ablate.agent.trainer import run_population

    configs = [_pong_config(variant, max_episodes=episodes, seed=seed) for seed in range(seeds)]
    alone = [run_trial(c) for c in configs]
    together = [o for i in range(0, seeds, members) for o in run_population(configs[i : i + members], device="cpu")]

    def runs(outcomes):
        return [([(m.episode_return, m.length) for m in o.episodes], o.summary()["auc"]) for o in outcomes]

    queue.put((runs(alone), runs(together)))


def _result_of(child, queue):
    """What ``child`` puts on ``queue``, or an error that says it died first (a bare ``queue.get`` would wait
    for ever)."""
    from queue import Empty

    while True:
        try:
            result = queue.get(timeout=5)
            child.join()
            return result
        except Empty:
            if not child.is_alive():
                raise SystemExit(f"the benchmark's child process died (exit code {child.exitcode})") from None


def bench_pong_seeds(seeds: int = 30, episodes: int = 25, members: int = 8) -> None:
    """The same science in Pong populations (issue 26, item 3): ``seeds`` seeds of each pong.toml arm at
    ``episodes`` episodes, one at a time and in populations of ``members``: how many members' whole runs
    (returns and lengths) are their trials', and AUC's distributions compared by a two-sample test
    (Mann-Whitney U). The two arms run side by side, one process each (a core each on 2 cores). The default
    budget (400 episodes) would take ~10 core-hours: this is the same check at a budget a machine affords."""
    import multiprocessing

    from scipy.stats import mannwhitneyu

    context = multiprocessing.get_context("spawn")
    children = {}
    for variant in ("mlp", "cnn"):
        queue = context.Queue()
        child = context.Process(target=_pong_seeds_child, args=(variant, seeds, episodes, members, queue))
        child.start()
        children[variant] = (child, queue)
    figures = {}
    for variant, (child, queue) in children.items():
        alone, together = _result_of(child, queue)
        identical = sum(a[0] == b[0] for a, b in zip(alone, together, strict=True))
        first_flip = [
            next((i for i, (x, y) in enumerate(zip(a[0], b[0], strict=True)) if x != y), None)
            for a, b in zip(alone, together, strict=True)
        ]
        auc_alone, auc_together = [a[1] for a in alone], [b[1] for b in together]
        p_value = float(mannwhitneyu(auc_together, auc_alone).pvalue)
        figures[variant] = {
            "identical_runs": identical,
            "first_different_episode": first_flip,
            "auc_alone_median": statistics.median(auc_alone),
            "auc_population_median": statistics.median(auc_together),
            "p": p_value,
        }
        print(
            f"pong-seeds: {variant}, {seeds} seeds x {episodes} episodes: {identical}/{seeds} members' whole runs "
            f"identical to their trials' (returns and lengths); AUC median {statistics.median(auc_together):.3f} "
            f"in populations of {members}, {statistics.median(auc_alone):.3f} one at a time; Mann-Whitney "
            f"p = {p_value:.2f}; first different episode per differing seed: "
            f"{[f for f in first_flip if f is not None]}",
            flush=True,
        )
    RESULTS["pong-seeds"] = figures
