"""The report as a hand-in: a body of about four printed pages (the question, the method in a paragraph, the
claims, two figures, the limitations that matter for this run, the student's discussion, the references), then
an appendix with everything else (every table, every comparison, the tuning, the glossary, the record)."""

from __future__ import annotations

import time
from pathlib import Path

from ablate.claims.family import CENSORED_SHARE
from ablate.design import ALPHA, CONFIDENCE, percent
from ablate.launch.secrets import shown_command
from ablate.measures import is_censored
from ablate.reporting.blocks import (
    AppendixStart,
    Authored,
    Block,
    Heading,
    Items,
    Note,
    Paragraph,
    Picture,
    Videos,
    number_tables,
    paragraphs,
)
from ablate.reporting.data import ReportData
from ablate.reporting.discussion import Discussion, missing_line
from ablate.reporting.figures import Figure
from ablate.reporting.findings import findings, summary
from ablate.reporting.glossary import GLOSSARY, references
from ablate.reporting.provenance import (
    _generation_note,
    _reproducibility,
    changed_file_note,
    earlier_note,
    missing_artifacts_note,
)
from ablate.reporting.results import Ablation
from ablate.reporting.rounds import rounds_section
from ablate.reporting.sections import (
    comparison_intro,
    convergence_blocks,
    limitations,
    method_blocks,
)
from ablate.reporting.text import Refs, _metric_name, esc
from ablate.reporting.tuning_sections import dependence_section, knob_words, tuning_section

BODY_FIGURES = (
    "learning_curves_episodes",
    "probability_of_improvement",
    "episodes_to_solve",
    "final_return",
    "learning_curves_by_variant",
)
"""The figures that carry the result, in order of preference: the body prints the first two there are."""

BODY_LIMITATIONS = ("seeds", "tuning", "shared", "capacity", "confound", "censoring", "threshold", "scope")
"""The limitations the body prints (the appendix has every one, wall-clock and videos too)."""

GENERATED = "(generated)"


def order_figures(figures: list[Figure]) -> list[Figure]:
    """The body's figures first (numbered 1 and 2), then the others in their usual order."""
    stems = [Path(f.path).stem for f in figures]
    body = [f for name in BODY_FIGURES for f, stem in zip(figures, stems, strict=True) if stem == name][:2]
    return body + [f for f in figures if f not in body]


def body_figures(figures: list[Figure]) -> list[Figure]:
    return [f for f in figures if f.number <= 2 and Path(f.path).stem in BODY_FIGURES]


def question(ablation: Ablation) -> str:
    others = [v for v in ablation.variants if v != ablation.baseline]
    # The claims' own metric (``Ablation.primary_metric``), and their rule for censored comparisons.
    primary = (
        "the area under the learning curve"
        if ablation.primary_metric == "auc"
        else _metric_name(ablation.primary_metric)
    )
    if is_censored(ablation.primary_metric):
        primary += (
            f" (a comparison with more than {CENSORED_SHARE:.0%} of its seeds unsolved at its first look: on the "
            "area under the learning curve)"
        )
    learns = (
        f"learns to reach a rolling mean return of {ablation.threshold:g}"
        if ablation.threshold is not None
        else "learns"
    )
    description = esc(ablation.grid.get("description") or "").strip()
    lead = (description if description[-1] in ".?!" else f"{description}.") + " " if description else ""
    varied = any(ablation.reference(v) != ablation.baseline for v in others)
    against = "its reference (the baseline, or the variant it extends)" if varied else esc(ablation.baseline)
    listed = ", ".join(esc(v) for v in others) or "none"
    return (
        f"{lead}Does each change to the baseline's settings change how fast REINFORCE {learns} on "
        f"`{esc(ablation.env_id)}`? {len(others)} variant{'s' if len(others) != 1 else ''} ({listed}) "
        f"{'are each' if len(others) != 1 else 'is'} compared with {against}, first on {primary}."
    )


