"""The report's one formatting module: user text made inert (``esc``), numbers (``fmt``), percentages, signed
numbers, intervals, metric names. Every section and figure caption formats through it."""

from __future__ import annotations

import html
from dataclasses import dataclass, field

import pandas as pd

from ablate.measures import lookup


def esc(text: object) -> str:
    """User text (descriptions, variant names, errors, commands) made inert in Markdown and HTML."""
    # quote=False: quotes are inert in Markdown and in HTML text; escaped, the Markdown read "course&#x27;s".
    return html.escape(str(text), quote=False).replace("|", "&#124;").replace("`", "&#96;")


@dataclass(frozen=True)
class Refs:
    """Where the report's cross-references point, resolved before any section is written (no token is replaced
    afterwards): each appendix section's letter and each figure's number; one the report lacks reads –."""

    letters: dict[str, str] = field(default_factory=dict)
    figures: dict[str, int] = field(default_factory=dict)

    def appendix(self, name: str) -> str:
        """``Appendix B`` for the section ``name`` (``tuning``, ``glossary``, ...)."""
        return f"Appendix {self.letters.get(name, '–')}"

    def figure(self, stem: str) -> str:
        """``Figure 6`` for the figure drawn into ``<stem>.png``."""
        return f"Figure {self.figures.get(stem, '–')}"

    def figures_of(self, *stems: str) -> str:
        """``Figures 1 and 2`` for those of ``stems`` the report drew (``Figure 1`` for one)."""
        numbers = [str(self.figures[s]) for s in stems if s in self.figures]
        if len(numbers) == 1:
            return f"Figure {numbers[0]}"
        return f"Figures {joined(numbers)}" if numbers else "Figure –"


NO_REFS = Refs()
"""A section written outside a report (a test, a notebook): every cross-reference reads –."""


def fmt(x: float | None, digits: int = 0) -> str:
    if pd.isna(x):  # None and NaN alike
        return "–"
    return f"{x:,.{digits}f}"


def setting_value(value) -> str:
    """A setting's value in a sentence: a number as ``%g`` (0.03, 1e-05), anything else as written."""
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError):
        return str(value)


def joined(words: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def _signed(x: float, digits: int = 1) -> str:
    return "–" if pd.isna(x) else f"{x:+,.{digits}f}"


def _signed_pct(x: float) -> str:
    if pd.isna(x):
        return "–"
    value = int(round(100 * x))
    return f"{value:+d}%" if value else "0%"


def _interval(low: float, high: float, digits: int = 0, n: int | None = None) -> str:
    if pd.isna(low) or pd.isna(high):
        return "[no interval: 1 seed]" if n == 1 else "[no interval]"
    return f"[{fmt(low, digits)}, {fmt(high, digits)}]"


def _metric_name(metric: str) -> str:
    """A measure's words in the report (``measures.Measure.words``); a name the registry lacks as written."""
    entry = lookup(metric)
    return entry.words if entry else metric
