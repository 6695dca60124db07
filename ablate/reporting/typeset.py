"""Typeset the report as a paper: the report's blocks (``blocks.py``) become report.typ (Typst markup) and
report.pdf, compiled by the ``typst`` wheel (why that wheel: docs/design.md).

Markdown (a block's inline markup, the student's own ``discussion.md``) is read by markdown-it (``blocks.MARKUP``)
and its syntax tree written as Typst. Every run of text becomes a Typst string literal, never markup, so no variant
name or sentence can be read as a Typst command.
"""

from __future__ import annotations

from pathlib import Path

from markdown_it.tree import SyntaxTreeNode

from ablate.reporting.blocks import (
    MARKUP,
    OWN_TAGS,
    AppendixStart,
    Authored,
    Block,
    Heading,
    Items,
    Note,
    Paragraph,
    Picture,
    Table,
    Videos,
    inline_nodes,
)
from ablate.reporting.render import NO_VIDEOS, nested
from ablate.reporting.text import esc

PREAMBLE = """\
#set document(title: {title})
#set page(paper: "a4", margin: (x: 2.2cm, top: 2.2cm, bottom: 2.4cm), numbering: "1 / 1",
  header: context if counter(page).get().first() > 1 [#set text(size: 8pt, fill: luma(90)); #{title} #h(1fr) #{date}])
#set text(font: ("Libertinus Serif", "New Computer Modern", "DejaVu Sans Mono"), size: 10.5pt, lang: "en")
#set par(justify: true, leading: 0.62em, spacing: 1.0em)
#set heading(numbering: "1.")
#show heading: set block(above: 1.3em, below: 0.7em)
#show heading.where(level: 1): set text(size: 13pt)
#show heading.where(level: 2): set text(size: 11.5pt)
#show raw: set text(font: "DejaVu Sans Mono", size: 0.85em)
#show link: set text(fill: rgb("#1a4d8f"))
#set figure(gap: 0.6em)
#set figure.caption(separator: [. ])
#show figure.caption: set text(size: 9pt)
#show figure.caption: set align(left)
#show figure.where(kind: table): set figure.caption(position: top)
#show figure.where(kind: table): set block(breakable: true)
#set table(stroke: none, inset: (x: 4pt, y: 3pt))
#set list(indent: 0.8em)
#context [#metadata(counter(page).final().first()) <page-count>]
"""

# Tables: the widest row in characters picks the type size; past the last step a table gets a landscape page.
TABLE_SIZES = ((95, "9pt"), (130, "8pt"), (175, "7pt"), (230, "6.5pt"))
LANDSCAPE_SIZE = "7pt"


def string(text: str, lines: bool = False) -> str:
    """``text`` as a Typst string literal: printed as is, whatever it holds (its line breaks kept with ``lines``)."""
    text = text.replace("\\", "\\\\").replace('"', '\\"').replace("\t", "    ")
    return '"' + text.replace("\n", "\\n" if lines else " ") + '"'


def _seen(node: SyntaxTreeNode) -> str:
    """What a reader sees of an inline node: its text without markup."""
    if node.type in ("softbreak", "hardbreak"):
        return " "
    if node.type == "html_inline":
        return "" if OWN_TAGS.fullmatch(node.content) else node.content
    return "".join(map(_seen, node.children)) if node.children else node.content


def _source(node: SyntaxTreeNode) -> str:
    """An inline node as written, its emphasis marks kept (the text of a ``<code>``)."""
    if node.type in ("strong", "em"):
        return node.markup + "".join(map(_source, node.children)) + node.markup
    return _seen(node)


def plain(text: str) -> str:
    """A block's text as a reader sees it, markup removed and entities decoded (for widths)."""
    return "".join(map(_seen, inline_nodes(text)))


def _inline(nodes: list[SyntaxTreeNode]) -> str:
    out: list[str] = []
    text: list[str] = []  # the run of plain text not yet written
    code: list[str] | None = None  # the text of an open <code>
    for node in nodes:
        tag = OWN_TAGS.fullmatch(node.content) if node.type == "html_inline" else None
        if code is not None and not (tag and node.content == "</code>"):
            code.append(_source(node))
            continue
        if node.type not in ("strong", "em", "link", "code_inline", "hardbreak") and not tag:
            text.append(_seen(node))
            continue
        out += _run(text)
        text = []
        if node.type == "strong":
            out.append(f"#strong[{_inline(node.children)}]")
        elif node.type == "em":
            out.append(f"#emph[{_inline(node.children)}]")
        elif node.type == "link":
            out.append(f"#link({string(node.attrs['href'])})[{_inline(node.children)}]")
        elif node.type == "code_inline":
            out.append(f"#raw({string(node.content)})")
        elif node.content == "<code>":
            code = []
        elif node.content == "</code>":
            out.append(f"#raw({string(''.join(code or []))})")
            code = None
        else:
            out.append("#linebreak()")
    return "".join(out + _run(text))


