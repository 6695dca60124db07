"""ablate.reporting.typeset: the report's blocks -> Typst -> PDF with the typst wheel: text never read as markup,
tables and figures numbered as the blocks number them, wide tables in smaller type or on a landscape page, the
student's own Markdown typeset, page counts."""

import pandas as pd
import pytest

from ablate.reporting.blocks import AppendixStart, Authored, Heading, Items, Paragraph, Picture, Table, number_tables
from ablate.reporting.figures import Figure
from ablate.reporting.typeset import compile_pdf, inline, page_counts, string, typst

typst_wheel = pytest.importorskip("typst")

WIDE = pd.DataFrame([{f"column {i} with a long header": "1,234 [1,000, 2,000]" for i in range(12)}])
NARROW = pd.DataFrame([{"variant": "a", "solved": "3/3"}])


def test_text_is_printed_as_written_never_as_typst():
    evil = 'a #import "x.typ": * // not a comment $x$ <label> @ref [b] \\ "quoted"'
    assert inline(evil) == "#" + string(evil)
    source = typst([Heading("Title", 1), Paragraph(evil), Items.of([f"**{evil}**"]), Authored(evil)], title=evil)
    pdf = typst_wheel.compile(source.encode())  # a #import or an unclosed bracket would not compile
    assert pdf.startswith(b"%PDF")
    assert inline("**bold** and *it* and `code` and <code>x</code>") == (
        '#strong[#"bold"]#" and "#emph[#"it"]#" and "#raw("code")#" and "#raw("x")'
    )
    assert inline("course&#x27;s &lt;b&gt; &#124;") == '#"course\'s <b> |"'  # HTML entities decoded


def test_tables_carry_the_number_and_caption_the_blocks_give_them():
    blocks = number_tables([Heading("Results"), Table(NARROW, "Episodes to solve"), Heading("Other"), Table(NARROW)])
    source = typst(blocks)
    assert "counter(figure.where(kind: table)).update(0)" in source and "update(1)" in source
    assert 'caption: [#"Episodes to solve"]' in source and 'caption: [#"Other"]' in source


def test_wide_tables_get_smaller_type_or_a_landscape_page(tmp_path):
    narrow, wide = typst(number_tables([Table(NARROW)])), typst(number_tables([Table(WIDE)]))
    assert "size: 9pt" in narrow and "flipped: true" not in narrow
    assert "flipped: true" in wide and "size: 7pt" in wide
    path = tmp_path / "report.typ"
    blocks = [Heading("T", 1), Paragraph("body"), AppendixStart(), Heading("Tables", 3, letter="A"), Table(WIDE)]
    path.write_text(typst(number_tables(blocks)))
    assert compile_pdf(path, tmp_path / "report.pdf") is None
    assert page_counts(path) == (1, 3)  # the body; the appendix: its heading, then the table on a landscape page


def test_figures_keep_their_numbers_and_prefer_svg(tmp_path):
    (tmp_path / "figures").mkdir()
    png = bytes.fromhex(
        "89504e470d0a1a0a0000000d4948445200000001000000010806000000"
        "1f15c4890000000d49444154789c6360606060000000050001a5f645400000000049454e44ae426082"
    )
    (tmp_path / "figures" / "a.png").write_bytes(png)
    (tmp_path / "figures" / "b.png").write_bytes(png)
    (tmp_path / "figures" / "b.svg").write_text(
        '<svg xmlns="http://www.w3.org/2000/svg" width="10" height="10"><rect width="10" height="10"/></svg>'
    )
    pictures = [Picture(Figure("figures/a.png", "The third.", "a", 3)), Picture(Figure("figures/b.png", "4th", "b", 4))]
    source = typst(pictures, tmp_path)
    assert "counter(figure.where(kind: image)).update(2)" in source and "update(3)" in source
    assert '"figures/b.svg"' in source and '"figures/a.png"' in source
    (tmp_path / "report.typ").write_text(source)
    assert compile_pdf(tmp_path / "report.typ", tmp_path / "report.pdf") is None


def test_the_students_markdown_is_typeset_under_the_reports_heading():
    text = "# My reading\n\nThe *deep* net.\n\n| a | b |\n| :--- | ---: |\n| x | 1 |\n\n- one\n- two\n"
    source = typst([Heading("Discussion"), Authored(text)])
    assert '#heading(level: 3)[#"My reading"]' in source  # "#" under "## Discussion": two levels down
    assert '#emph[#"deep"]' in source and "table(columns: 2" in source and '- #"one"' in source
    assert "figure(kind: table" not in source  # the student's table is theirs: not numbered among the report's


def test_a_compile_error_is_one_line(tmp_path):
    path = tmp_path / "report.typ"
    path.write_text('#image("missing.png")\n')
    note = compile_pdf(path, tmp_path / "report.pdf")
    assert note.startswith("no PDF: typst could not compile report.typ: ") and "\n" not in note
