"""Expand an experiment into trials (variants x seeds), each with a stable key.

The key is a hash of everything that changes a trial's result, so a re-run recognises finished trials.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from ablate.config import ConfigError, TrialConfig, key_fields
from ablate.experiment import Experiment
from ablate.schema import RESULTS_VERSION


@dataclass(frozen=True)
class GridTrial:
    key: str
    """``<variant>-s<seed>-<hash>``: stable across runs of the same experiment file."""
    variant: str
    seed: int
    config: TrialConfig
    stage: str = "eval"
    """``tune`` (stage 1: a candidate on a tuning seed) or ``eval`` (stage 2, and every untuned trial)."""


def config_hash(config: TrialConfig) -> str:
    """10 hex digits of the fields the schema puts in the key (``config.key_fields``) and of the trainer's results
    version (``schema.RESULTS_VERSION``)."""
    fields = {**key_fields(config), "results_version": RESULTS_VERSION}
    return hashlib.sha1(json.dumps(fields, sort_keys=True, default=list).encode()).hexdigest()[:10]


def variant_slug(variant: str) -> str:
    """The variant's name as it starts a trial key (a folder name): other characters become ``_``."""
    return re.sub(r"[^A-Za-z0-9._=-]+", "_", variant).strip("_") or "variant"


def trial_key(variant: str, config: TrialConfig) -> str:
    return f"{variant_slug(variant)}-s{config.seed}-{config_hash(config)}"


def expand(experiment: Experiment, every_round: bool = False) -> list[GridTrial]:
    """Every (variant, seed) pair, variant-major (``schedule_order`` gives the order they start in): round 1's
    seeds where seeds come in rounds, or with ``every_round`` every seed the rounds may add (the same keys).

    Two variant names with one slug (``"a b"`` and ``"a_b"``) are refused rather than told apart: with equal
    knobs they would share keys (one trial answering for both), and keys must stay what earlier launches
    recorded, so the slug rule cannot change."""
    by_slug: dict[str, str] = {}
    for variant in experiment.variants:
        other = by_slug.setdefault(variant_slug(variant.name), variant.name)
        if other != variant.name:
            raise ConfigError(
                f"{experiment.path}: variants {other!r} and {variant.name!r} would share the trial key prefix "
                f"{variant_slug(variant.name)!r}; valid: names that differ in letters, digits, '.', '=' or '-'"
            )
    return chosen_trials(experiment, {v.name: {} for v in experiment.variants}, every_round)


def schedule_order(trials: list[GridTrial], costs: dict[str, float] | None = None) -> list[GridTrial]:
    """The order trials are started in: seeds interleaved across variants (every variant's first seed, then
    every variant's second ...), so a quarter into a launch every variant's cost has been seen and the
    time-left estimate need not guess a slow variant from its budget. Within a round, trials known to be
    slow (``costs``: seconds by key, from earlier launches) go first, so no long trial starts last and runs
    alone. Only the order changes: every trial and its key stay as ``expand`` made them."""
    costs = costs or {}
    rounds: dict[str, int] = {}
    numbered = []
    for position, trial in enumerate(trials):
        rounds[trial.variant] = rounds.get(trial.variant, -1) + 1
        numbered.append((rounds[trial.variant], -costs.get(trial.key, 0.0), position, trial))
    return [trial for *_, trial in sorted(numbered, key=lambda item: item[:3])]


def tuning_trials(experiment: Experiment) -> list[GridTrial]:
    """Stage 1 of a ``[tune]`` experiment: every tuned variant x tuning seed x candidate, variant-major, each
    seed's candidates together (a quarter in, every candidate has a result, so the time-left estimate's guess
    at the choice is an informed one); ``[]`` without ``[tune]``. A variant that sets every tuned knob itself
    has no stage 1. Tuning trials record no video (nobody watches them) and use the tuning budget and seeds
    (``config.TUNE_SEED_START``)."""
    spec = experiment.tune
    if spec is None:
        return []
    trials = []
    budget = {"max_episodes": spec.max_episodes} if spec.max_episodes is not None else {}
    for variant in experiment.variants:
        if not spec.tuned_knobs(variant):
            continue  # it sets every tuned knob itself: nothing to choose
        for seed in spec.seeds:
            for values in spec.candidates(variant):
                config = replace(variant.config, seed=seed, record_video=False, **budget, **values)
                trials.append(GridTrial(trial_key(variant.name, config), variant.name, seed, config, "tune"))
    return trials


