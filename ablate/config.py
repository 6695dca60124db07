"""Typed, frozen configuration: a model, a trial, an experiment; loading and validating experiment files.

Standard library only. Every bad value raises ``ConfigError`` naming the key, the value and what is valid.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
import re
import tomllib
import unicodedata
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

SUPPORTED_ENVS = ("CartPole-v0", "CartPole-v1", "ALE/Pong-v5")
ARCHITECTURES = ("mlp", "cnn")
ACTIVATIONS = ("relu", "tanh", "elu", "gelu")
FAULTS = ("", "crash_once", "crash_after_checkpoint", "raise", "block")
MAX_NAME_LENGTH = 100
"""Characters in an experiment's name (any script). Where it names a folder, an MLflow experiment or a lock
file, ``storage_name`` stands in for it: a component of at most 57 ASCII bytes."""
_SAFE_NAME = re.compile(r"[A-Za-z0-9_-]{1,100}")
"""Names used as they are where a name becomes a folder: every name valid before names in any script were."""
MAX_VARIANT_NAME_LENGTH = 200
"""Characters in a variant's name: it starts every trial key, which names a folder of its own."""
MAX_TRIALS = 10_000
"""Trials (variants x seeds) one experiment may hold: more is a typo in a ``[grid]`` far more often than an
intent, and expanding it would take minutes and gigabytes before the first trial starts."""
# --- Pong env knobs (issue 9) ---
PONG_ACTION_SETS = ("all", "move")
# --- tuning (issue 19) ---
TUNABLE_KNOBS = ("learning_rate", "episodes_per_update")
"""Optimisation knobs ``[tune]`` may search; architecture and regularisation knobs are what an ablation
compares, so tuning them would tune away the effect being measured."""
TUNE_METRICS = {"auc": "max", "episodes_to_solve": "min", "final_return": "max"}
"""What "best" means for a tuning candidate, and its direction: ``auc`` (mean rolling return over the budget),
``episodes_to_solve`` (censored at the budget when a seed never solves), ``final_return`` (the rolling mean
return at the end of the budget)."""
TUNE_SEED_START = 10_000
"""Tuning seeds are ``TUNE_SEED_START``, ``+1``, ...; evaluation seeds must stay below it, so the comparison
never sees a seed its settings were chosen on."""
MAX_TUNE_SEEDS = 100
"""``all``: Pong's 6 actions; ``move``: only UP and DOWN (ALE actions 2 and 3), as in Karpathy's pg-pong."""


class ConfigError(ValueError):
    """Bad user input: the message is one line a user can act on."""


@dataclass(frozen=True)
class ModelConfig:
    """The architecture knobs an ablation varies."""

    architecture: str = "mlp"
    """``mlp``: the current observation through dense layers. ``cnn``: for CartPole, a 1-D convolution over
    time across the last ``history`` observations (it can read velocities and trends off the window), then
    the dense layers; for Pong, the course's 2-D convolutions over the 80x80 frame difference."""
    hidden_sizes: tuple[int, ...] = (32,)
    """Width of each dense hidden layer; its length is the depth. ``()`` is a linear policy."""
    activation: str = "relu"
    """Non-linearity after every hidden layer: one of ``ACTIVATIONS``."""
    dropout: float = 0.0
    """Dropout probability after every hidden layer, in [0, 1). Active in updates, off while acting."""
    history: int = 4
    """``cnn`` on CartPole only: how many recent observations the convolution sees (>= 2)."""
    conv_channels: tuple[int, ...] = (16,)
    """``cnn`` on CartPole only: output channels of each 1-D convolution layer."""
    kernel_size: int = 2
    """``cnn`` on CartPole only: temporal kernel size of each convolution, <= ``history``."""


