"""Pong trials with the policy on CUDA, through the trial function itself: steps/s against the raw emulator, GPU memory;
and a population of CartPole members (issue 26) on CUDA against the same population on the CPU.

Runs a short CNN and MLP trial of experiments/pong.toml (``run_trial``, no Ray, no MLflow imported) and prints,
for each, agent steps per second against the raw ``ALE/Pong-v5`` emulator's on the same machine, and the GPU
memory the trial used. Without a CUDA device it says "no CUDA device" and runs the same trials on the CPU. A few
minutes at most (``--episodes 10``: ~20,000 agent steps per trial).

It runs from the source tree and needs Python 3.11+, torch, numpy and threadpoolctl; gymnasium and ale-py may
come as wheels (a machine with a CUDA torch but without them, e.g. a lent GPU machine with Python 3.12). Here,
in the repository's root (``.whl/`` is git-ignored)::

    python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \\
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \\
        --platform manylinux2014_x86_64 --platform manylinux1_x86_64 \\
        -d .whl gymnasium==1.4.0 ale-py==0.12.1 farama-notifications==0.0.6

There, in the repository's root::

    python3 tools/gpu_check.py --wheels .whl

(``--wheels``: when gymnasium or ale-py cannot be imported, install the wheels in that folder into a temporary
folder first and import them from there; nothing is installed into the Python itself.)

The population part (``--members``, default 1,024 default CartPole trials at ``--cartpole-episodes`` each):
``agent.trainer.run_population`` with the members' networks on CUDA (acting by one batched forward of their
stacked parameters, the members ready at a step updating in one batched pass; the envs stay on the CPU), then on
the CPU, both as env steps per second. Pong populations (32 CNN members) are the same trainer; this script does
not measure them yet.
Measured once on a lent H200 (2026-12-04; docs/pong.md, docs/performance.md); tests/test_tools.py runs its short
form on the CPU.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _ensure_emulator(wheels: Path | None) -> None:
    """Import gymnasium and ale-py, installing them from ``wheels`` into a temporary folder if they are missing."""
    try:
        import ale_py  # noqa: F401
        import gymnasium  # noqa: F401

        return
    except ImportError as missing:
        if wheels is None:
            raise SystemExit(f"gpu_check: {missing}; pass --wheels FOLDER with gymnasium and ale-py wheels") from None
    target = Path(tempfile.mkdtemp(prefix="gpu_check_site_"))
    found = sorted(str(w) for w in wheels.glob("*.whl"))
    if not found:
        raise SystemExit(f"gpu_check: no wheels in {wheels}; see this script's docstring for the download command")
    command = [sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--no-compile", "--target"]
    subprocess.run([*command, str(target), *found], check=True)
    sys.path.insert(0, str(target))


def _raw_steps_per_s(config, steps: int = 8000) -> float:
    """Agent steps per wall second of ``gym.make(config.env_id)`` (``ALE/Pong-v5``) with random actions, nothing
    else; the env registered as a trial registers it (``env_spec.register``)."""
    import gymnasium as gym
    import numpy as np

    from ablate.env_spec import register

    register(config)
    env = gym.make(config.env_id)
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, 6, steps)
    started = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(int(action))
        if terminated or truncated:
            env.reset()
    spent = time.perf_counter() - started
    env.close()
    return steps / spent


def _population_steps_per_s(members: int, episodes: int, device: str) -> float:
    """Env steps per wall second of ``members`` default CartPole trials trained as one population on ``device``."""
    from ablate.agent.trainer import run_population
    from ablate.config import DEFAULT

    configs = [replace(DEFAULT, seed=i, max_episodes=episodes, record_video=False) for i in range(members)]
    started = time.perf_counter()
    outcomes = run_population(configs, device=device)
    return sum(o.env_steps for o in outcomes) / (time.perf_counter() - started)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=10, help="episodes per trial (default 10)")
    parser.add_argument("--wheels", type=Path, help="a folder of gymnasium and ale-py wheels, used if they are missing")
    parser.add_argument("--experiment", type=Path, default=ROOT / "experiments" / "pong.toml")
    parser.add_argument("--members", type=int, default=1024, help="CartPole population members (default 1024)")
    parser.add_argument("--cartpole-episodes", type=int, default=64, help="episodes per CartPole member (default 64)")
    args = parser.parse_args()
    _ensure_emulator(args.wheels)

    import torch

    from ablate.agent.trainer import run_trial
    from ablate.experiment import load_experiment

    cuda = torch.cuda.is_available()
    if cuda:
        print(f"CUDA device: {torch.cuda.get_device_name(0)}; torch {torch.__version__}", flush=True)
    else:
        print(f"no CUDA device: the CPU path (torch {torch.__version__})", flush=True)
    variants = {v.name: v.config for v in load_experiment(args.experiment).variants}
    raw = _raw_steps_per_s(variants["cnn"])
    print(f"raw ALE/Pong-v5: {raw:,.0f} agent steps/s (one process, wall clock)", flush=True)
    for name in ("cnn", "mlp"):
        config = replace(
            variants[name], max_episodes=args.episodes, record_video=False, video_every=0, checkpoint_every=0
        )
        if cuda:
            torch.cuda.reset_peak_memory_stats()
        result = run_trial(config)  # the trial puts its policy on CUDA whenever torch sees a device
        steps_per_s = result.env_steps / result.wall_s
        memory = (
            f"GPU memory peak {torch.cuda.max_memory_allocated() / 2**20:,.0f} MB allocated, "
            f"{torch.cuda.max_memory_reserved() / 2**20:,.0f} MB reserved"
            if cuda
            else "no GPU memory (CPU)"
        )
        print(
            f"{name}: {result.env_steps:,} agent steps in {result.wall_s:.1f} s = {steps_per_s:,.0f} steps/s, "
            f"{steps_per_s / raw:.2f}x the raw emulator; {memory}",
            flush=True,
        )
    on_cpu = _population_steps_per_s(args.members, args.cartpole_episodes, "cpu")
    line = f"CartPole population of {args.members}: CPU {on_cpu:,.0f} env steps/s"
    if cuda:
        on_gpu = _population_steps_per_s(args.members, args.cartpole_episodes, "cuda")
        line += f"; CUDA {on_gpu:,.0f} env steps/s ({on_gpu / on_cpu:.2f}x the CPU)"
    print(line + "; Pong CNN populations: not built yet (Pong trials run alone)", flush=True)
    heavy = [m for m in ("ray", "mlflow") if m in sys.modules]
    if heavy:
        print(f"gpu_check: imported {', '.join(heavy)}, which it must not need", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
