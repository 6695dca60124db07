"""Report statistics against values computed by hand or by SciPy directly."""

import re
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from ablate.report.results import (
    Ablation,
    area_under_curve,
    bootstrap_interval,
    compare_metric,
    comparisons,
    convergence_table,
    iqm,
    is_censored_statistic,
    probability_of_improvement,
    probability_of_improvement_interval,
    relative_reduction,
    trial_measures,
)


def test_iqm_of_a_known_array():
    # 8 values: trim 2 from each end -> mean of 3, 4, 5, 6
    assert iqm(np.array([100, 1, 2, 3, 4, 5, 6, -50])) == pytest.approx(np.mean([2, 3, 4, 5]))
    assert iqm(np.arange(1, 9)) == pytest.approx(4.5)


def test_bootstrap_interval_contains_the_known_mean():
    rng = np.random.default_rng(0)
    sample = rng.normal(10.0, 2.0, size=200)
    low, high = bootstrap_interval(sample, statistic=lambda x, axis=-1: np.mean(x, axis=axis))
    assert low < 10.0 < high
    assert high - low < 1.5
    reference = stats.bootstrap((sample,), np.mean, method="percentile", rng=np.random.default_rng(12345))
    assert low == pytest.approx(reference.confidence_interval.low, abs=0.05)


def test_bootstrap_of_a_constant_sample_is_the_value():
    assert bootstrap_interval(np.full(5, 7.0)) == (7.0, 7.0)
    assert all(np.isnan(bootstrap_interval(np.array([3.0]))))


def test_probability_of_improvement():
    same = np.array([10.0, 20.0, 30.0])
    assert probability_of_improvement(same, same) == pytest.approx(0.5)
    assert probability_of_improvement_interval(np.full(4, 5.0), np.full(4, 5.0)) == (0.5, 0.5)
    # every variant seed needs fewer episodes than every reference seed
    assert probability_of_improvement(np.array([1.0, 2.0]), np.array([5.0, 6.0])) == 1.0
    assert probability_of_improvement(np.array([5.0, 6.0]), np.array([1.0, 2.0])) == 0.0
    # by hand: pairs (x<y): (1,2),(1,3),(2,3) = 3; ties (2,2) = 0.5 -> 3.5 / 4
    assert probability_of_improvement(np.array([1.0, 2.0]), np.array([2.0, 3.0])) == pytest.approx(3.5 / 4)


def test_relative_reduction():
    point, low, high = relative_reduction(np.array([50.0] * 4), np.array([100.0] * 4))
    assert point == pytest.approx(0.5) and low == pytest.approx(0.5) and high == pytest.approx(0.5)
    rng = np.random.default_rng(1)
    point, low, high = relative_reduction(rng.normal(60, 5, 20), rng.normal(100, 5, 20))
    assert 0.3 < low < point < high < 0.5


def test_area_under_curve_carries_the_last_value_to_the_budget():
    assert area_under_curve(np.array([0.0, 10.0]), budget=4) == pytest.approx((0 + 10 + 10 + 10) / 4)


def _ablation(rows):
    trials = pd.DataFrame(rows)
    trials["censored_episodes"] = np.where(trials.solved == 1, trials.episodes_to_solve, trials.budget)
    grid = {"variants": [{"name": "a", "overrides": {}}, {"name": "b", "overrides": {}}], "baseline": "a"}
    return Ablation("t", grid, {}, trials, pd.DataFrame())


def _row(variant, seed, solved, episodes, budget=100, status="FINISHED"):
    return {
        "key": f"{variant}-{seed}",
        "variant": variant,
        "seed": seed,
        "status": status,
        "solved": float(solved),
        "episodes_to_solve": episodes if solved else np.nan,
        "budget": budget,
        "env_steps_to_solve": 1.0,
        "wall_s_to_solve": 1.0,
        "final_rolling_mean": 1.0,
        "auc": 1.0,
        "parameter_count": 10,
    }


