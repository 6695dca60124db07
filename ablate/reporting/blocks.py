"""The report as data: a list of blocks (headings, paragraphs, lists, tables from DataFrames, figures, videos, the
student's own text), built once by the sections from ``ReportData`` and written three ways by the renderers
(``render.markdown``, ``render.html_body``, ``typeset.typst``). Figure, table and appendix numbers are resolved in
the blocks (``number_tables``, ``Refs``): no renderer replaces a token or parses what another one wrote.

A block's text is one paragraph of the report's Markdown (``MARKUP``, CommonMark as report.md shows it):
``**strong**``, ``*emphasis*``, ```code```, ``[label](url)``, and of HTML only ``OWN_TAGS``; user text in it has
been made inert by ``text.esc`` (HTML entities), which markdown-it decodes once.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import pandas as pd
from markdown_it import MarkdownIt
from markdown_it.tree import SyntaxTreeNode

if TYPE_CHECKING:
    from ablate.reporting.figures import Figure

MARKUP = MarkdownIt("commonmark").enable("table")
"""The report's Markdown (CommonMark with pipe tables): a block's text, and the student's discussion."""
OWN_TAGS = re.compile(r"</?code>|<br\s*/?>")
"""The HTML a block's text may hold (a command in ``<code>``, where a code span would not decode ``esc``'s
entities); any other tag in it is text."""


def inline_nodes(text: str) -> list[SyntaxTreeNode]:
    """A block's text as markdown-it's inline nodes (text, strong, em, code_inline, link, html_inline, ...)."""
    return SyntaxTreeNode(MARKUP.parseInline(text)).children[0].children


@dataclass(frozen=True)
class Heading:
    """A section title. Level 1 is the report's title, 2 a body section, 3 an appendix section (``letter``: its
    appendix letter); ``generated``: written by ablate from the store (marked so in every rendering)."""

    title: str
    level: int = 2
    generated: bool = False
    letter: str = ""

    @property
    def text(self) -> str:
        lead = f"{self.letter}. " if self.letter else ""
        return f"{lead}{self.title}{' (generated)' if self.generated else ''}"


@dataclass(frozen=True)
class AppendixStart:
    """Where the appendix begins: a heading, and in print a new page."""


@dataclass(frozen=True)
class Paragraph:
    text: str


@dataclass(frozen=True)
class Note:
    """A call-out the reader must not miss (a partial generation, a changed experiment file, failed trials)."""

    text: str


@dataclass(frozen=True)
class Item:
    text: str
    sub: tuple[str, ...] = ()


@dataclass(frozen=True)
class Items:
    """A bulleted list; an item may hold one level of sub-items."""

    items: tuple[Item, ...]

    @classmethod
    def of(cls, texts: Iterable[str | Item]) -> Items:
        return cls(tuple(t if isinstance(t, Item) else Item(t) for t in texts))

    def lines(self, indent: str, write: Callable[[str], str] = str) -> str:
        """The list as ``- `` lines (Markdown and Typst), a sub-item ``indent`` deeper, each text through ``write``."""
        lines = []
        for item in self.items:
            lines.append(f"- {write(item.text)}")
            lines += [f"{indent}- {write(sub)}" for sub in item.sub]
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class Table:
    """A table from a DataFrame whose cells are inline text: columns of words left-aligned, of numbers right.
    ``caption``: its name (``None``: its section's title); ``number``: set by ``number_tables``."""

    frame: pd.DataFrame
    caption: str | None = None
    number: int = 0

    @property
    def align(self) -> list[str]:
        return ["left" if _is_text(self.frame[c]) else "right" for c in self.frame.columns]

    @property
    def header(self) -> list[str]:
        return [str(c) for c in self.frame.columns]

    @property
    def rows(self) -> list[list[str]]:
        return [[str(v) for v in row] for row in self.frame.itertuples(index=False)]


@dataclass(frozen=True)
class Picture:
    """One numbered figure (``figure.number``, ``figure.caption`` resolved before the blocks are built)."""

    figure: Figure


@dataclass(frozen=True)
class Videos:
    """The report's videos (``path``, ``caption`` each), or the line saying there are none."""

    videos: tuple[dict[str, str], ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class Authored:
    """Markdown the student wrote (``discussion.md``): printed as written, its headings nested under the report's."""

    text: str


Block = Heading | AppendixStart | Paragraph | Note | Items | Table | Picture | Videos | Authored


def _is_text(values) -> bool:
    """A column of words (left-aligned) rather than of numbers, intervals and counts (right-aligned)."""
    return any(re.search(r"[A-Za-z]", re.sub(r"\[[^\]]*\]|\([^)]*\)", "", str(v))) for v in values)


def number_tables(blocks: list[Block]) -> list[Block]:
    """Every table numbered in order, and one without a caption named after its section's title: the three
    renderings then number and name the tables alike."""
    out: list[Block] = []
    number, section = 0, "Table"
    for block in blocks:
        if isinstance(block, Heading):
            section = block.title
        elif isinstance(block, Table):
            number += 1
            block = replace(block, number=number, caption=block.caption or section)
        out.append(block)
    return out