@dataclass(frozen=True)
class TrialConfig:
    """Everything one training run depends on. Two equal configs give identical results."""

    env_id: str = "CartPole-v1"
    """Gymnasium id: one of ``SUPPORTED_ENVS``."""
    model: ModelConfig = field(default_factory=ModelConfig)
    learning_rate: float = 0.03
    """Adam step size, in (0, 1]."""
    gamma: float = 0.95
    """Discount factor in (0, 1]. The course uses 0.95 for CartPole and 0.99 for Pong."""
    l2: float = 0.0
    """L2 penalty coefficient (a loss term over weight matrices, see ``reinforce.train_step``), >= 0."""
    episodes_per_update: int = 32
    """Complete episodes collected (in parallel, from a vectorised env) per Adam step, >= 1."""
    max_episodes: int = 3000
    """Episode budget, >= 1: the trial stops here if it has not solved the task."""
    solve_threshold: float | None = None
    """Rolling mean return that counts as solved; ``None``: the env spec's ``reward_threshold``."""
    solve_window: int = 100
    """Episodes in the rolling mean, >= 1."""
    seed: int = 0
    """Seeds torch, the action sampler and the environment."""
    record_video: bool = True
    """Record one greedy episode of the trained agent."""
    video_max_frames: int = 500
    """Cap on the video's length in frames (25 fps for CartPole: 500 frames show a whole 1,000-step episode)."""
    fault: str = ""
    """Test-only: ``crash_once`` kills the trial's process the first time, ``crash_after_checkpoint`` the
    first time right after a checkpoint, ``raise`` raises after the first update, ``block`` waits until
    ``fault_marker`` exists. Never set it in a real experiment."""
    fault_marker: str = ""
    """Test-only: a file path ``crash_once`` uses to remember it already crashed, ``block`` waits for."""

    # --- Pong env, collection, videos and checkpoints (issue 9); CartPole ignores the Pong-only ones ---
    action_set: str = "all"
    """Pong only: ``all`` (the 6 actions) or ``move`` (UP and DOWN only, as in Karpathy's pg-pong)."""
    frameskip: int = 4
    """Pong only: emulator frames per agent step (the action repeats), ALE/Pong-v5's default 4."""
    repeat_action_probability: float = 0.25
    """Pong only: sticky actions, the chance the emulator repeats the previous action in a frame (v5: 0.25)."""
    max_episode_steps: int = 0
    """Agent steps after which an episode is cut short (truncated); 0: the env's own limit. For smoke runs."""
    num_envs: int = 0
    """Pong only: sub-envs stepped together, acting in one batched forward; finished ones start a new episode
    at once, so an update's episodes may begin under the previous weights. 0: ``episodes_per_update``."""
    video_every: int = 0
    """Pong only: every this many episodes, record the next episode of sub-env 0 as the *sampling* policy
    plays it during training (up to ``video_max_frames`` frames) into ``videos/``; 0: none."""
    checkpoint_every: int | None = None
    """Episodes between trial checkpoints (weights, optimizer, RNGs, envs, history); 0: never;
    ``None``: 50 for Pong, never for CartPole (its trials last seconds)."""

    @property
    def checkpoint_interval(self) -> int:
        if self.checkpoint_every is not None:
            return self.checkpoint_every
        return 50 if self.reset_on_score else 0

    @property
    def vector_envs(self) -> int:
        return self.num_envs or self.episodes_per_update

    @property
    def reset_on_score(self) -> bool:
        """Pong's return restarts at every point scored."""
        return self.env_id.startswith("ALE/Pong")


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return (isinstance(v, int | float)) and not isinstance(v, bool)


def _sizes(v: Any, allow_empty: bool) -> bool:
    return isinstance(v, list | tuple) and (allow_empty or len(v) > 0) and all(_is_int(x) and 1 <= x <= 4096 for x in v)


@dataclass(frozen=True)
class Knob:
    """One user-settable value: where it lives, how it is checked, what is valid (for the error)."""

    owner: str  # "trial" or "model"
    check: Callable[[Any], bool]
    valid: str
    convert: Callable[[Any], Any] = lambda v: v


