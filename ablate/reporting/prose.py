"""The report's sentences: Jinja2 templates (``reporting/templates/<part>.j2``, a macro per sentence or paragraph)
that the sections fill with the facts they computed, so a sentence is found and changed in one file.

A template wraps its prose as the code does (120 columns): the lines of a macro fold into one paragraph, one space
between them, and a line that renders empty (an ``{% if %}`` alone, a sentence left out) leaves no gap; ``{%-``
glues to the line before. User text stays as the sections escape it (``text.esc``): autoescape is off (Markdown).
"""

from __future__ import annotations

import re
from functools import cache

import jinja2
from jinja2.ext import Extension

from ablate.claims.family import CENSORED_SHARE
from ablate.design import ALPHA, CONFIDENCE, percent
from ablate.measures import POWER
from ablate.reporting.text import _interval, _metric_name, _signed, _signed_pct, esc, fmt, joined, setting_value

_FOLD = "\x1f\n"
"""A template's line break until the paragraph is rendered: the unit separator (whitespace to Jinja's lexer, never
in a report's text) marks it apart from a line break in user text, and the kept newline keeps errors' line numbers."""


class _Folded(Extension):
    """Each line break of a template, and the next line's indent, become ``_FOLD`` before Jinja reads them."""

    def preprocess(self, source: str, name: str | None, filename: str | None = None) -> str:
        return re.sub(r"\n[ \t]*", _FOLD, source)


def _plural(count: int, many: str = "s", one: str = "") -> str:
    """``{{ n }} seed{{ n | s }}``: the ending for ``count`` things."""
    return one if count == 1 else many


@cache
def _environment() -> jinja2.Environment:
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("ablate.reporting", "templates"),
        undefined=jinja2.StrictUndefined,
        autoescape=False,
        extensions=[_Folded],
    )
    env.globals.update(
        confidence=percent(CONFIDENCE),
        alpha=percent(ALPHA),
        power=percent(POWER),
        censored_share=percent(CENSORED_SHARE),
    )
    env.filters.update(
        esc=esc,
        fmt=fmt,
        spec=format,
        percent=percent,
        signed=_signed,
        signed_pct=_signed_pct,
        interval=_interval,
        metric=_metric_name,
        joined=joined,
        setting=setting_value,
        s=_plural,
    )
    return env


def say(sentence: str, **facts: object) -> str:
    """The sentence ``part.macro`` (``"layout.question"``: the macro ``question`` of ``templates/layout.j2``)
    said with ``facts``; a fact the macro needs and was not given raises, as does one it does not take."""
    part, _, macro = sentence.rpartition(".")
    said = getattr(_environment().get_template(f"{part}.j2").module, macro)(**facts)
    folds = f"(?:{_FOLD})+"
    return re.sub(folds, " ", re.sub(f"^{folds}|{folds}$", "", said))
