"""`make bench`: speed and memory figures, measured in one process run, medians over several runs.

Sections: `core` (course-style loop vs our trial, time to solve CartPole-v1), `runner`, `ablation` (the
default ablation: speed-up, tracking overhead, memory), `tracking` (the single writer with 256 synthetic
trials), `cluster` (a tiny ablation on the local default vs a joined head and a tracking server), `pong`
and `pong-memory` (Pong trials against the raw emulator; RSS over a long trial), `pong-population` (Pong
populations of 8 per member against the raw emulator; RSS per member), `pong-seeds` (30 seeds of each Pong arm
one at a time and in populations: the same runs and distribution), `tuning` (tuned vs untuned
default ablation; each launch's time-left estimate scored), `eta` (the time-left estimate against the time that
actually remained), `population` (CartPole populations against one trial; the same results), `seeds` (the
tuned default ablation at 4x its seeds in populations against today's launch), `trainer` (this checkout's
trainer against an earlier commit's, alternating in one run: CartPole populations of 16 of the built-in network
and of users' networks, a Breakout trial of the built-in and of a user's CNN, one Pong trial per arm; the same
runs or not), `start` (time to the first trial, cold and warm, and 64 seeds end
to end against one trial's pace, this checkout against an earlier commit's), `launch` (1,000 default CartPole
seeds through `ablate run` against the trainer's own rate on one core, and their report).
`python benchmarks/bench.py [SECTION ...]`; no argument runs them all.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the sections beside this file, also when imported

from bench_estimate import bench_eta, bench_tuning  # noqa: E402
from bench_launch import bench_ablation, bench_cluster, bench_launch, bench_runner, bench_tracking  # noqa: E402
from bench_pong import bench_pong, bench_pong_memory, bench_pong_population, bench_pong_seeds  # noqa: E402
from bench_population import bench_population, bench_seeds  # noqa: E402
from bench_results import RESULTS  # noqa: E402
from bench_start import bench_start  # noqa: E402
from bench_trainer import BEFORE_STACKED, bench_trainer  # noqa: E402
from bench_trial import bench_core  # noqa: E402

SECTIONS = {
    "core": bench_core,
    "runner": bench_runner,
    "ablation": bench_ablation,
    "tracking": bench_tracking,
    "cluster": bench_cluster,
    "pong": bench_pong,
    "pong-memory": bench_pong_memory,
    "pong-population": bench_pong_population,
    "pong-seeds": bench_pong_seeds,
    "tuning": bench_tuning,
    "eta": bench_eta,
    "population": bench_population,
    "seeds": bench_seeds,
    "trainer": bench_trainer,
    "start": bench_start,
    "launch": bench_launch,
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("sections", nargs="*", help=f"any of {', '.join(SECTIONS)} (default: all)")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    parser.add_argument(
        "--ablation-repeats", type=int, default=1, help="repeats of the default ablation's three runs (~11 min each)"
    )
    parser.add_argument(
        "--tuning-repeats", type=int, default=3, help="tuning: pairs of untuned and tuned ablations (~6 min each)"
    )
    parser.add_argument(
        "--eta-experiment",
        action="append",
        dest="eta_experiments",
        help="eta: an experiment file to measure (repeatable; default: cartpole.toml and pong-smoke.toml)",
    )
    parser.add_argument(
        "--eta-launches",
        default="cold,warm",
        help="eta: cold (a fresh store), warm (--fresh on it: earlier costs known) or both, comma-separated",
    )
    parser.add_argument(
        "--pong-memory-episodes", type=int, default=0, help="pong-memory: episodes (0: pong.toml's budget)"
    )
    parser.add_argument(
        "--pong-memory-cap", type=int, default=0, help="pong-memory: cut episodes at this many steps (0: none)"
    )
    parser.add_argument(
        "--population-variant",
        help="population: this variant of experiments/cartpole.toml (default: the default trial)",
    )
    parser.add_argument(
        "--population-members", default="16,64", help="population: population sizes M to time, comma-separated"
    )
    parser.add_argument("--population-repeats", type=int, default=3, help="population: repeats per size M")
    parser.add_argument(
        "--population-seeds", type=int, default=32, help="population: seeds of the same-science check (0: none)"
    )
    parser.add_argument(
        "--trainer-against", default=BEFORE_STACKED, help="trainer: the commit to measure against (a git ref)"
    )
    parser.add_argument("--trainer-pairs", type=int, default=5, help="trainer: alternating pairs of runs per case")
    parser.add_argument("--launch-seeds", type=int, default=1000, help="launch: seeds of the default trial (<= 1000)")
    parser.add_argument(
        "--launch-population", default="64", help="launch: --population values to measure, comma-separated"
    )
    parser.add_argument("--launch-repeats", type=int, default=1, help="launch: repeats of each (~5-15 min each)")
    args = parser.parse_args()
    print(f"python {sys.version.split()[0]}, torch {torch.__version__}, {time.strftime('%Y-%m-%d %H:%M')}")
    unknown = [name for name in args.sections if name not in SECTIONS]
    if unknown:
        parser.error(f"unknown section {unknown[0]!r}; valid: {', '.join(SECTIONS)}")
    bad_launches = [x for x in args.eta_launches.split(",") if x not in ("cold", "warm")]
    if bad_launches:
        parser.error(f"--eta-launches: {bad_launches[0]!r} is not a launch; valid: cold, warm")
    if args.ablation_repeats < 1:
        parser.error(f"--ablation-repeats must be at least 1, got {args.ablation_repeats}")
    if args.pong_memory_episodes < 0:
        parser.error(f"--pong-memory-episodes must be at least 0, got {args.pong_memory_episodes}")
    if args.trainer_pairs < 1:
        parser.error(f"--trainer-pairs must be at least 1, got {args.trainer_pairs}")
    if args.tuning_repeats < 1:
        parser.error(f"--tuning-repeats must be at least 1, got {args.tuning_repeats}")
    for name in args.sections or SECTIONS:
        print(f"== {name}", flush=True)
        kwargs = {
            "ablation": {"repeats": args.ablation_repeats},
            "pong-memory": {"max_episode_steps": args.pong_memory_cap, "episodes": args.pong_memory_episodes},
            "tuning": {"repeats": args.tuning_repeats},
            "population": {
                "variant": args.population_variant,
                "members": tuple(int(m) for m in args.population_members.split(",")),
                "repeats": args.population_repeats,
                "seeds": args.population_seeds,
            },
            "trainer": {"against": args.trainer_against, "pairs": args.trainer_pairs},
            "launch": {
                "seeds": args.launch_seeds,
                "populations": tuple(int(m) for m in args.launch_population.split(",")),
                "repeats": args.launch_repeats,
            },
            "eta": {
                "launches": tuple(args.eta_launches.split(",")),
                **({"experiments": tuple(args.eta_experiments)} if args.eta_experiments else {}),
            },
        }
        SECTIONS[name](**kwargs.get(name, {}))
    if args.json:
        args.json.write_text(json.dumps(RESULTS, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
