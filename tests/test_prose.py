"""ablate.reporting.prose: a template's lines fold into one paragraph, a sentence left out leaves no gap, user
text is kept as the sections escaped it, a missing or unknown fact raises, and the templates ship with the package."""

import re
import tomllib
from pathlib import Path

import jinja2
import pytest

from ablate.reporting import prose
from ablate.reporting.prose import say

ROOT = Path(__file__).resolve().parents[1]
TEMPLATES = ROOT / "ablate" / "reporting" / "templates"


@pytest.fixture
def part(monkeypatch, tmp_path):
    """A template ``test.j2`` of one's own, read by the report's environment (its folding, globals and filters)."""
    env = prose._environment().overlay(loader=jinja2.FileSystemLoader(tmp_path))
    monkeypatch.setattr(prose, "_environment", lambda: env)

    def write(text: str) -> None:
        (tmp_path / "test.j2").write_text(text)

    return write


def test_lines_fold_into_one_paragraph_and_a_sentence_left_out_leaves_no_gap(part):
    part(
        "{% macro m(n, extra) %}\n"
        "{{ n }} seed{{ n | s }} at {{ confidence }}.\n"
        "  {% if extra %}An extra sentence.{% endif %}\n"
        "{% if n > 1 %}\n    Several\n{%- endif %}.\n"
        "{% endmacro %}\n"
    )
    assert say("test.m", n=1, extra=False) == "1 seed at 95%. ."
    assert say("test.m", n=3, extra=True) == "3 seeds at 95%. An extra sentence. Several."


def test_user_text_keeps_its_line_breaks_and_its_escaping(part):
    part("{% macro m(name) %}\nA variant named\n{{ name | esc }}.\n{% endmacro %}\n")
    assert say("test.m", name="a|b\nc") == "A variant named a&#124;b\nc."


def test_a_missing_or_unknown_fact_raises(part):
    part("{% macro m(n) %}\n{{ n }}\n{% endmacro %}\n")
    with pytest.raises(jinja2.UndefinedError):
        say("test.m")
    with pytest.raises(TypeError):
        say("test.m", n=1, m=2)


def test_templates_write_no_level_as_a_literal_and_ship_with_the_package():
    """Issue 57: the confidence and the power are read from their constants, as in the code (test_design)."""
    literals = [
        f"{path.name}:{number}"
        for path in sorted(TEMPLATES.glob("*.j2"))
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if re.search(r"\b(95|80)%", line)
    ]
    assert not literals
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["tool"]["setuptools"]["package-data"]["ablate.reporting"] == ["templates/*.j2"]
    assert any(d.startswith("jinja2") for d in project["project"]["dependencies"])