def test_censoring_is_counted_not_dropped():
    rows = [
        _row("a", 0, True, 40),
        _row("a", 1, True, 60),
        _row("a", 2, False, None),
        _row("a", 3, False, None),
        _row("a", 4, False, None),
        _row("b", 0, True, 10),
        _row("b", 1, True, 20),
        _row("b", 2, True, 30),
        _row("b", 3, False, None),
        _row("b", 4, True, 50, status="FAILED"),
    ]
    table = convergence_table(_ablation(rows)).set_index("variant")
    assert table.loc["a", "seeds_run"] == 5 and table.loc["a", "solved"] == 2
    assert table.loc["a", "unsolved_censored"] == 3
    assert table.loc["a", "episodes_median"] == 100  # 40, 60, 100, 100, 100: the median is a censored value
    assert table.loc["a", "median_censored"] and table.loc["a", "iqm_censored"]
    assert table.loc["a", "episodes_iqm"] == pytest.approx(stats.trim_mean([40, 60, 100, 100, 100], 0.25))
    # b: the FAILED trial is not a seed run; one unsolved of four is censored at 100
    assert table.loc["b", "seeds_run"] == 4 and table.loc["b", "seeds_failed"] == 1
    assert table.loc["b", "fraction_solved"] == 0.75
    assert table.loc["b", "episodes_median"] == 25 and not table.loc["b", "median_censored"]


def test_vectorised_improvement_matches_mann_whitney():
    from ablate.report.results import _pairwise_improvement

    rng = np.random.default_rng(3)
    for _ in range(20):
        x, y = rng.integers(0, 10, 5).astype(float), rng.integers(0, 10, 7).astype(float)
        assert _pairwise_improvement(x, y) == pytest.approx(probability_of_improvement(x, y))
    low, high = probability_of_improvement_interval(np.array([1.0, 2, 3, 4]), np.array([3.0, 4, 5, 6]))
    assert 0 <= low <= probability_of_improvement(np.array([1.0, 2, 3, 4]), np.array([3.0, 4, 5, 6])) <= high <= 1


# --- honest findings on censored data (issue 8 item 8), small samples, one seed, Pong (issue 9 item 7) -------
def _frame(samples: dict[str, list], budget: int = 1500, metric_values: dict[str, list] | None = None):
    """An ablation from per-variant episodes-to-solve lists (None: unsolved, censored at ``budget``); the first
    variant is the baseline. ``metric_values`` gives each variant's AUC per seed (default: 1.0)."""
    rows = []
    for variant, values in samples.items():
        for seed, episodes in enumerate(values):
            row = _row(variant, seed, episodes is not None, episodes, budget=budget)
            if metric_values:
                row["auc"] = float(metric_values[variant][seed])
            rows.append(row)
    trials = pd.DataFrame(rows)
    trials["censored_episodes"] = np.where(trials.solved == 1, trials.episodes_to_solve, trials.budget)
    grid = {
        "variants": [{"name": v, "overrides": {}} for v in samples],
        "baseline": next(iter(samples)),
        "seeds": list(range(len(next(iter(samples.values()))))),
        "base": {"env_id": "CartPole-v1", "max_episodes": budget, "solve_window": 100},
    }
    return Ablation("t", grid, {"tags": {}, "environment": {}}, trials, pd.DataFrame())


BASELINE_4_OF_5 = [707, 749, 715, 900, None]  # the committed report's baseline: one seed unsolved


def _findings_text(ablation):
    from ablate.report.document import findings

    table = convergence_table(ablation)
    return "\n".join(findings(ablation, table, comparisons(ablation)))


def test_an_unsolved_variant_gets_a_lower_bound_not_an_estimate_with_an_upper_end():
    # course, linear, dropout in the committed report: 0 of 5 solved against a baseline that solved 4 of 5.
    # Reported as "needs 70% more episodes (IQM; 95% CI 8% to 110% more)": a bound read as an estimate.
    ablation = _frame({"baseline": BASELINE_4_OF_5, "course": [None] * 5})
    text = _findings_text(ablation)
    course = next(line for line in text.splitlines() if "more" in line and "episodes" in line.lower())
    assert "at least" in course and "no upper bound" in course, course
    assert not re.search(r"CI \d+% to \d+% more", text), text


def test_both_sides_censored_claim_nothing_on_episodes():
    ablation = _frame({"baseline": [None, None, None, 900, 800], "narrow": [None, None, None, 1000, 1100]})
    comparison = compare_metric(ablation, "narrow", "episodes_to_solve")
    assert comparison.bound == "censored" and comparison.verdict == "not separated"
    assert "cannot separate" in _findings_text(ablation)


def test_when_episodes_cannot_separate_the_area_under_the_curve_can():
    # narrow vs baseline in the committed report: both censored on episodes, but AUC's interval excludes 0
    ablation = _frame(
        {"baseline": BASELINE_4_OF_5, "narrow": [650, None, None, None, 720]},
        metric_values={"baseline": [290, 300, 310, 320, 200], "narrow": [150, 160, 170, 180, 240]},
    )
    assert compare_metric(ablation, "narrow", "episodes_to_solve").verdict == "not separated"
    auc = compare_metric(ablation, "narrow", "auc")
    assert auc.verdict == "worse" and auc.high < 0
    assert re.search(r"area under the curve \(AUC\): \*\*lower\*\*", _findings_text(ablation))