KNOBS: dict[str, Knob] = {
    "env_id": Knob("trial", lambda v: v in SUPPORTED_ENVS, f"one of {', '.join(SUPPORTED_ENVS)}"),
    "learning_rate": Knob("trial", lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]", float),
    "gamma": Knob("trial", lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]", float),
    "l2": Knob("trial", lambda v: _is_number(v) and 0 <= v <= 1, "a number in [0, 1]", float),
    "episodes_per_update": Knob("trial", lambda v: _is_int(v) and 1 <= v <= 256, "an integer in [1, 256]"),
    "max_episodes": Knob("trial", lambda v: _is_int(v) and 1 <= v <= 1_000_000, "an integer in [1, 1000000]"),
    "solve_threshold": Knob(
        "trial",
        lambda v: v is None or (_is_number(v) and math.isfinite(v)),
        "a finite number (or leave it out for the env's threshold)",
    ),
    "solve_window": Knob("trial", lambda v: _is_int(v) and 1 <= v <= 10_000, "an integer in [1, 10000]"),
    "seed": Knob("trial", lambda v: _is_int(v) and 0 <= v < 2**31, "an integer in [0, 2**31)"),
    "record_video": Knob("trial", lambda v: isinstance(v, bool), "true or false"),
    "video_max_frames": Knob("trial", lambda v: _is_int(v) and 1 <= v <= 100_000, "an integer in [1, 100000]"),
    "fault": Knob("trial", lambda v: v in FAULTS, f"one of {', '.join(map(repr, FAULTS))} (tests only)"),
    "fault_marker": Knob("trial", lambda v: isinstance(v, str), "a file path (tests only)"),
    # --- Pong env, collection, videos and checkpoints (issue 9) ---
    "action_set": Knob("trial", lambda v: v in PONG_ACTION_SETS, "'all' (6 actions) or 'move' (UP and DOWN)"),
    "frameskip": Knob("trial", lambda v: _is_int(v) and 1 <= v <= 16, "an integer in [1, 16]"),
    "repeat_action_probability": Knob("trial", lambda v: _is_number(v) and 0 <= v <= 1, "a number in [0, 1]", float),
    "max_episode_steps": Knob(
        "trial", lambda v: _is_int(v) and 0 <= v <= 1_000_000, "an integer in [0, 1000000] (0: the env's limit)"
    ),
    "num_envs": Knob(
        "trial", lambda v: _is_int(v) and 0 <= v <= 256, "an integer in [0, 256] (0: episodes_per_update)"
    ),
    "video_every": Knob("trial", lambda v: _is_int(v) and 0 <= v <= 1_000_000, "an integer in [0, 1000000] (0: off)"),
    "checkpoint_every": Knob(
        "trial", lambda v: _is_int(v) and 0 <= v <= 1_000_000, "an integer in [0, 1000000] (0: never)"
    ),
    "architecture": Knob("model", lambda v: v in ARCHITECTURES, f"one of {', '.join(ARCHITECTURES)}"),
    "hidden_sizes": Knob(
        "model",
        lambda v: _sizes(v, allow_empty=True),
        "a list of layer widths in [1, 4096], e.g. [64, 64]",
        tuple,
    ),
    "activation": Knob("model", lambda v: v in ACTIVATIONS, f"one of {', '.join(ACTIVATIONS)}"),
    "dropout": Knob("model", lambda v: _is_number(v) and 0 <= v < 1, "a number in [0, 1)", float),
    "history": Knob("model", lambda v: _is_int(v) and 2 <= v <= 64, "an integer in [2, 64]"),
    "conv_channels": Knob(
        "model",
        lambda v: _sizes(v, allow_empty=False),
        "a non-empty list of channel counts in [1, 4096]",
        tuple,
    ),
    "kernel_size": Knob("model", lambda v: _is_int(v) and 1 <= v <= 64, "an integer in [1, 64]"),
}
# Shorthands an experiment may use instead of hidden_sizes: ``depth`` layers of ``width`` units.
SHORTHANDS = {
    "depth": ("an integer in [0, 16]", lambda v: _is_int(v) and 0 <= v <= 16),
    "width": ("an integer in [1, 4096]", lambda v: _is_int(v) and 1 <= v <= 4096),
}


