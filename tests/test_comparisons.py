"""Comparisons and their findings on hand-made trial tables: censoring, small samples, one seed, references."""

import re
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from test_results import _grid_ablation, _row

from ablate.reporting.comparisons import compare_metric, comparisons
from ablate.reporting.render import markdown
from ablate.reporting.results import Ablation
from ablate.reporting.statistics import smallest_p_value
from ablate.reporting.tables import convergence_table


# honest findings on censored data (issue 8 item 8), small samples, one seed, Pong (issue 9 item 7) -------
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
    from ablate.reporting.findings import findings

    table = convergence_table(ablation)
    return markdown(findings(ablation, table, comparisons(ablation)))


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
    assert comparison["bound"] == "censored" and comparison["verdict"] == "exploratory: not separated"
    assert "cannot separate" in _findings_text(ablation)


def test_when_episodes_cannot_separate_the_area_under_the_curve_can():
    # narrow vs baseline in the committed report: both censored on episodes, but AUC's interval excludes 0
    ablation = _frame(
        {"baseline": BASELINE_4_OF_5, "narrow": [650, None, None, None, 720]},
        metric_values={"baseline": [290, 300, 310, 320, 200], "narrow": [150, 160, 170, 180, 240]},
    )
    assert compare_metric(ablation, "narrow", "episodes_to_solve")["verdict"] == "exploratory: not separated"
    auc = compare_metric(ablation, "narrow", "auc")
    assert auc["verdict"] == "exploratory: worse" and auc["high"] < 0
    assert re.search(r"area under the curve \(AUC\): \*exploratory: worse\*, \*\*lower\*\*", _findings_text(ablation))


def test_three_seeds_against_three_support_no_claim():
    assert smallest_p_value(3, 3) == pytest.approx(0.1) and smallest_p_value(5, 5) == pytest.approx(2 / 252)
    ablation = _frame({"a": [10, 11, 12], "b": [50, 60, 70]}, budget=100)
    assert compare_metric(ablation, "b", "episodes_to_solve")["verdict"] == "exploratory: too few seeds"
    assert "no ordering of the seeds can reach 95%" in _findings_text(ablation)
    # ... one verdict a student can repeat, said once for all, and the estimate with no direction words
    # (issue 19 item 6: "no claim" beside "the seeds suggest higher"); 3 seeds: the "IQM" is the mean, so named
    text = _findings_text(ablation)
    assert text.count("no ordering of the seeds can reach 95%") == 1
    (line,) = [x for x in text.splitlines() if "episodes to solve:" in x]
    assert "*exploratory: too few seeds*. mean 60 vs 11 episodes" in line and "suggest" not in text
    assert "IQM" not in line and "no claim" not in text
    assert "Seeds needed" not in line  # 3 seeds support no prediction: the claim says to run 10 first
    from ablate.reporting.findings import summary

    claims = markdown(summary(ablation, convergence_table(ablation), comparisons(ablation)))
    assert "| undetermined |" in claims and "The one primary comparison is a family" in claims
    assert "**b** vs a: **undetermined** (no ordering of 3 and 3 seeds reaches the family level" in claims
    assert "3 seeds cannot support a prediction of the seeds that would decide it: run 10 per variant first" in claims
    never = _frame({"a": [None, None, None], "b": [None, None, 50]}, budget=100)  # both IQMs use the budget
    (episodes_line,) = [line for line in _findings_text(never).splitlines() if "episodes to solve" in line]
    assert "episodes cannot separate them" in episodes_line and "vs" not in episodes_line.split("seeds*.")[1]


