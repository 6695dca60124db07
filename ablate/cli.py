"""Command line: ``ablate train`` (one trial), ``ablate run`` (an ablation), ``ablate status``, ``ablate report``.

Thin: parse, validate (one clear line and exit 2 on bad input), call the modules that do the work.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

from ablate import config as config_module
from ablate import experiment as experiment_module
from ablate import schema
from ablate.checks import check_configs, check_experiment
from ablate.config import KNOBS, PRESETS, SHORTHANDS, ConfigError, ModelConfig, TrialConfig, apply_knobs
from ablate.dry_run import dry_run
from ablate.experiment import Experiment, load_experiment
from ablate.launch.clock import EpisodeLine
from ablate.launch.lock import LaunchLocked
from ablate.launch.plan import LaunchPlan
from ablate.launch.secrets import masked_output, remember_uri, shown, shown_command
from ablate.launch.store import TrackingError, insecure_http
from ablate.train_from import STAGES, trial_from

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED, EXIT_PIPE = 0, 1, 2, 130, 141  # 141: ended by SIGPIPE

DESCRIPTION = """\
ablate: architecture ablations of REINFORCE (vanilla policy gradient) agents on CartPole and Pong.
An experiment file names the variants (depth, width, dropout, L2, CNN vs MLP, ...) and the seeds; ablate
runs every trial on Ray (a local one by default), tracks each in MLflow, and writes a report with
convergence tables, intervals over seeds, learning curves and videos."""

EPILOG = """\
examples:
  ablate run experiments/cartpole.toml           run the ablation (a re-run finishes what is missing)
  ablate run experiments/cartpole.toml --only deep,wide --seeds 0,1 --dry-run
                                                 list the trials a run of part of it would start
  ablate status                                  the ablations, launches and trials in the MLflow store
  ablate report experiments/cartpole.toml        rebuild reports/cartpole/ from the MLflow store
  ablate train --preset course                   one trial here, without Ray or MLflow
  ablate train --from experiments/cartpole.toml --variant deep --seed 3
                                                 one trial of an experiment, same key and config

