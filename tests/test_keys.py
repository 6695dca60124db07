"""Trial keys are users' resume state: every committed experiment file's keys, and a key per knob set away from
its default, are pinned (tests/data/trial_keys.json). A change to the schema or to how keys are made that moves one
fails here; a knob added at its default value must leave every pinned key as it is."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from ablate.config import DEFAULT
from ablate.experiment import load_experiment
from ablate.launch.grid import expand, trial_key, tuning_trials

ROOT = Path(__file__).resolve().parents[1]
PINNED = Path(__file__).with_name("data") / "trial_keys.json"

# One non-default value per knob that existed when the keys were pinned (a knob's field, as flatten names it).
SET_AWAY = {
    "env_id": "CartPole-v0",
    "env_args": (("sutton_barto_reward", True),),
    "env_module": "gymnasium.envs",
    "learning_rate": 0.01,
    "gamma": 0.99,
    "l2": 0.001,
    "episodes_per_update": 8,
    "max_episodes": 500,
    "solve_threshold": 150.0,
    "solve_window": 50,
    "action_set": "move",
    "frameskip": 2,
    "repeat_action_probability": 0.0,
    "max_episode_steps": 200,
    "num_envs": 4,
    "checkpoint_every": 10,
    "model.architecture": "cnn",
    "model.hidden_sizes": (64, 64),
    "model.activation": "tanh",
    "model.dropout": 0.2,
    "model.history": 3,
    "model.conv_channels": (8,),
    "model.kernel_size": 3,
    "model.factory": "examples/models/layernorm.py:create_model",
    "model.factory_args": (("width", 64),),
    "model.factory_hash": "0123456789ab",
}


def _set(name: str, value):
    if name.startswith("model."):
        return replace(DEFAULT, model=replace(DEFAULT.model, **{name.removeprefix("model."): value}))
    return replace(DEFAULT, **{name: value})


def current_keys() -> dict[str, list[str]]:
    keys: dict[str, list[str]] = {}
    for path in sorted((ROOT / "experiments").glob("*.toml")):
        experiment = load_experiment(path)
        trials = [*expand(experiment, every_round=True), *tuning_trials(experiment)]
        keys[path.name] = [t.key for t in trials]
    keys["knobs"] = [trial_key("v", DEFAULT)] + [f"{n}: {trial_key('v', _set(n, v))}" for n, v in SET_AWAY.items()]
    return keys


def test_every_pinned_trial_key_is_unchanged():
    pinned = json.loads(PINNED.read_text(encoding="utf-8"))
    assert current_keys() == pinned
