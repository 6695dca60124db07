"""``ablate run --dry-run``: the trials a run would start, listed with their keys; nothing started or written.
Moved out of ``cli.py`` as it was, to keep the CLI under 500 lines.
"""

from __future__ import annotations

import json

from ablate.experiment import Experiment
from ablate.launch.grid import GridTrial, expand, tuning_trials
from ablate.launch.rounds import dry_run_lines


def dry_run(experiment: Experiment, trials: list[GridTrial]) -> int:
    """``ablate run --dry-run``: the trials a run would consider, and nothing started or written. With
    ``[tune]``: stage 1 (every candidate on the tuning seeds), then stage 2, whose chosen values are known only
    after tuning (listed "after tuning"; the base-value trials are the untuned ones, with their keys)."""
    overrides = {v.name: ", ".join(f"{k}={json.dumps(x)}" for k, x in v.overrides) for v in experiment.variants}
    total = len(expand(experiment))
    rows = [("variant", "seed", "key", "overrides")]
    if experiment.tune is None:
        print(f"{experiment.name}: {len(trials)} of {total} trials (dry run: nothing started or written)")
        rows += [(t.variant, str(t.seed), t.key, overrides.get(t.variant, "") or "-") for t in trials]
    else:
        spec = experiment.tune
        wanted = {t.variant for t in trials}
        tuning = [t for t in tuning_trials(experiment) if t.variant in wanted]
        tuned = {v.name for v in experiment.variants if v.name in wanted and spec.tuned_knobs(v)}
        after = [t for t in trials if t.variant in tuned]
        print(
            f"{experiment.name}: {len(tuning)} tuning trials, then {len(trials)} at the base values and up to "
            f"{len(after)} at the chosen values (dry run: nothing started or written)"
        )
        rows += [
            (
                f"{t.variant} [tune]",
                str(t.seed),
                t.key,
                ", ".join(
                    f"{k}={getattr(t.config, k)}"
                    for k in spec.tuned_knobs(next(v for v in experiment.variants if v.name == t.variant))
                )
                or "its own values",
            )
            for t in tuning
        ]
        rows += [(f"{t.variant} [base]", str(t.seed), t.key, overrides.get(t.variant, "") or "-") for t in trials]
        rows += [(f"{t.variant} [chosen]", str(t.seed), "after tuning", "the chosen values") for t in after]
    print(*dry_run_lines(experiment, trials), sep="\n") if experiment.rounds else None
    if experiment.storage_name != experiment.name:
        print(
            f"stored as {experiment.storage_name!r}: reports/{experiment.storage_name}/, the MLflow experiment "
            f"and Tune's folders (the name in a form every file system takes)"
        )
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    for row in rows:
        print("  ".join(cell.ljust(w) for cell, w in zip(row[:3], widths, strict=True)) + "  " + row[3])
    print("a real run skips the trials already finished in the newest generation (see: ablate status)")
    return 0  # EXIT_OK
