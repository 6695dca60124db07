"""An env's facts from Gymnasium's registry, not from its name: a registered env with its own reward threshold
(issue 44) solves at it in the experiment's default metric, the rounds' judge and the report's fallback."""

import gymnasium as gym
import pandas as pd

from ablate.config import TrialConfig
from ablate.env_spec import profile_of, solve_threshold
from ablate.experiment import parse_experiment

ENV_ID = "AblateThreshold100-v0"
"""CartPole under a new id whose spec says ``reward_threshold=100``: no module knows it by name."""
if ENV_ID not in gym.registry:
    gym.register(
        id=ENV_ID,
        entry_point="gymnasium.envs.classic_control:CartPoleEnv",
        reward_threshold=100,
        max_episode_steps=200,
    )


def _experiment(**extra):
    data = {"name": "threshold100", "base": {"env_id": ENV_ID, "max_episodes": 400}, "seeds": [0, 1, 2, 3]}
    data["variants"] = [{"name": "small", "hidden_sizes": [8]}, {"name": "large", "hidden_sizes": [64]}]
    return parse_experiment(data | extra, "threshold100.toml")


def test_the_solve_threshold_is_the_files_else_the_specs_else_none():
    assert solve_threshold(TrialConfig(env_id=ENV_ID)) == 100.0
    assert solve_threshold(TrialConfig(env_id=ENV_ID, solve_threshold=50.0)) == 50.0
    assert solve_threshold(TrialConfig(env_id="CartPole-v1")) == 475.0
    assert solve_threshold(TrialConfig(env_id="ALE/Pong-v5")) is None


def test_the_profile_is_the_experiments_else_the_first_matching_the_env_id():
    assert profile_of(TrialConfig(env_id="ALE/Pong-v5")).name == "pong"
    assert profile_of(TrialConfig(env_id="ALE/Breakout-v5")).name == "atari"
    assert profile_of(TrialConfig(env_id="ALE/Breakout-v5", env_profile="pong")).name == "pong"
    assert profile_of(TrialConfig(env_id=ENV_ID)).name == "gym"
    assert (
        profile_of(TrialConfig(env_id="ALE/Pong-v5")).resets_on_score
        and not profile_of(TrialConfig(env_id=ENV_ID)).resets_on_score
    )


def test_a_registered_envs_threshold_makes_episodes_to_solve_the_default_primary_metric():
    assert _experiment().primary_metric == "episodes_to_solve"
    assert _experiment(primary="episodes_to_solve").primary == "episodes_to_solve"  # valid: it can solve


def test_the_rounds_judge_a_registered_env_on_episodes_to_solve():
    from ablate.launch.rounds import Primary
    from ablate.reporting.rounds import judge_for

    experiment = _experiment(seeds={"start": 4, "step": 4, "max": 8})
    solved = {"solved": 1.0, "episodes_to_solve": 150.0}
    finished = {
        "small": [Primary(s, solved, 400) for s in range(4)],
        "large": [Primary(s, {"solved": 0.0}, 400) for s in range(4)],
    }
    (verdict,) = judge_for(experiment)(finished).verdicts
    assert verdict.metric == "episodes_to_solve"


def test_the_report_names_the_threshold_the_trials_recorded_else_the_specs():
    from ablate.reporting.results import Ablation

    grid = {"base": {"env_id": "NotRegisteredHere-v0"}, "variants": [{"name": "a"}], "baseline": "a"}
    recorded = Ablation("t", grid, {}, pd.DataFrame(), pd.DataFrame(), {"a": {"env.solve_threshold": "100.0"}})
    assert recorded.threshold == 100.0 and recorded.primary_metric == "episodes_to_solve"
    ran_budget = Ablation("t", grid, {}, pd.DataFrame(), pd.DataFrame(), {"a": {"env.solve_threshold": "None"}})
    assert ran_budget.threshold is None and ran_budget.primary_metric == "auc"
    old = Ablation("t", grid | {"base": {"env_id": ENV_ID}}, {}, pd.DataFrame(), pd.DataFrame(), {"a": {}})
    assert old.threshold == 100.0  # a store from before the record: the spec's, by the one function