def test_leave_one_seed_out_marks_a_claim_that_rests_on_some_seeds():
    ablation = _frame(
        {"a": [10] * 5, "b": [10] * 5},
        budget=100,
        metric_values={"a": [10, 10.5, 11, 11.5, 12], "b": [11, 12, 13, 14, 25]},
    )
    fragile = compare_metric(ablation, "b", "auc")
    assert fragile["verdict"] == "exploratory: better" and fragile["fragile_seeds"] == "1 2 3"
    # by hand: without seed 1, b = [11, 13, 14, 25] against a = [10, 11, 11.5, 12]; the claim no longer holds
    without = ablation.trials[ablation.trials.seed != 1]
    again = compare_metric(replace(ablation, trials=without), "b", "auc", stability=False)
    assert again["verdict"] != "exploratory: better"
    robust = _frame(
        {"a": [10] * 5, "b": [10] * 5},
        budget=100,
        metric_values={"a": [10, 10.5, 11, 11.5, 12], "b": [20, 21, 22, 23, 24]},
    )
    assert compare_metric(robust, "b", "auc")["fragile_seeds"] == ""
    assert "Fragile" in _findings_text(ablation) and "holds leaving out any one seed" in _findings_text(robust)
    assert _findings_text(robust).count("leaving out") == 1  # said once, not on every line
    four = _frame(
        {"a": [10] * 4, "b": [10] * 4}, budget=100, metric_values={"a": [10, 11, 12, 13], "b": [20, 21, 22, 23]}
    )
    comparison = compare_metric(four, "b", "auc")  # 3 and 3 seeds left: no claim could survive, none is checked
    assert (
        comparison["verdict"] == "exploratory: better"
        and comparison["fragile_seeds"] == ""
        and not comparison["loo_checked"]
    )
    assert "Fragile" not in _findings_text(four) and "were not checked that way" in _findings_text(four)


def test_leave_one_seed_out_is_not_made_past_fifty_seeds_a_side_and_the_report_says_why():
    """640 seeds a side cost a bootstrap per seed, per metric: a 2,642-trial report spent minutes there."""
    from ablate.reporting.comparisons import LOO_MAX_SEEDS

    n = LOO_MAX_SEEDS + 1
    rng = np.random.default_rng(0)
    values = {"a": rng.normal(10, 1, n), "b": rng.normal(20, 1, n)}
    many = _frame({"a": [10] * n, "b": [10] * n}, budget=100, metric_values=values)
    comparison = compare_metric(many, "b", "auc")
    assert comparison["verdict"] == "exploratory: better" and not comparison["loo_checked"]
    text = _findings_text(many)
    assert f"more than {LOO_MAX_SEEDS} seeds, one seed is under 2%" in text and "were not checked that way" not in text
    fifty = _frame(
        {"a": [10] * (n - 1), "b": [10] * (n - 1)}, budget=100, metric_values={k: v[:-1] for k, v in values.items()}
    )
    assert compare_metric(fifty, "b", "auc")["loo_checked"]


def test_one_seed_gives_no_interval_and_no_crash():
    ablation = _frame({"a": [10], "b": [None]}, budget=100)
    table = convergence_table(ablation)
    assert np.isnan(table.loc[0, "episodes_iqm_ci_low"])
    assert all(v == "exploratory: too few seeds" for v in comparisons(ablation).verdict)
    assert "1 seed gives no interval" in _findings_text(ablation)


def test_not_separated_reads_as_no_effect_this_large_or_too_few_seeds():
    # issue 19 item 5: five seeds each, the same spread; one pair 1 point apart, one 15 points apart
    close = _frame(
        {"a": [100] * 5, "b": [100] * 5}, metric_values={"a": [10, 30, 50, 20, 40], "b": [11, 31, 51, 21, 41]}
    )
    (line,) = [x for x in _findings_text(close).splitlines() if "area under the curve" in x]
    assert "exploratory: not separated" in line and "**no effect this large**: even 50 seeds" in line, line
    far = _frame({"a": [100] * 5, "b": [100] * 5}, metric_values={"a": [10, 30, 50, 20, 40], "b": [25, 45, 65, 35, 55]})
    (line,) = [x for x in _findings_text(far).splitlines() if "area under the curve" in x]
    assert "exploratory: not separated" in line and "**too few seeds**: about" in line, line
    row = comparisons(far).set_index("metric").loc["auc"]
    assert 5 < row.seeds_needed <= 50 and row.seeds_needed_smallest > row.seeds_needed  # 10% of 30 < 15


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
    assert mlp_l2["point"] == pytest.approx(4.0) and mlp_l2["reference_value"] == pytest.approx(5.02)
    assert compare_metric(ablation, "mlp", "auc", stability=False)["point"] == pytest.approx(4.0)
    table = comparisons(replace(ablation, grid=ablation.grid | {"seeds": list(range(5))}), stability=False)
    assert dict(zip(table.variant, table.reference, strict=True)) == {"mlp": "cnn", "mlp-l2": "mlp"}


