"""Run an ablation: experiment file -> grid -> scheduler, every trial event written by the tracker.

The glue of ``ablate run``; it imports neither Ray nor MLflow (``scheduler`` and ``tracking`` do).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import subprocess
import sys
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ablate.config import ConfigError, Experiment, flatten, load_experiment
from ablate.curve import CurvePoint
from ablate.grid import GridTrial, expand, select
from ablate.progress import ProgressView, clock, stage
from ablate.scheduler import ClusterOptions, ClusterUnavailable, ensure_ray, run_trials, stop_ray
from ablate.tracking import TAG_NODE, Tracker


@dataclass
class RunOutcome:
    experiment: str
    generation: str
    launch_run_id: str | None
    skipped: int
    """Trials finished by an earlier launch of this generation, not run again."""
    total: int
    """Trials in the experiment's grid."""
    ui_link: str
    """The MLflow runs table of this experiment."""
    finished: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    killed: list[str] = field(default_factory=list)
    interrupted: bool = False
    view: ProgressView | None = field(default=None, repr=False)
    """The launch's progress view (its clock and stage times), when trials ran."""

    @property
    def exit_code(self) -> int:
        if self.interrupted:
            return 130
        return 1 if self.failed else 0


def git_commit() -> str:
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True)
        return commit + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def grid_document(experiment: Experiment, trials: list[GridTrial]) -> dict:
    """What the report needs to know of the launch without reading the experiment file again."""
    return {
        "experiment": experiment.name,
        "description": experiment.description,
        "baseline": experiment.baseline,
        "seeds": list(experiment.seeds),
        "variants": [{"name": v.name, "overrides": dict(v.overrides)} for v in experiment.variants],
        "base": {k: list(v) if isinstance(v, tuple) else v for k, v in flatten(experiment.base).items()},
        "trials": [{"key": t.key, "variant": t.variant, "seed": t.seed} for t in trials],
    }


PACKAGES = ("torch", "gymnasium", "ale-py", "ray", "mlflow", "numpy", "pandas", "scipy", "matplotlib", "imageio")


