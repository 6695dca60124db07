"""``ablate run --dry-run``: the trials a run would start, listed with their keys after their cost (``time_line``);
nothing started or written.
"""

from __future__ import annotations

import json
import os
import statistics
from collections.abc import Callable
from typing import Any, TypeVar

from ablate.config import DEFAULT_POPULATION
from ablate.env_spec import profile_named
from ablate.launch.clock import clock
from ablate.launch.grid import GridTrial
from ablate.launch.plan import LaunchPlan, plan_populations
from ablate.launch.rounds import Rounds, dry_run_lines

T = TypeVar("T")
START_S = 14.0
"""Seconds a launch spends outside its trials (starting a local Ray and opening the store, then shutting Ray
down), where the store has no launch of the experiment yet: 0:11-0:14 for a fresh store's launch on 2 idle cores
(a student's 12 trials and the default ablation's 2,642, 2026-12-06). Nothing records it before a first launch,
so the dry run says it is a guess."""
GUESS = "a guess, measured on 2 idle cores"
REPORT_S = 15.0
"""Seconds ``ablate run`` spends writing the report (Markdown, HTML, PDF) of a first trial, plus ``REPORT_S_TRIAL``
a trial: 0:16 for 12 trials, 1:29 for 2,642 (the same two launches)."""
REPORT_S_TRIAL = 0.028


def report_guess(trials: int) -> float:
    """Seconds the report of ``trials`` trials takes where the store has no launch of it yet."""
    return REPORT_S + REPORT_S_TRIAL * trials


FALLBACK_ENV = "CartPole-v1"
"""The env whose seconds per episode (``env_spec.Profile.episode_seconds``) cost an env never measured."""


def episode_seconds(env_id: str, env_profile: str = "") -> float | None:
    """Seconds per episode of budget its profile measured for ``env_id`` (``None``: never measured)."""
    return profile_named(env_id, env_profile).episode_seconds.get(env_id)


def _rate(env_id: str, env_profile: str) -> tuple[float, bool]:
    """The seconds per episode a never-run trial of ``env_id`` is costed at, and whether they were measured for it
    (else ``FALLBACK_ENV``'s)."""
    measured = episode_seconds(env_id, env_profile)
    return (measured, True) if measured else (episode_seconds(FALLBACK_ENV), False)


def time_line(plan: LaunchPlan, report: bool = True) -> str:
    """The whole command's time, first: the trials' (``trial_time``), the start's and the report's, each with
    how it was estimated: the start and the report as this store's newest launch of the experiment took them
    (``Tracker.launch_times``), else ``START_S`` and ``report_guess``."""
    experiment = plan.experiment
    start_s, report_s = from_store(plan, lambda store: store.launch_times(), (None, None))
    measured = start_s is not None and (report_s is not None or not report)
    start_s = start_s if measured else START_S
    report_s = (report_s if measured else report_guess(len(plan.trials))) or 0.0
    overhead = start_s + (report_s if report else 0.0)
    parts = f"~{clock(start_s)} to start" + (f" and ~{clock(report_s)} for the report" if report else "")
    how = "as this store's last launch of it took them" if measured else GUESS
    guess = f"{parts}: {how}"
    trials_words, left, most = trial_time(plan)
    total = f"~{clock(left + overhead)}" + (f", at most ~{clock(most + overhead)}" if most is not None else "")
    budget = experiment.rounds.max_minutes if experiment.rounds else None
    if most is not None and budget is not None and most + start_s > 60 * budget:  # ``Rounds.past_budget``
        most = max(60 * budget - start_s, left)  # from the command's start, the report after
        total = f"~{clock(left + overhead)}, at most ~{clock(most + overhead)}"
        total += f" (max_minutes = {budget:g}: no round starts that would end later)"
    return f"time: {total} in all: {trials_words}; {guess}"