def method_paragraph(ablation: Ablation, letters: dict[str, str]) -> str:
    base = ablation.grid["base"]
    fewest, most = ablation.seed_span
    seeds = (
        f"{most} seed{'s' if most != 1 else ''}"
        if fewest == most
        else f"{fewest} to {most} seeds"
        + (" (added in rounds while its primary comparison was open)" if ablation.launch.get("rounds") else "")
    )
    budget = int(base.get("max_episodes", 0))
    window = int(base.get("solve_window", 100))
    solve = (
        f"a trial is solved when its mean return over {window} consecutive episodes reaches {ablation.threshold:g}, "
        f"and stops then or after {budget:,} episodes"
        if ablation.threshold is not None
        else f"every trial runs {budget:,} episodes (no solve threshold)"
    )
    tuned = ""
    if ablation.tuning:
        tuning = ablation.tuning
        tuned = (
            f" Each variant's {knob_words(ablation).removeprefix('the ')} was chosen among "
            f"{max((len(c) for c in tuning.get('knobs', {}).values()), default=0)} candidates on "
            f"{len(tuning.get('seeds', []))} tuning seeds of its own, and the variants are compared at their chosen "
            "values on evaluation seeds tuning never saw (Patterson et al., 2024; Eimer et al., 2023)."
        )
    return (
        "REINFORCE (Williams, 1992), the vanilla policy gradient of the course's lab (MIT 6.S191, Lab 3), trains "
        f"each variant's policy from {seeds} on `{esc(ablation.env_id)}`: "
        f"{solve}. A variant changes only the knobs it names (Appendix {letters['method']}).{tuned} Every number "
        f"is over seeds: interquartile means with {percent(CONFIDENCE)} percentile bootstrap intervals (Agarwal et "
        "al., 2021); unsolved "
        "seeds count as the budget and make a statistic a bound (≥), never dropped. The primary claims are one family "
        f"at a family-wise {percent(ALPHA)}: a permutation test of the IQM difference per comparison, Holm's "
        "step-down, and "
        "*equivalent* by two one-sided tests within the smallest effect of interest (Good, 2005; Holm, 1979; "
        "Schuirmann, 1987); no claim is made where the seeds could not support one (Colas et al., 2019)."
    )


def _discussion(discussion: Discussion, where: str, launched_ms: int | None = None) -> list[Block]:
    if discussion.text is None:
        title = f"Discussion{f' — {esc(discussion.author)}' if discussion.author else ''}"
        return [Heading(title), Paragraph(missing_line(where))]
    author = esc(discussion.author or "the author (no Author line in discussion.md)")
    note = f"*Written by {author}; printed as written.*"
    if discussion.edited_ms is not None and launched_ms is not None and discussion.edited_ms < launched_ms:
        note = (
            f"*Written by {author}; printed as written. **Written about other data:** {esc(Path(where).name)} was "
            f"last saved {_when(discussion.edited_ms)}, before the launch of {_when(launched_ms)} whose trials this "
            "report shows; its numbers may not be these. Check them against the claims above, and save the file again.*"
        )
    return [Heading(f"Discussion — {author}"), Paragraph(note), Authored(discussion.text)]


def _when(ms: int) -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(ms / 1000))


def _videos_intro(ablation: Ablation, videos: list[dict[str, str]], letter: str) -> list[Block]:
    if not videos:
        return [Heading("Videos", 3, True, letter)]
    if ablation.profile.sampling_video:
        frames = int(ablation.grid["base"].get("video_max_frames", 500))
        return [
            Heading("Videos of the trained agent", 3, True, letter),
            Paragraph(
                "Each video is the trained policy sampling its actions, as in training, on a seed training never "
                f"used: up to {frames:,} frames ({frames / 30:.0f} s at 30 frames/s), for two seeds per variant chosen "
                "as the captions say. Not greedy: a Pong agent that has not learnt much holds one button for the whole "
                "video when it always takes its most likely action. Each trial's MLflow run also holds videos of it "
                "playing during training (`videos/`)."
            ),
        ]
    return [
        Heading("Videos of the greedy agent", 3, True, letter),
        Paragraph(
            "Each video is one greedy episode (the most likely action at every step) of a trained agent, for two "
            "seeds per variant chosen as the captions say."
        ),
    ]