def environment_document() -> dict:
    """Where the launch ran: Python, package versions, machine, CPU model and the CPU kernels torch uses."""
    from importlib.metadata import PackageNotFoundError, version

    packages = {}
    for name in PACKAGES:
        try:
            packages[name] = version(name)
        except PackageNotFoundError:
            packages[name] = "not installed"
    import torch

    # Float kernels differ by CPU: the model and the kernels torch picks say where the results were produced.
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.is_file() else []
    models = [line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")]
    cpu_model = models[0] if models else platform.processor() or "unknown"
    return {
        "python": platform.python_version(),
        "packages": packages,
        "machine": f"{platform.system()} {platform.machine()}, {os.cpu_count()} CPUs ({platform.platform()})",
        "cpu_model": cpu_model,
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
    }


class _Recorder:
    """Scheduler events -> tracker writes and the progress view (all on the driver: one MLflow writer)."""

    def __init__(
        self,
        tracker: Tracker,
        launch: str,
        generation: str,
        trials: dict[str, GridTrial],
        commit: str,
        view: ProgressView,
        outcome: RunOutcome,
    ) -> None:
        self.tracker, self.launch, self.generation = tracker, launch, generation
        self.trials, self.commit, self.view, self.outcome = trials, commit, view, outcome

    def _open(self, key: str) -> None:
        if key not in self.tracker.open_runs:
            trial = self.trials[key]
            params = {"variant": trial.variant, **flatten(trial.config)}
            self.tracker.start_trial(self.launch, self.generation, key, trial.variant, trial.seed, params, self.commit)

    def started(self, key: str) -> None:
        self._open(key)
        self.view.started(key)

    def episodes(self, key: str, points: list[CurvePoint]) -> None:
        self._open(key)
        self.tracker.log_points(key, points)
        self.view.episodes(key, points)

    def checkpoint(self, key: str, blob: bytes) -> None:
        self._open(key)
        self.tracker.log_checkpoint(key, blob)

    def restarted(self, key: str, reason: str) -> None:
        self.tracker.discard_trial(key, reason)

    def finished(self, key: str, summary: dict[str, float], artifacts: Path | None, node: str) -> None:
        self._open(key)
        self.tracker.finish_trial(key, summary, artifacts, tags={TAG_NODE: node})
        self.outcome.finished.append(key)
        self.view.finished(key, bool(summary.get("solved")))

    def failed(self, key: str, message: str) -> None:
        self._open(key)
        self.tracker.fail_trial(key, message)
        self.outcome.failed[key] = message
        self.view.failed(key)


def run_experiment(
    experiment: Experiment,
    tracking_uri: str | None = None,
    address: str | None = None,
    fresh: bool = False,
    max_concurrent: int | None = None,
    storage_path: str = "ray_results",
    show_progress: bool = True,
    command: str = "",
    only: Sequence[GridTrial] | None = None,
    started_at: float | None = None,
) -> RunOutcome:
    """Run every trial of ``experiment`` (or of ``only``, a part of its grid) that has no finished run in the
    current generation. ``started_at``: the command's ``time.monotonic()`` start, for the progress view's clock."""
    trials = expand(experiment)
    tracker = Tracker(tracking_uri, experiment.name)
    generation = (None if fresh else tracker.latest_generation()) or uuid.uuid4().hex[:12]
    finished_before = tracker.finished_keys(generation)
    chosen = trials if only is None else list(only)
    todo = [t for t in chosen if t.key not in finished_before]
    outcome = RunOutcome(
        experiment.name, generation, None, skipped=len(chosen) - len(todo), total=len(chosen), ui_link=tracker.ui_link()
    )
    if not todo:
        return outcome
    started_ray = ensure_ray(address)  # an unreachable cluster fails here, in seconds, before a launch is recorded
    # Trials a killed launch left with a checkpoint continue from it.
    resume = {t.key: blob for t in todo if (blob := tracker.latest_checkpoint(generation, t.key)) is not None}
    commit = git_commit()
    grid = grid_document(experiment, trials)
    launch = tracker.start_launch(
        generation,
        name=f"{experiment.name} {time.strftime('%Y-%m-%d %H:%M:%S')}",
        tags={"mlflow.source.git.commit": commit, "ablate.command": command, "ablate.experiment_file": experiment.path},
        files={
            "experiment.toml": Path(experiment.path).read_text(),
            "grid.json": json.dumps(grid, indent=1),
            "environment.json": json.dumps(environment_document(), indent=1),
        },
    )
    outcome.launch_run_id = launch
    slots = max_concurrent or (None if address else max(int((os.cpu_count() or 1) / experiment.resources_per_trial), 1))
    view = ProgressView(experiment.name, todo, len(finished_before), show_progress, slots, started_at)
    outcome.view = view
    recorder = _Recorder(tracker, launch, generation, {t.key: t for t in todo}, commit, view, outcome)
    options = ClusterOptions(
        address,
        max_concurrent,
        experiment.resources_per_trial,
        getattr(experiment, "gpus_per_trial", 0.0),
        storage_path,
    )
    status = "FINISHED"
    try:
        with view:
            run_trials(todo, recorder, options, run_name=f"{experiment.name}-{launch[:8]}", resume=resume)
    except KeyboardInterrupt:
        outcome.interrupted = True
        outcome.killed = tracker.kill_open_trials()
        status = "KILLED"
    finally:
        tracker.finish_launch(
            launch,
            "FAILED" if outcome.failed and status == "FINISHED" else status,
            {"trials_finished": len(outcome.finished), "trials_failed": len(outcome.failed)},
        )
        if started_ray:
            stop_ray()
    return outcome


def cmd_run(args: argparse.Namespace, started_at: float | None = None) -> int:
    started_at = time.monotonic() if started_at is None else started_at
    experiment = load_experiment(args.experiment)
    chosen = select(expand(experiment), args.only, args.seeds)
    if args.max_concurrent is not None and args.max_concurrent < 1:
        raise ConfigError(f"--max-concurrent = {args.max_concurrent} is invalid; valid: an integer >= 1")
    command = " ".join(shlex.quote(a) for a in ["ablate", *sys.argv[1:]])
    try:
        outcome = run_experiment(
            experiment,
            tracking_uri=args.tracking_uri,
            address=args.address,
            fresh=args.fresh,
            max_concurrent=args.max_concurrent,
            show_progress=True,
            command=command,
            only=chosen,
            started_at=started_at,
        )
    except ClusterUnavailable as error:
        sys.stderr.write(f"ablate run: {error}\n")
        return 1
    total = outcome.total
    if outcome.interrupted:
        print(
            f"interrupted: {len(outcome.killed)} running trial(s) marked killed; "
            f"run the same command again to finish the remaining {total - len(outcome.finished) - outcome.skipped}"
        )
    elif outcome.launch_run_id is None:
        print(f"all {total} trials of {experiment.name} already finished; --fresh starts over")
    else:
        print(f"{len(outcome.finished)} finished, {len(outcome.failed)} failed, {outcome.skipped} finished before")
    for key, message in outcome.failed.items():
        print(f"  FAILED {key}: {message}")
    print(f"MLflow runs: {outcome.ui_link}   (start the UI with: make mlflow-ui)")
    if not outcome.interrupted and getattr(args, "report", True):
        from ablate.report import NoResults, terminal_summary, write_report

        try:
            with stage(f"writing the report into reports/{experiment.name}/") as report_s:
                folder = write_report(experiment.name, tracking_uri=args.tracking_uri, out_root=Path("reports"))
        except NoResults as error:  # every trial failed: say so, and leave the last good report in place
            print(f"no report: {error}")
            return outcome.exit_code
        print(terminal_summary(folder))
        pdf = " and report.pdf" if (folder / "report.pdf").is_file() else ""
        print(f"report: {folder}/report.md, report.html{pdf}")
    else:
        report_s = []
    report_seconds = report_s[0] if report_s else None
    print(outcome.view.total_line(report_seconds) if outcome.view else f"total {clock(time.monotonic() - started_at)}")
    return outcome.exit_code