def chosen_trials(
    experiment: Experiment, choices: Mapping[str, Mapping[str, Any]], every_round: bool = False
) -> list[GridTrial]:
    """Stage 2 at the chosen values: each variant in ``choices`` on every evaluation seed (round 1's, or as in
    ``expand`` every seed the rounds may add) with its chosen knob values (a choice equal to the base value gives
    exactly the untuned trial, same key)."""
    trials = []
    for variant in experiment.variants:
        if variant.name not in choices:
            continue
        for seed in experiment.max_seeds_of(variant) if every_round else experiment.seeds_of(variant):
            config = replace(variant.config, seed=seed, **choices[variant.name])
            trials.append(GridTrial(trial_key(variant.name, config), variant.name, seed, config))
    return trials


PLOTTED_SEEDS = 5
"""Seeds per variant whose trials draw ``learning_curve.png`` in a launch: its first evaluation seeds (the first
round's, where seeds come in rounds) and its first tuning seeds. A figure costs the worker about what a CartPole
member's training does (~0.14 s), so a launch of thousands of seeds draws a bounded few; every trial keeps its
``episodes.csv``, curve metrics, weights and config, from which the report draws what it shows."""


def plotted_seeds(experiment: Experiment) -> dict[str, frozenset[int]]:
    """Per variant, the seeds whose trials draw their learning curve (``PLOTTED_SEEDS``): fixed by the experiment,
    so a resumed launch draws the same trials' figures."""
    tuning = experiment.tune.seeds[:PLOTTED_SEEDS] if experiment.tune is not None else ()
    return {v.name: frozenset((*experiment.max_seeds_of(v)[:PLOTTED_SEEDS], *tuning)) for v in experiment.variants}


def split_variants(text: str, names: list[str]) -> list[str]:
    """``--only a,b`` into variant names. Grid variants carry commas in their names (``depth=1,dropout=0.2``),
    so the longest run of comma-separated parts that is a known name wins; an unknown part is an error."""
    parts = [p.strip() for p in text.split(",")]
    chosen, i = [], 0
    while i < len(parts):
        for j in range(len(parts), i, -1):
            candidate = ",".join(parts[i:j])
            if candidate in names:
                chosen.append(candidate)
                i = j
                break
        else:
            raise ConfigError(f"--only: {parts[i]!r} is not a variant; valid: {', '.join(names)}")
    return chosen


def select(trials: list[GridTrial], only: list[str] | None, seeds: list[int] | None) -> list[GridTrial]:
    """The trials of the ``only`` variants (each a comma-separated list, see ``split_variants``) and ``seeds``;
    ``None`` keeps all. A variant or seed not in the experiment is a ``ConfigError`` naming the valid ones."""
    names = list(dict.fromkeys(t.variant for t in trials))
    all_seeds = list(dict.fromkeys(t.seed for t in trials))
    wanted = None if only is None else {name for text in only for name in split_variants(text, names)}
    for seed in seeds or []:
        if seed not in all_seeds:
            raise ConfigError(f"--seeds: {seed} is not a seed of this experiment; valid: {_ranges(all_seeds)}")
    return [t for t in trials if (wanted is None or t.variant in wanted) and (seeds is None or t.seed in seeds)]


def _ranges(seeds: list[int]) -> str:
    return (
        ", ".join(str(s) for s in seeds)
        if len(seeds) <= 12
        else f"{len(seeds)} seeds from {min(seeds)} to {max(seeds)}"
    )
