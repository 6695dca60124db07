"""The primary claims' rule (ablate/claims/): the permutation test against hand counts, the
spending boundaries against published values, and the family's error rates on synthetic nulls and planted
effects at the fixed and the sequential design.

Each rate is a Monte-Carlo estimate from a fixed RNG seed, so it cannot flake; each bound allows for the
simulation error: with R reports, a true rate of 5% is estimated within 5% + 2.33 sqrt(0.05 * 0.95 / R)
(its one-sided 99% end) in all but 1% of seeds, so a rule at or under 5% passes. The rates measured are in
docs/report.md.
"""

import math

import numpy as np
import pytest
from scipy import stats

from ablate.claims import (
    BETTER,
    EQUIVALENT,
    UNDETERMINED,
    WORSE,
    Design,
    Question,
    Sample,
    advice,
    decide,
    effect_interval,
    nominal_levels,
    p_values,
    smallest_p,
)

BUDGET = 1500.0
EPISODES = Question("episodes_to_solve", relative=True, lower_is_better=True, smallest_effect=0.1, budget=BUDGET)
AUC = Question("auc", relative=False, lower_is_better=False, smallest_effect=0.1)


def slack(reports: int, rate: float = 0.05) -> float:
    return rate + 2.33 * math.sqrt(rate * (1 - rate) / reports)


# --- the test and the boundaries against hand-computed values ------------------------------------------------


def test_complete_separation_of_5_against_5_is_4_of_252_splits():
    # The IQM of 5 trims one seed from each end, so swapping the variant's top seed with the reference's
    # bottom one leaves the difference as it is: 2 such splits on each side, 4 of the 252.
    x, y = Sample(np.arange(1.0, 6.0)), Sample(np.arange(10.0, 15.0))
    p_diff, _ = p_values(x, y, AUC)
    assert p_diff == pytest.approx(4 / 252) and smallest_p(5, 5) == pytest.approx(4 / 252)
    for n, m in [(6, 6), (8, 8), (4, 7), (8, 5)]:  # the formula against enumeration
        x, y = Sample(np.arange(float(n))), Sample(np.arange(100.0, 100 + m))
        assert smallest_p(n, m) <= p_values(x, y, AUC)[0] + 1e-12
    assert p_values(x, x, AUC)[0] == 1.0  # identical samples: every split is at least as extreme


def test_tost_shows_equivalence_only_within_the_margin():
    rng = np.random.default_rng(0)
    reference = rng.normal(100, 2, 30)
    same = Sample(reference + rng.normal(0, 0.5, 30))
    far = Sample(reference * 1.3)
    assert p_values(same, Sample(reference), AUC)[1] < 1e-3  # within +-10 of a 100: shown
    assert p_values(far, Sample(reference), AUC)[1] > 0.5  # 30 apart: not


def test_interval_inverts_the_test_and_covers_a_planted_ratio():
    rng = np.random.default_rng(1)
    y = rng.lognormal(np.log(500), 0.3, 20)
    x = 0.7 * rng.lognormal(np.log(500), 0.3, 20)
    estimate, low, high = effect_interval(Sample(x), Sample(y), EPISODES, 0.05)
    assert low < -0.3 < high and low < estimate < high and high < 0
    # a bound: every variant seed censored at the budget leaves the upper end open
    _, low, high = effect_interval(Sample(np.full(6, BUDGET), np.ones(6, bool)), Sample(y[:6]), EPISODES, 0.05)
    assert high == math.inf and low > 0


def test_spending_boundaries_match_published_values():
    # Lan-DeMets O'Brien-Fleming-type, two looks at t = 0.5, 1: z = 2.782, 1.977 (Jennison & Turnbull Table 7.6
    # gives 2.80 / 1.98 for the classical boundary); Pocock-type, 5 equal looks: 2.438 ... 2.386.
    z = [stats.norm.isf(p / 2) for p in nominal_levels((0.5, 1.0), 0.05)]
    assert z[0] == pytest.approx(2.772, abs=0.005) and z[1] == pytest.approx(1.977, abs=0.005)
    z = [stats.norm.isf(p / 2) for p in nominal_levels((0.2, 0.4, 0.6, 0.8, 1.0), 0.05, "pocock")]
    assert z[0] == pytest.approx(2.438, abs=0.005) and z[-1] == pytest.approx(2.386, abs=0.005)
    assert nominal_levels((1.0,), 0.05) == pytest.approx((0.05,))  # one look: the fixed design's level