def trial_time(plan: LaunchPlan) -> tuple[str, float, float | None]:
    """The trials' time in words, with the two figures a launch's progress line gives, before anything runs: the
    time of round 1 (with its tuning) and the most the launch can take (every comparison to ``max`` seeds, round
    after round; None without rounds), from the store's earlier runs of these trials (and of their variants);
    without any, ``guessed_s``. Trials finished in the newest generation are skipped, as the run skips them
    (``plan.fresh``: none)."""
    from ablate.launch.estimate import estimate
    from ablate.launch.state import LaunchState
    from ablate.launch.tuning import unique

    experiment, trials, tuning = plan.experiment, plan.trials, plan.tuning
    wanted = {t.variant for t in trials}
    done = set() if plan.fresh else from_store(plan, finished_keys, set())
    known = {t.key for t in [*tuning, *trials]}
    todo = unique([*tuning, *trials], done)
    tuned = {t.variant for t in tuning}
    later = [t for t in trials if t.variant in tuned and t.key not in done]  # stage 2's stand-ins, at the base values
    slots = max(int((os.cpu_count() or 1) / experiment.resources_per_trial), 1)

    def groups(ts: list[GridTrial]) -> list[list[str]]:
        return [p.keys for p in plan_populations(ts, cap=DEFAULT_POPULATION, slots=slots)]

    possible: list[list[GridTrial]] = []
    if experiment.rounds is not None:
        possible = Rounds(experiment, wanted, judge=lambda samples: None).possible({}, known)  # type: ignore[arg-type, return-value]
    every = [*todo, *later, *(t for r in possible for t in r)]
    # The skipped ones' earlier runs too: they cost their variant's others.
    looked_up = [*known, *(t.key for t in every)]
    earlier = from_store(plan, lambda store: store.earlier_runs(looked_up)[0], {})
    prior = costed(every, earlier) or {t.key: guessed_s(t) for t in every}
    state = LaunchState(experiment.name, todo, 0, slots, 0.0, prior, groups=groups(todo), later=later,
                        later_groups=groups(later))  # fmt: skip
    state.set_possible(possible, groups([t for r in possible for t in r]))
    left, most = estimate(state, state.start)
    more = sum(len(r) for r in possible)
    rounds = f" and at most {more} more in later rounds" if more else ""
    assert left is not None and most is not None  # every trial has a prior cost
    words = f"trials ~{clock(left)} for round 1" if more else f"trials ~{clock(left)}"
    upper = f", at most ~{clock(most)}" if more else ""
    source = "from the store's earlier runs" if earlier else guess_words(every)
    source += f", on {slots} slot(s)"
    before = f", {len(known & done)} finished before" if known & done else ""
    return f"{words}{upper} ({len(todo) + len(later)} trials{before}{rounds}; {source})", left, most if more else None


def finished_keys(store: Any) -> set[str]:
    """The trials finished in the store's newest generation: what a run that continues it skips."""
    generation = store.latest_generation()
    return {r.key for r in store.trial_runs(generation) if r.status == "FINISHED"} if generation else set()


def costed(trials: list[GridTrial], earlier: dict[str, float]) -> dict[str, float]:
    """Seconds for each of ``trials`` before anything runs: its earlier run's where the store has one, else the
    mean of its variant's earlier runs, else of every earlier run (none without any earlier run)."""
    if not earlier:
        return {}
    by_variant: dict[str, list[float]] = {}
    for t in trials:
        if t.key in earlier:
            by_variant.setdefault(t.variant, []).append(earlier[t.key])
    overall = statistics.fmean(earlier.values())
    return {
        t.key: earlier[t.key] if t.key in earlier else statistics.fmean(by_variant.get(t.variant) or [overall])
        for t in trials
    }


def guessed_s(trial: GridTrial) -> float:
    """Seconds a trial no launch has run yet costs: its budget at its env's seconds per episode, ``FALLBACK_ENV``'s
    where its profile never measured its env."""
    return _rate(trial.config.env_id, trial.config.env_profile)[0] * trial.config.max_episodes


def guess_words(trials: list[GridTrial]) -> str:
    """How ``guessed_s`` costed ``trials``: each env's seconds per episode, ``FALLBACK_ENV``'s for one not measured."""
    envs = sorted({(t.config.env_id, t.config.env_profile) for t in trials})
    words = ", ".join(
        f"{rate:g} s per {e} episode" + ("" if measured else f" ({FALLBACK_ENV}'s: never measured)")
        for e, (rate, measured) in ((e, _rate(e, p)) for e, p in envs)
    )
    return f"no earlier run in the store: a guess at {words} of budget, measured once on 2 cores"


def from_store(plan: LaunchPlan, read: Callable[[Any], T], nothing: T) -> T:
    """``read`` of the experiment's store opened to read (its ``Tracker``), or ``nothing`` where the store does not
    exist yet (MLflow not imported for nothing) or cannot be read."""
    from ablate.launch.store import TrackingError, resolve_uri, sqlite_path

    path = sqlite_path(resolve_uri(plan.tracking_uri))
    if path is not None and not path.exists():
        return nothing
    from ablate.launch.tracking import Tracker

    try:
        return read(Tracker(plan.tracking_uri, plan.experiment.name, write=False))
    except TrackingError:
        return nothing


def dry_run(plan: LaunchPlan, report: bool = True) -> int:
    """``ablate run --dry-run``: the trials a run would consider, and nothing started or written. With
    ``[tune]``: stage 1 (every candidate on the tuning seeds), then stage 2, whose chosen values are known only
    after tuning (listed "after tuning"; the base-value trials are the untuned ones, with their keys)."""
    experiment, trials = plan.experiment, plan.trials
    overrides = {v.name: ", ".join(f"{k}={json.dumps(x)}" for k, x in v.overrides) for v in experiment.variants}
    total = len(plan.grid)
    print(time_line(plan, report))  # first: `| head` keeps it
    rows = [("variant", "seed", "key", "overrides")]
    if experiment.tune is None:
        print(f"{experiment.name}: {len(trials)} of {total} trials (dry run: nothing started or written)")
        rows += [(t.variant, str(t.seed), t.key, overrides.get(t.variant, "") or "-") for t in trials]
    else:
        spec, tuning = experiment.tune, plan.tuning
        variants = {v.name: v for v in experiment.variants}
        tuned = {t.variant for t in tuning}
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
                ", ".join(f"{k}={getattr(t.config, k)}" for k in spec.tuned_knobs(variants[t.variant]))
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
