"""Experiment files: an experiment's variants, seeds, ``[tune]`` and name, loaded from TOML and validated into
frozen dataclasses over ``ablate.config``'s trial configuration. Standard library only.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import re
import tomllib
import unicodedata
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from ablate.config import (
    DEFAULT,
    KNOBS,
    MAX_NAME_LENGTH,
    MAX_TRIALS,
    MAX_TUNE_SEEDS,
    MAX_VARIANT_NAME_LENGTH,
    SHORTHANDS,
    TUNABLE_KNOBS,
    TUNE_SEED_START,
    ConfigError,
    TrialConfig,
    apply_knobs,
    clipped,
    declared_values,
    is_int,
)
from ablate.env_spec import solve_threshold_or_none
from ablate.measures import claim_names, default_primary_metric, measure, tune_names
from ablate.schema import knob, number, one_of
from ablate.seeds import SeedRounds, parse_seeds

_SAFE_NAME = re.compile(r"[A-Za-z0-9_-]{1,100}")
"""Names used as they are where a name becomes a folder: every name valid before names in any script were."""


@dataclass(frozen=True)
class Variant:
    """A named architecture (or setting) in an ablation, with the knobs it changes over the base."""

    name: str
    overrides: tuple[tuple[str, Any], ...]
    config: TrialConfig
    """The base with the overrides applied; ``seed`` is left at the base's and set per trial."""
    seeds: tuple[int, ...] | None = None
    """Its own ``seeds`` (round 1's, with ``rounds``); ``None``: the experiment's."""
    rounds: SeedRounds | None = None
    """Its own seeds table; ``None``: the experiment's (or none, where its own ``seeds`` is fixed)."""


@dataclass(frozen=True)
class TuneSpec:
    """``[tune]``: per variant, which values of the optimisation knobs to try on the tuning seeds, and how to
    pick one (see ``ablate.launch.tuning``)."""

    knobs: tuple[tuple[str, tuple[Any, ...]], ...]
    """``(knob, candidate values)`` pairs, in file order; a variant tries every combination."""
    seeds: tuple[int, ...]
    """Tuning seeds, from ``TUNE_SEED_START`` up: disjoint from every evaluation seed."""
    metric: str = knob("auc", **one_of(tune_names()))
    """A tunable measure's name (``measures.tune_names``)."""
    max_episodes: int | None = knob(
        None, check=lambda v: v is None or KNOBS["max_episodes"].check(v), valid=KNOBS["max_episodes"].valid
    )
    """Tuning trials' episode budget; ``None``: the evaluation budget (each variant's ``max_episodes``)."""

    @property
    def direction(self) -> str:
        """``max`` or ``min``: which way the metric is better."""
        return measure(self.metric).direction

    @property
    def knob_names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.knobs)

    def tuned_knobs(self, variant: Variant) -> tuple[str, ...]:
        """The knobs this variant is tuned on: those it does not set itself (``course`` keeps its own rate)."""
        own = {key for key, _ in variant.overrides}
        return tuple(name for name in self.knob_names if name not in own)

    def candidates(self, variant: Variant) -> list[dict[str, Any]]:
        """Every combination of candidate values of the variant's tuned knobs (``[{}]`` when it tunes none)."""
        tuned = self.tuned_knobs(variant)
        values = dict(self.knobs)
        return [dict(zip(tuned, combo, strict=True)) for combo in itertools.product(*(values[k] for k in tuned))]