def test_the_table_carries_the_reports_sign_and_units_and_a_testable_seed_cap():
    # issue 27: the report said "change +5% (95% CI -21% to +40%)", results.comparisons "point -0.049,
    # low -0.40, high 0.21", and seeds_needed = 51 meant "more than 50"
    from ablate.reporting.findings import finding
    from ablate.reporting.statistics import SEEDS_CAP

    ablation = _frame({"a": [500, 520, 540, 560, 580], "b": [510, 530, 560, 600, 640]}, metric_values=None)
    compare = comparisons(ablation)
    row = compare[compare.metric == "episodes_to_solve"].iloc[0]
    assert row.change == pytest.approx(-100 * row.point) and row.change > 0  # b needs more episodes: +
    assert (row.change_low, row.change_high) == pytest.approx((-100 * row.high, -100 * row.low))
    assert row.change_unit.startswith("% episodes")
    text = finding(row, ablation, convergence_table(ablation))
    assert f"change {row.change:+.0f}%" in text and f"95% CI {row.change_low:+.0f}% to {row.change_high:+.0f}%" in text
    auc = compare[compare.metric == "auc"].iloc[0]
    assert auc.change == auc.point and auc.change_unit.startswith("return")
    from ablate.claims import SEEDS_CAP as CLAIMS_CAP

    assert (compare[~compare.primary].seeds_cap == SEEDS_CAP).all() and (
        compare[compare.primary].seeds_cap == CLAIMS_CAP
    ).all()
    needed = compare.seeds_needed.dropna()
    assert not ((needed > SEEDS_CAP) & ~np.isinf(needed)).any()  # past the cap it is inf, never cap + 1


def test_every_comparisons_column_is_documented_in_python_md_and_help():
    from pathlib import Path

    from ablate.api import Results

    ablation = _frame({"a": [500, 520, 540, 560, 580], "b": [510, 530, 560, 600, 640]})
    page = (Path(__file__).parents[1] / "docs" / "python.md").read_text()
    for column in comparisons(ablation).columns:
        assert f"`{column}`" in page, column
        assert f"``{column}``" in Results.__doc__, column


# --- the primary claims lead the report (issue 25) ------------------------------------------------------


def test_the_summary_states_each_primary_claim_in_words_with_the_family_sentence():
    from ablate.reporting.findings import summary

    rng = np.random.default_rng(0)
    samples = {"baseline": [int(x) for x in rng.normal(500, 60, 8)]}
    samples["fast"] = [int(x) for x in rng.normal(200, 30, 8)]
    samples["same"] = [int(x) for x in rng.normal(505, 20, 8)]
    samples["never"] = [None] * 8
    aucs = {v: [300.0 + i for i in range(8)] for v in samples} | {"never": [40.0 + i for i in range(8)]}
    ablation = _frame(samples, metric_values=aucs)
    text = markdown(summary(ablation, convergence_table(ablation), comparisons(ablation, power=False)))
    assert text.startswith("The 3 primary comparisons form one family whose chance of any false claim is at most 5%")
    assert "Holm's step-down" in text and "on episodes to solve" in text
    assert re.search(r"\*\*fast\*\* is \*\*better\*\* than baseline: \d+% fewer episodes to solve \(interval", text)
    assert "**same** is **equivalent** to baseline within ±10%" in text
    # never solved: half the pooled seeds censored, so judged on the AUC, and it says why (claims.CENSORED_SHARE)
    assert re.search(r"\*\*never\*\* is \*\*worse\*\* than baseline: area under the curve \(AUC\) -", text)
    assert "Judged on area under the curve (AUC), not episodes to solve: 50% of its seeds never solved" in text
    assert "*Exploratory:*" in text.split("- **never**")[1]  # the ranked table comes after, labelled


