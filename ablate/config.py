"""Typed, frozen configuration of one trial: the model and trial dataclasses, each field declared once with its
check (``ablate.schema``), and the lists every other module reads off those declarations; presets.

Standard library only. Every bad value raises ``ConfigError`` naming the key, the value and what is valid.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from ablate import schema, sources
from ablate.env_spec import PROFILES, profile_of
from ablate.schema import Knob, boolean, derived, integer, is_int, is_number, knob, number, one_of

__all__ = ["Knob", "is_int", "is_number"]  # re-exported: older callers import them from here

BUILT_IN_ENVS = ("CartPole-v0", "CartPole-v1", "ALE/Pong-v5")
"""The course's envs; ``env_id`` may name others (its docstring says which)."""
ARCHITECTURES = ("mlp", "cnn")
ACTIVATIONS = ("relu", "tanh", "elu", "gelu")
DEFAULT_POPULATION = 8
"""At most this many trials of a variant train together as one population unless ``--population`` says otherwise
(``launch.plan.population_size``; on a CPU a population changes speed, not results: ``agent.trainer``)."""

FAULTS = ("", "crash_once", "crash_after_checkpoint", "raise", "block")
MAX_NAME_LENGTH = 100
"""Characters in an experiment's name (any script); ``experiment.storage_name`` is its form on disk."""
MAX_VARIANT_NAME_LENGTH = 200
"""Characters in a variant's name: it starts every trial key, which names a folder of its own."""
MAX_TRIALS = 10_000
"""Trials (variants x seeds) one experiment may hold: more is a typo in a ``[grid]`` far more often than an
intent, and expanding it would take minutes and gigabytes before the first trial starts."""
# --- the Pong profile's knobs (issue 9) ---
ACTION_SETS = ("all", "move")
# --- tuning (issue 19) ---
TUNE_SEED_START = 10_000
"""Tuning seeds are ``TUNE_SEED_START``, ``+1``, ...; evaluation seeds must stay below it, so the comparison
never sees a seed its settings were chosen on."""
MAX_TUNE_SEEDS = 100


class ConfigError(ValueError):
    """Bad user input: the message is one line a user can act on."""


def clipped(value: Any, limit: int = 60) -> str:
    """``repr`` of a bad value, shortened so the error stays one readable line."""
    text = repr(value)
    size = len(value) if isinstance(value, str) else len(text)
    return text if len(text) <= limit else f"{text[:limit]}... ({size} characters)"


