"""``ablate run`` and ``ablate report`` as commands: their arguments to ``ablate.api``, which does the work, and
what they print; ``run``'s signals.
"""

from __future__ import annotations

import argparse
import html
import re
import signal
import sys
import time
from pathlib import Path

from ablate.launch.clock import clock
from ablate.launch.mlflow_store import ui_hint
from ablate.launch.plan import LaunchPlan
from ablate.launch.runner import RunOutcome, raise_interrupted, signals_received
from ablate.launch.secrets import Shown, shown_command


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
    from ablate.api import launch

    try:
        outcome = launch(plan, args.seeds, args.report, said=_said)
    except Exception as error:
        # The scheduler (and Ray) is only imported when trials run: its error class is known only then.
        scheduler = sys.modules.get("ablate.launch.scheduler")
        if scheduler is None or not isinstance(error, scheduler.ClusterUnavailable):
            raise
        sys.stderr.write(f"ablate run: {error}\n")
        return 1
    if outcome.report_note:
        print(outcome.report_note)
        return outcome.exit_code
    if outcome.report:
        from ablate.reporting.document import terminal_summary  # after the trials: heavy

        print(terminal_summary(outcome.report.folder))
        print(f"report: {outcome.report.folder}/{outcome.report.written()}")
        if outcome.report.pdf_note:
            print(outcome.report.pdf_note)
    print(
        outcome.view.total_line(outcome.report_seconds)
        if outcome.view
        else f"total {clock(time.monotonic() - plan.started_at)}"
    )
    if outcome.view and (bounds := outcome.view.bounds_line()):
        print(bounds)  # which of the two figures the launch ended near
    return outcome.exit_code


def _said(outcome: RunOutcome) -> None:
    """What the launch did, as its trials end (before the report is written)."""
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
        print(f"all {total} trials of {outcome.experiment} already finished; --fresh starts over")
    else:
        print(f"{len(outcome.finished)} finished, {len(outcome.failed)} failed, {outcome.skipped} finished before")
    for key, message in outcome.failed.items():
        print(f"  FAILED {key}: {message}")
    print(f"MLflow, the variants compared: {outcome.ui_link}{ui_hint(outcome.ui_served)}")


def report_command(args: argparse.Namespace) -> Shown:
    """``ablate report`` as the user typed it: the experiment as given (``experiments/activations.toml``, not
    its name) and every option that was set, so the reproducibility record can be pasted back into a shell;
    masked (a password in ``--tracking-uri`` is ``***``)."""
    words = ["ablate", "report", args.experiment]
    for flag, value in (
        ("--generation", getattr(args, "generation", None)),
        ("--variants", getattr(args, "variants", None)),
        ("--baseline", getattr(args, "baseline", None)),
        ("--tracking-uri", getattr(args, "tracking_uri", None)),
        ("--out", None if Path(getattr(args, "out", "reports")) == Path("reports") else args.out),
    ):
        if value:
            words += [flag, str(value)]
    if not getattr(args, "pdf", True):
        words.append("--no-pdf")
    return shown_command(words)


def cmd_report(args: argparse.Namespace) -> int:
    """``ablate report``: exit 0 with the report written; 1 with nothing to report; 2 for bad input. Nothing
    is written (and no store created) unless the whole report could be built; finished trials whose files the
    store cannot give are a warning line, the report written from their tracked metrics (exit 0)."""
    from ablate.api import experiment_name
    from ablate.reporting.document import NoResults, build_report

    try:
        result = build_report(
            experiment_name(args.experiment),  # a bad file is a ConfigError: one line, exit 2
            args.tracking_uri,
            args.out,
            generation=getattr(args, "generation", None),
            variants=[v.strip() for v in args.variants.split(",") if v.strip()] if args.variants else None,
            baseline=getattr(args, "baseline", None),
            pdf=getattr(args, "pdf", True),
            command=report_command(args),
        )
    except NoResults as error:
        sys.stderr.write(f"ablate report: nothing to report: {error}; nothing written\n")
        return 1
    except OSError as error:  # a read-only or full reports folder: an environment problem, not a bug
        where = error.filename or args.out
        sys.stderr.write(f"ablate report: cannot write the report under {args.out}: {error.strerror} ({where})\n")
        return 1
    if result.missing_note:  # the report stands without them: a warning, exit 0
        sys.stderr.write(f"ablate report: {result.missing_note}\n")
    print(f"wrote {result.folder}/: {result.written()}")
    for note in (result.generation_note, result.file_note, result.pdf_note, result.attach_note):
        if note and note != "no PDF (--no-pdf)":
            print(re.sub(r"</?code>", "", html.unescape(note)))
    return 0
