"""ablate.reporting.render and typeset: one document model, three renderings that agree. Every table and figure
has the same number and caption in report.md, report.html and report.typ; user text stays inert in HTML; no
renderer leaves a placeholder behind."""

import re

import pandas as pd

from ablate.reporting import render
from ablate.reporting.blocks import (
    AppendixStart,
    Authored,
    Heading,
    Item,
    Items,
    Note,
    Paragraph,
    Picture,
    Table,
    Videos,
    number_tables,
)
from ablate.reporting.figures import Figure
from ablate.reporting.text import esc
from ablate.reporting.typeset import typst

EVIL = "<img src=x onerror=alert(1)>"


def _document():
    frame = pd.DataFrame([{"variant": esc(EVIL), "seeds": 3}, {"variant": "b", "seeds": 4}])
    return number_tables(
        [
            Heading("Ablation report: x", 1),
            Note("**Changed** since the launch: <code>ablate run x --fresh</code>"),
            Heading("Claims", generated=True),
            Items.of([f"**{esc(EVIL)}** vs b: **undetermined**", Item("b:", ("one", "two"))]),
            Table(frame),
            Picture(Figure("figures/a.png", "Curves; see Figure 2.", "curves", 1)),
            Picture(Figure("figures/b.png", "Bands.", "bands", 2)),
            Heading("Discussion"),
            Authored("# Mine\n\nI *think* so."),
            AppendixStart(),
            Heading("Results", 3, True, "A"),
            Paragraph("**Returns.** IQM over seeds, `CartPole-v1`."),
            Table(frame, "Returns"),
            Videos(({"path": "videos/a.mp4", "caption": f"{EVIL}, seed 0"},)),
        ]
    )


def test_the_three_renderings_number_and_name_tables_and_figures_alike():
    blocks = _document()
    md, page, typ = render.markdown(blocks), render.html_body(blocks), typst(blocks)
    assert re.findall(r"\*Table (\d+)\. ([^*]+)\*", md) == [("1", "Claims"), ("2", "Returns")]
    assert re.findall(r"<caption><strong>Table (\d+)\.</strong> ([^<]+)</caption>", page) == [
        ("1", "Claims"),
        ("2", "Returns"),
    ]
    assert re.findall(r"kind: table\)\)\.update\((\d+)\)\n#figure\(kind: table, caption: \[#\"([^\"]+)\"", typ) == [
        ("0", "Claims"),
        ("1", "Returns"),
    ]
    assert re.findall(r"\*Figure (\d+)\. ", md) == ["1", "2"]
    assert re.findall(r'<figure id="figure-(\d+)">', page) == ["1", "2"]
    assert re.findall(r"kind: image\)\)\.update\((\d+)\)", typ) == ["0", "1"]
    for text in (md, page, typ):
        assert "FIGURE:" not in text and "PLACEHOLDER" not in text


def test_html_keeps_user_text_inert_and_writes_every_block():
    page = render.html_body(_document())
    assert "<img src=x" not in page and "&lt;img src=x onerror=alert(1)&gt;" in page
    assert "<blockquote><p><strong>Changed</strong> since the launch: <code>ablate run x --fresh</code>" in page
    assert "<li>b:<ul><li>one</li><li>two</li></ul></li>" in page
    assert '<td style="text-align: right">3</td>' in page and "<code>CartPole-v1</code>" in page
    assert "<h4>Mine</h4>" in page and "<em>think</em>" in page  # the student's "#" sits under "## Discussion"
    assert '<video controls muted loop preload="metadata" src="videos/a.mp4">' in page


def test_markdown_nests_sub_items_and_lists_videos_as_links():
    md = render.markdown(_document())
    assert "- b:\n    - one\n    - two" in md
    assert "#### Mine" in md and "### A. Results (generated)" in md and "## Appendix" in md
    assert "- [&lt;img src=x onerror=alert(1)&gt;, seed 0](videos/a.mp4)" in md
    assert render.markdown([Videos()]) == "No videos were recorded.\n"


def test_the_students_markdown_reads_as_commonmark_in_html_and_typst():
    """One parser (markdown-it) for both: a two-space nested list and a fenced block are the same structure in the
    HTML and the PDF, and a name in asterisks inside an italic line is italics, not stray stars."""
    text = "- two\n  - nested\n\n```\nablate run x\n  indented\n```\n"
    page, typ = render.html_body([Authored(text)]), typst([Authored(text)])
    assert "<li>two\n<ul>\n<li>nested</li>" in page and '  - #"nested"' in typ
    assert (
        "<pre><code>ablate run x\n  indented\n</code></pre>" in page
        and 'raw(block: true, "ablate run x\\n  indented")' in typ
    )
    line = "*Written by Ada *Lovelace*; printed as written.*"
    assert (
        render.html_body([Paragraph(line)]) == "<p><em>Written by Ada <em>Lovelace</em>; printed as written.</em></p>"
    )
    assert typst([Paragraph(line)]).endswith('#emph[#"Written by Ada "#emph[#"Lovelace"]#"; printed as written."]\n\n')
