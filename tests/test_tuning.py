"""Selection of each variant's knob values from hand-made stage-1 tables: means, ties, censoring."""

import pytest

from ablate.experiment import parse_experiment
from ablate.launch.grid import chosen_trials, tuning_trials
from ablate.launch.tuning import TuningResult, choose, choose_all, tuning_document
from ablate.measures import measure


def _spec(metric="auc", candidates=(0.01, 0.03, 0.1)):
    return parse_experiment(
        {
            "base": {"learning_rate": 0.03},
            "variants": [{"name": "a"}, {"name": "own", "learning_rate": 0.001}],
            "tune": {"learning_rate": list(candidates), "seeds": 2, "metric": metric, "max_episodes": 100},
        },
        "exp.toml",
    )


def _rows(table, budget=100):
    """``{lr: [metrics of seed 10000, metrics of seed 10001]}`` -> results of variant ``a``."""
    return [
        TuningResult("a", {"learning_rate": lr}, 10_000 + i, metrics, budget)
        for lr, per_seed in table.items()
        for i, metrics in enumerate(per_seed)
    ]


def _finished(experiment, table):
    """As ``_rows``, as the launch has them: summary metrics by the key of variant ``a``'s tuning trial."""
    keys = {(t.config.learning_rate, t.seed): t.key for t in tuning_trials(experiment)}
    return {keys[lr, 10_000 + i]: metrics for lr, per_seed in table.items() for i, metrics in enumerate(per_seed)}


def _choose(experiment, table):
    return choose(experiment.tune, ("learning_rate",), {"learning_rate": 0.03}, _rows(table))


def _solved(episodes, auc=100.0):
    return {"solved": 1.0, "episodes_to_solve": episodes, "auc": auc, "final_rolling_mean": 400.0}


def _unsolved(auc=50.0):
    return {"solved": 0.0, "auc": auc, "final_rolling_mean": 100.0}


def test_best_mean_auc_wins_not_the_best_single_seed():
    choice = _choose(
        _spec(), {0.01: [{"auc": 10}, {"auc": 250}], 0.03: [{"auc": 150}, {"auc": 151}], 0.1: [{"auc": 1}, {"auc": 2}]}
    )
    assert choice.values == {"learning_rate": 0.03} and choice.reason == "best mean auc" and choice.tuned
    assert choice.scores == {"learning_rate=0.01": 130.0, "learning_rate=0.03": 150.5, "learning_rate=0.1": 1.5}


def test_auc_tie_goes_to_the_candidate_nearest_the_base_value_in_log_space():
    table = {0.01: [{"auc": 5}, {"auc": 5}], 0.03: [{"auc": 1}, {"auc": 1}], 0.1: [{"auc": 5}, {"auc": 5}]}
    # |log 0.01 - log 0.03| = 1.10 < |log 0.1 - log 0.03| = 1.20
    choice = _choose(_spec(), table)
    assert choice.values == {"learning_rate": 0.01} and choice.reason == "tie on mean auc: nearest the base value"


def test_fewest_episodes_wins_when_every_seed_solved():
    experiment = _spec("episodes_to_solve")
    table = {0.01: [_solved(90), _solved(80)], 0.03: [_solved(60), _solved(70)], 0.1: [_solved(40), _unsolved()]}
    # 0.1's mean (40 + 100 censored) / 2 = 70 is a bound above 65: 0.03 is better whatever 0.1's true value.
    choice = _choose(experiment, table)
    assert choice.values == {"learning_rate": 0.03} and choice.reason == "best mean episodes_to_solve"


def test_censored_best_episodes_fall_back_to_auc():
    experiment = _spec("episodes_to_solve")
    table = {
        0.01: [_unsolved(auc=20), _unsolved(auc=20)],
        0.03: [_solved(90, auc=80), _unsolved(auc=60)],  # mean 95, but a bound
        0.1: [_unsolved(auc=90), _solved(95, auc=90)],  # mean 97.5, a bound
    }
    choice = _choose(experiment, table)
    assert choice.values == {"learning_rate": 0.1}
    assert choice.reason == "episodes to solve censored (a tuning seed never solved): best mean auc"


def test_episode_ties_fall_back_to_auc_then_to_the_base_value():
    experiment = _spec("episodes_to_solve")
    table = {
        0.01: [_solved(50, 70), _solved(50, 70)],
        0.03: [_solved(50, 70), _solved(50, 70)],
        0.1: [_solved(60), _solved(60)],
    }
    choice = _choose(experiment, table)
    assert choice.values == {"learning_rate": 0.03}
    assert choice.reason == "tie on mean episodes_to_solve and on mean auc: nearest the base value"
    table[0.01] = [_solved(50, 71), _solved(50, 71)]
    assert _choose(experiment, table).values == {"learning_rate": 0.01}


def test_final_return_and_nan_ranks_last():
    experiment = _spec("final_return")
    table = {
        0.01: [{"final_rolling_mean": 10.0}, {"final_rolling_mean": float("nan")}],
        0.03: [{"final_rolling_mean": 5.0}, {"final_rolling_mean": 6.0}],
        0.1: [{"final_rolling_mean": 1.0}, {"final_rolling_mean": 2.0}],
    }
    assert _choose(experiment, table).values == {"learning_rate": 0.03}