def test_five_seeds_can_never_claim_in_a_family_of_nine():
    rng = np.random.default_rng(2)
    samples = {"base": Sample(rng.normal(100, 1, 5))} | {f"v{i}": Sample(rng.normal(200, 1, 5)) for i in range(9)}
    result = decide(samples, {f"v{i}": "base" for i in range(9)}, AUC, Design.fixed(5), intervals=False)
    assert all(v.verdict == UNDETERMINED for v in result.verdicts)  # 2/252 = 0.0079 > 0.05 / 9
    assert "no ordering of 5 and 5 seeds" in result.verdicts[0].reason
    # 5 seeds a side support no prediction of the seeds needed (tools/seed_advice.py): run 10 first
    assert all(not v.seeds_estimated and v.seeds_first == advice.MIN_SEEDS for v in result.verdicts)
    assert result.done and result.needs_seeds == ()


def test_the_seeds_advice_grows_as_the_effect_shrinks_and_names_none_a_family_level_cannot_reach():
    rng = np.random.default_rng(5)
    reference = rng.normal(100, 10, 12)
    needed = [
        advice.seeds_needed(Sample(rng.normal(100 + shift, 10, 12)), Sample(reference), AUC, 0.05 / 9)
        for shift in (12, 6, 3)
    ]
    assert needed[0] is not None and needed[0] < needed[1] < needed[2] <= advice.SEEDS_CAP
    # equivalence is a decision too: no effect at all is decided (within +-10% of 100) with enough seeds
    assert advice.seeds_needed(Sample(reference + 0.01), Sample(reference), AUC, 0.05 / 9) <= 100
    # 4 and 4 seeds can never reach 0.05 / 9 (smallest p 2 / 70): never named
    assert all(n >= 6 for n in needed)


def test_censoring_allows_only_the_claim_a_bound_supports():
    rng = np.random.default_rng(3)
    fast = Sample(rng.uniform(100, 200, 12), np.zeros(12, bool))
    slow = Sample(np.full(12, BUDGET), np.ones(12, bool))  # never solved: IQM is a bound
    result = decide({"r": fast, "v": slow}, {"v": "r"}, EPISODES, Design.fixed(12), intervals=False)
    assert result.verdicts[0].verdict == WORSE and result.verdicts[0].bound == "at least"
    result = decide({"r": slow, "v": fast}, {"v": "r"}, EPISODES, Design.fixed(12), intervals=False)
    assert result.verdicts[0].verdict == BETTER
    both = decide({"r": slow, "v": slow}, {"v": "r"}, EPISODES, Design.fixed(12), intervals=False)
    assert both.verdicts[0].verdict == UNDETERMINED and both.verdicts[0].bound == "censored"


# --- family-wise rates on synthetic nulls at the fixed design ------------------------------------------------

VARIANTS, SEEDS, REPORTS = 10, 8, 150


def _normal(rng, n):
    return rng.normal(100, 20, n)


def _bimodal(rng, n):  # half the seeds learn fast, half slowly: two modes
    return np.where(rng.random(n) < 0.5, rng.normal(300, 30, n), rng.normal(900, 60, n)).clip(1)


def _heavy(rng, n):  # Student t, 2 degrees of freedom: infinite variance
    return 100 + 20 * rng.standard_t(2, n)


def _censored(rng, n):  # episodes to solve, a fifth of the seeds past the budget
    return rng.lognormal(np.log(700), 0.6, n)


NULLS = {
    "normal": (_normal, AUC),
    "bimodal": (_bimodal, EPISODES),
    "heavy": (_heavy, AUC),
    "censored": (_censored, EPISODES),
}


def _report(rng, draw, question, n, effects):
    """One report's samples: the baseline and VARIANTS - 1 variants, variant i ``effects[i - 1]`` away from it
    (a ratio - 1 for episodes, a shift otherwise)."""
    samples = {}
    for i in range(VARIANTS):
        values = draw(rng, n)
        effect = effects[i - 1] if i else 0.0
        if effect:
            values = values * (1 + effect) if question.relative else values + effect
        if question.budget is not None:
            censored = values >= question.budget
            samples[f"v{i}"] = Sample(np.minimum(values, question.budget), censored)
        else:
            samples[f"v{i}"] = Sample(values)
    return samples


REFERENCES = {f"v{i}": "v0" for i in range(1, VARIANTS)}


def _false(verdict, effect, margin, question) -> bool:
    """Is this claim false for a variant planted ``effect`` away (``margin`` in the same units)?"""
    if verdict in (BETTER, WORSE):
        better = effect < 0 if question.lower_is_better else effect > 0
        return effect == 0 or (verdict == BETTER) != better
    return verdict == EQUIVALENT and abs(effect) > margin