def test_complete_separation_of_five_seeds_is_not_an_interval_of_one_point():
    low, high = probability_of_improvement_interval(np.array([1.0, 2, 3, 4, 5]), np.array([6.0, 7, 8, 9, 10]))
    assert (low, high) != (1.0, 1.0)
    assert low == pytest.approx(0.025 ** (1 / 5)) and high == 1.0  # exact bound for 5 of 5
    low, high = probability_of_improvement_interval(np.array([6.0, 7, 8, 9, 10]), np.array([1.0, 2, 3, 4, 5]))
    assert low == 0.0 and high == pytest.approx(1 - 0.025 ** (1 / 5))


def test_three_seeds_against_three_support_no_claim():
    from ablate.report.results import smallest_p_value

    assert smallest_p_value(3, 3) == pytest.approx(0.1) and smallest_p_value(5, 5) == pytest.approx(2 / 252)
    ablation = _frame({"a": [10, 11, 12], "b": [50, 60, 70]}, budget=100)
    assert compare_metric(ablation, "b", "episodes_to_solve").verdict == "no claim"
    assert "no ordering of the seeds can reach 95%" in _findings_text(ablation)
    # ... but the reader still sees the estimate, its interval, and the direction worded as a suggestion
    text = _findings_text(ablation)
    assert "Estimate: IQM 60 vs 11 episodes" in text and "the seeds suggest more episodes for b" in text
    assert "to be confirmed with more seeds" in text
    from ablate.report.document import summary

    assert "no claim; the seeds suggest worse" in summary(ablation, convergence_table(ablation), comparisons(ablation))
    overlapping = _frame({"a": [10, 30, 50], "b": [20, 40, 60]}, budget=100)
    assert "the interval includes no difference" in _findings_text(overlapping)
    never = _frame({"a": [None, None, None], "b": [None, None, 50]}, budget=100)  # both IQMs use the budget
    (episodes_line,) = [line for line in _findings_text(never).splitlines() if "episodes to solve" in line]
    assert "episodes cannot separate them" in episodes_line and "Estimate" not in episodes_line


def test_leave_one_seed_out_marks_a_claim_that_rests_on_some_seeds():
    ablation = _frame(
        {"a": [10] * 5, "b": [10] * 5},
        budget=100,
        metric_values={"a": [10, 10.5, 11, 11.5, 12], "b": [11, 12, 13, 14, 25]},
    )
    fragile = compare_metric(ablation, "b", "auc")
    assert fragile.verdict == "better" and fragile.fragile_seeds == (1, 2, 3)
    # by hand: without seed 1, b = [11, 13, 14, 25] against a = [10, 11, 11.5, 12]; the claim no longer holds
    without = ablation.trials[ablation.trials.seed != 1]
    assert compare_metric(replace(ablation, trials=without), "b", "auc", stability=False).verdict != "better"
    robust = _frame(
        {"a": [10] * 5, "b": [10] * 5},
        budget=100,
        metric_values={"a": [10, 10.5, 11, 11.5, 12], "b": [20, 21, 22, 23, 24]},
    )
    assert compare_metric(robust, "b", "auc").fragile_seeds == ()
    assert "Fragile" in _findings_text(ablation) and "Holds leaving out any one seed" in _findings_text(robust)


def test_one_seed_gives_no_interval_and_no_crash():
    ablation = _frame({"a": [10], "b": [None]}, budget=100)
    table = convergence_table(ablation)
    assert np.isnan(table.loc[0, "episodes_iqm_ci_low"])
    assert all(v == "no claim" for v in comparisons(ablation).verdict)
    assert "1 seed gives no interval" in _findings_text(ablation)


def test_trial_measures_on_a_hand_made_pong_curve():
    returns = np.array([-21.0, -21, -20, -19, -16, -15, -14, -12, -11, -10, -9, -8])
    curve = pd.DataFrame({"episode": np.arange(1, 13), "return": returns})
    curve["rolling_mean"] = curve["return"].rolling(4, min_periods=1).mean()
    measures = trial_measures(curve, budget=12, levels=(-15.0, -10.0, 0.0), window=4)
    # the full-window rolling mean over 3 episodes (a quarter of the budget) first reaches -15 at episode 7
    # (-16, -15, -14), -10 at episode 11 (-11, -10, -9); 0 never: censored at the budget
    assert measures["episodes_to_-15"] == 7 and measures["reached_-15"] == 1
    assert measures["episodes_to_-10"] == 11
    assert measures["episodes_to_0"] == 12 and measures["reached_0"] == 0
    assert measures["initial_return"] == pytest.approx(returns[:10].mean())
    assert measures["improvement"] == pytest.approx(returns[-4:].mean() - returns[:10].mean())
    assert measures["return_at_3"] == pytest.approx(returns[:3].mean())  # a quarter of the budget
    assert measures["return_at_6"] == pytest.approx(returns[2:6].mean())


