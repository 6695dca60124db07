"""Report statistics against values computed by hand or by SciPy directly."""

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from ablate.results import (
    Ablation,
    area_under_curve,
    bootstrap_interval,
    convergence_table,
    iqm,
    probability_of_improvement,
    probability_of_improvement_interval,
    relative_reduction,
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
    from ablate.results import _pairwise_improvement

    rng = np.random.default_rng(3)
    for _ in range(20):
        x, y = rng.integers(0, 10, 5).astype(float), rng.integers(0, 10, 7).astype(float)
        assert _pairwise_improvement(x, y) == pytest.approx(probability_of_improvement(x, y))
    low, high = probability_of_improvement_interval(np.array([1.0, 2, 3, 4]), np.array([3.0, 4, 5, 6]))
    assert 0 <= low <= probability_of_improvement(np.array([1.0, 2, 3, 4]), np.array([3.0, 4, 5, 6])) <= high <= 1