def _rates(draw, question, design, effect=0.0, reports=REPORTS, seed=0, permutations=4999):
    """Over ``reports`` synthetic reports: the share with any false claim, with any better/worse, with any
    equivalent; the mean share of comparisons decided; the mean seeds run per report. ``effect``: one for every
    variant, or one per variant. Random splits: 4,999 unless told (fewer than the report's: a coarser p-value)."""
    effects = list(effect) if isinstance(effect, list | tuple) else [effect] * (VARIANTS - 1)
    margin = question.smallest_effect if question.relative else question.smallest_effect * 100  # 10% of 100
    rng = np.random.default_rng(seed)
    false = any_difference = any_equivalent = 0
    decided, spent = [], []
    for _ in range(reports):
        samples = _report(rng, draw, question, design.max, effects)
        result = decide(
            samples, REFERENCES, question, design, intervals=False, estimate_seeds=False, permutations=permutations
        )
        verdicts = [v.verdict for v in result.verdicts]
        false += any(_false(v, e, margin, question) for v, e in zip(verdicts, effects, strict=True))
        any_difference += any(v in (BETTER, WORSE) for v in verdicts)
        any_equivalent += any(v == EQUIVALENT for v in verdicts)
        decided.append(np.mean([v != UNDETERMINED for v in verdicts]))
        spent.append(sum(n for _, n in result.spent))
    return {
        "false": false / reports,
        "difference": any_difference / reports,
        "equivalent": any_equivalent / reports,
        "decided": float(np.mean(decided)),
        "spent": float(np.mean(spent)),
    }


@pytest.mark.parametrize("null", list(NULLS))
def test_family_wise_false_difference_rate_on_nulls_at_the_fixed_design(null):
    draw, question = NULLS[null]
    assert _rates(draw, question, Design.fixed(SEEDS))["false"] <= slack(REPORTS)


@pytest.mark.parametrize("null", ["normal", "censored"])
def test_equivalence_past_the_margin_is_rarely_claimed(null):
    draw, question = NULLS[null]
    effect = 0.2 if question.relative else 20.0  # twice the margin (10% of 100 on AUC; 10% on episodes)
    assert _rates(draw, question, Design.fixed(SEEDS), effect)["false"] <= slack(REPORTS)


def _narrow(rng, n):  # a spread small enough against the margin (10 on 100) for 30 seeds to show equivalence
    return rng.normal(100, 8, n)


def test_equivalence_on_a_null_and_just_past_the_margin_with_30_seeds():
    # Identical variants are shown equivalent, and showing it releases no share of alpha to their "no
    # difference": the false-difference rate stays at the family level (releasing it measured 18%).
    # 999 random splits resolve p-values to 0.001, enough for 0.05 / 9.
    null = _rates(_narrow, AUC, Design.fixed(30), reports=300, permutations=999)
    assert null["decided"] >= 0.8 and null["false"] <= slack(300)
    past = _rates(_narrow, AUC, Design.fixed(30), effect=10.5, permutations=999)  # 1.05 margins apart
    assert past["false"] <= slack(REPORTS)
    mixed = [0.0] * 4 + [10.5, -10.5] * 2 + [30.0]  # nulls, just past the margin both ways, a clear effect
    assert _rates(_narrow, AUC, Design.fixed(30), effect=mixed, reports=300, permutations=999)["false"] <= slack(300)


def test_power_on_a_planted_effect_at_the_fixed_design():
    rates = _rates(_censored, EPISODES, Design.fixed(SEEDS), effect=-0.6, reports=60)
    assert rates["decided"] >= 0.5 and rates["false"] <= slack(60)  # 60% fewer episodes: half decided at 8 seeds


# --- the sequential design -------------------------------------------------------------------------------------

SEQUENTIAL = Design(5, 5, 15)


def test_sequential_family_wise_rate_on_a_censored_null():
    rates = _rates(_censored, EPISODES, SEQUENTIAL, reports=REPORTS, permutations=1999)
    assert rates["false"] <= slack(REPORTS)
    assert rates["spent"] == VARIANTS * SEQUENTIAL.max  # nothing decides on a null at these seeds: every round runs


def test_sequential_design_stops_early_on_a_planted_effect():
    rates = _rates(_censored, EPISODES, SEQUENTIAL, effect=-0.6, reports=40, permutations=1999)
    assert rates["decided"] >= 0.8 and rates["spent"] < VARIANTS * SEQUENTIAL.max and rates["false"] <= slack(40)


def test_a_round_names_the_variants_that_need_seeds():
    rng = np.random.default_rng(4)
    samples = {
        "base": Sample(rng.normal(100, 5, 10)),
        "far": Sample(rng.normal(300, 5, 10)),
        "near": Sample(rng.normal(104, 15, 10)),
    }
    result = decide(samples, {"far": "base", "near": "base"}, AUC, Design(10, 5, 30))
    assert result.look == 0 and not result.done
    assert [v.verdict for v in result.verdicts] == [BETTER, UNDETERMINED]
    far = result.verdicts[0]
    assert far.low < far.estimate < far.high and far.low > 150  # 200 apart, an interval at the look's level
    assert result.verdicts[1].seeds_estimated  # asked, an open comparison gets its advice mid-rounds too
    assert set(result.needs_seeds) == {"base", "near"}  # "far" is decided: no more seeds for it
