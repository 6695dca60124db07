"""The report as a hand-in: a body of about four printed pages, then an appendix with everything else (the order:
``build_document`` and docs/design.md's layout row)."""

from __future__ import annotations

import time
from pathlib import Path

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
)
from ablate.reporting.data import ReportData
from ablate.reporting.discussion import Discussion
from ablate.reporting.figures import Figure
from ablate.reporting.findings import findings, summary
from ablate.reporting.glossary import GLOSSARY, references
from ablate.reporting.prose import say
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
from ablate.reporting.text import Refs, esc
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


def question(ablation: Ablation) -> str:
    others = [v for v in ablation.variants if v != ablation.baseline]
    return say(
        "layout.question",
        description=ablation.grid.get("description") or "",
        env=ablation.env_id,
        threshold=ablation.threshold,
        others=others,
        varied=any(ablation.reference(v) != ablation.baseline for v in others),
        baseline=ablation.baseline,
        primary_metric=ablation.primary_metric,
        censored=is_censored(ablation.primary_metric),
    )


def method_paragraph(ablation: Ablation, letters: dict[str, str]) -> str:
    base, tuning = ablation.grid["base"], ablation.tuning or {}
    fewest, most = ablation.seed_span
    return say(
        "layout.method",
        env=ablation.env_id,
        fewest=fewest,
        most=most,
        rounds=bool(ablation.launch.get("rounds")),
        threshold=ablation.threshold,
        window=int(base.get("solve_window", 100)),
        budget=int(base.get("max_episodes", 0)),
        appendix=f"Appendix {letters['method']}",
        knobs=knob_words(ablation).removeprefix("the ") if ablation.tuning else None,
        candidates=max((len(c) for c in tuning.get("knobs", {}).values()), default=0),
        tuning_seeds=len(tuning.get("seeds", [])),
    )


def _discussion(discussion: Discussion, where: str, launched_ms: int | None = None) -> list[Block]:
    if discussion.text is None:
        title = f"Discussion{f' — {esc(discussion.author)}' if discussion.author else ''}"
        return [Heading(title), Paragraph(say("layout.discussion_missing", path=where))]
    author = esc(discussion.author or "the author (no Author line in discussion.md)")
    edited = discussion.edited_ms
    stale = edited is not None and launched_ms is not None and edited < launched_ms
    note = say(
        "layout.discussion_note",
        author=author,
        stale_file=Path(where).name if stale else None,
        saved=_when(edited) if stale else None,
        launched=_when(launched_ms) if stale else None,
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
            Paragraph(say("layout.sampling_videos", frames=frames)),
        ]
    return [Heading("Videos of the greedy agent", 3, True, letter), Paragraph(say("layout.greedy_videos"))]


def build_document(
    data: ReportData,
    figures: list[Figure],
    videos: list[dict[str, str]],
    discussion: Discussion,
    discussion_path: str,
) -> list[Block]:
    """The report as blocks, from its data computed once (``data.ReportData``): the Claims section from
    ``data.claims``, the findings from ``data.comparisons``, the tables from ``data.convergence``. ``figures``
    are numbered (``order_figures``); every cross-reference and table number is resolved here."""
    ablation, table, compare, claimed = data.ablation, data.convergence, data.comparisons, data.claims
    command, untuned = data.command, data.untuned
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
    doc.append(Paragraph(say("layout.authorship", marked=GENERATED, author=author)))
    if len(failed):
        appendix = refs.appendix("failed")
        doc.append(Note(say("layout.unfinished", failed=len(failed), trials=len(ablation.trials), appendix=appendix)))
    lost = missing_artifacts_note(ablation)
    doc += [Note(lost)] if lost else []
    doc += [Heading("Question", generated=True), Paragraph(question(ablation))]
    doc += [Heading("Method", generated=True), Paragraph(method_paragraph(ablation, letters))]
    doc += [Heading("Claims", generated=True), *summary(ablation, table, compare, claimed)]
    opening = " ".join(line for line in comparison_intro(ablation) if line)
    doc += [Paragraph(opening)] if opening else []
    see = say("layout.see_appendix", comparisons=refs.appendix("comparisons"), results=refs.appendix("results"))
    doc.append(Paragraph(see))
    shown = [f for f in figures if f.number <= 2 and Path(f.path).stem in BODY_FIGURES]
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
    doc.append(Paragraph(say("layout.tables_as_csv", tuned=bool(ablation.tuning))))
    metrics = [m for m in dict.fromkeys(compare.metric) if isinstance(m, str)]
    intro = " ".join(comparison_intro(ablation, full=True))
    doc += [
        Heading("Every comparison", 3, True, letters["comparisons"]),
        Paragraph(say("layout.every_comparison", intro=intro, metrics=metrics)),
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
    doc += [Heading("Reproducibility", 3, True, letters["record"]), *_reproducibility(ablation, command)]
    doc += [Heading("Glossary", 3, letter=letters["glossary"]), Items.of(GLOSSARY)]
    return number_tables(doc)