def test_censored_statistics():
    assert is_censored_statistic(1, 5, "iqm") is False  # the one censored seed is trimmed
    assert is_censored_statistic(2, 5, "iqm") and not is_censored_statistic(2, 5, "median")
    assert is_censored_statistic(3, 5, "median")


def _grid_ablation(variants: dict[str, dict], baseline: str) -> Ablation:
    grid = {"variants": [{"name": n, "overrides": o} for n, o in variants.items()], "baseline": baseline}
    grid["base"] = {"architecture": "cnn", "hidden_sizes": [64], "l2": 0.0}
    return Ablation("t", grid, {}, pd.DataFrame(), pd.DataFrame())


def test_each_variant_is_compared_with_the_variant_whose_changes_it_extends():
    # the default Pong ablation: mlp-l2 against cnn would change two things at once; against mlp, one
    ablation = _grid_ablation(
        {
            "cnn": {},
            "cnn-l2": {"l2": 0.001},
            "cnn-wide": {"hidden_sizes": [256]},  # before mlp, as in pong.toml
            "mlp": {"architecture": "mlp"},
            "mlp-l2": {"architecture": "mlp", "l2": 0.001},
            "mlp-wide": {"architecture": "mlp", "hidden_sizes": [256]},
            "mlp-wide-l2": {"architecture": "mlp", "hidden_sizes": [256], "l2": 0.001},
            "cnn-as-base": {"architecture": "cnn"},  # the base's own value: no change
            "mlp-l2-strong": {"architecture": "mlp", "l2": 0.01},  # a different value is another change
        },
        baseline="cnn",
    )
    assert ablation.changes("mlp-l2") == {"architecture": "mlp", "l2": 0.001}
    assert ablation.changes("mlp-l2", "mlp") == {"l2": 0.001}
    assert ablation.changes("cnn-as-base") == {}
    references = {v: ablation.reference(v) for v in ablation.variants}
    assert references == {
        "cnn": "cnn",
        "cnn-l2": "cnn",
        "mlp": "cnn",
        "mlp-l2": "mlp",
        "cnn-wide": "cnn",
        "mlp-wide": "mlp",  # its own family: width within the MLPs, not the architecture at width 256
        "mlp-wide-l2": "mlp-l2",  # the largest part of its changes; mlp-wide is as large and comes later
        "cnn-as-base": "cnn",
        "mlp-l2-strong": "mlp",
    }


def test_with_another_baseline_the_references_follow_it():
    variants = {"cnn": {}, "mlp": {"architecture": "mlp"}, "mlp-l2": {"architecture": "mlp", "l2": 0.001}}
    ablation = _grid_ablation(variants, baseline="mlp")
    assert ablation.changes("cnn") == {"architecture": "cnn"} and ablation.reference("mlp-l2") == "mlp"
    assert ablation.reference("cnn") == "mlp"


def test_comparisons_are_against_each_variants_reference():
    rows = []
    for variant, auc in (("cnn", 1.0), ("mlp", 5.0), ("mlp-l2", 9.0)):
        for seed in range(5):
            row = _row(variant, seed, False, None)
            row["auc"] = auc + seed * 0.01
            rows.append(row)
    trials = pd.DataFrame(rows)
    trials["censored_episodes"] = trials.budget
    variants = {"cnn": {}, "mlp": {"architecture": "mlp"}, "mlp-l2": {"architecture": "mlp", "l2": 0.001}}
    ablation = replace(_grid_ablation(variants, baseline="cnn"), trials=trials)
    mlp_l2 = compare_metric(ablation, "mlp-l2", "auc", stability=False)
    assert mlp_l2.point == pytest.approx(4.0) and mlp_l2.reference_value == pytest.approx(5.02)
    assert compare_metric(ablation, "mlp", "auc", stability=False).point == pytest.approx(4.0)
    table = comparisons(replace(ablation, grid=ablation.grid | {"seeds": list(range(5))}), stability=False)
    assert dict(zip(table.variant, table.reference, strict=True)) == {"mlp": "cnn", "mlp-l2": "mlp"}
