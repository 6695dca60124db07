"""Seeds in rounds, the report's side: the judge the runner calls after each round (``judge_for``), and the
report's words on each variant's seeds and why it stopped (``rounds_section``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ablate.claims.family import SPENDING_WORDS
from ablate.experiment import Experiment
from ablate.launch.records import grid_document
from ablate.launch.rounds import Primary
from ablate.measures import AUC, measure
from ablate.reporting.settings import references
from ablate.seeds import added_words


def sample(rows: Sequence[Primary], metric: str):
    """A variant's finished primary trials as ``claims.Sample`` (a censored measure: seeds that never got there
    count as the budget, with their AUC to fall back on)."""
    import numpy as np

    from ablate.claims import Sample

    entry = measure(metric)
    values, censored = zip(*(entry.from_summary(r.metrics, r.budget) for r in rows), strict=True)
    if not entry.censored:
        return Sample(np.asarray(values, float))
    auc = np.asarray([AUC.from_summary(r.metrics, r.budget)[0] for r in rows], float)
    return Sample(np.asarray(values, float), np.asarray(censored, bool), auc)


def judge_for(experiment: Experiment, seeds: Sequence[int] | None = None):
    """The runner's judge (``launch.rounds.Judge``) for ``experiment``'s seed rounds: ``claims.decide`` over the
    whole family at the design's looks, without intervals or seed estimates (the report computes those).
    ``None`` without rounds, or when ``seeds`` (``--seeds``) asks for given seeds only."""
    design = experiment.rounds
    if design is None or seeds:
        return None
    from ablate.claims import Design, decide, primary_question

    metric = experiment.primary_metric
    question = primary_question(metric, experiment.smallest_effect, float(experiment.base.max_episodes))
    family = {v: r for v, r in references(grid_document(experiment, [])).items() if v != experiment.baseline}

    def judge(finished: Mapping[str, Sequence[Primary]]):
        # The comparisons whose two sides have trials: all of them, but in a launch of a part (--only).
        asked = {v: r for v, r in family.items() if finished.get(v) and finished.get(r)}
        samples = {name: sample(rows, metric) for name, rows in finished.items() if rows}
        return decide(
            samples,
            asked,
            question,
            Design.of(design),
            intervals=False,
            estimate_seeds=False,
        )

    return judge


def seconds_per_trial(document: Mapping[str, Any] | None) -> float | None:
    """What a seed added in rounds cost this launch: the time from its second round's start to the end of its
    rounds over the trials those rounds ran (judging, scheduling and tracking included); ``None`` without them."""
    document = document or {}
    later = [r for r in document.get("rounds_run", []) if "started_s" in r]
    if not later or "elapsed_s" not in document:
        return None
    trials = sum(r.get("trials", 0) for r in later)
    spent = float(document["elapsed_s"]) - float(later[0]["started_s"])
    return spent / trials if trials and spent > 0 else None


WHY = {
    "reached max": "reached the most seeds (max) undecided",
    "time budget": "the time budget ended",
    "trials failed": "a trial failed (a rerun retries it)",
    "not asked": "not run by this launch (--only)",
}


def rounds_section(document: Mapping[str, Any] | None) -> list[Any]:
    """The design of the rounds, then a table of each variant's seeds and why it got no more (report blocks).
    ``document``: the launch's ``rounds.json`` (no blocks without rounds)."""
    import pandas as pd  # here, not above: a launch imports this module for its judge, and starts faster without

    from ablate.reporting.blocks import Paragraph, Table
    from ablate.reporting.text import esc

    if not document:
        return []
    design = document["design"]
    budget = (
        f", no round that would end after {design['max_minutes']:g} minutes at the pace measured"
        if design.get("max_minutes")
        else ""
    )
    intro = (
        f"Seeds were added in rounds: {design['start']} per variant first, then "
        f"{added_words(design['step'], design.get('growth') or 1.0)} per round to "
        f"each variant whose primary comparison was still undetermined (and its reference), up to {design['max']}"
        f"{budget}; the error rate holds across the rounds (a "
        f"{SPENDING_WORDS[design.get('spending') or 'obrien-fleming']} alpha-spending boundary). "
        f"{document['round']} round{'s' if document['round'] != 1 else ''} ran."
    )
    rows = []
    for name, entry in document["variants"].items():
        why = entry.get("why") or "the reference of the others"
        verdict = f"{entry['verdict']}, " if entry.get("verdict") and why.startswith("decided") else ""
        rows.append(
            {"variant": esc(name), "seeds": entry.get("seeds", 0), "why it stopped": f"{verdict}{WHY.get(why, why)}"}
        )
    return [Paragraph(intro), Table(pd.DataFrame(rows), "Seeds in rounds")]
