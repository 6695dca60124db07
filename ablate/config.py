"""Typed, frozen configuration of one trial: the model and trial dataclasses, every knob with its check, presets.

Standard library only. Every bad value raises ``ConfigError`` naming the key, the value and what is valid.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

BUILT_IN_ENVS = ("CartPole-v0", "CartPole-v1", "ALE/Pong-v5")
"""The course's envs; ``env_id`` may name any registered Gymnasium env with discrete actions and a Box observation
(``agent.checks`` refuses the others before a launch)."""
ARCHITECTURES = ("mlp", "cnn")
ACTIVATIONS = ("relu", "tanh", "elu", "gelu")
DEFAULT_POPULATION = 8
"""At most this many trials of a variant train together as one population unless ``--population`` says otherwise:
on a CPU each member is its trial alone, bit for bit, so a population changes speed, not results; ``launch.plan``
sizes them smaller where that keeps every CPU busy."""

FAULTS = ("", "crash_once", "crash_after_checkpoint", "raise", "block")
MAX_NAME_LENGTH = 100
"""Characters in an experiment's name (any script). Where it names a folder, an MLflow experiment or a lock
file, ``storage_name`` stands in for it: a component of at most 57 ASCII bytes."""
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
    factory: str = ""
    """The user's own network (the experiment's ``model`` key): ``FILE.py:FUNCTION`` (a path relative to the
    experiment file) or ``package.module:FUNCTION``; "" for the built-in networks, whose knobs above then apply."""
    factory_args: tuple[tuple[str, Any], ...] = ()
    """``model_args``: keyword arguments of the factory, as sorted ``(name, value)`` pairs (lists as tuples)."""
    factory_hash: str = ""
    """SHA-1 (12 hex digits) of the factory's source file: in the trial key, so an edited network reruns."""
    factory_source: str = field(default="", repr=False)
    """The text of a ``FILE.py`` factory, shipped with the trial so a node without the file builds the same
    network (checked against ``factory_hash``); not a tracked parameter."""


@dataclass(frozen=True)
class TrialConfig:
    """Everything one training run depends on. Two equal configs give identical results."""

    env_id: str = "CartPole-v1"
    """Gymnasium id: any registered env with ``Discrete`` actions and a ``Box`` observation (``BUILT_IN_ENVS``
    are the course's)."""
    env_args: tuple[tuple[str, Any], ...] = ()
    """Keyword arguments of ``gym.make`` (the experiment's ``env_args`` table), as sorted ``(name, value)`` pairs."""
    env_module: str = ""
    """A module imported before ``gym.make`` (where a user's own env registers itself); "" for none."""
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
    """A video of one greedy episode of the trained agent: ``ablate train`` writes it; in a launch the report
    records it for the seeds it shows (from the run's ``weights.pt`` and ``config.json``)."""
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
        """Pong's return restarts at every point scored (``env_spec.resets_on_score``)."""
        from ablate.env_spec import resets_on_score

        return resets_on_score(self.env_id)


def is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v: Any) -> bool:
    return (isinstance(v, int | float)) and not isinstance(v, bool)


def _sizes(v: Any, allow_empty: bool) -> bool:
    return isinstance(v, list | tuple) and (allow_empty or len(v) > 0) and all(is_int(x) and 1 <= x <= 4096 for x in v)


@dataclass(frozen=True)
class Knob:
    """One user-settable value: where it lives, how it is checked, what is valid (for the error)."""

    owner: str  # "trial" or "model"
    check: Callable[[Any], bool]
    valid: str
    convert: Callable[[Any], Any] = lambda v: v
    attr: str = ""
    """The dataclass field it sets, where it is not the key's own name (``model`` sets ``factory``)."""


