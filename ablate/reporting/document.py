"""Write ``reports/<experiment>/``: report.md, a self-contained report.html, report.typ and the report.pdf typeset
from it (the ``typst`` wheel), figures, tables, videos.

Reads only from the tracking store (through ``results``), so it works from any machine that reaches it. A
report is built in a temporary folder and swapped in whole: a failed build never replaces a good report.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from ablate.config import ConfigError
from ablate.experiment import NAME_RULE, name_problem, storage_name
from ablate.launch.secrets import Shown, shown_command
from ablate.launch.variant_runs import log_variant_runs
from ablate.reporting import discussion, render
from ablate.reporting.data import ReportData, report_data
from ablate.reporting.figures import (
    figure_improvement,
    figure_observation,
    figure_overview,
    figure_parameters,
    figure_per_seed,
    figure_sensitivity,
    figure_small_multiples,
    figure_wallclock,
)
from ablate.reporting.layout import build_document, order_figures
from ablate.reporting.provenance import _generation_note, changed_file_note, missing_artifacts_line
from ablate.reporting.reader import RunReader
from ablate.reporting.results import Ablation, NoResults, load_ablation, select
from ablate.reporting.tables import meeting
from ablate.reporting.text import fmt
from ablate.reporting.typeset import compile_pdf as print_pdf
from ablate.reporting.typeset import page_counts, typst
from ablate.reporting.variant_records import variant_records


def _video_picks(ablation: Ablation, done: pd.DataFrame) -> list[tuple[pd.Series, str]]:
    """The best and the median seed, with why each was chosen."""
    if ablation.any_solved:
        ordered = done.sort_values(["censored_episodes", "final_rolling_mean"], ascending=[True, False])
        why_best, why_median = "fewest episodes to solve", "median seed by episodes to solve"
    else:
        ordered = done.sort_values(["auc"], ascending=False)
        why_best, why_median = "highest AUC", "median seed by AUC"
    picks = [(ordered.iloc[0], f"the seed with the {why_best} of {len(done)}")]
    median = ordered.iloc[(len(ordered) - 1) // 2]
    if median.run_id != picks[0][0].run_id:
        picks.append((median, f"the {why_median}"))
    return picks


def _videos(ablation: Ablation, tracker: RunReader, folder: Path) -> list[dict[str, str]]:
    chosen = []
    folder.mkdir(parents=True, exist_ok=True)
    lost = {key for _, key in ablation.missing}  # their artifact folder is gone: no video either
    for variant in ablation.variants:
        done = ablation.finished[(ablation.finished.variant == variant) & ~ablation.finished.key.isin(lost)]
        if done.empty:
            continue
        for row, why in _video_picks(ablation, done):
            safe = re.sub(r"[^A-Za-z0-9_.,=-]", "_", variant)
            target = folder / f"{safe}-seed{row.seed}.mp4"
            played = _video(tracker, row.run_id, target, f"{variant}, seed {row.seed}", row.greedy_return)
            if played is None:
                continue
            outcome = (
                f"solved at episode {int(row.episodes_to_solve)}"
                if row.solved == 1
                else f"not solved after {int(row.episodes_run)} episodes"
                if ablation.threshold is not None
                else f"{int(row.episodes_run)} episodes, final rolling return {row.final_rolling_mean:.1f}"
            )
            greedy = f"; greedy return {played:.0f} in this one episode" if not pd.isna(played) else ""
            caption = f"{variant}, seed {row.seed}: {why}; {outcome}{greedy}"
            chosen.append({"path": f"videos/{target.name}", "caption": caption})
    return chosen


def _video(tracker: RunReader, run_id: str, target: Path, which: str, recorded: float) -> float | None:
    """The trained policy's video of a run into ``target``: the run's own ``video.mp4`` (``ablate train``, or a
    launch before the report recorded them), else recorded now (``trial_files.replay_video``). Returns the greedy
    return the video played (``recorded``, the run's own, for its own video; NaN: none, as on Pong), or ``None``
    where there is no video: ``record_video = false``, or a network or env this machine cannot build (said on
    stderr)."""
    with contextlib.suppress(Exception):  # no video in the run: recorded from its weights below
        shutil.copyfile(tracker.download(run_id, "video.mp4"), target)
        return recorded
    try:
        settings = Path(tracker.download(run_id, "config.json"))
        if not json.loads(settings.read_text(encoding="utf-8")).get("record_video", True):
            return None
        weights = Path(tracker.download(run_id, "weights.pt"))
    except Exception:  # noqa: BLE001 - an older run without its config, or record_video = false
        return None
    from ablate.trial_files import replay_video  # torch, Gymnasium and ffmpeg: only where a video is recorded

    try:
        played = replay_video(settings, weights, target)
    except Exception as error:  # noqa: BLE001 - a user's env or network this machine cannot build: no video
        print(f"ablate report: no video of {which}: {type(error).__name__}: {error}", file=sys.stderr)
        target.unlink(missing_ok=True)
        return None
    return float("nan") if played is None else played


def report_folder(name: str, out_root: Path) -> Path:
    """``out_root/<the name's storage form>`` (``experiment.storage_name``), refusing a name no experiment could
    have (``experiment.name_problem``)."""
    problem = name_problem(name)
    if problem:
        raise ConfigError(f"experiment name {name!r} is invalid ({problem}); valid: {NAME_RULE}")
    folder = out_root / storage_name(name)
    if folder.resolve().parent != out_root.resolve():
        raise ConfigError(f"experiment name {name!r} is invalid: {folder} is outside {out_root}/")
    return folder


@dataclass
class ReportResult:
    folder: Path
    pdf_note: str | None
    """Why no PDF was written (None when it was)."""
    attach_note: str | None
    """Why the report was not attached to the launch run (None when it was)."""
    generation_note: str
    pages: tuple[int | None, int] | None = None
    """The PDF's (body, total) pages, where it was written."""
    missing_note: str = ""
    """What the store could not give and the report left out, in one line (``""`` when nothing)."""
    file_note: str = ""
    """Where the experiment file on disk differs from the launch's copy, the report's line saying so."""

    def written(self) -> str:
        """``report.md, report.html and report.pdf (9 pages: the body 3, the appendix 6)``: the files written."""
        if self.pdf_note is not None:
            return "report.md, report.html"
        if not self.pages:
            return "report.md, report.html and report.pdf"
        body, total = self.pages
        split = f": the body {body}, the appendix {total - body}" if body is not None else ""
        return f"report.md, report.html and report.pdf ({total} page{'s' if total != 1 else ''}{split})"


def build_report(
    name: str,
    tracking_uri: str | None = None,
    out_root: Path = Path("reports"),
    generation: str | None = None,
    variants: list[str] | None = None,
    baseline: str | None = None,
    pdf: bool = True,
    attach: bool = True,
    command: Shown | None = None,
) -> ReportResult:
    """Build the report of experiment ``name`` into ``out_root/name/``; with it, what the caller tells its user.
    Raises ``ConfigError`` (bad name, store, generation, variant) or ``NoResults`` before anything is written.
    ``command``: the report's own command line for its reproducibility record, masked (``secrets.shown_command``):
    the record takes no text as typed."""
    folder = report_folder(name, Path(out_root))
    ablation = select(load_ablation(name, tracking_uri, generation), variants, baseline)
    if ablation.finished.empty:
        raise NoResults(
            f"none of the {len(ablation.trials)} trials of generation "
            f"{ablation.launch['tags'].get('ablate.generation')}"
            " finished ("
            + ", ".join(
                f"{r.key}: {r.status} {r.error if isinstance(r.error, str) else ''}".strip()
                for r in ablation.trials.head(3).itertuples()
            )
            + (", ..." if len(ablation.trials) > 3 else "")
            + "); see the MLflow runs for their errors"
        )
    command = command or shown_command(["ablate", "report", name])
    Path(out_root).mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.new-", dir=out_root))
    staging.chmod(0o755)  # mkdtemp's 0700 would make the swapped-in report readable by its owner only
    try:
        tracker = RunReader(tracking_uri, name)
        pdf_note, data = _build(ablation, tracker, staging, pdf, command, discussion.read(folder), folder)
        discussion.keep(folder, staging)
        _swap(staging, folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    attach_note = _attach(tracker, ablation.launch["run_id"], folder, data) if attach else None
    pages = None
    if pdf_note is None:
        with contextlib.suppress(Exception):  # a count is a courtesy: the PDF stands without it
            pages = page_counts(folder / "report.typ")
    missing = missing_artifacts_line(ablation, tracker.shown_uri)
    return ReportResult(
        folder, pdf_note, attach_note, _generation_note(ablation), pages, missing, changed_file_note(ablation)
    )


def _attach(tracker: RunReader, launch_id: str, folder: Path, data: ReportData) -> str | None:
    """Attach the written report to its launch's run and replace the launch's variant runs (one per variant,
    ``launch.variant_runs``: MLflow's runs table and charts show the variants); why not, or None."""
    try:
        tracker.attach_report(launch_id, folder)
    except Exception as error:  # noqa: BLE001 - a read-only or remote store: the report on disk stands
        return f"not attached to the launch run: {str(error).splitlines()[0][:200]}"
    try:
        log_variant_runs(tracker, launch_id, variant_records(data))
    except Exception as error:  # noqa: BLE001 - as above: the report on disk and on the launch run stands
        return f"its variant runs were not written to the store: {str(error).splitlines()[0][:200]}"
    return None


def _swap(staging: Path, folder: Path) -> None:
    """Replace ``folder`` by ``staging`` with two renames, so a reader never sees a half-written report."""
    old = None
    if folder.exists():
        old = folder.parent / f".{folder.name}.old-{time.time_ns()}"
        folder.rename(old)
    staging.rename(folder)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _build(
    ablation: Ablation,
    tracker: RunReader,
    folder: Path,
    pdf: bool,
    command: Shown,
    written: discussion.Discussion,
    final: Path,
) -> tuple[str | None, ReportData]:
    """Write the report into ``folder`` (the staging folder that will become ``final``); why no PDF (or None),
    and the data it was written from."""
    for sub in ("figures", "tables", "videos"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    data = report_data(ablation, command)  # every table the report writes and words, computed once
    data.convergence.to_csv(folder / "tables" / "convergence.csv", index=False)  # one row per variant, budgets named
    # The tables ``ablate.load`` returns, as it returns them (``tables.meeting``: two ablations' tables concatenate).
    returned = {"claims": data.claims, "comparisons": data.comparisons, "trials": data.trials}
    for stem, frame in {**returned, "tuning": ablation.tuning_trials}.items():
        if frame is not None:
            meeting(frame, ablation).to_csv(folder / "tables" / f"{stem}.csv", index=False)
    table, compare = data.convergence, data.comparisons
    figures_folder = folder / "figures"
    candidates = [
        figure_overview(ablation, figures_folder),
        figure_small_multiples(ablation, figures_folder),
        figure_wallclock(ablation, figures_folder),
        figure_per_seed(ablation, figures_folder),
        figure_improvement(ablation, compare, figures_folder),
        figure_parameters(ablation, table, figures_folder),
        figure_sensitivity(ablation, figures_folder),
        figure_observation(ablation, tracker, figures_folder),
    ]
    figures = order_figures([f for f in candidates if f is not None])
    for number, figure in enumerate(figures, 1):
        figure.number = number
    videos = _videos(ablation, tracker, folder / "videos")
    blocks = build_document(data, figures, videos, written, str(final / discussion.FILE))
    (folder / "report.md").write_text(render.markdown(blocks))
    title = f"Ablation report: {ablation.name}"
    (folder / "report.html").write_text(render.html_page(blocks, title, folder))
    (folder / "report.typ").write_text(typst(blocks, folder, title, time.strftime("%Y-%m-%d")))
    if not pdf:
        return "no PDF (--no-pdf)", data
    return print_pdf(folder / "report.typ", folder / "report.pdf"), data


def terminal_summary(folder: Path) -> str:
    """The convergence table in a few lines, for the end of ``ablate run``."""
    path = folder / "tables" / "convergence.csv"
    if not path.is_file():
        return f"no report in {folder}"
    table = pd.read_csv(path)
    width = max([len("variant"), *(len(str(v)) for v in table.variant)])  # a grid's names run past 16 characters
    lines = [f"{'variant':<{width}} {'solved':>7} {'episodes to solve (median)':>26} {'final rolling mean (IQM)':>24}"]
    for row in table.itertuples():
        seeds = int(row.seeds_run) if not pd.isna(row.seeds_run) else 0
        if not seeds:
            lines.append(f"{row.variant:<{width}} no finished seeds")
            continue
        median = ("≥ " if row.median_censored else "") + fmt(row.episodes_median)
        solved = f"{int(row.solved)}/{seeds}"
        lines.append(f"{row.variant:<{width}} {solved:>7} {median:>26} {fmt(row.final_rolling_mean_iqm, 1):>24}")
    return "\n".join(lines)
