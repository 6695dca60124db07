"""The README is a front door and the docs/ pages stay true: size, first lines, links, knob tables, names.

Each test reads files only (no Ray, no MLflow): the whole module runs in about a second.
"""

from __future__ import annotations

import ast
import contextlib
import importlib.util
import io
import re
import tomllib
from pathlib import Path

import pytest

from ablate import config, experiment
from ablate.cli import TEST_ONLY_KNOBS, format_value, knob_defaults, main
from ablate.launch.grid import expand

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, *DOCS]

COURSE_NAMES = (
    "create_cartpole_model",
    "choose_action",
    "Memory.add_to_memory",
    "discount_rewards",
    "compute_loss",
    "train_step",
    "create_pong_model",
    "pre_process",
    "plot_progress",
)

FENCE = re.compile(r"^```.*?^```", re.M | re.S)
CODE_SPAN = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _knob_docs():
    spec = importlib.util.spec_from_file_location("knob_docs", ROOT / "tools" / "knob_docs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def links(path: Path) -> list[str]:
    """The targets of a Markdown file's links and images, outside code blocks and code spans."""
    text = CODE_SPAN.sub("code", FENCE.sub("", path.read_text(encoding="utf-8")))
    return LINK.findall(text)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    return {slug(h) for h in re.findall(r"^#{1,6} (.+)$", text, re.M)}


def test_readme_is_under_10_kib():
    size = len(README.read_bytes())
    assert size < 10 * 1024, f"README.md is {size:,} bytes; move detail into docs/ (limit 10,240)"


def test_readme_opens_with_the_two_commands():
    """Its first lines: a code block whose commands are `make ablation-cartpole`, then `make test`."""
    lines = README.read_text(encoding="utf-8").splitlines()
    head = [line for line in lines[:6] if line.strip()]
    assert head[0].startswith("# "), head
    assert head[1].startswith("```"), head
    assert head[2].split("#")[0].split() == ["make", "ablation-cartpole"], head[2]
    assert head[3].split("#")[0].split() == ["make", "test"], head[3]


def test_every_docs_page_is_linked_from_the_readme():
    assert DOCS, "no docs/*.md pages"
    linked = {(README.parent / target.split("#")[0]).resolve() for target in links(README)}
    missing = [page.name for page in DOCS if page.resolve() not in linked]
    assert not missing, f"docs/ pages not linked from README.md: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    """Each relative link names a file of the repository (and, for a Markdown file, a heading it has)."""
    broken = []
    for target in links(page):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: ...
            continue
        file_part, _, anchor = target.partition("#")
        resolved = (page.parent / file_part).resolve() if file_part else page.resolve()
        if not resolved.is_relative_to(ROOT) or not resolved.exists():
            broken.append(f"{target} (no such file)")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            broken.append(f"{target} (no heading #{anchor} in {resolved.name})")
    assert not broken, f"{page.relative_to(ROOT)}: broken links: {broken}"


def _defines(path: Path, name: str) -> bool:
    """Whether ``path`` defines ``name`` at its top level (``Class.method``: the class, with the method)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    owner, _, member = name.rpartition(".")
    for node in tree.body:
        if not owner and isinstance(node, ast.FunctionDef | ast.ClassDef) and node.name == name:
            return True
        if owner and isinstance(node, ast.ClassDef) and node.name == owner:
            return any(isinstance(n, ast.FunctionDef) and n.name == member for n in node.body)
    return False


@pytest.mark.parametrize("name", COURSE_NAMES)
def test_the_courses_names_are_findable(name):
    """The MIT 6.S191 lab's names appear in the docs beside the module that defines them."""
    lines = [
        (page, line, set(re.findall(r"ablate/[\w/]+\.py", line)))
        for page in PAGES
        for line in page.read_text(encoding="utf-8").splitlines()
        if f"`{name}`" in line
    ]
    placed = [(page, line, paths) for page, line, paths in lines if paths]
    assert placed, f"`{name}` is in no line of README.md or docs/ that names its module (ablate/....py)"
    for page, line, paths in placed:  # a line that places the name must place it right
        assert any((ROOT / p).is_file() and _defines(ROOT / p, name) for p in paths), (
            f"{page.relative_to(ROOT)}: `{name}` beside {sorted(paths)}, none of which defines it: {line.strip()}"
        )


def test_readme_example_experiment_is_valid_and_as_large_as_it_says():
    """The README's own experiment parses, and its comment's 'N variants x S seeds' is the truth."""
    text = README.read_text(encoding="utf-8")
    block = re.search(r"```toml\n(.*?)```", text, re.S)
    assert block, "README.md has no ```toml experiment example"
    example = experiment.parse_experiment(tomllib.loads(block.group(1)), "README.md")
    claim = re.search(r"(\d+) variants x (\d+) seeds", block.group(1))
    assert claim, "the example's first comment should say how many variants and seeds it has"
    assert (len(example.variants), len(example.seeds)) == (int(claim[1]), int(claim[2]))
    trials = len(expand(example))
    assert f"the {trials} trials" in text, f"the README's --dry-run line should say it lists {trials} trials"


# --- the knob tables of docs/experiments.md (generated by tools/knob_docs.py) ---


def _documented_rows() -> dict[str, str]:
    """``{key: default cell}`` from the tables of docs/experiments.md."""
    text = (ROOT / "docs" / "experiments.md").read_text(encoding="utf-8")
    return dict(re.findall(r"^\| `([a-z0-9_]+)` \| ((?:[^|\\]|\\.)*?) \|", text, re.M))


def test_every_knob_and_top_level_key_is_documented_with_its_default():
    rows = _documented_rows()
    defaults = knob_defaults()
    for name in config.KNOBS:
        assert name in rows, f"knob {name} is missing from docs/experiments.md: python tools/knob_docs.py --write"
        expected = "not set" if defaults[name] is None else f"`{format_value(defaults[name])}`"
        assert rows[name] == expected, f"{name}: docs/experiments.md says {rows[name]}, ablate/config.py {expected}"
    for name in [*config.SHORTHANDS, *experiment.EXPERIMENT_KEYS]:
        assert name in rows, f"{name} is missing from docs/experiments.md: python tools/knob_docs.py --write"
    top = _knob_docs().top_level_defaults()
    for name in experiment.EXPERIMENT_KEYS:
        assert rows[name] == top[name], f"{name}: docs/experiments.md says {rows[name]}, the parser {top[name]}"


def test_knob_tables_are_as_generated():
    """Meanings and valid values too: the page holds exactly what tools/knob_docs.py writes."""
    knob_docs = _knob_docs()
    text = (ROOT / "docs" / "experiments.md").read_text(encoding="utf-8")
    assert knob_docs.current_block(text) == knob_docs.render(), (
        "docs/experiments.md's knob tables are out of date: python tools/knob_docs.py --write"
    )


def test_run_help_lists_every_knob_with_its_default_and_the_page():
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(out.getvalue().split())
    for name, value in knob_defaults().items():
        if name in (*TEST_ONLY_KNOBS, "seed"):
            continue
        assert f"{name} = {format_value(value)}" in text, name
    assert all(name in text for name in config.SHORTHANDS)
    assert "docs/experiments.md" in text
