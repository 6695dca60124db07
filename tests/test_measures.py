"""Each measure defined once: AUC by hand, censoring, the default primary metric, and the trainer's recorded AUC
equal to the report's on the same curve."""

import math

import numpy as np
import pandas as pd
import pytest

from ablate.agent.records import EpisodeMetrics, TrialResult
from ablate.config import TrialConfig
from ablate.measures import (
    area_under_curve,
    censored_episodes,
    default_primary_metric,
    reaches_threshold,
    trial_measures,
)


def test_area_under_curve_carries_the_last_value_to_the_budget():
    assert area_under_curve(np.array([0.0, 10.0]), budget=4) == pytest.approx((0 + 10 + 10 + 10) / 4)
    assert area_under_curve([1.0, 2.0, 3.0], budget=2) == 1.5  # a curve past the budget is cut at it
    assert np.isnan(area_under_curve([], budget=5))


def test_unsolved_trials_count_as_their_budget():
    episodes = censored_episodes([True, False], [120.0, np.nan], [400, 400])
    assert episodes.tolist() == [120.0, 400.0]


def test_the_solve_rule_needs_a_full_window_and_a_threshold():
    assert reaches_threshold(100.0, True, 100.0)
    assert not reaches_threshold(100.0, False, 100.0) and not reaches_threshold(99.9, True, 100.0)
    assert not reaches_threshold(1e9, True, None)


def test_the_default_primary_metric_is_episodes_only_where_every_trial_can_solve():
    assert default_primary_metric([475.0, 100.0]) == "episodes_to_solve"
    assert default_primary_metric([475.0, None]) == "auc"


def test_the_trainers_recorded_auc_is_the_reports_on_the_same_curve():
    window, budget = 4, 12
    returns = [9.0, 14.0, 10.0, 31.0, 22.0, 40.0, 57.0]  # stopped early, as a solved trial does
    rolling = [math.fsum(returns[max(0, i - window + 1) : i + 1]) / min(i + 1, window) for i in range(len(returns))]
    episodes = [
        EpisodeMetrics(i + 1, r, 10, 0.0, 0.0, m, 10 * (i + 1), 0.1, i + 1)
        for i, (r, m) in enumerate(zip(returns, rolling, strict=True))
    ]
    config = TrialConfig(max_episodes=budget, solve_window=window)
    recorded = TrialResult(config, episodes, None, None, 70, 1.0, 10).summary()["auc"]
    curve = pd.DataFrame({"episode": range(1, len(returns) + 1), "return": returns})
    curve["rolling_mean"] = curve["return"].rolling(window, min_periods=1).mean()  # as results._curve reads it
    assert recorded == trial_measures(curve, budget, (), window)["auc"]


def test_each_name_maps_back_to_one_entry_and_a_parameterised_one_to_its_value():
    from ablate.measures import AUC, EPISODES_TO_SOLVE, FINAL_RETURN, episodes_to, lookup, measure, return_at

    assert measure("auc") is AUC and measure("episodes_to_solve") is EPISODES_TO_SOLVE
    assert measure("return") is FINAL_RETURN and measure("final_return") is FINAL_RETURN  # a claim's name, a tune's
    assert measure("return_at_750") == return_at(750) and measure("return_at_750").parameter == 750
    assert measure("episodes_to_-15") == episodes_to(-15.0) and measure("episodes_to_-15").reached == "reached_-15"
    assert measure(episodes_to(0.5).name).parameter == 0.5 and measure(episodes_to(1e6).name).parameter == 1e6
    assert lookup("return_at_x") is None and lookup("speed") is None
    with pytest.raises(KeyError):
        measure("speed")
    assert (AUC.direction, EPISODES_TO_SOLVE.direction, FINAL_RETURN.direction) == ("max", "min", "max")