def build_document(
    data: ReportData,
    figures: list[Figure],
    videos: list[dict[str, str]],
    discussion: Discussion | None = None,
    discussion_path: str = "discussion.md",
) -> list[Block]:
    """The report as blocks, from its data computed once (``data.ReportData``): the Claims section from
    ``data.claims``, the findings from ``data.comparisons``, the tables from ``data.convergence``. ``figures``
    are numbered (``order_figures``); every cross-reference and table number is resolved here."""
    ablation, table, compare, claimed = data.ablation, data.convergence, data.comparisons, data.claims
    command, untuned = data.command, data.untuned
    discussion = discussion or Discussion(None, None)
    failed = ablation.trials[ablation.trials.status.isin(["FAILED", "KILLED", "NOT RUN"])]
    tuned_dependence = bool(ablation.tuning and untuned is not None)
    appendix = ["method", "results", "comparisons"]
    appendix[1:1] = ["tuning"] if ablation.tuning else []
    appendix += ["dependence"] if tuned_dependence else []
    appendix += ["figures", "videos"] + (["failed"] if len(failed) else []) + ["limitations", "record", "glossary"]
    letters = {name: chr(ord("A") + i) for i, name in enumerate(appendix)}
    refs = Refs(letters, {Path(f.path).stem: f.number for f in figures})  # every cross-reference, resolved first
    for f in figures:
        f.resolve(refs)

    author = esc(discussion.author) if discussion.author and discussion.text else "the student"
    doc: list[Block] = [Heading(f"Ablation report: {esc(ablation.name)}", 1)]
    notes = (_generation_note(ablation), changed_file_note(ablation), earlier_note(ablation.earlier))
    doc += [Note(n) for n in notes if n]
    doc.append(
        Paragraph(
            f"*Every section marked {GENERATED} is written by ablate from the tracking store; the Discussion is "
            f"{author}'s own. The appendix holds every table and comparison.*"
        )
    )
    if len(failed):
        doc.append(
            Note(
                f"{len(failed):,} of {len(ablation.trials):,} trials did not finish (failed, killed or not run); "
                f"they are left out of the statistics and listed in Appendix {letters['failed']}."
            )
        )
    lost = missing_artifacts_note(ablation)
    doc += [Note(lost)] if lost else []
    doc += [Heading("Question", generated=True), Paragraph(question(ablation))]
    doc += [Heading("Method", generated=True), Paragraph(method_paragraph(ablation, letters))]
    doc += [Heading("Claims", generated=True), *summary(ablation, table, compare, claimed)]
    doc += paragraphs(" ".join(line for line in comparison_intro(ablation) if line))
    doc.append(
        Paragraph(
            f"Every comparison on every metric, with its interval: Appendix {letters['comparisons']}; every table: "
            f"Appendix {letters['results']}."
        )
    )
    shown = body_figures(figures)
    doc += [Heading("Figures", generated=True), *(Picture(f) for f in shown)] if shown else []
    kept = [
        text for kind, text in limitations(ablation, table, compare, bool(videos), refs) if kind in BODY_LIMITATIONS
    ]
    doc += [Heading("Limitations", generated=True), Items.of(kept)]
    doc += _discussion(discussion, discussion_path, ablation.launch.get("started_ms"))
    doc += [Heading("References"), Items.of(references(ablation))]

    doc += [AppendixStart(), Heading("Method in detail", 3, True, letters["method"])]
    doc += [*method_blocks(ablation, table, refs), *rounds_section(ablation.launch.get("rounds"))]
    if ablation.tuning:
        doc += [Heading("Tuning", 3, True, letters["tuning"]), *tuning_section(ablation, refs)]
    doc += [Heading("Results", 3, True, letters["results"]), *convergence_blocks(ablation, table)]
    doc.append(
        Paragraph(
            "Tables as CSV: tables/convergence.csv, tables/comparisons.csv, tables/trials.csv"
            + (", tables/tuning.csv." if ablation.tuning else ".")
        )
    )
    metrics = ", ".join(_metric_name(m) for m in dict.fromkeys(compare.metric) if isinstance(m, str))
    doc += [
        Heading("Every comparison", 3, True, letters["comparisons"]),
        Paragraph(
            " ".join(comparison_intro(ablation, full=True))
            + f", on {metrics}. Episodes: the relative change of the IQM; returns: the difference of the IQMs; each "
            f"with its {percent(CONFIDENCE)} interval, sized as a bound where censoring makes it one."
        ),
        *findings(ablation, table, compare),
    ]
    if tuned_dependence:
        title = f"Does the finding depend on {knob_words(ablation)}?"
        doc += [Heading(title, 3, True, letters["dependence"]), *dependence_section(ablation, compare, untuned)]
    rest = [f for f in figures if f not in shown]
    doc += [Heading("More figures", 3, True, letters["figures"])]
    doc += [Picture(f) for f in rest] or [Paragraph("No other figures.")]
    doc += [*_videos_intro(ablation, videos, letters["videos"]), Videos(tuple(videos))]
    if len(failed):
        doc += [
            Heading("Trials that did not finish", 3, True, letters["failed"]),
            Items.of(
                f"{esc(r.key)}: {r.status}{(' — ' + esc(r.error)) if isinstance(r.error, str) and r.error else ''}"
                for r in failed.itertuples()
            ),
        ]
    every = [text for _, text in limitations(ablation, table, compare, bool(videos), refs)]
    doc += [Heading("Every limitation", 3, True, letters["limitations"]), Items.of(every)]
    record = _reproducibility(ablation, command or shown_command(["ablate", "report", ablation.name]))
    doc += [Heading("Reproducibility", 3, True, letters["record"]), *record]
    doc += [
        Heading("Glossary", 3, letter=letters["glossary"]),
        Items.of(f"**{term}.** {text}" for term, text in GLOSSARY),
    ]
    return number_tables(doc)