def freeze(value: Any) -> Any:
    """A TOML value made hashable: tables as sorted ``(name, value)`` tuples, lists as tuples."""
    if isinstance(value, Mapping):
        return tuple(sorted((str(k), freeze(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(freeze(v) for v in value)
    return value


_FACTORY = re.compile(r"^(?P<target>[^:]+):(?P<function>[A-Za-z_][A-Za-z0-9_]*)$")
_ENV_ID = re.compile(r"^[A-Za-z0-9_./-]+$")


def _sizes(allow_empty: bool, valid: str) -> dict[str, Any]:
    return {
        "check": lambda v: (
            isinstance(v, list | tuple) and (allow_empty or len(v) > 0) and all(is_int(x) and 1 <= x <= 4096 for x in v)
        ),
        "valid": valid,
        "convert": tuple,
    }


def _table(valid: str) -> dict[str, Any]:
    return {"check": lambda v: isinstance(v, dict), "valid": valid, "convert": freeze}


_NET = {"population": True, "built_in": True}


@dataclass(frozen=True)
class ModelConfig:
    """The architecture knobs an ablation varies."""

    architecture: str = knob("mlp", **one_of(ARCHITECTURES), **_NET, architecture=True)
    """``mlp``: the current observation through dense layers. ``cnn``: for CartPole, a 1-D convolution over
    time across the last ``history`` observations (it can read velocities and trends off the window), then
    the dense layers; for Pong, the course's 2-D convolutions over the 80x80 frame difference."""
    hidden_sizes: tuple[int, ...] = knob(
        (32,), **_sizes(True, "a list of layer widths in [1, 4096], e.g. [64, 64]"), **_NET, architecture=True
    )
    """Width of each dense hidden layer; its length is the depth. ``()`` is a linear policy."""
    activation: str = knob("relu", **one_of(ACTIVATIONS), **_NET)
    """Non-linearity after every hidden layer: one of ``ACTIVATIONS``."""
    dropout: float = knob(0.0, **number(0, 1, open_high=True), **_NET, words="dropout {}")
    """Dropout probability after every hidden layer, in [0, 1). Active in updates, off while acting."""
    layer_norm: bool = knob(False, **boolean(), **_NET, key_since=3, words="LayerNorm before each hidden activation")
    """A ``LayerNorm`` (with its scale and shift) after each dense hidden layer, before its activation."""
    history: int = knob(4, **integer(2, 64), **_NET, architecture=True, only_for="cnn")
    """``cnn`` on CartPole only: how many recent observations the convolution sees (>= 2)."""
    conv_channels: tuple[int, ...] = knob(
        (16,),
        **_sizes(False, "a non-empty list of channel counts in [1, 4096]"),
        **_NET,
        architecture=True,
        only_for="cnn",
    )
    """``cnn`` on CartPole only: output channels of each 1-D convolution layer."""
    kernel_size: int = knob(2, **integer(1, 64), **_NET, architecture=True, only_for="cnn")
    """``cnn`` on CartPole only: temporal kernel size of each convolution, <= ``history``."""
    factory: str = knob(
        "",
        check=lambda v: isinstance(v, str) and bool(_FACTORY.match(v)),
        valid="'FILE.py:FUNCTION' (relative to the experiment file) or 'package.module:FUNCTION'",
        name="model",
        key_since=2,
        population=True,
    )
    """The user's own network (the experiment's ``model`` key): ``FILE.py:FUNCTION`` (a path relative to the
    experiment file) or ``package.module:FUNCTION``; "" for the built-in networks, whose knobs above then apply."""
    factory_args: tuple[tuple[str, Any], ...] = knob(
        (),
        **_table("a table of the model factory's keyword arguments"),
        name="model_args",
        key_since=2,
        population=True,
    )
    """``model_args``: keyword arguments of the factory, as sorted ``(name, value)`` pairs (lists as tuples)."""
    factory_hash: str = derived("", key_since=2, population=True)
    """SHA-1 (12 hex digits) of the factory's source file and the local files it imports (``sources``): in the
    trial key, so an edited network or helper reruns."""
    factory_source: sources.Bundle = derived((), key_since=None, tracked=False, population=True, repr=False)
    """A ``FILE.py`` factory (or a module in the experiment's folder) and the local files it imports, as
    ``(path, text)`` pairs, shipped with the trial so a node without them builds the same network (checked against
    ``factory_hash``); not a tracked parameter."""


_ENV = {"population": True, "env": True}
_ATARI = tuple(name for name, profile in PROFILES.items() if profile.atari)


@dataclass(frozen=True)
class TrialConfig:
    """Everything one training run depends on. Two equal configs give identical results."""

    env_id: str = knob(
        "CartPole-v1",
        check=lambda v: isinstance(v, str) and bool(_ENV_ID.match(v)),
        valid=f"a registered Gymnasium id such as {', '.join(BUILT_IN_ENVS)}, Acrobot-v1 or ALE/Breakout-v5",
        aliases=("--env",),
        **_ENV,
    )
    """Gymnasium id: any registered env with ``Discrete`` actions and a ``Box`` observation (``BUILT_IN_ENVS``
    are the course's)."""
    env_args: tuple[tuple[str, Any], ...] = knob(
        (), **_table("a table of gym.make's keyword arguments"), key_since=2, **_ENV
    )
    """Keyword arguments of ``gym.make`` (the experiment's ``env_args`` table), as sorted ``(name, value)`` pairs."""
    env_module: str = knob(
        "",
        check=sources.is_module_spec,
        valid="a module to import before gym.make, e.g. 'mypkg.envs', or 'module:function' to call, e.g. "
        "'minatar.gym:register_envs'",
        key_since=2,
        **_ENV,
    )
    """A module imported before ``gym.make`` (where a user's own env registers itself), ``module:function`` to call
    a function of it too (``minatar.gym:register_envs``); "" for none."""
    env_module_hash: str = derived("", key_since=3, **_ENV)
    """SHA-1 (12 hex digits) of a local ``env_module`` (in the experiment's folder) and the local files it imports:
    in the trial key; "" for an installed one."""
    env_module_source: sources.Bundle = derived((), key_since=None, tracked=False, repr=False)
    """A local ``env_module``'s files as ``(path, text)`` pairs, shipped with the trial like a factory's."""
    model: ModelConfig = field(default_factory=ModelConfig)
    learning_rate: float = knob(0.03, **number(0, 1, open_low=True), tunable=True, setting=True)
    """Adam step size, in (0, 1]."""
    gamma: float = knob(0.95, **number(0, 1, open_low=True), setting=True)
    """Discount factor in (0, 1]. The course uses 0.95 for CartPole and 0.99 for Pong."""
    l2: float = knob(0.0, **number(0, 1), setting=True)
    """L2 penalty coefficient (a loss term over weight matrices, see ``reinforce.train_step``), >= 0."""
    episodes_per_update: int = knob(32, **integer(1, 256), tunable=True, population=True, setting=True)
    """Complete episodes collected (in parallel, from a vectorised env) per Adam step, >= 1."""
    max_episodes: int = knob(3000, **integer(1, 1_000_000), setting=True)
    """Episode budget, >= 1: the trial stops here if it has not solved the task."""
    solve_threshold: float | None = knob(
        None,
        check=lambda v: v is None or (is_number(v) and math.isfinite(v)),
        valid="a finite number (or leave it out for the env's threshold)",
    )
    """Rolling mean return that counts as solved; ``None``: the env spec's ``reward_threshold``."""
    solve_window: int = knob(100, **integer(1, 10_000), setting=True)
    """Episodes in the rolling mean, >= 1."""
    seed: int = knob(0, check=lambda v: is_int(v) and 0 <= v < 2**31, valid="an integer in [0, 2**31)")
    """Seeds torch, the action sampler and the environment."""
    record_video: bool = knob(True, **boolean(), key_since=None)
    """A video of one greedy episode of the trained agent: ``ablate train`` writes it; in a launch the report
    records it for the seeds it shows (from the run's ``weights.pt`` and ``config.json``)."""
    video_max_frames: int = knob(500, **integer(1, 100_000), key_since=None)
    """Cap on the video's length in frames (25 fps for CartPole: 500 frames show a whole 1,000-step episode)."""
    fault: str = knob(
        "", **one_of(FAULTS, f"one of {', '.join(map(repr, FAULTS))} (tests only)"), key_since=None, test_only=True
    )
    """Test-only: ``crash_once`` kills the trial's process the first time, ``crash_after_checkpoint`` the
    first time right after a checkpoint, ``raise`` raises after the first update, ``block`` waits until
    ``fault_marker`` exists. Never set it in a real experiment."""
    fault_marker: str = knob(
        "", check=lambda v: isinstance(v, str), valid="a file path (tests only)", key_since=None, test_only=True
    )
    """Test-only: a file path ``crash_once`` uses to remember it already crashed, ``block`` waits for."""

    # --- env profiles and their knobs, collection, videos and checkpoints (issue 9) ---
    env_profile: str = knob(
        "",
        **one_of(("", *PROFILES), "one of " + ", ".join(map(repr, PROFILES)) + " (or leave it out: by env_id)"),
        key_since=4,
        **_ENV,
    )
    """The env family's pipeline (``env_spec.PROFILES``): ``pong`` (the course's Pong pre-processing, for any Atari
    game), ``atari`` (``AtariPreprocessing``), ``gym`` (the env as Gymnasium makes it); "": by ``env_id``."""
    action_set: str = knob(
        "all",
        **one_of(ACTION_SETS, "'all' (the game's minimal action set) or 'move' (its RIGHT and LEFT)"),
        profiles=("pong",),
        **_ENV,
    )
    """Pong profile: ``all`` (the game's minimal action set) or ``move`` (RIGHT and LEFT only, as in pg-pong)."""
    frameskip: int = knob(4, **integer(1, 16), profiles=_ATARI, **_ENV)
    """Atari profiles: emulator frames per agent step (the action repeats), ALE v5's default 4."""
    repeat_action_probability: float = knob(0.25, **number(0, 1), profiles=_ATARI, **_ENV)
    """Atari profiles: sticky actions, the chance the emulator repeats the previous action in a frame (v5: 0.25)."""
    max_episode_steps: int = knob(0, **integer(0, 1_000_000, " (0: the env's limit)"), **_ENV)
    """Agent steps after which an episode is cut short (truncated); 0: the env's own limit. For smoke runs."""
    num_envs: int = knob(0, **integer(0, 256, " (0: episodes_per_update)"), population=True)
    """Pong only: sub-envs stepped together, acting in one batched forward; finished ones start a new episode
    at once, so an update's episodes may begin under the previous weights. 0: ``episodes_per_update``."""
    video_every: int = knob(0, **integer(0, 1_000_000, " (0: off)"))
    """Pong only: every this many episodes, record the next episode of sub-env 0 as the *sampling* policy
    plays it during training (up to ``video_max_frames`` frames) into ``videos/``; 0: none."""
    checkpoint_every: int | None = knob(None, **integer(0, 1_000_000, " (0: never)"))
    """Episodes between trial checkpoints (weights, optimizer, RNGs, envs, history); 0: never;
    ``None``: 50 for Pong, never for CartPole (its trials last seconds)."""

    @property
    def checkpoint_interval(self) -> int:
        if self.checkpoint_every is not None:
            return self.checkpoint_every
        return profile_of(self).checkpoint_every


SCHEMA: dict[str, Knob] = schema.fields_of(TrialConfig)
"""Every field of a trial's config by column (``model.hidden_sizes``), declared once above."""
KNOBS: dict[str, Knob] = {k.key_name: k for k in SCHEMA.values() if k.user}
"""The knobs a user writes, by the experiment file's key."""
TUNABLE_KNOBS = tuple(name for name, k in KNOBS.items() if k.tunable)
"""Optimisation knobs ``[tune]`` may search; architecture and regularisation knobs are what an ablation
compares, so tuning them would tune away the effect being measured."""
SETTING_KNOBS = tuple(name for name, k in KNOBS.items() if k.setting)
POPULATION_COLUMNS = tuple(column for column, k in SCHEMA.items() if k.population)
ENV_COLUMNS = tuple(column for column, k in SCHEMA.items() if k.env)


# Shorthands an experiment may use instead of hidden_sizes: ``depth`` layers of ``width`` units.
SHORTHANDS = {
    "depth": ("an integer in [0, 16]", lambda v: is_int(v) and 0 <= v <= 16),
    "width": ("an integer in [1, 4096]", lambda v: is_int(v) and 1 <= v <= 4096),
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


def declared_values(cls: type, table: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The value in ``table`` (else the default) of each field of ``cls`` declared with ``schema.knob``, checked and
    converted, by field name; a bad one is a ``ConfigError`` naming ``where``, the key and what is valid."""
    values = {}
    for f in fields(cls):
        declared = f.metadata.get("knob")
        if declared is None:
            continue
        key = declared.name or f.name
        value = table.get(key, f.default)
        if not declared.check(value):
            raise ConfigError(f"{where}{key} = {clipped(value)} is invalid; valid: {declared.valid}")
        values[f.name] = declared.convert(value)
    return values


BUILT_IN_MODEL_KNOBS = (*(name for name, k in KNOBS.items() if k.built_in), *SHORTHANDS)
ARCHITECTURE_KNOBS = frozenset(name for name, k in KNOBS.items() if k.architecture) | set(SHORTHANDS)


def _check_profile(config: TrialConfig, where: str) -> None:
    """The env profile can make the env, and every env knob set away from its default is one the profile honours."""
    profile = profile_of(config)
    if not config.env_id.startswith(profile.needs):
        raise ConfigError(
            f"{where}env_profile = {profile.name!r} is invalid for env_id = {config.env_id!r}; valid: an env id "
            f"starting {profile.needs!r}, or another profile ({', '.join(PROFILES)})"
        )
    for name, declared in KNOBS.items():
        if declared.profiles and profile.name not in declared.profiles and getattr(config, name) != declared.default:
            raise ConfigError(
                f"{where}{name} = {getattr(config, name)!r} is invalid for env_id = {config.env_id!r} (profile "
                f"{profile.name!r}, which ignores it); valid: only with env_profile "
                + " or ".join(map(repr, declared.profiles))
            )


def apply_knobs(
    base: TrialConfig, knobs: Mapping[str, Any], where: str = "", base_dir: Path | None = None
) -> TrialConfig:
    """A copy of ``base`` with the flat ``knobs`` applied (``depth``/``width`` expand to ``hidden_sizes``; a
    ``model`` factory is resolved relative to ``base_dir``, the experiment file's folder)."""
    trial_updates: dict[str, Any] = {}
    model_updates: dict[str, Any] = {}
    for key, value in knobs.items():
        converted = check_knob(key, value, where)
        if key in SHORTHANDS:
            continue
        knob = KNOBS[key]
        (model_updates if knob.owner == "model" else trial_updates)[knob.attr or key] = converted
    built_in = [k for k in knobs if k in BUILT_IN_MODEL_KNOBS]
    if "model" in knobs and built_in:
        raise ConfigError(
            f"{where}{built_in[0]}: a built-in network knob beside model = {knobs['model']!r}; valid: one or the "
            "other (your factory takes its own settings from model_args)"
        )
    if "model" in knobs:
        try:
            source, digest = sources.resolve_model(_FACTORY.match(knobs["model"])["target"], base_dir or Path.cwd())
        except sources.SourceError as error:
            raise ConfigError(f"{where}model = {knobs['model']!r} is invalid: {error}") from None
        model_updates |= {"factory_source": source, "factory_hash": digest}
    if "env_module" in knobs:
        bundle, digest = sources.resolve_env_module(knobs["env_module"], base_dir or Path.cwd())
        trial_updates |= {"env_module_source": bundle, "env_module_hash": digest}
    if "depth" in knobs or "width" in knobs:
        if "hidden_sizes" in knobs:
            raise ConfigError(f"{where}hidden_sizes: give either hidden_sizes or depth/width, not both")
        sizes = base.model.hidden_sizes
        depth = knobs.get("depth", len(sizes))
        width = knobs.get("width", sizes[0] if sizes else 32)
        model_updates["hidden_sizes"] = (width,) * depth
    model = replace(base.model, **model_updates)
    config = replace(base, model=model, **trial_updates)
    _check_profile(config, where)
    # Judged for every cnn, not by the env's name: the window's knobs are unused over an image, whose default pass.
    if model.architecture == "cnn" and model.kernel_size > model.history:
        raise ConfigError(
            f"{where}kernel_size = {model.kernel_size} is invalid; valid: at most history ({model.history})"
        )
    return config


def flatten(config: TrialConfig) -> dict[str, Any]:
    """Every tracked field as a flat ``{column: value}`` (model knobs prefixed ``model.``), for tracking and tables."""
    return schema.flatten(config, SCHEMA)


def key_fields(config: TrialConfig) -> dict[str, Any]:
    """The fields of ``config`` its trial key is made of (``Knob.in_key``)."""
    return {column: value for column, value in flatten(config).items() if SCHEMA[column].in_key(value)}


# The MIT 6.S191 lab's own setting: one episode per Adam step at 1e-3, one hidden layer of 32 units.
COURSE = TrialConfig(learning_rate=1e-3, episodes_per_update=1, gamma=0.95, model=ModelConfig(hidden_sizes=(32,)))
# Our default: the same network and gamma; 32 episodes per step from a vectorised env and a 30x larger
# step size (tuned on CartPole-v1, seeds 0-4: all solve, median under 2 s; see `make bench`).
DEFAULT = TrialConfig()
PRESETS: dict[str, TrialConfig] = {"default": DEFAULT, "course": COURSE}


def config_from_document(document: Mapping[str, Any]) -> TrialConfig:
    """The ``TrialConfig`` of a trial's ``config.json`` (``dataclasses.asdict`` of it, so its network can be rebuilt
    later: the report's videos): lists as tuples again; fields this version does not know are dropped, fields the
    document lacks (an older trial's) take their defaults."""

    def known(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
        names = {f.name for f in fields(cls)}
        return {k: freeze(v) if isinstance(v, list) else v for k, v in values.items() if k in names}

    model_values = known(ModelConfig, document.get("model", {}))
    if isinstance(model_values.get("factory_source"), str):  # an older trial's: the factory file's text alone
        text, target = model_values["factory_source"], model_values.get("factory", ":").rsplit(":", 1)[0]
        model_values["factory_source"] = ((Path(target).name, text),) if text else ()
    model = ModelConfig(**model_values)
    return TrialConfig(**(known(TrialConfig, document) | {"model": model}))


def population_group(config: TrialConfig) -> tuple:
    """Configs with one group share a population: the fields the schema marks ``population`` (one env, one
    network, one batch shape); everything else (seed, learning rate, L2, discount, budget, stop rule) is per member."""
    return tuple(schema.value_of(config, column) for column in POPULATION_COLUMNS)


def can_share(configs: Sequence[TrialConfig]) -> bool:
    """Whether ``configs`` can train as one population (one is always a population)."""
    return len({population_group(c) for c in configs}) <= 1
