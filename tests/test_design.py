"""The pre-run design check: the report's own rules, without pandas or SciPy."""

import pytest

from ablate.design import design_warning, smallest_p_value, smallest_permutation_p


def test_three_seeds_cannot_reach_a_claim_four_can():
    # the exploratory (per-comparison) rule: a rank test's best p-value
    assert smallest_p_value(3, 3) == pytest.approx(0.1)  # above 0.05: no claim
    assert smallest_p_value(4, 4) == pytest.approx(2 / 70)
    assert smallest_p_value(0, 10) == 1.0  # no seed: no test at all
    assert min(n for n in range(2, 10) if smallest_p_value(n, n) <= 0.05) == 4


def test_a_family_of_nine_needs_six_seeds_per_variant():
    # Holm's first step tests at 0.05 / 9 = 0.0056; 5 and 5 seeds give at best 4 / 252 = 0.016, 6 and 6 4 / 924
    assert smallest_permutation_p(5, 5) == pytest.approx(4 / 252) and smallest_permutation_p(6, 6) == pytest.approx(
        4 / 924
    )
    assert "at least 5 seeds per variant (seeds = 5)" in design_warning(4, 1)  # 4 and 4: 4 / 70 = 0.057
    warning = design_warning(5, 9)
    assert "5 seeds per variant no primary comparison can reach a claim" in warning and "9 comparisons" in warning
    assert "at least 6 seeds per variant (seeds = 6)" in warning and "undetermined" in warning
    assert design_warning(6, 9) is None and design_warning(5, 1) is None and design_warning(20, 30) is None


def test_the_rule_is_the_reports_own():
    """The report decides with the very functions and level --dry-run warns with (one copy of each rule)."""
    from ablate import claims, design
    from ablate.reporting import comparisons, statistics

    assert statistics.smallest_p_value is design.smallest_p_value and statistics.CONFIDENCE == design.CONFIDENCE
    assert comparisons.smallest_p_value is design.smallest_p_value
    assert claims.smallest_p is design.smallest_permutation_p


def test_the_confidence_level_is_one_fact_and_prose_writes_it_from_there():
    """Issue 57: "95%" was written 62 times in ``ablate/``. ``ALPHA`` is the fact, ``CONFIDENCE`` the same float as
    the literal 0.95, and no string outside a docstring writes the level or the power as a literal."""
    import io
    import tokenize
    from pathlib import Path

    import ablate
    from ablate.claims import ALPHA as family_alpha
    from ablate.design import ALPHA, CONFIDENCE, percent

    assert CONFIDENCE == 0.95 and family_alpha is ALPHA and percent(CONFIDENCE) == "95%"
    literals = []
    for path in sorted(Path(ablate.__file__).parent.rglob("*.py")):
        for token in tokenize.generate_tokens(io.StringIO(path.read_text()).readline):
            docstring = token.string.lstrip("rbfuRBFU").startswith(('"""', "'''"))
            if token.type == tokenize.STRING and not docstring and ("95%" in token.string or "80%" in token.string):
                literals.append(f"{path.name}:{token.start[0]}")
    assert not literals
