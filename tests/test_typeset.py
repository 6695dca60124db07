"""ablate.reporting.typeset: report.md -> Typst -> PDF with the typst wheel: text never read as markup, tables and
figures numbered as the Markdown numbers them, wide tables in smaller type or on a landscape page, page counts."""

import pytest

from ablate.reporting.typeset import compile_pdf, inline, number_tables, page_counts, string, to_typst

typst = pytest.importorskip("typst")

WIDE = "| " + " | ".join(f"column {i} with a long header" for i in range(12)) + " |\n"
WIDE += "| " + " | ".join(["---:"] * 12) + " |\n" + "| " + " | ".join(["1,234 [1,000, 2,000]"] * 12) + " |\n"
NARROW = "| variant | solved |\n| :--- | ---: |\n| a | 3/3 |\n"


def test_text_is_printed_as_written_never_as_typst():
    evil = 'a #import "x.typ": * // not a comment $x$ <label> @ref [b] \\ "quoted"'
    assert inline(evil) == "#" + string(evil)
    source = to_typst(f"# Title\n\n{evil}\n\n- **{evil}**\n", title=evil)
    pdf = typst.compile(source.encode())  # a #import or an unclosed bracket would not compile
    assert pdf.startswith(b"%PDF")
    assert inline("**bold** and *it* and `code` and <code>x</code>") == (
        '#strong[#"bold"]#" and "#emph[#"it"]#" and "#raw("code")#" and "#raw("x")'
    )
    assert inline("course&#x27;s &lt;b&gt; &#124;") == '#"course\'s <b> |"'  # HTML entities decoded


def test_tables_are_numbered_and_captioned_from_their_lead_in():
    text = number_tables(f"## Results\n\n**Episodes to solve.** Unsolved seeds ...\n\n{NARROW}\n## Other\n\n{NARROW}")
    assert "*Table 1. Episodes to solve*\n\n| variant" in text and "*Table 2. Other*\n\n| variant" in text
    source = to_typst(text)
    assert "counter(figure.where(kind: table)).update(0)" in source and "update(1)" in source
    assert 'caption: [#"Episodes to solve"]' in source


def test_wide_tables_get_smaller_type_or_a_landscape_page(tmp_path):
    narrow, wide = to_typst(number_tables(NARROW)), to_typst(number_tables(WIDE))
    assert "size: 9pt" in narrow and "flipped: true" not in narrow
    assert "flipped: true" in wide and "size: 7pt" in wide
    path = tmp_path / "report.typ"
    path.write_text(to_typst("# T\n\nbody\n\n## Appendix\n\n### A. Tables\n\n" + number_tables(WIDE)))
    assert compile_pdf(path, tmp_path / "report.pdf") is None
    assert page_counts(path) == (1, 3)  # the body; the appendix: its heading, then the table on a landscape page


def test_figures_keep_their_markdown_numbers_and_prefer_svg(tmp_path):
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
    text = "![a](figures/a.png)\n\n*Figure 3. The third.*\n\n![b](figures/b.png)\n\n*Figure 4. The fourth.*\n"
    source = to_typst(text, tmp_path)
    assert "counter(figure.where(kind: image)).update(2)" in source and "update(3)" in source
    assert '"figures/b.svg"' in source and '"figures/a.png"' in source
    (tmp_path / "report.typ").write_text(source)
    assert compile_pdf(tmp_path / "report.typ", tmp_path / "report.pdf") is None


def test_a_compile_error_is_one_line(tmp_path):
    path = tmp_path / "report.typ"
    path.write_text('#image("missing.png")\n')
    note = compile_pdf(path, tmp_path / "report.pdf")
    assert note.startswith("no PDF: typst could not compile report.typ: ") and "\n" not in note