def freeze(value: Any) -> Any:
    """A TOML value made hashable: tables as sorted ``(name, value)`` tuples, lists as tuples."""
    if isinstance(value, Mapping):
        return tuple(sorted((str(k), freeze(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(freeze(v) for v in value)
    return value


_FACTORY = re.compile(r"^(?P<target>[^:]+):(?P<function>[A-Za-z_][A-Za-z0-9_]*)$")
_ENV_ID = re.compile(r"^[A-Za-z0-9_./-]+$")


KNOBS: dict[str, Knob] = {
    "env_id": Knob(
        "trial",
        lambda v: isinstance(v, str) and bool(_ENV_ID.match(v)),
        f"a registered Gymnasium id such as {', '.join(BUILT_IN_ENVS)}, Acrobot-v1 or ALE/Breakout-v5",
    ),
    "env_args": Knob("trial", lambda v: isinstance(v, dict), "a table of gym.make's keyword arguments", freeze),
    "env_module": Knob(
        "trial",
        lambda v: isinstance(v, str) and all(p.isidentifier() for p in v.split(".")),
        "a module to import before gym.make, e.g. 'mypkg.envs'",
    ),
    "model": Knob(
        "model",
        lambda v: isinstance(v, str) and bool(_FACTORY.match(v)),
        "'FILE.py:FUNCTION' (relative to the experiment file) or 'package.module:FUNCTION'",
        attr="factory",
    ),
    "model_args": Knob(
        "model",
        lambda v: isinstance(v, dict),
        "a table of the model factory's keyword arguments",
        freeze,
        attr="factory_args",
    ),
    "learning_rate": Knob("trial", lambda v: is_number(v) and 0 < v <= 1, "a number in (0, 1]", float),
    "gamma": Knob("trial", lambda v: is_number(v) and 0 < v <= 1, "a number in (0, 1]", float),
    "l2": Knob("trial", lambda v: is_number(v) and 0 <= v <= 1, "a number in [0, 1]", float),
    "episodes_per_update": Knob("trial", lambda v: is_int(v) and 1 <= v <= 256, "an integer in [1, 256]"),
    "max_episodes": Knob("trial", lambda v: is_int(v) and 1 <= v <= 1_000_000, "an integer in [1, 1000000]"),
    "solve_threshold": Knob(
        "trial",
        lambda v: v is None or (is_number(v) and math.isfinite(v)),
        "a finite number (or leave it out for the env's threshold)",
    ),
    "solve_window": Knob("trial", lambda v: is_int(v) and 1 <= v <= 10_000, "an integer in [1, 10000]"),
    "seed": Knob("trial", lambda v: is_int(v) and 0 <= v < 2**31, "an integer in [0, 2**31)"),
    "record_video": Knob("trial", lambda v: isinstance(v, bool), "true or false"),
    "video_max_frames": Knob("trial", lambda v: is_int(v) and 1 <= v <= 100_000, "an integer in [1, 100000]"),
    "fault": Knob("trial", lambda v: v in FAULTS, f"one of {', '.join(map(repr, FAULTS))} (tests only)"),
    "fault_marker": Knob("trial", lambda v: isinstance(v, str), "a file path (tests only)"),
    # --- Pong env, collection, videos and checkpoints (issue 9) ---
    "action_set": Knob("trial", lambda v: v in PONG_ACTION_SETS, "'all' (6 actions) or 'move' (UP and DOWN)"),
    "frameskip": Knob("trial", lambda v: is_int(v) and 1 <= v <= 16, "an integer in [1, 16]"),
    "repeat_action_probability": Knob("trial", lambda v: is_number(v) and 0 <= v <= 1, "a number in [0, 1]", float),
    "max_episode_steps": Knob(
        "trial", lambda v: is_int(v) and 0 <= v <= 1_000_000, "an integer in [0, 1000000] (0: the env's limit)"
    ),
    "num_envs": Knob("trial", lambda v: is_int(v) and 0 <= v <= 256, "an integer in [0, 256] (0: episodes_per_update)"),
    "video_every": Knob("trial", lambda v: is_int(v) and 0 <= v <= 1_000_000, "an integer in [0, 1000000] (0: off)"),
    "checkpoint_every": Knob(
        "trial", lambda v: is_int(v) and 0 <= v <= 1_000_000, "an integer in [0, 1000000] (0: never)"
    ),
    "architecture": Knob("model", lambda v: v in ARCHITECTURES, f"one of {', '.join(ARCHITECTURES)}"),
    "hidden_sizes": Knob(
        "model",
        lambda v: _sizes(v, allow_empty=True),
        "a list of layer widths in [1, 4096], e.g. [64, 64]",
        tuple,
    ),
    "activation": Knob("model", lambda v: v in ACTIVATIONS, f"one of {', '.join(ACTIVATIONS)}"),
    "dropout": Knob("model", lambda v: is_number(v) and 0 <= v < 1, "a number in [0, 1)", float),
    "history": Knob("model", lambda v: is_int(v) and 2 <= v <= 64, "an integer in [2, 64]"),
    "conv_channels": Knob(
        "model",
        lambda v: _sizes(v, allow_empty=False),
        "a non-empty list of channel counts in [1, 4096]",
        tuple,
    ),
    "kernel_size": Knob("model", lambda v: is_int(v) and 1 <= v <= 64, "an integer in [1, 64]"),
}
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


BUILT_IN_MODEL_KNOBS = (
    "architecture", "hidden_sizes", "depth", "width", "activation", "dropout", "history", "conv_channels",
    "kernel_size",
)  # fmt: skip
"""Knobs of the built-in networks, which a user's own ``model`` does not read."""


def resolve_factory(spec: str, base_dir: Path, where: str = "") -> tuple[str, str]:
    """``model = spec``'s (source, hash): a ``FILE.py`` is read relative to ``base_dir`` and its text travels with
    the trial; a ``package.module`` is found on the path (its source is only hashed: each node imports its own).
    A file or module that does not exist is a ``ConfigError``."""
    target = _FACTORY.match(spec)["target"]
    if target.endswith(".py"):
        path = (base_dir / target).resolve()
        if not path.is_file():
            raise ConfigError(f"{where}model = {spec!r} is invalid: no such file {path}")
        text = path.read_text(encoding="utf-8")
        return text, hashlib.sha1(text.encode()).hexdigest()[:12]
    try:
        found = importlib.util.find_spec(target)
    except (ImportError, ValueError) as error:
        raise ConfigError(f"{where}model = {spec!r} is invalid: cannot import {target} ({error})") from None
    if found is None or not found.origin or not Path(found.origin).is_file():
        raise ConfigError(f"{where}model = {spec!r} is invalid: no module {target} on the Python path")
    return "", hashlib.sha1(Path(found.origin).read_bytes()).hexdigest()[:12]


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
        source, digest = resolve_factory(knobs["model"], base_dir or Path.cwd(), where)
        model_updates |= {"factory_source": source, "factory_hash": digest}
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


NOT_FLAT = ("model.factory_source",)
"""Fields that travel with a trial but are not knobs to track (a factory file's text: its hash is)."""


def flatten(config: TrialConfig) -> dict[str, Any]:
    """Every knob as a flat ``{name: value}`` (model knobs prefixed ``model.``), for tracking and tables."""
    flat: dict[str, Any] = {}
    for f in fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            for g in fields(value):
                if f"{f.name}.{g.name}" not in NOT_FLAT:
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


def config_document(config: TrialConfig) -> dict[str, Any]:
    """``config`` as JSON-safe data (tuples as lists), every field: what a trial leaves as ``config.json`` so that
    its network can be rebuilt later (the report's videos, ``config_from_document``)."""
    return dataclasses.asdict(config)


def config_from_document(document: Mapping[str, Any]) -> TrialConfig:
    """The ``TrialConfig`` of a ``config_document``: lists as tuples again; fields this version does not know are
    dropped, fields the document lacks (an older trial's) take their defaults."""

    def known(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
        names = {f.name for f in fields(cls)}
        return {k: freeze(v) if isinstance(v, list) else v for k, v in values.items() if k in names}

    model = ModelConfig(**known(ModelConfig, document.get("model", {})))
    return TrialConfig(**(known(TrialConfig, document) | {"model": model}))