def _run(text: list[str]) -> list[str]:
    joined = "".join(text)
    return ["#" + string(joined)] if joined else []


def inline(text: str) -> str:
    """One block's text (bold, italics, code, links) as Typst content; everything else as strings."""
    return _inline(inline_nodes(text))


def table(header: list[str], rows: list[list[str]], align: list[str], caption: str = "", number: int = 0) -> str:
    """A table in type sized to its widest row (a landscape page past the last size); a numbered figure with its
    caption above it where it has a number, a bare table otherwise (one in the student's own text)."""
    widths = [max(len(plain(row[i])) for row in [header, *rows]) for i in range(len(header))]
    # A column's share of the width: its longest cell, capped so one long text column cannot starve the rest.
    total = sum(min(w, 60) for w in widths) + 3 * len(widths)
    size = next((s for limit, s in TABLE_SIZES if total <= limit), None)
    landscape = size is None
    size = size or LANDSCAPE_SIZE
    cells = [", ".join(f"[{inline(cell)}]" for cell in row) for row in rows]
    body = (
        f"table(columns: {len(header)}, align: ({', '.join(align)},),\n"
        "  table.hline(stroke: 0.8pt),\n"
        f"  table.header({', '.join(f'[*{inline(cell)}*]' for cell in header)}),\n"
        "  table.hline(stroke: 0.5pt),\n" + "".join(f"  {row},\n" for row in cells) + "  table.hline(stroke: 0.8pt),\n)"
    )
    sized = f"{{set text(size: {size}); set par(justify: false); {body}}}"
    if number:
        figure = (
            f"#counter(figure.where(kind: table)).update({number - 1})\n"
            f"#figure(kind: table, caption: [{inline(caption)}], {sized})\n"
        )
    else:
        figure = f"#{sized}\n"
    return f"#page(flipped: true)[\n{figure}]\n" if landscape else figure


def image(path: str, folder: Path | None, alt: str) -> str:
    """The figure's vector form where the report wrote one (``figures/x.svg`` beside ``x.png``)."""
    if folder is not None and path.endswith(".png") and (folder / path).with_suffix(".svg").is_file():
        path = path[: -len(".png")] + ".svg"
    return f"image({string(path)}, width: 82%, alt: {string(plain(alt))})"


def _text_of(node: SyntaxTreeNode) -> str:
    """The Markdown source of a list item's or a quote's paragraphs, one line."""
    return " ".join(c.children[0].content for c in node.children if c.type == "paragraph")


def _list(node: SyntaxTreeNode, depth: int = 0) -> list[str]:
    marker = "+" if node.type == "ordered_list" else "-"
    lines = []
    for item in node.children:
        lines.append(f"{'  ' * depth}{marker} {inline(_text_of(item))}")
        for sub in item.children:
            if sub.type in ("bullet_list", "ordered_list"):
                lines += _list(sub, depth + 1)
    return lines


def _pipe_table(node: SyntaxTreeNode) -> str:
    """A pipe table of the student's own Markdown, unnumbered."""
    rows = [
        [cell.children[0].content if cell.children else "" for cell in row.children]
        for part in node.children
        for row in part.children
    ]
    first = node.children[0].children[0].children
    align = ["right" if "right" in cell.attrs.get("style", "") else "left" for cell in first]
    return table(rows[0], rows[1:], align)


