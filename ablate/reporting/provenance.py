"""Where a report comes from: the reproducibility record (command, commit and whether the experiment file is
the committed one, machine, packages, launch run) and the note on which generation it covers."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Mapping
from pathlib import Path

from ablate.launch.secrets import Shown, shown
from ablate.reporting.blocks import Block, Items, Paragraph
from ablate.reporting.experiment_file import edited
from ablate.reporting.prose import say
from ablate.reporting.results import Ablation
from ablate.reporting.text import esc


def experiment_file_state(commit: str, path: str, text: str | None, cwd: str | Path | None = None) -> str:
    """Whether the experiment file that ran is the one in the recorded commit, as a sentence for the
    reproducibility record: a run from a file never committed, or edited since, cannot be rebuilt from the
    commit alone. Checked in the git clone at ``cwd`` (the report's folder); ``""`` when nothing can be said."""
    commit = commit.removesuffix("-dirty")
    if not path or not commit or commit == "unknown":
        return ""

    def git(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *argv], cwd=cwd, capture_output=True, text=True, timeout=30, check=False)

    try:
        top = git("rev-parse", "--show-toplevel")
        if top.returncode != 0:
            return f"Not checked whether the experiment file {esc(path)} is in that commit: no git clone here."
        if git("cat-file", "-e", f"{commit}^{{commit}}").returncode != 0:
            return f"Not checked whether the experiment file {esc(path)} is in that commit: this clone lacks it."
        where = Path(path)
        if where.is_absolute():
            try:
                where = where.resolve().relative_to(Path(top.stdout.strip()).resolve())
            except ValueError:
                return f"**The experiment file {esc(path)} is outside the git clone**: the commit does not hold it."
        committed = git("show", f"{commit}:./{where.as_posix()}")
    except (OSError, subprocess.TimeoutExpired):
        return ""
    if committed.returncode != 0:
        return (
            f"**The experiment file {esc(path)} was not committed at {esc(commit[:12])}**: the commit alone cannot "
            "rebuild this run; the launch run's <code>experiment.toml</code> artifact holds the file as it ran."
        )
    if text is not None and committed.stdout.strip() != text.strip():
        return (
            f"**The experiment file {esc(path)} had uncommitted changes** when it ran: it differs from the file at "
            f"{esc(commit[:12])}; the launch run's <code>experiment.toml</code> artifact holds the file as it ran."
        )
    return f"The experiment file {esc(path)} is the one committed at {esc(commit[:12])}."


def _reproducibility(ablation: Ablation, command: Shown) -> list[Block]:
    """The reproducibility record. ``command`` (the report's) is taken masked (``secrets.shown_command``), never
    as typed; the launch's, read from the store, is masked again here (a store written before the masks)."""
    if not isinstance(command, Shown):
        raise TypeError("the provenance takes a masked command (secrets.shown_command), not the command as typed")
    tags = ablation.launch["tags"]
    environment = ablation.launch["environment"]
    versions = environment.get("packages", {})
    cpu = environment.get("cpu_model", "not recorded")
    capability = environment.get("torch_cpu_capability", "not recorded")
    state = experiment_file_state(
        tags.get("mlflow.source.git.commit", ""),
        tags.get("ablate.experiment_file", ""),
        ablation.launch.get("experiment_text"),
    )
    launched = shown(tags.get("ablate.command") or "ablate run " + tags.get("ablate.experiment_file", ""))
    lines = [
        f"Command: <code>{esc(launched)}</code>",
        f"Code version (git commit): <code>{esc(tags.get('mlflow.source.git.commit', 'unknown'))}</code>"
        + (f". {state}" if state else ""),
        f"Machine: {esc(environment.get('machine', 'unknown'))}; CPU model: {esc(cpu)}; torch CPU capability "
        f"(the vector kernels torch picked): {esc(capability)}",
        f"Python {esc(environment.get('python', '?'))}; "
        + ", ".join(f"{esc(k)} {esc(v)}" for k, v in versions.items()),
        f"MLflow launch run: <code>{esc(ablation.launch['run_id'])}</code> (generation "
        f"<code>{esc(tags.get('ablate.generation', ''))}</code>); this report is attached to it as artifacts.",
        f"Report written {time.strftime('%Y-%m-%d %H:%M')}, from the tracking store only: <code>{esc(command)}</code>",
    ]
    return [Items.of(lines), Paragraph(say("provenance.same_results", cpu=cpu, capability=capability))]


def changed_file_note(ablation: Ablation, cwd: str | Path | None = None) -> str:
    """One line where the experiment file the launch ran (its copy in the store) differs from the file at the
    same path now (which of the two the report reads: ``experiment_file``). ``""`` where they match, or where
    either is missing."""
    path = ablation.launch["tags"].get("ablate.experiment_file", "")
    changed = f"**The experiment file {esc(path)} has changed since this launch ran it**"
    if ablation.launch.get("read_from_disk"):
        return f"{changed}, in nothing a trial ran (every trial key is the same): this report reads it as it is now."
    if edited(path, ablation.launch.get("experiment_text"), cwd) is None:
        return ""
    return (
        f"{changed}, in the settings of its trials: this report describes the launch's copy (stored with it); "
        f"<code>ablate run {esc(path)} --fresh</code> runs the file as it is now."
    )


def earlier_note(earlier: Mapping[str, int]) -> str:
    """The report's one line on ``Ablation.earlier`` (per variant, its trials under keys the plan no longer holds,
    left out of every number); ``""`` where there are none."""
    return say("provenance.earlier", earlier=earlier) if earlier else ""


def _generation_note(ablation: Ablation) -> str:
    generations = ablation.launch.get("generations", [])
    current = ablation.launch["tags"].get("ablate.generation", "")
    # A tuned launch's grid also lists tuning trials; its evaluation trials at the chosen values are the report's.
    total = len(ablation.trials) if ablation.tuning else len(ablation.grid["trials"])
    done = len(ablation.finished)
    if done >= total:
        return ""
    other = next((g for g in generations if g["generation"] != current and g["finished"] > done), None)
    return say("provenance.generation", current=current, done=done, total=total, other=other, name=ablation.name)


def _listed(keys: list[str], most: int = 3) -> str:
    return ", ".join(keys[:most]) + (f" and {len(keys) - most} more" if len(keys) > most else "")


def missing_artifacts_note(ablation: Ablation) -> str:
    """The report's note on finished trials whose files the store could not give; ``""`` when none."""
    keys = [key for _, key in ablation.missing]
    return say("provenance.missing_artifacts", count=len(keys), listed=_listed(keys)) if keys else ""


def missing_artifacts_line(ablation: Ablation, shown_uri: str) -> str:
    """The same, in the one line the terminal gets; ``""`` when nothing is missing."""
    keys = [key for _, key in ablation.missing]
    if not keys:
        return ""
    one = len(keys) == 1
    return (
        f"MLflow store {shown_uri}: episodes.csv of {len(keys)} finished trial{'' if one else 's'} cannot be read "
        f"({_listed(keys)}; was {'its' if one else 'their'} artifact folder moved or removed?): the report is "
        f"written from the tracked metrics and params, without {'its' if one else 'their'} curves and videos"
    )