def check_knob(key: str, value: Any, where: str = "") -> Any:
    """Validate one knob and return it converted (lists to tuples, ints to floats where a float is meant)."""
    prefix = f"{where}{key}"
    if key in SHORTHANDS:
        valid, check = SHORTHANDS[key]
        if not check(value):
            raise ConfigError(f"{prefix} = {value!r} is invalid; valid: {valid}")
        return value
    knob = KNOBS.get(key)
    if knob is None:
        known = ", ".join(sorted([*KNOBS, *SHORTHANDS]))
        raise ConfigError(f"{prefix}: unknown key; valid keys: {known}")
    if not knob.check(value):
        raise ConfigError(f"{prefix} = {value!r} is invalid; valid: {knob.valid}")
    return knob.convert(value)


def apply_knobs(base: TrialConfig, knobs: Mapping[str, Any], where: str = "") -> TrialConfig:
    """A copy of ``base`` with the flat ``knobs`` applied (``depth``/``width`` expand to ``hidden_sizes``)."""
    trial_updates: dict[str, Any] = {}
    model_updates: dict[str, Any] = {}
    for key, value in knobs.items():
        converted = check_knob(key, value, where)
        if key in SHORTHANDS:
            continue
        (model_updates if KNOBS[key].owner == "model" else trial_updates)[key] = converted
    if "depth" in knobs or "width" in knobs:
        if "hidden_sizes" in knobs:
            raise ConfigError(f"{where}hidden_sizes: give either hidden_sizes or depth/width, not both")
        sizes = base.model.hidden_sizes
        depth = knobs.get("depth", len(sizes))
        width = knobs.get("width", sizes[0] if sizes else 32)
        model_updates["hidden_sizes"] = (width,) * depth
    model = replace(base.model, **model_updates)
    config = replace(base, model=model, **trial_updates)
    if model.architecture == "cnn" and config.env_id.startswith("CartPole") and model.kernel_size > model.history:
        raise ConfigError(
            f"{where}kernel_size = {model.kernel_size} is invalid; valid: at most history ({model.history})"
        )
    return config


def flatten(config: TrialConfig) -> dict[str, Any]:
    """Every knob as a flat ``{name: value}`` (model knobs prefixed ``model.``), for tracking and tables."""
    flat: dict[str, Any] = {}
    for f in fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            for g in fields(value):
                flat[f"{f.name}.{g.name}"] = getattr(value, g.name)
        else:
            flat[f.name] = value
    return flat


# The MIT 6.S191 lab's own setting: one episode per Adam step at 1e-3, one hidden layer of 32 units.
COURSE = TrialConfig(learning_rate=1e-3, episodes_per_update=1, gamma=0.95, model=ModelConfig(hidden_sizes=(32,)))
# Our default: the same network and gamma; 32 episodes per step from a vectorised env and a 30x larger
# step size (tuned on CartPole-v1, seeds 0-4: all solve, median under 2 s; see `make bench`).
DEFAULT = TrialConfig()
PRESETS: dict[str, TrialConfig] = {"default": DEFAULT, "course": COURSE}


@dataclass(frozen=True)
class Variant:
    """A named architecture (or setting) in an ablation, with the knobs it changes over the base."""

    name: str
    overrides: tuple[tuple[str, Any], ...]
    config: TrialConfig
    """The base with the overrides applied; ``seed`` is left at the base's and set per trial."""


@dataclass(frozen=True)
class TuneSpec:
    """``[tune]``: per variant, which values of the optimisation knobs to try on the tuning seeds, and how to
    pick one (see ``ablate.run.tuning``)."""

    knobs: tuple[tuple[str, tuple[Any, ...]], ...]
    """``(knob, candidate values)`` pairs, in file order; a variant tries every combination."""
    seeds: tuple[int, ...]
    """Tuning seeds, from ``TUNE_SEED_START`` up: disjoint from every evaluation seed."""
    metric: str = "auc"
    """A key of ``TUNE_METRICS``."""
    max_episodes: int | None = None
    """Tuning trials' episode budget; ``None``: the evaluation budget (each variant's ``max_episodes``)."""

    @property
    def direction(self) -> str:
        """``max`` or ``min``: which way the metric is better."""
        return TUNE_METRICS[self.metric]

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
    """An ablation: a base trial config, variants over it, seeds, and the variant the others are compared to."""

    name: str
    path: str
    description: str
    base: TrialConfig
    variants: tuple[Variant, ...]
    seeds: tuple[int, ...]
    baseline: str
    resources_per_trial: float = 1.0
    """CPUs Ray reserves per trial; fractions allowed (e.g. 0.5 packs two trials per core)."""
    gpus_per_trial: float = 0.0
    """GPUs Ray reserves per trial; fractions allowed (0.25 packs four trials per GPU). A trial puts its policy
    on CUDA whenever torch sees one."""
    smallest_effect: float = 0.1
    """The smallest difference worth finding, as a fraction of the reference variant's value (0.1: 10% fewer
    or more episodes to solve; a return or AUC 10% of the reference's apart). The report says how many seeds
    per variant would separate a difference this large; it changes no trial."""
    tune: TuneSpec | None = None
    """``[tune]``: tune each variant's optimisation knobs on tuning seeds first; ``None``: no tuning stage."""

    @property
    def storage_name(self) -> str:
        """The name where it names a folder, an MLflow experiment or a lock file (see ``storage_name``)."""
        return storage_name(self.name)