def _authored(node: SyntaxTreeNode, folder: Path | None) -> str:
    """A block of the student's own Markdown (the discussion) as Typst: a heading, paragraph, list, pipe table,
    image, block quote, fenced code or rule; other HTML than a comment as plain text."""
    if node.type == "heading":
        return f"#heading(level: {max(int(node.tag[1:]) - 1, 1)})[{_inline(node.children[0].children)}]\n"
    if node.type == "paragraph":
        nodes = node.children[0].children
        if len(nodes) == 1 and nodes[0].type == "image":
            return f"#align(center, {image(nodes[0].attrs['src'], folder, nodes[0].content)})\n"
        return _inline(nodes) + "\n"
    if node.type in ("bullet_list", "ordered_list"):
        return "\n".join(_list(node)) + "\n"
    if node.type == "table":
        return _pipe_table(node)
    if node.type == "blockquote":
        return _quote(_text_of(node))
    if node.type in ("fence", "code_block"):
        code = string(node.content.removesuffix("\n"), lines=True)
        return f"#block(fill: luma(245), inset: 6pt, width: 100%, raw(block: true, {code}))\n"
    if node.type == "hr":
        return "#line(length: 100%)\n"
    return "" if node.content.lstrip().startswith("<!--") else "#" + string(node.content.strip()) + "\n"


def _quote(text: str) -> str:
    return (
        f'#block(fill: rgb("#fff4e0"), stroke: (left: 3pt + rgb("#f0a000")), inset: 8pt, width: 100%)[{inline(text)}]\n'
    )


def _block(block: Block, folder: Path | None) -> str:
    if isinstance(block, Heading):
        if block.level == 1:
            return f'#align(center, text(size: 17pt, weight: "bold")[{inline(block.text)}])\n'
        return f"#heading(level: {block.level - 1})[{inline(block.text)}]\n"
    if isinstance(block, AppendixStart):
        return (
            "#pagebreak(weak: true)\n#set heading(numbering: none)\n"
            "#context [#metadata(here().page()) <appendix-page>]\n#heading(level: 1)[Appendix]\n"
        )
    if isinstance(block, Paragraph):
        return inline(block.text) + "\n"
    if isinstance(block, Note):
        return _quote(block.text)
    if isinstance(block, Items):
        return block.lines("  ", inline) + "\n"
    if isinstance(block, Table):
        return table(block.header, block.rows, block.align, block.caption or "", block.number)
    if isinstance(block, Picture):
        f = block.figure
        return (
            f"#counter(figure.where(kind: image)).update({f.number - 1})\n"
            f"#figure({image(f.path, folder, f.alt)}, caption: [{inline(f.caption)}])\n"
        )
    if isinstance(block, Videos):
        listed = [f"- #link({string(v['path'])})[{inline(esc(v['caption']))}]" for v in block.videos]
        return "\n".join(listed) + "\n" if listed else inline(NO_VIDEOS) + "\n"
    if isinstance(block, Authored):
        typeset = (_authored(node, folder) for node in SyntaxTreeNode(MARKUP.parse(nested(block.text, 3))).children)
        return "".join(f"{text}\n" for text in typeset if text)
    raise TypeError(f"not a report block: {block!r}")


def typst(blocks: list[Block], folder: Path | None = None, title: str = "Report", date: str = "") -> str:
    """The report's blocks as a Typst document: numbered sections, figures and tables (the numbers the blocks
    carry), page numbers, wide tables in smaller type or on a landscape page; the appendix starts a new page and
    its sections carry their own letters."""
    out = [PREAMBLE.format(title=string(title), date=string(date))]
    for block in blocks:
        out += [_block(block, folder), "\n"]
    return "".join(out)


def compile_pdf(typ_path: Path, pdf_path: Path) -> str | None:
    """Compile ``typ_path`` into ``pdf_path``; the reason it could not, in one line, or None."""
    try:
        import typst
    except ImportError:
        return "no PDF: the typst package is missing (pip install typst, or make setup)"
    try:
        typst.compile(str(typ_path), output=str(pdf_path), root=str(typ_path.parent))
    except Exception as error:  # noqa: BLE001 - the compiler's own message, first line, is the reason
        return f"no PDF: typst could not compile {typ_path.name}: {str(error).strip().splitlines()[0][:300]}"
    if not pdf_path.is_file() or pdf_path.stat().st_size == 0:
        return "no PDF: typst wrote nothing"
    return None


def page_counts(typ_path: Path) -> tuple[int | None, int]:
    """(the pages before the appendix, all pages) of the typeset report, as the compiler laid them out; the first
    is None for a document without an appendix."""
    import typst

    def value(label: str) -> int:
        return int(typst.query(str(typ_path), label, field="value", one=True, root=str(typ_path.parent)))

    total = value("<page-count>")
    try:
        appendix = value("<appendix-page>")
    except Exception:  # noqa: BLE001 - no appendix in this document
        return None, total
    return appendix - 1, total
