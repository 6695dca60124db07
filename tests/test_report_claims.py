"""One answer everywhere (issue 36): the report's claims, ``tables/claims.csv``, ``ablate.load(...).claims`` and
the ``claim`` column of the comparisons are one table, read line for line against the report's words, on a
synthetic store (the tracker's own writes, no training) with a claim of each kind."""

import io
import math

import numpy as np
import pandas as pd
import pytest
from test_report import make_store

import ablate
from ablate.reporting.document import build_report


def _line(stop: float, per_seed: float):
    return lambda seed: np.linspace(5, stop + per_seed * seed, 40) + np.sin(np.arange(40) + seed)


def _spread(seed: int):
    return np.linspace(5, 30 + (12 if seed % 2 else -4), 40) + np.sin(np.arange(40) + seed)


# base solves around episode 31; fast well before (better); slow never (worse, a bound); spread either way
VARIANTS = {
    "base": {"curve": _line(30, 2)},
    "fast": {"curve": _line(60, 3)},
    "slow": {"curve": _line(18, 1)},
    "spread": {"curve": _spread},
}


@pytest.fixture(scope="module")
def claimed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("claims")
    uri = make_store(folder, "claimed", VARIANTS, seeds=tuple(range(6)))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test")
        report = build_report("claimed", tracking_uri=uri, out_root=folder / "reports", attach=False).folder
    return report, uri


def _claims_section(text: str) -> list[str]:
    section = text.split("## Claims (generated)")[1].split("\n## ")[0]
    return [line for line in section.splitlines() if line.startswith("- **")]


def _pct_words(change: float) -> str:
    return "no change" if round(abs(change)) == 0 else f"{round(abs(change))}% {'fewer' if change < 0 else 'more'}"


def test_the_claims_csv_the_api_and_the_report_are_one_table_line_for_line(claimed):
    report, uri = claimed
    table = pd.read_csv(report / "tables" / "claims.csv")
    assert sorted(table.verdict) == ["better", "undetermined", "worse"]  # the store has one of each
    loaded = ablate.load("claimed", tracking_uri=uri).claims
    pd.testing.assert_frame_equal(pd.read_csv(io.StringIO(loaded.to_csv(index=False))), table)  # as written
    lines = _claims_section((report / "report.md").read_text())
    assert len(lines) == len(table)
    for line, row in zip(lines, table.itertuples(), strict=True):
        assert line.startswith(f"- **{row.variant}** ") and f" {row.reference}" in line, line
        assert f"**{row.verdict}**" in line, line
        assert f"{row.n_variant} and {row.n_reference} seeds" in line, line
        if row.metric == "auc":  # most seeds unsolved: judged on the AUC (claims.CENSORED_SHARE), in its units
            assert f"area under the curve (AUC) {row.change:+.1f} (interval {row.change_low:+.1f}" in line, line
            assert "Judged on area under the curve (AUC), not episodes to solve" in line, line
        else:
            assert f"{_pct_words(row.change)} episodes to solve" in line, line
            for end in (row.change_low, row.change_high):
                if math.isfinite(end):
                    assert _pct_words(end) in line.split("(interval")[1], line
        if row.verdict == "undetermined" and math.isinf(row.seeds_needed):
            assert f"more than {row.seeds_cap} seeds per variant" in line, line
        elif row.verdict == "undetermined" and row.seeds_first:
            assert f"run {row.seeds_first} per variant first" in line, line
        elif row.verdict == "undetermined":
            assert f"about {int(row.seeds_needed)} seeds per variant" in line, line
        else:
            assert "seeds per variant" not in line, line


def test_the_comparisons_repeat_the_claims_on_the_primary_rows_in_their_own_words(claimed):
    report, _ = claimed
    claims = pd.read_csv(report / "tables" / "claims.csv").set_index("variant")
    compare = pd.read_csv(report / "tables" / "comparisons.csv", keep_default_na=False)
    primary = compare[compare.primary.astype(str) == "True"].set_index("variant")
    assert set(primary.metric) == {"episodes_to_solve"} and set(primary.index) == set(claims.index)
    assert dict(primary.claim) == dict(claims.verdict)
    assert set(compare[compare.primary.astype(str) == "False"].claim) == {""}
    assert all(v.startswith("exploratory: ") for v in compare.verdict)  # never a claim's word
    # one seeds-needed figure per comparison: the claims'
    undetermined = claims[claims.verdict == "undetermined"]
    for variant, row in undetermined.iterrows():
        if row.seeds_first:  # too few seeds for a prediction: none in either table
            assert primary.loc[variant, "seeds_needed"] == "" and math.isnan(row.seeds_needed)
        else:
            assert float(primary.loc[variant, "seeds_needed"]) == row.seeds_needed
    text = (report / "report.md").read_text()
    appendix = text.split("Every comparison (generated)")[1].split("\n### ")[0]
    for variant, row in claims.iterrows():
        block = appendix.split(f"- **{variant}** vs")[1].split("\n- **")[0]
        (line,) = [x for x in block.splitlines() if x.startswith("    - episodes to solve:")]
        assert f"The primary claim (above): **{row.verdict}**." in line, line
        if row.verdict == "undetermined" and not row.seeds_first:
            seeds = f"more than {row.seeds_cap}" if math.isinf(row.seeds_needed) else f"about {int(row.seeds_needed)}"
            assert f"Seeds needed (the primary claim's): {seeds} seeds per variant" in line, line
        assert line.count("Seeds needed") <= 1, line


