"""Command line: ``ablate train`` (one trial), ``ablate run`` (an ablation), ``ablate report``.

Thin: parse, validate (one clear line and exit 2 on bad input), call the modules that do the work.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

from ablate.config import PRESETS, ConfigError, apply_knobs
from ablate.lock import LaunchLocked
from ablate.tracking import TrackingError

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (no usage dump) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: {message}\n")
        raise SystemExit(EXIT_USAGE)


def _sizes(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of integers, e.g. 64,64") from None


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ablate", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    train = commands.add_parser("train", help="train one agent and save its curve, video and weights")
    train.add_argument("--preset", choices=sorted(PRESETS), default="default", help="starting config")
    train.add_argument("--env", dest="env_id", help="CartPole-v0, CartPole-v1 or ALE/Pong-v5")
    train.add_argument("--seed", type=int)
    train.add_argument("--learning-rate", dest="learning_rate", type=float)
    train.add_argument("--gamma", type=float)
    train.add_argument("--l2", type=float)
    train.add_argument("--episodes-per-update", dest="episodes_per_update", type=int)
    train.add_argument("--max-episodes", dest="max_episodes", type=int, help="episode budget")
    train.add_argument("--architecture", help="mlp or cnn")
    train.add_argument("--hidden-sizes", dest="hidden_sizes", type=_sizes, help="e.g. 64,64")
    train.add_argument("--activation")
    train.add_argument("--dropout", type=float)
    train.add_argument("--solve-threshold", dest="solve_threshold", type=float)
    train.add_argument("--no-video", dest="record_video", action="store_false", default=None)
    train.add_argument("--out", type=Path, default=None, help="output folder (default: outputs/train/<env>-s<seed>)")

    run = commands.add_parser("run", help="run an ablation experiment file on Ray, tracked in MLflow")
    run.add_argument("experiment", type=Path, help="e.g. experiments/cartpole.toml")
    run.add_argument("--address", help="join this Ray cluster (default: start a local one)")
    run.add_argument("--tracking-uri", dest="tracking_uri", help="MLflow tracking URI (default: sqlite:///mlflow.db)")
    run.add_argument("--fresh", action="store_true", help="start over under a new parent run")
    run.add_argument("--max-concurrent", dest="max_concurrent", type=int, help="trials at once (default: CPUs)")
    run.add_argument("--no-report", dest="report", action="store_false", help="skip the report at the end")

    report = commands.add_parser("report", help="write reports/<experiment>/ from the MLflow store")
    report.add_argument("experiment", help="experiment file or name, e.g. experiments/cartpole.toml or cartpole")
    report.add_argument("--tracking-uri", dest="tracking_uri")
    report.add_argument("--out", type=Path, default=Path("reports"), help="reports folder (default: reports)")
    return parser


TRAIN_KNOBS = (
    "env_id",
    "seed",
    "learning_rate",
    "gamma",
    "l2",
    "episodes_per_update",
    "max_episodes",
    "architecture",
    "hidden_sizes",
    "activation",
    "dropout",
    "solve_threshold",
    "record_video",
)


def cmd_train(args: argparse.Namespace) -> int:
    knobs = {k: getattr(args, k) for k in TRAIN_KNOBS if getattr(args, k) is not None}
    config = apply_knobs(PRESETS[args.preset], knobs)  # ConfigError before anything is written
    out = args.out or Path("outputs/train") / f"{config.env_id.replace('/', '_')}-s{config.seed}"

    from ablate.trial import run_trial  # heavy imports only once the input is known to be good

    progress = _ProgressLine()
    result = run_trial(config, on_episodes=progress.update, artifacts_dir=out)
    progress.close()
    summary = result.summary()
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    solved = (
        f"solved at episode {result.episodes_to_solve}"
        if result.solved
        else f"not solved in {len(result.episodes)} episodes"
    )
    print(
        f"{config.env_id} seed {config.seed}: {solved} "
        f"(rolling mean {summary['final_rolling_mean']:.1f}, {result.env_steps:,} steps, {result.wall_s:.1f} s)"
    )
    print(f"wrote {out}/: " + ", ".join(sorted(p.name for p in out.iterdir())))
    return EXIT_OK


class _ProgressLine:
    """One refreshing line on a terminal; a line every few seconds when output is a file or a pipe."""

    def __init__(self) -> None:
        self.tty = sys.stdout.isatty()
        self.last_print = 0.0

    def update(self, episodes: list[Any]) -> None:
        now = time.monotonic()
        if not self.tty and now - self.last_print < 2.0:
            return
        self.last_print = now
        m = episodes[-1]
        line = (
            f"episode {m.episode:>6} | return {m.episode_return:7.1f} | rolling mean {m.rolling_mean:7.1f}"
            f" | {m.env_steps / max(m.wall_s, 1e-9):>9,.0f} steps/s"
        )
        print(f"\r{line}" if self.tty else line, end="" if self.tty else "\n", flush=True)

    def close(self) -> None:
        if self.tty:
            print()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "train":
            return cmd_train(args)
        if args.command == "run":
            from ablate.runner import cmd_run

            return cmd_run(args)
        from ablate.report import cmd_report

        return cmd_report(args)
    except ConfigError as error:
        sys.stderr.write(f"ablate {args.command}: {error}\n")
        return EXIT_USAGE
    except (TrackingError, LaunchLocked) as error:
        sys.stderr.write(f"ablate {args.command}: {error}\n")
        return getattr(error, "exit_code", EXIT_FAILED)
    except KeyboardInterrupt as interrupt:  # before the launch began (SIGTERM too, in `run`: exit code 143)
        sys.stderr.write(f"ablate {args.command}: interrupted\n")
        return getattr(interrupt, "exit_code", EXIT_INTERRUPTED)


if __name__ == "__main__":
    raise SystemExit(main())
