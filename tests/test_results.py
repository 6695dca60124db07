"""Tidy frames from trial tables: censoring counted, a curve's measures by hand, each variant's reference."""

import re

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from ablate.measures import trial_measures
from ablate.reporting.results import Ablation
from ablate.reporting.tables import convergence_table


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


# --- issue 44, item 4: a tuned launch's results are read by key ---

MYLAB = """from torch import nn


def create_cartpole_model():
    return nn.Sequential(nn.Linear(4, {width}), nn.ReLU(), nn.Linear({width}, 2))
"""

TUNED_OWN = """
name = "lab"
seeds = 3
[base]
env_id = "CartPole-v1"
max_episodes = 20
episodes_per_update = 10
[[variants]]
name = "baseline"
hidden_sizes = [8]
[[variants]]
name = "mylab"
model = "mylab.py:create_cartpole_model"
[tune]
learning_rate = [0.01, 0.1]
seeds = 1
max_episodes = 10
"""


def test_an_edited_network_is_counted_by_its_current_keys_only(run_quiet, tmp_path):
    """The lab's own network, tuned; its width edited from 32 to 64 and the launch run again: the report and
    ``.claims`` count the 3 seeds of the current network per variant (not 6 of ``mylab``: the first network's
    trials stay in the store under their own keys), and say how many earlier trials they left out."""
    from stores import fresh_store

    import ablate
    from ablate.experiment import load_experiment
    from ablate.reporting.document import build_report
    from ablate.reporting.results import load_ablation
    from ablate.reporting.status import detail

    uri = fresh_store(tmp_path / "mlflow.db")
    (tmp_path / "lab.toml").write_text(TUNED_OWN)
    for width in (32, 64):
        (tmp_path / "mylab.py").write_text(MYLAB.format(width=width))
        outcome = run_quiet(load_experiment(tmp_path / "lab.toml"), tmp_path, uri)
        assert outcome.exit_code == 0 and not outcome.failed

    ablation = load_ablation("lab", uri)
    assert ablation.finished.groupby("variant").size().to_dict() == {"baseline": 3, "mylab": 3}
    assert set(ablation.finished[ablation.finished.variant == "mylab"].parameter_count) == {4 * 64 + 64 + 64 * 2 + 2}
    # The first network: 3 base-value trials, 2 tuning trials and up to 3 at its chosen value, none counted.
    assert 5 <= ablation.earlier.get("mylab", 0) <= 8 and "baseline" not in ablation.earlier
    assert set(ablation.tuning_trials[ablation.tuning_trials.variant == "mylab"].status) == {"FINISHED"}
    assert len(ablation.tuning_trials[ablation.tuning_trials.variant == "mylab"]) == 2

    claims = ablate.load("lab", tracking_uri=uri).claims
    assert set(claims.n_variant) == {3} and set(claims.n_reference) == {3}

    folder = build_report("lab", tracking_uri=uri, out_root=tmp_path / "reports", attach=False, pdf=False).folder
    text = (folder / "report.md").read_text()
    assert "3 per variant" in text and "6 seeds" not in text
    assert "Linear(4→64)" in text and "Linear(4→32)" not in text
    n = ablation.earlier["mylab"]
    assert text.count(f"{n} earlier trials of `mylab`") == 1

    # ablate status counts the same plan: 3 base-value trials, 2 tuning trials, 3 at a choice other than the base.
    moved = ablation.tuning["choices"]["mylab"]["values"] != ablation.tuning["base"]
    newest = detail(uri, "lab").split("\ngeneration ")[1]
    assert re.search(rf"^  mylab\s+{3 + 2 + 3 * moved}$", newest, re.M), newest
    assert f"not counted: {n} earlier trials ({n} of mylab)" in newest


# tidy tables (issue 46) ---------------------------------------------------------------------------------------
def _tidy_ablation(budget: int, overrides: dict[str, dict]) -> Ablation:
    rows = [_row(v, s, True, 10 + s, budget=budget) for v in overrides for s in range(2)]
    trials = pd.DataFrame(rows)
    trials["censored_episodes"] = trials.episodes_to_solve
    for episodes in (budget // 4, budget // 2, budget):
        trials[f"return_at_{episodes}"] = 1.0
    grid = {"variants": [{"name": n, "overrides": o} for n, o in overrides.items()], "baseline": next(iter(overrides))}
    grid["base"] = {"model.hidden_sizes": [32], "learning_rate": 0.03, "episodes_per_update": 4, "gamma": 0.99}
    grid["base"] |= {"l2": 0.0, "model.factory_args": []}
    curve = [{"key": r["key"], "variant": r["variant"], "seed": r["seed"], "episode": 1, "return": 1.0} for r in rows]
    return Ablation("t", grid, {}, trials, pd.DataFrame(curve))


def test_settings_are_typed_by_the_schema_in_trials_and_claims():
    from ablate.reporting.tables import side_settings, trials_table

    overrides = {"narrow": {"hidden_sizes": [8, 8]}, "wide": {"width": 64, "model_args": {"width": 64, "act": "tanh"}}}
    ablation = _tidy_ablation(100, overrides)
    trials = trials_table(ablation).set_index("key")
    assert trials.loc["narrow-0", "hidden_sizes"] == (8, 8) and trials.loc["wide-0", "hidden_sizes"] == (64,)
    assert trials.loc["wide-0", "model_args.width"] == 64 and trials.loc["wide-0", "model_args.act"] == "tanh"
    assert "model_args" not in trials and trials.loc["narrow-0", "depth"] == 2
    claims = side_settings(pd.DataFrame({"variant": ["wide"], "reference": ["narrow"]}), ablation).iloc[0]
    assert claims["variant.hidden_sizes"] == (64,) and claims["reference.hidden_sizes"] == (8, 8)
    assert claims["variant.model_args.width"] == 64 and claims["variant.learning_rate"] == 0.03
    setting_columns = [c for c in trials.columns if f"variant.{c}" in claims]
    assert {"learning_rate", "hidden_sizes", "width", "model_args.act"} <= set(setting_columns)


def test_convergence_and_curves_concatenate_across_budgets():
    from ablate.reporting.tables import convergence_long, convergence_table, curves_table

    short, long = _tidy_ablation(100, {"a": {}, "b": {}}), _tidy_ablation(400, {"a": {}, "b": {}})
    tables = [convergence_long(convergence_table(a)) for a in (short, long)]
    assert list(tables[0].columns) == list(tables[1].columns)
    assert not [c for c in tables[0].columns if any(ch.isdigit() for ch in c)]  # no budget in a column's name
    both = pd.concat(tables, ignore_index=True)
    assert sorted(both[both.variant == "a"].episode) == [25, 50, 100, 100, 200, 400]
    assert set(both.budget) == {100, 400} and (both.return_iqm == 1.0).all()
    curves = curves_table(short)
    assert list(curves.columns[:4]) == ["key", "variant", "seed", "stage"] and set(curves.stage) == {"eval"}