def test_an_undetermined_claim_says_why_and_the_seeds_it_would_take():
    from ablate.reporting.findings import claims

    ablation = _frame({"baseline": [500, 520, 480, 510, 530], "slower": [700, 650, 720, 690, 710]})
    (line,) = [item.text for item in claims(ablation)[1].items]
    assert "**worse**" in line  # one comparison at 5%: 4/252 = 0.016 is enough
    five = _frame({"baseline": [500, 520, 480, 510, 530], **{f"v{i}": [505, 515, 495, 500, 525] for i in range(9)}})
    lines = [item.text for item in claims(five)[1].items]
    assert len(lines) == 9 and all("**undetermined** (no ordering of 5 and 5 seeds" in x for x in lines)
    # 5 seeds a side support no prediction (tools/seed_advice.py): the claim says what to run first
    assert all("5 seeds cannot support a prediction" in x and "run 10 per variant first" in x for x in lines)


def test_the_claims_table_has_one_row_per_comparison_in_the_reports_units():
    from ablate.reporting.comparisons import CLAIM_COLUMNS, claims_table

    ablation = _frame({"baseline": [500, 520, 480, 510, 530], "slower": [700, 650, 720, 690, 710]})
    table = claims_table(ablation)
    assert list(table.columns) == list(CLAIM_COLUMNS) and len(table) == 1
    row = table.iloc[0]
    assert row.verdict == "worse" and row.metric == "episodes_to_solve"
    assert row.change == pytest.approx(100 * (700 / 510 - 1)) and row.change_low > 0  # IQMs 700 vs 510 episodes
    assert (row.variant_value, row.reference_value) == pytest.approx((700, 510))
    assert (row.n_variant, row.n_reference) == (5, 5) and row.level == pytest.approx(0.05)
    # the exploratory table repeats the claim on its primary row, and its own words are not the claims'
    compare = comparisons(ablation, claims=table)
    primary = compare[compare.primary]
    assert list(primary.metric) == ["episodes_to_solve"] and list(primary.claim) == ["worse"]
    assert set(compare[~compare.primary].claim) == {""}
    assert all(v.startswith("exploratory: ") for v in compare.verdict)
    empty = claims_table(_frame({"baseline": [500, 520]}))  # nothing compared: the columns stay
    assert list(empty.columns) == list(CLAIM_COLUMNS) and empty.empty


def test_every_claims_column_is_documented_in_python_md_and_help():
    from pathlib import Path

    from ablate.api import Results
    from ablate.reporting.comparisons import CLAIM_COLUMNS

    page = (Path(__file__).parents[1] / "docs" / "python.md").read_text()
    section = page.split("## The report's claims, in one line")[1].split("\n## ")[0]
    assert 'ablate.load("cartpole").claims' in section
    for column in CLAIM_COLUMNS:
        assert f"`{column}`" in section, column
    for column in ("variant", "verdict", "change_low", "level", "seeds_needed"):
        assert f"``{column}``" in Results.__doc__.split("``trials``")[0], column


def test_the_lower_bound_mark_goes_on_the_side_that_counts_unsolved_seeds():
    # issue 46: "mean ≥ 492 vs 916 episodes" marked the variant that solved every seed; the reference's mean
    # counts its unsolved seeds as the budget, so it is the bound
    from ablate.reporting.findings import finding

    ablation = _frame({"base": [None, 850, None], "solver": [480, 490, 505]}, budget=950)
    table = convergence_table(ablation)
    compare = comparisons(ablation)
    row = compare[compare.metric == "episodes_to_solve"].iloc[0]
    assert row.bound == "at least" and row.verdict == "exploratory: too few seeds"
    text = finding(row, ablation, table)
    assert "mean 492 vs ≥ 917 episodes" in text, text
    assert "≥ 492" not in text
    # the other way round: the variant that left seeds unsolved is the bound
    slow = _frame({"base": [480, 490, 505], "slow": [None, 850, None]}, budget=950)
    row = comparisons(slow).iloc[0]
    assert "mean ≥ 917 vs 492 episodes" in finding(row, slow, convergence_table(slow))