def test_an_interval_open_at_one_end_is_worded_from_its_closed_end():
    # "better: 43% fewer (interval: at least 51% fewer, no upper end)" read an interval [-51%, +inf) backwards
    from ablate.claims import Question
    from ablate.reporting.findings import claim_line

    question = Question("episodes_to_solve", relative=True, lower_is_better=True, smallest_effect=0.1, budget=40)
    row = dict(variant="v", reference="base", metric="episodes_to_solve", verdict="better", change=-43.0, bound="")
    row |= dict(variant_value=18.0, reference_value=31.0, n_variant=6, n_reference=6, level=0.0167, seeds_cap=100)
    row |= dict(seeds_needed=np.nan, reason="")
    words = {
        (-51.0, np.inf): "interval: from 51% fewer, no upper end",
        (18.0, np.inf): "interval: at least 18% more, no upper end",
        (-np.inf, -20.0): "interval: at least 20% fewer, no lower end",
        (-np.inf, 30.0): "interval: at most 30% more, no lower end",
    }
    for (low, high), expected in words.items():
        line = claim_line(pd.Series(row | {"change_low": low, "change_high": high}), question)
        assert expected in line, line


def test_an_unsolved_variant_keeps_its_row_and_an_empty_table_its_columns(claimed):
    # issue 36: an all-censored comparison must stay in comparisons (a bound, not a gap), and an empty table
    # keep its columns. Both already held when checked; this keeps them.
    _, uri = claimed
    results = ablate.load("claimed", tracking_uri=uri)
    slow = results.trials[results.trials.variant == "slow"]
    assert len(slow) and (slow.solved == 0).all()  # every seed of slow unsolved
    row = results.comparisons.query("variant == 'slow' and metric == 'episodes_to_solve'")
    assert len(row) == 1 and row.bound.iloc[0] == "at least" and row.change.iloc[0] > 0 and bool(row.primary.iloc[0])
    alone = ablate.load("claimed", tracking_uri=uri, variants=["base"])  # nothing to compare
    assert alone.claims.empty and list(alone.claims.columns) == list(results.claims.columns)
    assert alone.comparisons.empty and list(alone.comparisons.columns) == list(results.comparisons.columns)
    assert alone.tuning.empty and list(alone.tuning.columns) == [
        "ablation",
        "env_id",
        "variant",
        "seed",
        "auc",
        "status",
    ]


def test_a_claim_marks_the_censored_side_as_the_bound():
    # issue 46: the ≥ went on the variant whatever the verdict; a "better" bound is the reference's IQM, which
    # counts its unsolved seeds as the budget (a "worse" one the variant's)
    from ablate.claims import Question
    from ablate.reporting.findings import claim_line

    question = Question("episodes_to_solve", relative=True, lower_is_better=True, smallest_effect=0.1, budget=950)
    row = dict(variant="v", reference="base", metric="episodes_to_solve", change=-46.0, bound="at least")
    row |= dict(variant_value=492.0, reference_value=917.0, n_variant=6, n_reference=6, level=0.05, seeds_cap=100)
    row |= dict(seeds_needed=np.nan, reason="", change_low=-49.0, change_high=-42.0)
    assert "IQM 492 vs ≥ 917" in claim_line(pd.Series(row | {"verdict": "better"}), question)
    slower = row | dict(variant_value=917.0, reference_value=492.0, change=85.0, change_low=70.0, change_high=95.0)
    assert "IQM ≥ 917 vs 492" in claim_line(pd.Series(slower | {"verdict": "worse"}), question)


def test_a_claim_with_no_change_reads_as_a_sentence():
    # issue 46: a zero change read "no change episodes to solve (interval no change to 20% more)"
    from ablate.claims import Question
    from ablate.reporting.findings import claim_line

    question = Question("episodes_to_solve", relative=True, lower_is_better=True, smallest_effect=0.1, budget=950)
    row = dict(variant="v", reference="base", metric="episodes_to_solve", change=0.0, bound="", verdict="undetermined")
    row |= dict(variant_value=500.0, reference_value=500.0, n_variant=6, n_reference=6, level=0.05, seeds_cap=100)
    row |= dict(seeds_needed=np.nan, reason="too few seeds", change_low=0.0, change_high=20.0)
    line = claim_line(pd.Series(row), question)
    assert "no change in episodes to solve (interval 0% to 20% more)" in line, line
    line = claim_line(pd.Series(row | dict(change_low=-20.0, change_high=0.0)), question)
    assert "(interval 20% fewer to 0%)" in line and "no change episodes" not in line, line