def test_a_censored_measure_read_from_a_summary_is_the_budget_where_it_never_got_there():
    from ablate.measures import AUC, EPISODES_TO_SOLVE, FINAL_RETURN

    assert EPISODES_TO_SOLVE.from_summary({"solved": 1.0, "episodes_to_solve": 120.0}, 400) == (120.0, False)
    assert EPISODES_TO_SOLVE.from_summary({"solved": 0.0}, 400) == (400.0, True)
    assert EPISODES_TO_SOLVE.from_summary({"solved": 0.0, "episodes_to_solve": np.nan}, 400) == (400.0, True)
    assert FINAL_RETURN.from_summary({"final_rolling_mean": 31.5}, 400) == (31.5, False)
    value, censored = AUC.from_summary({}, 400)
    assert math.isnan(value) and not censored


def test_the_curves_solve_rule_is_the_trainers():
    from ablate.measures import Curve, recorded

    curve = Curve(np.array([30.0, 5.0, 20.0, 20.0, 30.0]), budget=8, threshold=20.0, window=3)
    # episode 1's rolling mean is above 20, but over a window of one: the first full window ends at episode 3
    assert curve.first_full(20.0) == 3 and curve.first_full(25.0) == 5
    assert math.isnan(curve.first_full(31.0))
    assert recorded(curve)["auc"] == area_under_curve(curve.rolling, 8)  # each entry with a curve function
    assert recorded(Curve(np.array([]), 8, 20.0, 3)) == {}


def test_a_measure_added_as_one_entry_is_recorded_tuned_and_claimed_on_by_name(tmp_path):
    # Episodes until the full-window rolling mean first reaches 90% of the solve threshold, censored at the budget:
    # one registry entry; an experiment file tunes and claims on it by name, the trainer records it, the report
    # recomputes it from the same curve.
    from ablate.claims import primary_question
    from ablate.config import ConfigError
    from ablate.experiment import load_experiment
    from ablate.measures import measure

    name, reached = "episodes_to_90pct_threshold", "reached_90pct_threshold"
    path = tmp_path / "exp.toml"
    path.write_text(
        f"primary = '{name}'\n[base]\nsolve_threshold = 21\n[tune]\nlearning_rate = [0.01, 0.1]\nmetric = '{name}'\n"
        "[[variants]]\nname = 'a'\n"
    )
    experiment = load_experiment(path)
    assert experiment.primary_metric == name and experiment.tune.metric == name and experiment.tune.direction == "min"
    question = primary_question(name, 0.1, 40.0)
    assert question.relative and question.lower_is_better and question.budget == 40.0
    assert question.fallback is not None and question.fallback.metric == "auc"
    path.write_text(f"primary = '{name}'\n[base]\nenv_id = 'ALE/Pong-v5'\n[[variants]]\nname = 'a'\n")
    with pytest.raises(ConfigError, match="has no solve threshold"):
        load_experiment(path)

    # window 4: full-window rolling means 13, 15, 17.5, 20.25, 23.75 at episodes 4-8; 90% of 21 is 18.9
    window, budget, returns = 4, 10, [10.0, 12.0, 14.0, 16.0, 18.0, 22.0, 25.0, 30.0]
    rolling = [math.fsum(returns[max(0, i - window + 1) : i + 1]) / min(i + 1, window) for i in range(len(returns))]
    episodes = [
        EpisodeMetrics(i + 1, r, 10, 0.0, 0.0, m, 10 * (i + 1), 0.1, i + 1)
        for i, (r, m) in enumerate(zip(returns, rolling, strict=True))
    ]
    config = TrialConfig(max_episodes=budget, solve_window=window, solve_threshold=21.0)
    summary = TrialResult(config, episodes, 8, 21.0, 80, 1.0, 10).summary()
    assert summary[name] == 7 and summary["episodes_to_solve"] == 8
    curve = pd.DataFrame({"episode": range(1, len(returns) + 1), "return": returns})
    curve["rolling_mean"] = curve["return"].rolling(window, min_periods=1).mean()
    assert trial_measures(curve, budget, (), window, 21.0, [measure(name)])[name] == summary[name]
    # never there (a threshold of 30): not recorded, so tuning and the rounds read the budget, censored
    unsolved = TrialResult(config, episodes, None, 30.0, 80, 1.0, 10).summary()
    assert name not in unsolved and measure(name).from_summary(unsolved, budget) == (budget, True)
    far = trial_measures(curve, budget, (), window, 30.0, [measure(name)])
    assert far[name] == budget and far[reached] == 0