@dataclass(frozen=True)
class Experiment:
    """An ablation: a base trial config, variants over it, seeds, and the variant the others are compared to. The
    fields declared with ``schema.knob`` are top-level keys of the file, checked as declared (``parse_experiment``)."""

    name: str
    path: str
    base: TrialConfig
    variants: tuple[Variant, ...]
    seeds: tuple[int, ...]
    baseline: str
    description: str = knob("", check=lambda v: isinstance(v, str), valid="a string")
    resources_per_trial: float = knob(1.0, **number(0, 64, open_low=True), name="cpus_per_trial")
    """CPUs Ray reserves per trial; fractions allowed (e.g. 0.5 packs two trials per core)."""
    gpus_per_trial: float = knob(0.0, **number(0, 16))
    """GPUs Ray reserves per trial; fractions allowed (0.25 packs four trials per GPU)."""
    smallest_effect: float = knob(
        0.1,
        **number(0, 1, open_low=True, open_high=True)
        | {"valid": "a fraction in (0, 1), e.g. 0.1 for a difference of 10% of the reference variant's value"},
    )
    """The smallest difference worth finding, as a fraction of the reference variant's value (0.1: 10% fewer
    or more episodes to solve; a return or AUC 10% of the reference's apart). The report says how many seeds
    per variant would separate a difference this large; it changes no trial."""
    primary: str | None = knob(
        None,
        check=lambda v: v is None or v in claim_names(),
        valid=f"one of {', '.join(claim_names())} (or leave it out: episodes_to_solve where the env has a solve "
        "threshold, else auc)",
    )
    """The metric the report's claims are made on (``measures.claim_names``); ``None``: as
    ``measures.default_primary_metric`` picks. The other metrics stay exploratory. It changes no trial."""
    tune: TuneSpec | None = None
    """``[tune]``: tune each variant's optimisation knobs on tuning seeds first; ``None``: no tuning stage."""
    rounds: SeedRounds | None = None
    """``seeds = { start, step, max }``: seeds added in rounds (``seeds`` then holds round 1's); ``None``: the
    fixed ``seeds``."""

    @property
    def primary_metric(self) -> str:
        """``primary``, or its default for this experiment's env."""
        if self.primary is not None:
            return self.primary
        return default_primary_metric([solve_threshold_or_none(v.config) for v in self.variants])

    def seeds_of(self, variant: Variant) -> tuple[int, ...]:
        """The variant's evaluation seeds of round 1 (every seed, without rounds)."""
        return self.seeds if variant.seeds is None else variant.seeds

    def rounds_of(self, variant: Variant) -> SeedRounds | None:
        """The variant's seed rounds: its own table, the experiment's unless it fixes its own seeds, or none."""
        if variant.seeds is not None:
            return variant.rounds
        return self.rounds

    def max_seeds_of(self, variant: Variant) -> tuple[int, ...]:
        """Every evaluation seed the variant may run (round 1's, then those rounds may add)."""
        rounds = self.rounds_of(variant)
        return tuple(range(rounds.max)) if rounds else self.seeds_of(variant)

    @property
    def storage_name(self) -> str:
        """The name where it names a folder, an MLflow experiment or a lock file (see ``storage_name``)."""
        return storage_name(self.name)


_SETTINGS = (f.metadata["knob"].name or f.name for f in fields(Experiment) if "knob" in f.metadata)
EXPERIMENT_KEYS = ("name", "seeds", "baseline", *_SETTINGS, "base", "variants", "grid", "tune")
"""The top-level keys; the settings among them (``description``, ``cpus_per_trial`` ...) as ``Experiment``
declares them."""


