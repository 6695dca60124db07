"""Typeset the report as a paper: report.md's text becomes report.typ (Typst markup) and report.pdf, compiled by
the ``typst`` wheel (the Typst compiler with its fonts inside: no browser, no system package, any machine pip reaches).

Only the Markdown the report writes is read (headings, paragraphs, lists, pipe tables, figures, block quotes, fenced
code) plus whatever a student writes in ``discussion.md``; anything else is printed as plain text, never as markup:
every run of text becomes a Typst string literal, so no variant name or sentence can be read as a Typst command.
"""

from __future__ import annotations

import html
import re
from dataclasses import dataclass, field
from pathlib import Path

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


INLINE = re.compile(
    r"\*\*(?P<strong>.+?)\*\*"
    r"|(?<![\w*])\*(?P<emph>[^*\s](?:[^*]*[^*\s])?)\*(?![\w*])"
    r"|`(?P<code>[^`]+)`"
    r"|<code>(?P<html_code>.*?)</code>"
    r"|\[(?P<label>[^\]]+)\]\((?P<url>[^)\s]+)\)"
    r"|<br\s*/?>"
)


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


@dataclass
class Counters:
    """What the document has numbered so far; a caption's own number wins, so Markdown and PDF agree."""

    tables: int = 0
    seen: dict = field(default_factory=dict)


def table(lines: list[str], caption: str | None, counters: Counters) -> str:
    header, rule, rows = _cells(lines[0]), _cells(lines[1]), [_cells(line) for line in lines[2:]]
    rows = [row + [""] * (len(header) - len(row)) for row in rows]
    align = ["right" if cell.endswith(":") and not cell.startswith(":") else "left" for cell in rule]
    align += ["left"] * (len(header) - len(align))
    widths = [max(len(plain(row[i])) for row in [header, *rows]) for i in range(len(header))]
    # A column's share of the width: its longest cell, capped so one long text column cannot starve the rest.
    total = sum(min(w, 60) for w in widths) + 3 * len(widths)
    size = next((s for limit, s in TABLE_SIZES if total <= limit), None)
    landscape = size is None
    size = size or LANDSCAPE_SIZE
    number = caption_number(caption, counters)
    text = caption_text(caption) or "Table"
    cells = []
    for row in rows:
        cells.append(", ".join(f"[{inline(cell)}]" for cell in row))
    body = (
        f"table(columns: {len(header)}, align: ({', '.join(align)},),\n"
        "  table.hline(stroke: 0.8pt),\n"
        f"  table.header({', '.join(f'[*{inline(cell)}*]' for cell in header)}),\n"
        "  table.hline(stroke: 0.5pt),\n" + "".join(f"  {row},\n" for row in cells) + "  table.hline(stroke: 0.8pt),\n)"
    )
    figure = (
        f"#counter(figure.where(kind: table)).update({number - 1})\n"
        f"#figure(kind: table, caption: [{inline(text)}], {{set text(size: {size}); set par(justify: false); "
        f"{body}}})\n"
    )
    return f"#page(flipped: true)[\n{figure}]\n" if landscape else figure


def caption_number(caption: str | None, counters: Counters) -> int:
    found = re.match(r"Table (\d+)\.", caption or "")
    counters.tables = int(found.group(1)) if found else counters.tables + 1
    return counters.tables


def caption_text(caption: str | None) -> str:
    return re.sub(r"^(Table|Figure) \d+\.\s*", "", caption or "")


FIGURE_CAPTION = re.compile(r"^\*Figure (\d+)\. (.*)\*$")
TABLE_CAPTION = re.compile(r"^\*(Table \d+\. .*)\*$")
IMAGE = re.compile(r"^!\[(?P<alt>[^\]]*)\]\((?P<path>[^)\s]+)\)$")


def image(path: str, folder: Path | None, alt: str) -> str:
    """The figure's vector form where the report wrote one (``figures/x.svg`` beside ``x.png``)."""
    if folder is not None and path.endswith(".png") and (folder / path).with_suffix(".svg").is_file():
        path = path[: -len(".png")] + ".svg"
    return f"image({string(path)}, width: 82%, alt: {string(plain(alt))})"


def blocks(markdown: str) -> list[tuple[str, list[str]]]:
    """The Markdown as (kind, lines) blocks: heading, table, list, quote, code, image, paragraph, comment."""
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


