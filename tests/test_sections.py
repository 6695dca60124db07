"""reporting/sections.py: the method's tables take their columns from the schema (``config.SETTING_KNOBS``, an
env's knobs by their declaration), not from lists of knob names kept beside it."""

from __future__ import annotations

import pandas as pd

from ablate import config
from ablate.reporting.blocks import Table
from ablate.reporting.results import Ablation
from ablate.reporting.sections import method_blocks


def _ablation(**base: object) -> Ablation:
    grid = {
        "variants": [{"name": "baseline", "overrides": {}}],
        "baseline": "baseline",
        "seeds": [0, 1],
        "base": {k: knob.default for k, knob in config.KNOBS.items()} | {"env_id": "CartPole-v1"} | base,
    }
    trials = pd.DataFrame({"key": ["b-0", "b-1"], "variant": "baseline", "seed": [0, 1], "status": "FINISHED"})
    return Ablation("t", grid, {}, trials, pd.DataFrame())


def _base_table(ablation: Ablation) -> pd.DataFrame:
    table = pd.DataFrame({"variant": ["baseline"], "parameter_count": [100]})
    found = [b for b in method_blocks(ablation, table) if isinstance(b, Table) and b.caption == "Base hyper-parameters"]
    return found[0].frame


def test_the_base_table_holds_every_setting_and_the_env_knobs_set_away_from_their_default():
    shown = _base_table(_ablation(max_episode_steps=200, action_set="all"))
    assert list(shown.columns) == [*config.SETTING_KNOBS, "max_episode_steps"]
    assert shown.max_episode_steps.iloc[0] == 200  # an env knob the base sets; action_set is at its default
    assert {"learning_rate", "gamma", "l2", "episodes_per_update", "max_episodes"} <= set(config.SETTING_KNOBS)
