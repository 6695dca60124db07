"""Typeset the report as a paper: the report's blocks (``blocks.py``) become report.typ (Typst markup) and
report.pdf, compiled by the ``typst`` wheel (the Typst compiler with its fonts inside: no browser, no system package,
any machine pip reaches).

The only Markdown read here is the student's own ``discussion.md`` (headings, paragraphs, lists, pipe tables, images,
block quotes, fenced code). Every run of text becomes a Typst string literal, never markup, so no variant name or
sentence can be read as a Typst command.
"""

from __future__ import annotations

import html
import re
from pathlib import Path

from ablate.reporting.blocks import (
    INLINE,
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


def plain(text: str) -> str:
    """Markdown text with its HTML entities decoded and its markup removed: what a reader sees (for widths)."""
    text = re.sub(r"<[^>]+>", "", text)
    text = re.sub(r"\*\*|`", "", text)
    text = re.sub(r"\[([^\]]+)\]\([^)]+\)", r"\1", text)
    return html.unescape(text)


def inline(text: str) -> str:
    """One paragraph's Markdown (bold, italics, code, links) as Typst content; everything else as strings."""
    out, at = [], 0
    for match in INLINE.finditer(text):
        if match.start() > at:
            out.append("#" + string(html.unescape(text[at : match.start()])))
        if match.group("strong") is not None:
            out.append(f"#strong[{inline(match.group('strong'))}]")
        elif match.group("emph") is not None:
            out.append(f"#emph[{inline(match.group('emph'))}]")
        elif match.group("code") is not None or match.group("html_code") is not None:
            code = match.group("code") if match.group("code") is not None else match.group("html_code")
            out.append(f"#raw({string(html.unescape(code))})")
        elif match.group("label") is not None:
            out.append(f"#link({string(html.unescape(match.group('url')))})[{inline(match.group('label'))}]")
        else:
            out.append("#linebreak()")
        at = match.end()
    if at < len(text):
        out.append("#" + string(html.unescape(text[at:])))
    return "".join(out)


def _cells(line: str) -> list[str]:
    body = line.strip()
    body = body[1:] if body.startswith("|") else body
    body = body[:-1] if body.endswith("|") else body
    return [cell.strip() for cell in body.split("|")]


def table(header: list[str], rows: list[list[str]], align: list[str], caption: str = "", number: int = 0) -> str:
    """A table in type sized to its widest row (a landscape page past the last size); a numbered figure with its
    caption above it where it has a number, a bare table otherwise (one in the student's own text)."""
    rows = [row + [""] * (len(header) - len(row)) for row in rows]
    align = align + ["left"] * (len(header) - len(align))
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


def pipe_table(lines: list[str]) -> str:
    """A pipe table of the student's own Markdown, unnumbered."""
    header, rule, rows = _cells(lines[0]), _cells(lines[1]), [_cells(line) for line in lines[2:]]
    align = ["right" if cell.endswith(":") and not cell.startswith(":") else "left" for cell in rule]
    return table(header, rows, align)


IMAGE = re.compile(r"^!\[(?P<alt>[^\]]*)\]\((?P<path>[^)\s]+)\)$")


def image(path: str, folder: Path | None, alt: str) -> str:
    """The figure's vector form where the report wrote one (``figures/x.svg`` beside ``x.png``)."""
    if folder is not None and path.endswith(".png") and (folder / path).with_suffix(".svg").is_file():
        path = path[: -len(".png")] + ".svg"
    return f"image({string(path)}, width: 82%, alt: {string(plain(alt))})"


def markdown_blocks(markdown: str) -> list[tuple[str, list[str]]]:
    """The student's Markdown as (kind, lines) blocks: heading, table, list, quote, code, image, paragraph, comment."""
    out: list[tuple[str, list[str]]] = []
    lines = markdown.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        if line.startswith("```"):
            end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), len(lines))
            out.append(("code", lines[i + 1 : end]))
            i = end + 1
            continue
        if line.lstrip().startswith("<!--"):
            end = next((j for j in range(i, len(lines)) if "-->" in lines[j]), len(lines) - 1)
            out.append(("comment", lines[i : end + 1]))
            i = end + 1
            continue
        if re.match(r"^#{1,6} ", line):
            out.append(("heading", [line]))
            i += 1
            continue
        kind = (
            "table"
            if line.lstrip().startswith("|")
            else "list"
            if re.match(r"^\s*([-*+]|\d+\.) ", line)
            else "quote"
            if line.startswith(">")
            else "image"
            if IMAGE.match(line.strip())
            else "paragraph"
        )
        if kind == "image":
            out.append(("image", [line.strip()]))
            i += 1
            continue
        group = [line]
        i += 1
        while i < len(lines) and lines[i].strip() and not re.match(r"^#{1,6} |```", lines[i]):
            following = lines[i]
            if kind == "table" and not following.lstrip().startswith("|"):
                break
            if kind == "paragraph" and (following.lstrip().startswith(("|", ">")) or IMAGE.match(following.strip())):
                break
            if kind == "paragraph" and re.match(r"^\s*([-*+]|\d+\.) ", following):
                break
            group.append(following)
            i += 1
        out.append((kind, group))
    return out


def list_items(lines: list[str]) -> str:
    items: list[tuple[int, str, str]] = []
    for line in lines:
        found = re.match(r"^(\s*)([-*+]|\d+\.) (.*)$", line)
        if found:
            depth = len(found.group(1).replace("\t", "    ")) // 2
            items.append((depth, "+" if found.group(2)[0].isdigit() else "-", found.group(3)))
        elif items:
            depth, marker, text = items[-1]
            items[-1] = (depth, marker, f"{text} {line.strip()}")
    levels = sorted({depth for depth, _, _ in items})
    return "\n".join(f"{'  ' * levels.index(d)}{marker} {inline(text)}" for d, marker, text in items) + "\n"


def authored(markdown: str, folder: Path | None = None) -> str:
    """The student's own Markdown (the discussion) as Typst: headings, paragraphs, lists, pipe tables, images, block
    quotes and fenced code; anything else as plain text."""
    out = []
    for kind, lines in markdown_blocks(markdown):
        if kind == "comment":
            continue
        if kind == "heading":
            hashes, text = lines[0].split(" ", 1)
            out.append(f"#heading(level: {max(len(hashes) - 1, 1)})[{inline(text)}]\n")
        elif kind == "image":
            found = IMAGE.match(lines[0])
            out.append(f"#align(center, {image(found.group('path'), folder, found.group('alt'))})\n")
        elif kind == "table":
            out.append(pipe_table(lines) if len(lines) >= 2 else f"{inline(lines[0])}\n")
        elif kind == "list":
            out.append(list_items(lines))
        elif kind == "quote":
            out.append(_quote(" ".join(re.sub(r"^>\s?", "", line) for line in lines)))
        elif kind == "code":
            code = string("\n".join(lines), lines=True)
            out.append(f"#block(fill: luma(245), inset: 6pt, width: 100%, raw(block: true, {code}))\n")
        else:
            out.append(inline(" ".join(line.strip() for line in lines)) + "\n")
        out.append("\n")
    return "".join(out)


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
        lines = []
        for item in block.items:
            lines.append(f"- {inline(item.text)}")
            lines += [f"  - {inline(sub)}" for sub in item.sub]
        return "\n".join(lines) + "\n"
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
        return authored(nested(block.text, 3), folder)
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