EXPERIMENT_KEYS = (
    "name",
    "description",
    "seeds",
    "baseline",
    "cpus_per_trial",
    "gpus_per_trial",
    "smallest_effect",
    "base",
    "variants",
    "grid",
    "tune",
)


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
        raise ConfigError(f"{source}: name = {_clip(name)} is invalid ({problem}); valid: {NAME_RULE}")
    name = unicodedata.normalize("NFC", name)
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError(f"{source}: description = {description!r} is invalid; valid: a string")

    seeds_value = data.get("seeds", 5)
    if _is_int(seeds_value) and 1 <= seeds_value <= 1000:
        seeds = tuple(range(seeds_value))
    elif (
        isinstance(seeds_value, list)
        and seeds_value
        and all(_is_int(s) and 0 <= s < 2**31 for s in seeds_value)
        and len(set(seeds_value)) == len(seeds_value)
    ):
        seeds = tuple(seeds_value)
    else:
        raise ConfigError(
            f"{source}: seeds = {seeds_value!r} is invalid; valid: a count in [1, 1000] or a list of distinct "
            "non-negative integers"
        )

    cpus = data.get("cpus_per_trial", 1.0)
    if not (_is_number(cpus) and 0 < cpus <= 64):
        raise ConfigError(f"{source}: cpus_per_trial = {cpus!r} is invalid; valid: a number in (0, 64]")

    gpus = data.get("gpus_per_trial", 0.0)
    if not (_is_number(gpus) and 0 <= gpus <= 16):
        raise ConfigError(f"{source}: gpus_per_trial = {gpus!r} is invalid; valid: a number in [0, 16]")

    smallest_effect = data.get("smallest_effect", Experiment.smallest_effect)
    if not (_is_number(smallest_effect) and 0 < smallest_effect < 1):
        raise ConfigError(
            f"{source}: smallest_effect = {smallest_effect!r} is invalid; valid: a fraction in (0, 1), e.g. 0.1 for "
            "a difference of 10% of the reference variant's value"
        )

    base_table = data.get("base", {})
    if not isinstance(base_table, dict):
        raise ConfigError(f"{source}: base must be a table of knobs, e.g. [base] learning_rate = 0.01")
    base = apply_knobs(DEFAULT, _without_seed(base_table, f"{source}: base."), where=f"{source}: base.")

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
                f"{where}name = {_clip(vname)} is invalid; valid: at most {MAX_VARIANT_NAME_LENGTH} characters"
            )
        knobs = _without_seed(table, where)
        variants.append(Variant(vname, tuple(knobs.items()), apply_knobs(base, knobs, where)))

    grid = data.get("grid", {})
    if not isinstance(grid, dict):
        raise ConfigError(f"{source}: grid must be a table of axes, e.g. [grid] dropout = [0.0, 0.2]")
    if grid:
        for key, values in grid.items():
            if not isinstance(values, list) or not values:
                raise ConfigError(
                    f"{source}: grid.{key} = {values!r} is invalid; valid: a non-empty list of values to try"
                )
        axes = list(grid)
        count = (len(explicit) + math.prod(len(grid[a]) for a in axes)) * len(seeds)
        if count > MAX_TRIALS:
            sizes = " x ".join(f"{len(grid[a])} {a}" for a in axes)
            raise ConfigError(
                f"{source}: grid: {sizes} x {len(seeds)} seeds is {count:,} trials; valid: at most {MAX_TRIALS:,}"
            )
        for combo in itertools.product(*(grid[a] for a in axes)):
            knobs = _without_seed(dict(zip(axes, combo, strict=True)), f"{source}: grid.")
            vname = ",".join(f"{a}={_short(v)}" for a, v in knobs.items())
            variants.append(Variant(vname, tuple(knobs.items()), apply_knobs(base, knobs, f"{source}: grid.")))

    if not variants:
        raise ConfigError(f"{source}: the grid is empty; add [[variants]] tables or a [grid] with at least one axis")
    if len(variants) * len(seeds) > MAX_TRIALS:
        raise ConfigError(
            f"{source}: {len(variants)} variants x {len(seeds)} seeds is {len(variants) * len(seeds):,} trials; "
            f"valid: at most {MAX_TRIALS:,}"
        )
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
    tune = _parse_tune(data.get("tune"), source, grid, tuple(variants), seeds)
    return Experiment(
        name,
        source,
        description,
        base,
        tuple(variants),
        seeds,
        baseline,
        float(cpus),
        float(gpus),
        smallest_effect=smallest_effect,
        tune=tune,
    )