def to_typst(markdown: str, folder: Path | None = None, title: str = "Report", date: str = "") -> str:
    """The report's Markdown as a Typst document: numbered sections, figures and tables (the numbers the
    Markdown gives them), page numbers, wide tables in smaller type or on a landscape page.

    ``## Appendix`` starts the appendix on a new page: its sections carry their own letters (``### A. ...``)."""
    out = [PREAMBLE.format(title=string(title), date=string(date))]
    counters = Counters()
    parts = blocks(markdown)
    skip = set()
    for index, (kind, lines) in enumerate(parts):
        if index in skip or kind == "comment":
            continue
        following = parts[index + 1] if index + 1 < len(parts) else ("", [])
        if kind == "heading":
            hashes, text = lines[0].split(" ", 1)
            level = len(hashes)
            if level == 1:
                out.append(f'#align(center, text(size: 17pt, weight: "bold")[{inline(text)}])\n')
            elif level == 2 and text.strip() == "Appendix":
                out.append("#pagebreak(weak: true)\n#set heading(numbering: none)\n")
                out.append("#context [#metadata(here().page()) <appendix-page>]\n")
                out.append(f"#heading(level: 1)[{inline(text)}]\n")
            else:
                out.append(f"#heading(level: {level - 1})[{inline(text)}]\n")
        elif kind == "image":
            found = IMAGE.match(lines[0])
            caption, number = "", None
            if following[0] == "paragraph":
                cap = FIGURE_CAPTION.match(" ".join(following[1]).strip())
                if cap:
                    number, caption = int(cap.group(1)), cap.group(2)
                    skip.add(index + 1)
            counter = f"#counter(figure.where(kind: image)).update({number - 1})\n" if number else ""
            out.append(
                f"{counter}#figure({image(found.group('path'), folder, found.group('alt'))}, "
                f"caption: [{inline(caption)}])\n"
                if caption
                else f"#align(center, {image(found.group('path'), folder, found.group('alt'))})\n"
            )
        elif kind == "paragraph" and following[0] == "table" and TABLE_CAPTION.match(" ".join(lines).strip()):
            continue  # the caption of the table that follows
        elif kind == "table":
            before = parts[index - 1] if index else ("", [])
            cap = TABLE_CAPTION.match(" ".join(before[1]).strip()) if before[0] == "paragraph" else None
            if len(lines) < 2:
                out.append(f"{inline(lines[0])}\n")
                continue
            out.append(table(lines, cap.group(1) if cap else None, counters))
        elif kind == "list":
            out.append(list_items(lines))
        elif kind == "quote":
            text = " ".join(re.sub(r"^>\s?", "", line) for line in lines)
            out.append(
                f'#block(fill: rgb("#fff4e0"), stroke: (left: 3pt + rgb("#f0a000")), inset: 8pt, width: 100%)'
                f"[{inline(text)}]\n"
            )
        elif kind == "code":
            code = string("\n".join(lines), lines=True)
            out.append(f"#block(fill: luma(245), inset: 6pt, width: 100%, raw(block: true, {code}))\n")
        else:
            out.append(inline(" ".join(line.strip() for line in lines)) + "\n")
        out.append("\n")
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


def number_tables(markdown: str) -> str:
    """Give every pipe table a numbered caption line (``*Table 3. Episodes to solve*``) just above it: the lead-in
    of the paragraph before it (``**Episodes to solve.** ...``), else its section's heading. The Markdown, the HTML
    and the PDF then number and name the tables alike."""
    lines, out, number = markdown.splitlines(), [], 0
    heading, lead = "", ""
    for i, line in enumerate(lines):
        starts = line.lstrip().startswith("|") and (i == 0 or not lines[i - 1].lstrip().startswith("|"))
        if starts:
            number += 1
            caption = lead or heading or "Table"
            while out and not out[-1].strip():
                out.pop()
            out += ["", f"*Table {number}. {caption}*", ""]
            lead = ""
        elif line.startswith("#"):
            heading = re.sub(r"^#+\s*", "", line).strip()
            heading = re.sub(r"^[A-Z]\.\s+|\s*\(generated\)$", "", heading)
            lead = ""
        elif line.strip() and not line.lstrip().startswith("|"):
            found = re.match(r"^\*\*(.+?)\.?\*\*", line.strip())
            lead = found.group(1).rstrip(".") if found else ""
        out.append(line)
    return "\n".join(out) + ("\n" if markdown.endswith("\n") else "")


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
