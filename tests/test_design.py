"""The pre-run design check: the report's own decision rule, without pandas or SciPy."""

import pytest

from ablate.design import can_claim, design_warning, smallest_p_value, smallest_seed_count


def test_three_seeds_cannot_reach_a_claim_four_can():
    assert smallest_p_value(3, 3) == pytest.approx(0.1) and not can_claim(3, 3)
    assert smallest_p_value(4, 4) == pytest.approx(2 / 70) and can_claim(4, 4)
    assert not can_claim(1, 10)  # one seed: no interval at all
    assert smallest_seed_count() == 4
    assert "3 seeds per variant" in design_warning(3) and "at least 4 seeds" in design_warning(3)
    assert design_warning(4) is None and design_warning(20) is None


def test_the_rule_is_the_reports_own():
    """The report decides with the very function and level --dry-run warns with (one copy of the rule)."""
    from ablate import design
    from ablate.reporting import comparisons, statistics

    assert statistics.smallest_p_value is design.smallest_p_value and statistics.CONFIDENCE == design.CONFIDENCE
    assert comparisons.smallest_p_value is design.smallest_p_value
