"""Two of the report's renderers: the blocks (``blocks.py``) as Markdown (report.md) and as one self-contained
HTML page (report.html, figures and videos inlined). The third, Typst for the PDF, is ``typeset.typst``. Each
writes every block type; none reads another's output."""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

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
)
from ablate.reporting.text import esc

NO_VIDEOS = "No videos were recorded."
CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222;
       line-height: 1.45; }
table { border-collapse: collapse; font-size: 0.85em; margin: 1em 0; }
caption { caption-side: top; text-align: left; font-size: 0.9em; color: #333; padding: 0.3em 0; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: top; }
img { max-width: 100%; }
figure { margin: 1.5em 0; break-inside: avoid; }
figcaption { font-size: 0.9em; color: #333; margin-top: 0.3em; }
.videos { display: flex; flex-wrap: wrap; gap: 12px; }
figure.video { margin: 0; width: 260px; font-size: 0.8em; }
figure.video video { width: 260px; }
blockquote { background: #fff4e0; border-left: 4px solid #f0a000; margin: 1em 0; padding: 0.5em 1em; }
@media print {
  body { max-width: none; margin: 0; font-size: 10pt; }
  video { display: none; }
  figure.video { width: 45%; }
  table { font-size: 8pt; }
  h2 { break-after: avoid; }
  tr { break-inside: avoid; }
}
"""


def nested(text: str, levels: int) -> str:
    """The student's Markdown with its headings moved ``levels`` deeper, under the report's own heading."""
    return re.sub(r"^(#{1,4}) ", lambda m: "#" * (len(m.group(1)) + levels) + " ", text, flags=re.M)


# --- Markdown ---------------------------------------------------------------------------------------------------
def _md_table(table: Table) -> str:
    rule = [":---" if a == "left" else "---:" for a in table.align]
    lines = [f"*Table {table.number}. {table.caption}*", ""] if table.number else []
    lines += ["| " + " | ".join(cells) + " |" for cells in (table.header, rule)]
    lines += ["| " + " | ".join(row) + " |" for row in table.rows]
    return "\n".join(lines)


def _md_block(block: Block) -> str:
    if isinstance(block, Heading):
        return f"{'#' * block.level} {block.text}"
    if isinstance(block, AppendixStart):
        return "## Appendix"
    if isinstance(block, Paragraph):
        return block.text
    if isinstance(block, Note):
        return f"> {block.text}"
    if isinstance(block, Items):
        return block.lines("    ")
    if isinstance(block, Table):
        return _md_table(block)
    if isinstance(block, Picture):
        f = block.figure
        return f"![{f.alt}]({f.path})\n\n*Figure {f.number}. {f.caption}*"
    if isinstance(block, Videos):
        return "\n".join(f"- [{esc(v['caption'])}]({v['path']})" for v in block.videos) or NO_VIDEOS
    if isinstance(block, Authored):
        return nested(block.text, 3)
    raise TypeError(f"not a report block: {block!r}")


def markdown(blocks: list[Block]) -> str:
    """The blocks as Markdown, one blank line between blocks."""
    return "\n\n".join(_md_block(b) for b in blocks) + "\n"


# --- HTML -------------------------------------------------------------------------------------------------------
def inline_html(text: str) -> str:
    """One block's text as HTML; a tag other than ``OWN_TAGS`` in it is text."""
    tokens = MARKUP.parseInline(text)
    for token in tokens[0].children or []:
        if token.type == "html_inline" and not OWN_TAGS.fullmatch(token.content):
            token.type = "text"
    return MARKUP.renderer.render(tokens, MARKUP.options, {})


def _html_table(table: Table) -> str:
    align = table.align  # read off every column's values: once per table, not once per row

    def row(cells: list[str], tag: str) -> str:
        shown = (f'<{tag} style="text-align: {a}">{inline_html(c)}</{tag}>' for c, a in zip(cells, align, strict=True))
        return f"<tr>{''.join(shown)}</tr>"

    caption = f"<caption><strong>Table {table.number}.</strong> {inline_html(table.caption or '')}</caption>"
    body = "\n".join(row(cells, "td") for cells in table.rows)
    head = f"<thead>{row(table.header, 'th')}</thead>"
    return f"<table>{caption if table.number else ''}\n{head}\n<tbody>\n{body}\n</tbody></table>"


def _html_block(block: Block) -> str:
    if isinstance(block, Heading):
        anchor = f' id="appendix-{block.letter.lower()}"' if block.letter else ""
        return f"<h{block.level}{anchor}>{inline_html(block.text)}</h{block.level}>"
    if isinstance(block, AppendixStart):
        return '<h2 id="appendix">Appendix</h2>'
    if isinstance(block, Paragraph):
        return f"<p>{inline_html(block.text)}</p>"
    if isinstance(block, Note):
        return f"<blockquote><p>{inline_html(block.text)}</p></blockquote>"
    if isinstance(block, Items):
        items = []
        for item in block.items:
            sub = "".join(f"<li>{inline_html(s)}</li>" for s in item.sub)
            items.append(f"<li>{inline_html(item.text)}{f'<ul>{sub}</ul>' if sub else ''}</li>")
        return "<ul>\n" + "\n".join(items) + "\n</ul>"
    if isinstance(block, Table):
        return _html_table(block)
    if isinstance(block, Picture):
        f = block.figure
        return (
            f'<figure id="figure-{f.number}"><img src="{html.escape(f.path)}" alt="{html.escape(f.alt)}">'
            f"<figcaption><strong>Figure {f.number}.</strong> {inline_html(f.caption)}</figcaption></figure>"
        )
    if isinstance(block, Videos):
        if not block.videos:
            return f"<p>{NO_VIDEOS}</p>"
        shown = "\n".join(
            f'<figure class="video"><video controls muted loop preload="metadata" src="{html.escape(v["path"])}">'
            f"</video><figcaption>{html.escape(v['caption'], quote=False)}</figcaption></figure>"
            for v in block.videos
        )
        return f'<div class="videos">\n{shown}\n</div>'
    if isinstance(block, Authored):
        return MARKUP.render(nested(block.text, 3))
    raise TypeError(f"not a report block: {block!r}")


def html_body(blocks: list[Block]) -> str:
    """The blocks as the body of an HTML page."""
    return "\n".join(_html_block(b) for b in blocks)


def html_page(blocks: list[Block], title: str, folder: Path) -> str:
    """The blocks as report.html, its ``figures/`` and ``videos/`` (relative to ``folder``) inlined as data URIs."""
    page = (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
        f"</title><style>{CSS}</style></head><body>\n{html_body(blocks)}\n</body></html>\n"
    )
    mime = {".png": "image/png", ".svg": "image/svg+xml", ".mp4": "video/mp4"}

    def inlined(match: re.Match) -> str:
        path = folder / html.unescape(match.group(1))
        if not path.is_file():
            return match.group(0)
        data = base64.b64encode(path.read_bytes()).decode()
        return f'src="data:{mime.get(path.suffix, "application/octet-stream")};base64,{data}"'

    return re.sub(r'src="((?:figures|videos)/[^"]+)"', inlined, page)
