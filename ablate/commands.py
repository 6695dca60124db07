"""``ablate run`` as a command: signals, the launch, what it prints, then the report. The CLI's glue over the
launch layer (``run.runner``) and the report layer, which the launch layer itself must not import.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path

from ablate.config import ConfigError
from ablate.launch.clock import clock, stage
from ablate.launch.mlflow_store import ui_hint
from ablate.launch.plan import LaunchPlan
from ablate.launch.runner import raise_interrupted, run_plan, signals_received
from ablate.reporting.rounds import judge_for


def cmd_run(args: argparse.Namespace, plan: LaunchPlan) -> int:
    # SIGTERM (a supervisor, `kill`, a CI timeout) stops the launch as Ctrl-C does, with exit code 143 (the
    # shell's 128 + 15, so a supervisor sees which signal ended it). The scheduler keeps this handler across
    # ray.init, which would install one that exits mid-call and aborts in C++.
    previous = signal.signal(signal.SIGTERM, raise_interrupted)
    signals_received.clear()
    try:
        return _cmd_run(args, plan)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _cmd_run(args: argparse.Namespace, plan: LaunchPlan) -> int:
    experiment = plan.experiment
    if plan.max_concurrent is not None and plan.max_concurrent < 1:
        raise ConfigError(f"--max-concurrent = {plan.max_concurrent} is invalid; valid: an integer >= 1")
    if plan.population < 1:
        raise ConfigError(f"--population = {plan.population} is invalid; valid: an integer >= 1")
    try:
        outcome = run_plan(replace(plan, judge=judge_for(experiment, args.seeds)))
    except Exception as error:
        # The scheduler (and Ray) is only imported when trials run: its error class is known only then.
        scheduler = sys.modules.get("ablate.launch.scheduler")
        if scheduler is None or not isinstance(error, scheduler.ClusterUnavailable):
            raise
        sys.stderr.write(f"ablate run: {error}\n")
        return 1
    total = outcome.total
    if outcome.reaped:
        print(f"marked {outcome.reaped} run(s) KILLED that a launch which died had left RUNNING")
    if outcome.interrupted:
        print(
            f"interrupted: {len(outcome.killed)} running trial(s) marked killed ({outcome.signal_name}); "
            f"run the same command again to finish the remaining {total - len(outcome.finished) - outcome.skipped}"
        )
    elif outcome.error:
        print(
            f"the scheduler failed: {outcome.error}; {len(outcome.finished)} finished, {len(outcome.killed)} "
            "running trial(s) marked killed, launch recorded FAILED; run the same command again to finish the rest"
        )
    elif outcome.launch_run_id is None:
        print(f"all {total} trials of {experiment.name} already finished; --fresh starts over")
    else:
        print(f"{len(outcome.finished)} finished, {len(outcome.failed)} failed, {outcome.skipped} finished before")
    for key, message in outcome.failed.items():
        print(f"  FAILED {key}: {message}")
    print(f"MLflow, the variants compared: {outcome.ui_link}{ui_hint(outcome.ui_served)}")
    if not outcome.interrupted and not outcome.error and getattr(args, "report", True):
        from ablate.reporting.document import NoResults, build_report, terminal_summary  # after the trials: heavy

        try:
            with stage(f"writing the report into reports/{experiment.storage_name}/") as report_s:
                result = build_report(
                    experiment.name, tracking_uri=plan.tracking_uri, out_root=Path("reports"), command=plan.command
                )
        except NoResults as error:  # every trial failed: say so, and leave the last good report in place
            print(f"no report: {error}")
            return outcome.exit_code
        folder = result.folder
        print(terminal_summary(folder))
        print(f"report: {folder}/{result.written()}")
        if result.pdf_note:
            print(result.pdf_note)
    else:
        report_s = []
    report_seconds = report_s[0] if report_s else None
    if report_seconds is not None and outcome.launch_run_id:
        from ablate.launch.tracking import Tracker

        with contextlib.suppress(Exception):  # a courtesy for the next --dry-run: the report stands without it
            Tracker(plan.tracking_uri, experiment.name).record_report_time(outcome.launch_run_id, report_seconds)
    print(
        outcome.view.total_line(report_seconds)
        if outcome.view
        else f"total {clock(time.monotonic() - plan.started_at)}"
    )
    if outcome.view and (bounds := outcome.view.bounds_line()):
        print(bounds)  # which of the two figures the launch ended near
    return outcome.exit_code
