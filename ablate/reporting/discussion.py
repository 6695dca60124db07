"""The student's own part of the report: ``reports/<experiment>/discussion.md``, created once with a few prompts,
never overwritten by a rebuild, and printed verbatim in the report's body under its author's name."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

FILE = "discussion.md"

TEMPLATE = """\
<!-- Your discussion of this ablation, in your own words. `ablate report` and `ablate run` print this file
verbatim in the report's body, under the name on the Author line, and never overwrite it: edit it, then run
`ablate report` again. Until it differs from this template, the report says the discussion is missing. -->

Author: (your name)

**What did you expect, and why?**

(Before the run: which variants did you expect to learn faster or slower, and on what reasoning?)

**What surprised you?**

(Which result differs from what you expected, or from the course's lab? What might explain it?)

**What would you run next?**

(Which comparison is undetermined, and what would decide it: more seeds, a longer budget, another knob?)
"""


@dataclass(frozen=True)
class Discussion:
    author: str | None
    """The name on the ``Author:`` line, or None where it is still the template's."""
    text: str | None
    """The discussion as written, without its comment and Author line; None until it differs from the template."""
    edited_ms: int | None = None
    """When the file was last saved (ms since the epoch): a discussion saved before the launch the report shows
    was written about other data."""


def read(folder: Path) -> Discussion:
    """The discussion in ``folder`` (a report folder), or an empty one where the file is missing or unedited."""
    path = folder / FILE
    if not path.is_file():
        return Discussion(None, None)
    raw = path.read_text(encoding="utf-8", errors="replace")
    if raw.strip() == TEMPLATE.strip():
        return Discussion(None, None)
    body = re.sub(r"<!--.*?-->", "", raw, flags=re.S)
    found = re.search(r"^Author:[ \t]*(.*)$", body, flags=re.M)
    author = found.group(1).strip() if found else ""
    if found:
        body = body[: found.start()] + body[found.end() :]
    author = None if not author or author == "(your name)" else author
    text = body.strip() or None
    return Discussion(author, text, int(path.stat().st_mtime * 1000))


def keep(old_folder: Path, new_folder: Path) -> None:
    """Carry ``discussion.md`` from the report being replaced into the new one, or start it from the template.
    Called just before the swap, so an edit made while the report was building is kept too."""
    source, target = old_folder / FILE, new_folder / FILE
    if source.is_file():
        target.write_bytes(source.read_bytes())
    elif not target.exists():
        target.write_text(TEMPLATE, encoding="utf-8")