def _parse_tune(
    table: Any, source: str, grid: Mapping[str, Any], variants: tuple[Variant, ...], seeds: tuple[int, ...]
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
                    f"{where}.{key} = {_clip(value)} is invalid; valid: a non-empty list of candidate values"
                )
            knob = KNOBS[key]
            for candidate in value:
                if not knob.check(candidate):
                    raise ConfigError(f"{where}.{key}: candidate {_clip(candidate)} is invalid; valid: {knob.valid}")
            converted = tuple(knob.convert(v) for v in value)
            if len(set(converted)) != len(converted):
                raise ConfigError(f"{where}.{key} = {_clip(value)} is invalid; valid: distinct candidate values")
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
    if not (_is_int(count) and 1 <= count <= MAX_TUNE_SEEDS):
        raise ConfigError(
            f"{where}.seeds = {_clip(count)} is invalid; valid: a count of tuning seeds in [1, {MAX_TUNE_SEEDS}] "
            f"(they are {TUNE_SEED_START}, {TUNE_SEED_START + 1}, ...)"
        )
    metric = table.get("metric", "auc")
    if metric not in TUNE_METRICS:
        raise ConfigError(f"{where}.metric = {_clip(metric)} is invalid; valid: one of {', '.join(TUNE_METRICS)}")
    budget = table.get("max_episodes")
    if budget is not None and not KNOBS["max_episodes"].check(budget):
        raise ConfigError(f"{where}.max_episodes = {_clip(budget)} is invalid; valid: {KNOBS['max_episodes'].valid}")
    high = [s for s in seeds if s >= TUNE_SEED_START]
    if high:
        raise ConfigError(
            f"{source}: seeds: {high[0]} is invalid with [tune]; valid: evaluation seeds below {TUNE_SEED_START:,} "
            f"(tuning seeds are {TUNE_SEED_START:,} up)"
        )
    spec = TuneSpec(tuple(knobs), tuple(range(TUNE_SEED_START, TUNE_SEED_START + count)), metric, budget)
    # Stage 1 (every candidate on every tuning seed) and stage 2 (the choice and the base value per seed).
    tuning = sum(len(spec.candidates(v)) for v in variants if spec.tuned_knobs(v)) * count
    evaluation = 2 * len(variants) * len(seeds)
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


def _clip(value: Any, limit: int = 60) -> str:
    """``repr`` of a bad value, shortened so the error stays one readable line."""
    text = repr(value)
    return (
        text
        if len(text) <= limit
        else f"{text[:limit]}... ({len(value) if isinstance(value, str) else len(text)} characters)"
    )


def _short(value: Any) -> str:
    if isinstance(value, list | tuple):
        return "x".join(str(v) for v in value) or "linear"
    return str(value)