Every command has its own --help. MLflow store: sqlite:///mlflow.db in this folder unless --tracking-uri
or MLFLOW_TRACKING_URI says otherwise."""

TEST_ONLY_KNOBS = tuple(name for name, k in KNOBS.items() if k.test_only)
"""Knobs for injecting faults in tests: no flag for them."""
NOT_IN_KEY_KNOBS = tuple(name for name, k in KNOBS.items() if k.key_since is None and not k.test_only)
"""Knobs that change what a trial records, not what it learns: allowed with ``train --from``."""


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (no usage dump) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: {message}\n")
        raise SystemExit(EXIT_USAGE)


def _sizes(text: str) -> list[int]:
    if text.strip().lower() in ("", "linear", "none"):
        return []
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a comma-separated list of integers, e.g. 64,64 (or 'linear' for none)"
        ) from None


def _seed_list(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of seeds, e.g. 0,1") from None


def field_docs(code_mark: str = "") -> dict[str, str]:
    """The docstring under each field of ``TrialConfig`` and ``ModelConfig`` (the flags' help), one line each, by
    the experiment file's key; the docstrings' ````code```` marks become ``code_mark`` (```` ` ```` for Markdown)."""
    docs = schema.field_docs(config_module, (TrialConfig, ModelConfig), code_mark)
    return {name: docs.get(k.attr, "") for name, k in KNOBS.items()}


def knob_defaults() -> dict[str, Any]:
    """Each knob of ``config.KNOBS`` at its typed default: what an experiment file gets for a knob it does not
    set."""
    return {name: k.default for name, k in KNOBS.items()}


def format_value(value: Any) -> str:
    """A value as an experiment file writes it (TOML, here JSON's spelling): ``"relu"``, ``[32, 32]``, ``true``;
    ``None``: not set."""
    return "not set" if value is None else json.dumps(value, ensure_ascii=False)


def _knobs_epilog() -> str:
    """``ablate run --help``'s list of knobs with their defaults, from the config itself so it cannot go stale."""
    defaults = knob_defaults()
    # seed is the one knob a table may not set: seeds are the experiment's, at the top level.
    items = [f"{name} = {format_value(defaults[name])}" for name in KNOBS if name not in (*TEST_ONLY_KNOBS, "seed")]
    items += [
        f"{name} (with {other}: instead of hidden_sizes)" for name, other in (("depth", "width"), ("width", "depth"))
    ]
    lines = [""]
    for item in items:  # whole items per line: a knob and its default are never split
        if lines[-1] and len(lines[-1]) + len(item) > 104:
            lines.append("")
        lines[-1] += ("; " if lines[-1] else "") + item
    return (
        "knobs an experiment file may set in [base], [[variants]] and [grid], with their defaults:\n"
        + "\n".join(f"  {line}" for line in lines)
        + f"\ntop-level keys: {', '.join(experiment_module.EXPERIMENT_KEYS)}.\n"
        "Each knob's meaning and valid values, and the top-level keys' defaults: docs/experiments.md."
    )


def _json_table(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except json.JSONDecodeError:
        value = None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"{text!r} is not a JSON object, e.g. '{{\"width\": 64}}'")
    return value


# A flag's parser and metavar by the field's type, as the schema records it.
_FLAG_TYPES = (
    ("tuple[tuple", _json_table, "JSON"),
    ("tuple", _sizes, "N,N"),
    ("float", float, "X"),
    ("int", int, "N"),
    ("str", str, "NAME"),
)

TRAIN_KNOBS = tuple(k for k in KNOBS if k not in TEST_ONLY_KNOBS) + tuple(SHORTHANDS)
"""The knobs ``ablate train`` has a flag for (each flag's dest is the knob's name): every knob but the tests'."""


def add_knob_flags(parser: argparse.ArgumentParser) -> None:
    """A flag per knob of ``config.KNOBS`` (and the depth/width shorthands), typed from the schema, with the
    field's docstring and the valid values as help."""
    docs = field_docs()
    for name, knob in KNOBS.items():
        if knob.test_only:
            continue
        flags = [knob.flag, *knob.aliases]
        doc = docs.get(name, "")
        help_text = doc if knob.type == "bool" else f"{doc} Valid: {knob.valid}."
        if name == "seed":
            help_text += " With --from: one of the experiment's seeds."
        help_text = help_text.replace("%", "%%")
        if knob.type == "bool":
            parser.add_argument(*flags, dest=name, action=argparse.BooleanOptionalAction, default=None, help=help_text)
            if name == "record_video":
                parser.add_argument("--no-video", dest=name, action="store_false", help="same as --no-record-video")
        else:
            convert, metavar = next((c, m) for prefix, c, m in _FLAG_TYPES if knob.type.startswith(prefix))
            parser.add_argument(*flags, dest=name, type=convert, metavar=metavar, help=help_text)
    for name, (valid, _) in SHORTHANDS.items():
        other = "width" if name == "depth" else "depth"
        parser.add_argument(
            f"--{name}",
            type=int,
            help=f"shorthand with --{other} for --hidden-sizes: --depth layers of --width units. Valid: {valid}.",
        )


def add_launch_flags(command: argparse.ArgumentParser) -> None:
    """The flags of a command that launches trials (``run``, ``calibrate``): the same words, the same defaults."""
    command.add_argument(
        "--address", help="join this Ray cluster, host:port or auto (default: RAY_ADDRESS, else a new local Ray)"
    )
    command.add_argument("--tracking-uri", help="MLflow tracking URI (default: sqlite:///mlflow.db)")
    command.add_argument("--max-concurrent", type=int, help="trials at once (default: CPUs)")
    command.add_argument(
        "--population",
        type=int,
        default=config_module.DEFAULT_POPULATION,
        metavar="M",
        help="train up to M trials of a variant together in one process, as one batched population (default "
        f"{config_module.DEFAULT_POPULATION}; 1: each alone); on a CPU a member is its trial alone "
        "(CartPole: bit for bit)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="ablate", description=DESCRIPTION, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")

    train = commands.add_parser(
        "train",
        help="train one agent here (no Ray, no MLflow) and save its curve, video and weights",
        description="Train one agent in this process and write its learning curve, video, weights, per-episode "
        "table and summary. Start from a preset and override any knob, or take one trial of an experiment "
        "file with --from, --variant and --seed (the same key and config as in `ablate run`).",
    )
    train.add_argument(
        "--preset", choices=sorted(PRESETS), default="default", help="starting config (default: default)"
    )
    train.add_argument(
        "--from",
        dest="from_experiment",
        type=Path,
        metavar="EXPERIMENT",
        help="an experiment file: train its trial of --variant and --seed instead of a preset",
    )
    train.add_argument("--variant", help="with --from: the variant's name, as in the experiment file")
    train.add_argument(
        "--stage",
        choices=STAGES,
        help="with --from: eval (default), the trial the report's claims use, at the values tuning chose (read "
        "from --tracking-uri); tune, a tuning trial (a tuning --seed, the candidate's --learning-rate); base, the "
        "evaluation trial at the shared base value",
    )
    train.add_argument(
        "--tracking-uri",
        help="with --from on a [tune] experiment: the store whose tuning chose the values (default: "
        "sqlite:///mlflow.db); read only",
    )
    add_knob_flags(train)
    train.add_argument(
        "--out", type=Path, default=None, help="output folder (default: outputs/train/<env>-s<seed>, or the trial key)"
    )

    run = commands.add_parser(
        "run",
        help="run an ablation experiment file on Ray, tracked in MLflow",
        description="Run every trial of an experiment file that has no finished run yet, on a local Ray (or a "
        "cluster), track each in MLflow, show a live progress view, and write the report at the end.",
        epilog=_knobs_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    run.add_argument("experiment", type=Path, help="e.g. experiments/cartpole.toml")
    add_launch_flags(run)
    run.add_argument(
        "--storage-path",
        default="ray_results",
        help="Tune's bookkeeping folder, on the driver (an NFS path or s3:// if you have one; artifacts never use it)",
    )
    run.add_argument("--fresh", action="store_true", help="start over under a new parent run (a new generation)")
    run.add_argument("--no-report", dest="report", action="store_false", help="skip the report at the end")
    run.add_argument(
        "--only",
        action="append",
        metavar="VARIANT[,VARIANT...]",
        help="run only these variants (repeatable; grid variant names may themselves contain commas)",
    )
    run.add_argument("--seeds", type=_seed_list, metavar="SEED[,SEED...]", help="run only these seeds, e.g. 0,1")
    run.add_argument(
        "--dry-run",
        action="store_true",
        help="list the trials (variant, seed, key) and exit: starts no Ray, writes nothing",
    )

    status = commands.add_parser(
        "status",
        help="what the MLflow store holds: ablations, launches, generations, trials by state",
        description="Without EXPERIMENT: one line per ablation in the MLflow store. With it: its generations, "
        "their launches and trials by state, and the newest generation per variant (with an experiment file, "
        "its trials that have no run yet count as pending). Reads only.",
    )
    status.add_argument(
        "experiment",
        nargs="?",
        help="an ablation's name or experiment file, e.g. cartpole or experiments/cartpole.toml",
    )
    status.add_argument("--tracking-uri", help="MLflow tracking URI (default: sqlite:///mlflow.db)")

    report = commands.add_parser(
        "report",
        help="write reports/<experiment>/ (Markdown, HTML, PDF) from the MLflow store",
        description="Write reports/<experiment>/ from the MLflow store: report.md, a self-contained report.html, "
        "report.pdf (typeset by the typst package), discussion.md (yours, kept across rebuilds), figures, tables "
        "and videos; the report is attached to the launch's MLflow run. Nothing is written unless the whole report "
        "could be built.",
    )
    report.add_argument("experiment", help="experiment file or name, e.g. experiments/cartpole.toml or cartpole")
    report.add_argument("--tracking-uri", help="MLflow store to read (default: sqlite:///mlflow.db); never created")
    report.add_argument("--out", type=Path, default=Path("reports"), help="reports folder (default: reports)")
    report.add_argument(
        "--generation",
        help="report this generation (an id or a unique prefix; default: the newest launch's), e.g. the complete one "
        "before a --fresh run was interrupted",
    )
    report.add_argument(
        "--variants",
        help="only these variants, comma-separated, e.g. deep,cnn; the baseline is always kept (default: all)",
    )
    report.add_argument("--baseline", help="the variant the others are compared to (default: the experiment's)")
    report.add_argument(
        "--no-pdf",
        dest="pdf",
        action="store_false",
        help="skip report.pdf (report.md, report.html and report.typ are still written)",
    )
    from ablate.calibration import add_parser as add_calibrate

    add_launch_flags(add_calibrate(commands))
    for command in commands.choices.values():  # each opens an MLflow store
        command.add_argument(
            "--allow-insecure-http",
            action="store_true",
            help="let the MLflow login go over plain http:// to another machine, in clear (refused without it; "
            "docs/cluster.md shows HTTPS through a reverse proxy)",
        )
    return parser


def cmd_train(args: argparse.Namespace) -> int:
    knobs = {k: getattr(args, k) for k in TRAIN_KNOBS if getattr(args, k) is not None}
    trial = None
    chosen = None
    if args.from_experiment is not None:
        chosen = trial_from(args, knobs, NOT_IN_KEY_KNOBS)
        config, trial = chosen.config, chosen.trial
    elif args.variant is not None:
        raise ConfigError("--variant: only with --from EXPERIMENT (a preset has no variants)")
    else:
        config = apply_knobs(PRESETS[args.preset], knobs)  # ConfigError before anything is written
    # Flags name no file and no variant: the error is the problem alone (the command prefixes its name).
    check_configs([(trial.variant if trial else "", config)], str(args.from_experiment or ""))
    name = trial.key if trial else f"{config.env_id.replace('/', '_')}-s{config.seed}"
    out = args.out or Path("outputs/train") / name
    if trial:
        print(
            f"trial {trial.key}: variant {trial.variant}, seed {trial.seed} of {args.from_experiment}, {chosen.words}"
        )

    from ablate.agent.trainer import run_trial  # heavy imports only once the input is known to be good
    from ablate.trial_files import write_artifacts

    progress = EpisodeLine()
    result = run_trial(config, on_episodes=progress.update, artifacts_dir=out)
    progress.close()
    write_artifacts(result, out)
    summary = result.summary()
    if trial:
        summary = {"trial_key": trial.key, "experiment_file": str(args.from_experiment), **summary}
        summary |= {"stage": chosen.stage, "tuned_values": chosen.values}
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


def cmd_status(args: argparse.Namespace) -> int:
    from ablate.reporting.status import detail, overview

    if args.experiment is None:
        print(overview(args.tracking_uri))
        return EXIT_OK
    experiment = None
    name = args.experiment
    if name.endswith(".toml") or "/" in name:
        experiment = load_experiment(name)  # a bad file is a ConfigError: one line, exit 2
        name = experiment.name
    print(detail(args.tracking_uri, name, experiment))
    return EXIT_OK


def warn_design(experiment: Experiment) -> None:
    """Before any compute: say when the design can never reach a primary claim at the family level."""
    from ablate.design import design_warning

    seeds = experiment.rounds.max if experiment.rounds else len(experiment.seeds)
    warning = design_warning(seeds, len(experiment.variants) - 1)
    if warning:
        print(f"warning: {warning}", flush=True)


def main(argv: list[str] | None = None) -> int:
    started_at = time.monotonic()
    args = build_parser().parse_args(argv)
    # Every line this command prints, through Python, passes the secrets' masks (ablate.launch.secrets).
    remember_uri(getattr(args, "tracking_uri", None))
    try:
        with masked_output(), insecure_http(getattr(args, "allow_insecure_http", False)):
            code = _main(args, started_at)
            sys.stdout.flush()  # here, not at exit: a closed pipe is met where it can be caught
            return code
    except BrokenPipeError:  # stdout's reader left (`ablate run --dry-run | head`): quietly, as Unix tools do
        with contextlib.suppress(OSError, ValueError):  # Python's flush at exit would say it could not write
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_PIPE


def _main(args: argparse.Namespace, started_at: float) -> int:
    try:
        if args.command == "train":
            return cmd_train(args)
        if args.command == "status":
            return cmd_status(args)
        if args.command == "calibrate":
            from ablate.calibration import cmd_calibrate

            return cmd_calibrate(args)
        if args.command == "run":
            experiment = load_experiment(args.experiment)  # bad input: one line, before Ray or MLflow is imported
            check_experiment(experiment)
            plan = LaunchPlan.of(
                experiment, args.only, args.seeds,
                tracking_uri=args.tracking_uri, address=args.address, fresh=args.fresh, started_at=started_at,
                max_concurrent=args.max_concurrent, storage_path=args.storage_path, population=args.population,
                command=shown_command(["ablate", *sys.argv[1:]]),  # as it is recorded and shown
            )  # fmt: skip
            if args.dry_run:
                code = dry_run(plan, args.report)
                warn_design(experiment)
                return code
            warn_design(experiment)  # before any compute
            tuning, trials = plan.tuning, plan.trials
            count = f"{len(tuning)} tuning trials, then {len(trials)}" if tuning else f"{len(trials)}"
            print(f"ablate run {experiment.name}: {count} trials; reading the MLflow store ...", flush=True)
            from ablate.commands import cmd_run

            return cmd_run(args, plan)
        from ablate.commands import cmd_report

        return cmd_report(args)
    except (ConfigError, TrackingError, LaunchLocked) as error:
        sys.stderr.write(f"ablate {args.command}: {shown(error)}\n")
        return EXIT_USAGE if isinstance(error, ConfigError) else getattr(error, "exit_code", EXIT_FAILED)
    except KeyboardInterrupt as interrupt:  # before the launch began (SIGTERM too, in `run`: exit code 143)
        sys.stderr.write(f"ablate {args.command}: interrupted\n")
        return getattr(interrupt, "exit_code", EXIT_INTERRUPTED)


if __name__ == "__main__":
    raise SystemExit(main())