def load_experiment(path: str | Path) -> Experiment:
    """Read and validate an experiment TOML file; every problem is a ``ConfigError`` naming file and key."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such experiment file")
    try:
        # utf-8-sig: a byte-order mark (Windows editors write one) is not part of the TOML.
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML: tables or arrays nested too deeply to read") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file") from None
    return parse_experiment(data, str(path))


def parse_experiment(data: Mapping[str, Any], source: str) -> Experiment:
    for key in data:
        if key not in EXPERIMENT_KEYS:
            raise ConfigError(f"{source}: {key}: unknown key; valid top-level keys: {', '.join(EXPERIMENT_KEYS)}")
    name = data.get("name", Path(source).stem)
    problem = name_problem(name)
    if problem:
        raise ConfigError(f"{source}: name = {clipped(name)} is invalid ({problem}); valid: {NAME_RULE}")
    name = unicodedata.normalize("NFC", name)
    settings = declared_values(Experiment, data, f"{source}: ")
    seeds, rounds = parse_seeds(data.get("seeds", 5), f"{source}: seeds")

    base_table = data.get("base", {})
    if not isinstance(base_table, dict):
        raise ConfigError(f"{source}: base must be a table of knobs, e.g. [base] learning_rate = 0.01")
    folder = Path(source).parent
    base = apply_knobs(DEFAULT, _without_seed(base_table, f"{source}: base."), f"{source}: base.", folder)

    variants: list[Variant] = []
    explicit = data.get("variants", [])
    if not isinstance(explicit, list) or not all(isinstance(v, dict) for v in explicit):
        raise ConfigError(f'{source}: variants must be an array of tables, e.g. [[variants]] name = "deep"')
    for i, table in enumerate(explicit):
        where = f"{source}: variants[{i}]."
        table = dict(table)
        vname = table.pop("name", None)
        if not isinstance(vname, str) or not vname.strip():
            raise ConfigError(f"{where}name: missing or empty; valid: a non-empty string naming the variant")
        if len(vname) > MAX_VARIANT_NAME_LENGTH:
            raise ConfigError(
                f"{where}name = {clipped(vname)} is invalid; valid: at most {MAX_VARIANT_NAME_LENGTH} characters"
            )
        own_seeds, own_rounds = parse_seeds(table.pop("seeds"), f"{where}seeds") if "seeds" in table else (None, None)
        knobs = _without_seed(table, where)
        config = apply_knobs(base, knobs, where, folder)
        variants.append(Variant(vname, tuple(knobs.items()), config, own_seeds, own_rounds))

    grid = data.get("grid", {})
    if not isinstance(grid, dict):
        raise ConfigError(f"{source}: grid must be a table of axes, e.g. [grid] dropout = [0.0, 0.2]")
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"{source}: grid.{key} = {values!r} is invalid; valid: a non-empty list of values to try")
    axes = list(grid)
    count = len(explicit) + (math.prod(len(grid[a]) for a in axes) if axes else 0)
    most = rounds.max if rounds else len(seeds)
    if count * most > MAX_TRIALS:
        sizes = [f"{len(explicit)} variants"] if explicit else []
        if axes:
            sizes.append("grid: " + " x ".join(f"{len(grid[a])} {a}" for a in axes))
        what = sizes[0] if len(sizes) == 1 else f"({' + '.join(sizes)})"
        raise ConfigError(f"{source}: {what} x {most} seeds is {count * most:,} trials; valid: at most {MAX_TRIALS:,}")
    if axes:
        for combo in itertools.product(*(grid[a] for a in axes)):
            knobs = _without_seed(dict(zip(axes, combo, strict=True)), f"{source}: grid.")
            vname = ",".join(f"{a}={_short(v)}" for a, v in knobs.items())
            variants.append(Variant(vname, tuple(knobs.items()), apply_knobs(base, knobs, f"{source}: grid.", folder)))

    if not variants:
        raise ConfigError(f"{source}: the grid is empty; add [[variants]] tables or a [grid] with at least one axis")
    seen: set[str] = set()
    for v in variants:
        if v.name in seen:
            raise ConfigError(f"{source}: variants: duplicate variant name {v.name!r}; valid: unique names")
        seen.add(v.name)

    baseline = data.get("baseline", variants[0].name)
    if baseline not in seen:
        raise ConfigError(
            f"{source}: baseline = {baseline!r} is invalid; valid: one of the variant names {sorted(seen)}"
        )
    every_seed = {s for v in variants for s in (v.seeds or ())} | set(range(rounds.max) if rounds else seeds)
    every_seed |= {s for v in variants if v.rounds for s in range(v.rounds.max)}
    first_round = len(seeds) if rounds else len(every_seed)  # a tuned variant's base-value trials: round 1's seeds
    tune = _parse_tune(data.get("tune"), source, grid, tuple(variants), tuple(sorted(every_seed)), first_round)
    primary = settings["primary"]
    needs_threshold = primary is not None and measure(primary).needs_threshold
    if needs_threshold and any(solve_threshold_or_none(v.config) is None for v in variants):
        without = " or ".join(m for m in claim_names() if not measure(m).needs_threshold)
        raise ConfigError(
            f"{source}: primary = {primary!r} is invalid: {base.env_id} has no solve threshold; valid: {without}, or "
            "set solve_threshold in [base]"
        )
    return Experiment(name, source, base, tuple(variants), seeds, baseline, tune=tune, rounds=rounds, **settings)


def _parse_tune(
    table: Any,
    source: str,
    grid: Mapping[str, Any],
    variants: tuple[Variant, ...],
    seeds: tuple[int, ...],
    first_round: int,
) -> TuneSpec | None:
    """``[tune]`` checked as a whole: each bad value is one ``ConfigError`` naming ``tune.<key>``."""
    if table is None:
        return None
    where = f"{source}: tune"
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table, e.g. [tune] learning_rate = [0.01, 0.03, 0.1]")
    knobs: list[tuple[str, tuple[Any, ...]]] = []
    tunable = ", ".join(TUNABLE_KNOBS)
    for key, value in table.items():
        if key in ("seeds", "metric", "max_episodes"):
            continue
        if key in TUNABLE_KNOBS:
            if key in grid:
                raise ConfigError(
                    f"{where}.{key}: also a [grid] axis; valid: a knob is either compared ([grid]) or tuned ([tune])"
                )
            if not isinstance(value, list) or not value:
                raise ConfigError(
                    f"{where}.{key} = {clipped(value)} is invalid; valid: a non-empty list of candidate values"
                )
            knob = KNOBS[key]
            for candidate in value:
                if not knob.check(candidate):
                    raise ConfigError(f"{where}.{key}: candidate {clipped(candidate)} is invalid; valid: {knob.valid}")
            converted = tuple(knob.convert(v) for v in value)
            if len(set(converted)) != len(converted):
                raise ConfigError(f"{where}.{key} = {clipped(value)} is invalid; valid: distinct candidate values")
            knobs.append((key, converted))
        elif key in KNOBS or key in SHORTHANDS:
            raise ConfigError(
                f"{where}.{key}: not tunable (architecture, regularisation and setting knobs are what the ablation "
                f"compares); valid: optimisation knobs {tunable}, and seeds, metric, max_episodes"
            )
        else:
            raise ConfigError(
                f"{where}.{key}: unknown key; valid: {tunable} (candidate lists), seeds, metric, max_episodes"
            )
    if not knobs:
        raise ConfigError(f"{where}: no knob to tune; valid: e.g. learning_rate = [0.01, 0.03, 0.1]")
    count = table.get("seeds", 3)
    if not (is_int(count) and 1 <= count <= MAX_TUNE_SEEDS):
        raise ConfigError(
            f"{where}.seeds = {clipped(count)} is invalid; valid: a count of tuning seeds in [1, {MAX_TUNE_SEEDS}] "
            f"(they are {TUNE_SEED_START}, {TUNE_SEED_START + 1}, ...)"
        )
    settings = declared_values(TuneSpec, table, f"{where}.")
    high = [s for s in seeds if s >= TUNE_SEED_START]
    if high:
        raise ConfigError(
            f"{source}: seeds: {high[0]} is invalid with [tune]; valid: evaluation seeds below {TUNE_SEED_START:,} "
            f"(tuning seeds are {TUNE_SEED_START:,} up)"
        )
    spec = TuneSpec(tuple(knobs), tuple(range(TUNE_SEED_START, TUNE_SEED_START + count)), **settings)
    # Stage 1 (every candidate on every tuning seed) and stage 2 (the choice and the base value per seed).
    tuning = sum(len(spec.candidates(v)) for v in variants if spec.tuned_knobs(v)) * count
    evaluation = len(variants) * (len(seeds) + first_round)  # at the chosen values, and at the base value
    if tuning + evaluation > MAX_TRIALS:
        raise ConfigError(
            f"{where}: {tuning:,} tuning trials and up to {evaluation:,} evaluation trials is more than "
            f"{MAX_TRIALS:,} trials; valid: fewer candidates, tuning seeds or variants"
        )
    return spec


def _without_seed(table: Mapping[str, Any], where: str) -> dict[str, Any]:
    if "seed" in table:
        raise ConfigError(f"{where}seed: set seeds at the top level (seeds = 5 or seeds = [0, 1, 2])")
    return dict(table)


NAME_RULE = f"1 to {MAX_NAME_LENGTH} characters in any script, without control characters, '/' or '\\'"


def name_problem(name: Any) -> str:
    """Why ``name`` cannot name an experiment ("" when it can): ``NAME_RULE``, and not only dots (``.`` and
    ``..`` are folders already). Judged on its NFC form, the form it is stored under."""
    if not isinstance(name, str):
        return "not a string"
    name = unicodedata.normalize("NFC", name)
    if not name.strip():
        return "empty"
    if len(name) > MAX_NAME_LENGTH:
        return f"{len(name)} characters"
    if any(unicodedata.category(c) in ("Cc", "Cs", "Cn") for c in name):
        return "a control or unassigned character"
    if "/" in name or "\\" in name:
        return "a path separator"
    if not name.strip("."):
        return "only dots"
    return ""


def storage_name(name: str) -> str:
    """The form of an experiment's name where it names a folder (``reports/<this>``, ``mlartifacts/<this>``,
    Tune's ``<this>-<launch>``), an MLflow experiment or a lock file: the name itself when it is 1 to 100
    ASCII letters, digits, '-' and '_' (so every name valid before keeps its folders and its MLflow
    experiment), else a readable ASCII slug of it and 8 hex digits of its NFC form's SHA-1: ``实验é`` is
    ``e-<hash>``. At most 57 bytes: within any file system's 255 for one component. A storage name maps to
    itself, so a report asked for by it finds the same experiment."""
    name = unicodedata.normalize("NFC", name)
    if _SAFE_NAME.fullmatch(name):
        return name
    digest = hashlib.sha1(name.encode()).hexdigest()[:8]
    # é -> e, ﬁ -> fi: letters with marks keep their base letter; other scripts drop out (the hash tells apart).
    ascii_text = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode()
    slug = re.sub(r"[^A-Za-z0-9_]+", "-", ascii_text).strip("-_")[:48].strip("-_")
    return f"{slug or 'experiment'}-{digest}"


def _short(value: Any) -> str:
    if isinstance(value, list | tuple):
        return "x".join(str(v) for v in value) or "linear"
    return str(value)