def test_tuning_values_censor_unsolved_episodes_at_the_budget():
    assert measure("episodes_to_solve").from_summary(_unsolved(), 77) == (77.0, True)
    assert measure("episodes_to_solve").from_summary(_solved(12), 77) == (12.0, False)
    assert measure("final_return").from_summary(_solved(12), 77) == (400.0, False)


def test_choose_all_waits_for_every_tuning_trial_and_keeps_a_variants_own_value():
    experiment = _spec()
    table = {0.01: [{"auc": 1}, {"auc": 1}], 0.03: [{"auc": 2}, {"auc": 2}], 0.1: [{"auc": 3}]}
    choices = choose_all(experiment, tuning_trials(experiment), _finished(experiment, table))
    assert "a" not in choices  # 0.1 on seed 10001 has not finished
    own = choices["own"]
    assert (own.values, own.tuned, own.reason) == ({"learning_rate": 0.001}, False, "set by the variant")
    table[0.1].append({"auc": 3})
    choices = choose_all(experiment, tuning_trials(experiment), _finished(experiment, table))
    assert choices["a"].values == {"learning_rate": 0.1}
    document = tuning_document(experiment, choices)
    assert document["knobs"] == {"learning_rate": [0.01, 0.03, 0.1]} and document["seeds"] == [10_000, 10_001]
    assert (document["metric"], document["direction"], document["max_episodes"]) == ("auc", "max", 100)
    assert document["base"] == {"learning_rate": 0.03}
    assert document["choices"]["a"]["values"] == {"learning_rate": 0.1} and document["choices"]["a"]["tuned"]
    assert "best mean auc" in document["rule"]
    # Stage 2 by key: the tuned variant on every evaluation seed at its choice (``own`` keeps its untuned trials).
    wanted = chosen_trials(experiment, {"a": {"learning_rate": 0.1}})
    assert document["trials"] == [{"key": t.key, "variant": "a", "seed": t.seed} for t in wanted] and wanted


@pytest.mark.parametrize("metric", ["auc", "episodes_to_solve", "final_return"])
def test_a_choice_is_always_one_of_the_candidates(metric):
    experiment = _spec(metric, candidates=(0.003, 0.3))
    table = {0.003: [_unsolved(), _unsolved()], 0.3: [_unsolved(), _unsolved()]}
    assert _choose(experiment, table).values["learning_rate"] in (0.003, 0.3)


def test_stage_plan_reads_stage_1_from_finished_summaries_and_narrows_stage_2_to_the_seeds_asked_for():
    from ablate.launch.grid import expand
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.tuning import unique

    experiment = _spec()
    evaluation = [t for t in expand(experiment) if t.seed == 0]  # as --seeds 0 selects
    plan = LaunchPlan(experiment, only=evaluation)
    assert {t.variant for t in plan.tuning} == {"a"} and len(plan.tuning) == 3 * 2
    finished = {t.key: {"auc": 10.0 * t.config.learning_rate} for t in plan.tuning}
    assert plan.choices({}) == {"own": plan.choices({})["own"]}  # nothing finished: only the untuned variant
    choices = plan.choices(finished)
    assert choices["a"].values == {"learning_rate": 0.1}
    chosen = plan.chosen(choices)
    assert [(t.variant, t.seed, t.config.learning_rate) for t in chosen] == [("a", 0, 0.1)]
    at_base = plan.chosen({"a": choices["a"].__class__({"learning_rate": 0.03}, True, "")})
    assert unique([*evaluation, *at_base], set()) == evaluation  # the choice equal to the base adds no trial


def test_provisional_stage_2_is_the_best_candidate_so_far_and_stands_in_for_a_variant_not_seen_yet():
    from ablate.launch.grid import expand
    from ablate.launch.plan import LaunchPlan

    experiment = _spec()
    evaluation = expand(experiment)
    plan = LaunchPlan(experiment)
    known = {t.key for t in [*plan.tuning, *evaluation]}
    # No tuning trial has finished: "a" stands in with its evaluation trials, as many as its choice would add.
    assert plan.provisional({}, known) == [t for t in evaluation if t.variant == "a"]
    # One seed of one candidate finished: the best so far is that one.
    first = next(t for t in plan.tuning if t.config.learning_rate == 0.1)
    ahead = plan.provisional({first.key: {"auc": 5.0}}, known)
    assert {(t.variant, t.config.learning_rate) for t in ahead} == {("a", 0.1)}
    assert sorted(t.seed for t in ahead) == sorted(t.seed for t in evaluation if t.variant == "a")
    # The base value ahead: its evaluation trials are known already, so stage 2 adds nothing.
    finished = {t.key: {"auc": 10.0 if t.config.learning_rate == 0.03 else 1.0} for t in plan.tuning}
    assert plan.provisional(finished, known) == []
