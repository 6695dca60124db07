"""Report statistics against values computed by hand or by SciPy directly."""

import numpy as np
import pytest
from scipy import stats

from ablate.reporting.statistics import (
    bootstrap_interval,
    iqm,
    iqm_change,
    is_censored_statistic,
    probability_of_improvement,
    probability_of_improvement_interval,
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
    assert probability_of_improvement_interval(np.full(4, 5.0), np.full(4, 5.0)) == (0.5, 0.5, 0.5)
    # every variant seed needs fewer episodes than every reference seed
    assert probability_of_improvement(np.array([1.0, 2.0]), np.array([5.0, 6.0])) == 1.0
    assert probability_of_improvement(np.array([5.0, 6.0]), np.array([1.0, 2.0])) == 0.0
    # by hand: pairs (x<y): (1,2),(1,3),(2,3) = 3; ties (2,2) = 0.5 -> 3.5 / 4
    assert probability_of_improvement(np.array([1.0, 2.0]), np.array([2.0, 3.0])) == pytest.approx(3.5 / 4)


def test_iqm_change_relative():
    point, low, high = iqm_change(np.array([50.0] * 4), np.array([100.0] * 4), relative=True)
    assert point == pytest.approx(0.5) and low == pytest.approx(0.5) and high == pytest.approx(0.5)
    rng = np.random.default_rng(1)
    point, low, high = iqm_change(rng.normal(60, 5, 20), rng.normal(100, 5, 20), relative=True)
    assert 0.3 < low < point < high < 0.5


def test_vectorised_improvement_counts_the_pairs():
    rng = np.random.default_rng(3)
    x, y = rng.integers(0, 10, (20, 5)).astype(float), rng.integers(0, 10, (20, 7)).astype(float)
    less, ties = x[:, :, None] < y[:, None, :], x[:, :, None] == y[:, None, :]  # every pair, by hand
    by_hand = (less.sum(axis=(1, 2)) + ties.sum(axis=(1, 2)) / 2) / 35
    assert probability_of_improvement(x, y) == pytest.approx(by_hand)
    assert probability_of_improvement(x[0], y[0]) == pytest.approx(by_hand[0])
    _, low, high = probability_of_improvement_interval(np.array([1.0, 2, 3, 4]), np.array([3.0, 4, 5, 6]))
    assert 0 <= low <= probability_of_improvement(np.array([1.0, 2, 3, 4]), np.array([3.0, 4, 5, 6])) <= high <= 1


def test_complete_separation_of_five_seeds_is_not_an_interval_of_one_point():
    _, low, high = probability_of_improvement_interval(np.array([1.0, 2, 3, 4, 5]), np.array([6.0, 7, 8, 9, 10]))
    assert (low, high) != (1.0, 1.0)
    assert low == pytest.approx(0.025 ** (1 / 5)) and high == 1.0  # exact bound for 5 of 5
    _, low, high = probability_of_improvement_interval(np.array([6.0, 7, 8, 9, 10]), np.array([1.0, 2, 3, 4, 5]))
    assert low == 0.0 and high == pytest.approx(1 - 0.025 ** (1 / 5))


def test_censored_statistics():
    assert is_censored_statistic(1, 5, "iqm") is False  # the one censored seed is trimmed
    assert is_censored_statistic(2, 5, "iqm") and not is_censored_statistic(2, 5, "median")
    assert is_censored_statistic(3, 5, "median")


def test_seeds_needed_for_a_large_clear_effect_are_few():
    from ablate.reporting.statistics import seeds_needed

    assert seeds_needed(np.array([10.0, 11, 12]), np.array([50.0, 52, 54]), relative=True) == 4
    assert seeds_needed(np.array([60.0, 61, 62]), np.array([20.0, 21, 22]), relative=False) == 4


def test_no_effect_needs_more_than_the_cap():
    from ablate.reporting.statistics import SEEDS_CAP, seeds_needed

    same = np.array([10.0, 20, 30])
    assert seeds_needed(same, same, relative=False) == SEEDS_CAP + 1
    assert seeds_needed(np.array([10.0, 30, 50]), np.array([12.0, 28, 51]), relative=False) == SEEDS_CAP + 1


def test_seeds_needed_for_the_smallest_effect_of_interest():
    from ablate.reporting.statistics import SEEDS_CAP, seeds_needed

    noisy = np.array([90.0, 100, 110, 95, 105]), np.array([91.0, 99, 111, 96, 104])
    small = seeds_needed(*noisy, relative=False, effect=0.05)  # 5 points apart, seeds spread +-10
    large = seeds_needed(*noisy, relative=False, effect=0.5)  # 50 points apart
    assert large == 4 and large < small <= SEEDS_CAP + 1
    # a variant that never solves against one that always does (episodes censored at 100): a claim of
    # "fewer episodes" for the variant needs its IQM to be an estimate, which resampling never gives
    assert seeds_needed(np.full(4, 100.0), np.array([40.0, 50, 60, 70]), True, np.ones(4, bool)) == 4
    unsolved = seeds_needed(np.array([40.0, 50, 60, 70]), np.full(4, 100.0), True, np.ones(4, bool), np.zeros(4, bool))
    assert unsolved == SEEDS_CAP + 1
