"""The report of a tuned ablation (issue 19) from a hand-made store: the tuning table, the Tuning section, the
sensitivity figure, findings on the evaluation seeds at the chosen values, and the comparison at the base value."""

import json
import re
from pathlib import Path

import pandas as pd
import pytest
from stores import fresh_store
from test_report import rising, write_trial

from ablate.launch.tracking import Tracker
from ablate.reporting.document import build_report
from ablate.reporting.results import load_ablation
from ablate.reporting.tuning import at_values, base_values, chosen_values, edge, tuning_table

BASE_LR, CANDIDATES, TUNE_SEEDS, EVAL_SEEDS = 0.03, [0.01, 0.03, 0.1], [10000, 10001], [0, 1, 2, 3]
TUNING = {
    "knobs": {"learning_rate": CANDIDATES},
    "seeds": TUNE_SEEDS,
    "metric": "auc",
    "direction": "max",
    "max_episodes": 30,
    "rule": "the candidate with the best mean AUC over the tuning seeds; ties: the candidate nearest the base value",
    "base": {"learning_rate": BASE_LR},
    "choices": {
        "baseline": {"values": {"learning_rate": 0.1}, "tuned": True, "reason": "best mean auc"},
        "deep": {"values": {"learning_rate": 0.03}, "tuned": True, "reason": "best mean auc"},
        "course": {"values": {"learning_rate": 0.001}, "tuned": False, "reason": "set by the variant"},
    },
}
# Returns by (variant, learning rate): at the base value deep beats the baseline; at each one's own best
# rate the baseline (at 0.1) beats deep: the finding flips with the learning rate.
LEVEL = {("baseline", 0.01): 12, ("baseline", 0.03): 20, ("baseline", 0.1): 60, ("deep", 0.01): 15}
LEVEL |= {("deep", 0.03): 40, ("deep", 0.1): 30, ("course", 0.001): 14}


def curve(variant, lr, seed, n):
    return rising(5, LEVEL[(variant, lr)] + seed % 100, n)(seed)


def make_tuned_store(folder: Path, eval_seeds: list[int] = EVAL_SEEDS) -> str:
    """A tuned launch as issue 19's contract has it: tune-stage runs on seeds 10000+ (shorter budget),
    evaluation runs at the base value (the grid's trials, untuned keys) and at each variant's choice."""
    uri = fresh_store(folder / "mlflow.db")
    tracker = Tracker(uri, "tuned")
    base = {"env_id": "CartPole-v1", "max_episodes": 40, "solve_window": 8, "solve_threshold": 1000.0}
    base |= {"learning_rate": BASE_LR, "gamma": 0.95, "episodes_per_update": 4, "model.hidden_sizes": [32]}
    variants = {"baseline": {}, "deep": {"hidden_sizes": [8, 8]}, "course": {"preset": "course"}}
    trials = [{"key": f"{v}-s{s}", "variant": v, "seed": s} for v in variants for s in eval_seeds]
    grid = {"experiment": "tuned", "description": "tuned", "seeds": eval_seeds, "baseline": "baseline"}
    grid |= {"base": base, "trials": trials, "variants": [{"name": v, "overrides": o} for v, o in variants.items()]}
    tune_trials = [
        {"key": f"{v}-lr{lr}-s{s}", "variant": v, "seed": s, "stage": "tune"}
        for v in ("baseline", "deep")
        for lr in CANDIDATES
        for s in TUNE_SEEDS
    ]
    grid["tune_trials"] = tune_trials  # stage 1 is planned (grid.json); stage 2, at the choice, is recognised
    files = {"grid.json": json.dumps(grid), "environment.json": json.dumps({"machine": "m"})}
    files["tuning.json"] = json.dumps(TUNING)
    launch = (tracker.start_launch("g1", "tuned", {"ablate.command": "ablate run tuned.toml"}, files), "g1")
    for trial in tune_trials:
        lr = float(trial["key"].split("-lr")[1].split("-s")[0])
        params = {"learning_rate": lr}
        write_trial(tracker, launch, trial, curve(trial["variant"], lr, trial["seed"], 30), params, (30, 8, 1000.0))
    for variant in variants:
        own = TUNING["choices"][variant]["values"]["learning_rate"]
        for lr in sorted({own, BASE_LR if variant != "course" else own}):
            for seed in eval_seeds:
                key = f"{variant}-s{seed}" if lr in (BASE_LR, 0.001) else f"{variant}-lr{lr}-s{seed}"
                trial = {"key": key, "variant": variant, "seed": seed, "stage": "eval"}
                params = {"learning_rate": lr}
                write_trial(tracker, launch, trial, curve(variant, lr, seed, 40), params, (40, 8, 1000.0))
    tracker.finish_launch(launch[0], "FINISHED", {})
    return uri


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tuned")
    uri = make_tuned_store(folder)
    return folder, uri


def test_the_evaluation_uses_the_chosen_values_and_the_untuned_comparison_the_base_value(tuned):
    _, uri = tuned
    ablation = load_ablation("tuned", uri)
    assert set(ablation.trials.seed) == set(EVAL_SEEDS)  # never a tuning seed
    chosen = ablation.trials.groupby("variant").learning_rate.unique().map(list).to_dict()
    assert chosen == {"baseline": [0.1], "deep": [0.03], "course": [0.001]}
    base = ablation.untuned.trials.groupby("variant").learning_rate.unique().map(list).to_dict()
    assert base == {"baseline": [0.03], "deep": [0.03], "course": [0.001]}  # course keeps its own value
    assert len(ablation.curves) and set(ablation.curves.seed) == set(EVAL_SEEDS)
    table = ablation.tuning_trials
    assert len(table) == 12 and list(table.columns) == ["variant", "seed", "learning_rate", "auc", "status"]
    assert set(table.seed) == set(TUNE_SEEDS) and set(table.variant) == {"baseline", "deep"}


def test_the_tuning_table_ranks_what_tuning_chose(tuned):
    _, uri = tuned
    table = load_ablation("tuned", uri).tuning_trials
    means = table.groupby(["variant", "learning_rate"]).auc.mean()
    assert means["baseline"].idxmax() == 0.1 and means["deep"].idxmax() == 0.03


def test_selection_helpers_on_a_hand_made_frame():
    assert chosen_values(TUNING, "deep") == {"learning_rate": 0.03}
    assert base_values(TUNING, "baseline", {}) == {"learning_rate": BASE_LR}
    assert base_values(TUNING, "course", {"preset": "course"}) == {"learning_rate": 0.001}
    assert base_values(TUNING, "wide", {"learning_rate": 0.5}) == {"learning_rate": 0.5}
    trials = pd.DataFrame({"variant": ["baseline", "baseline", "deep"], "learning_rate": ["0.1", "0.03", "0.03"]})
    assert at_values(trials, lambda v: chosen_values(TUNING, v)).tolist() == [True, False, True]
    assert edge(TUNING, {"learning_rate": 0.1}) == ["learning rate at the highest candidate"]
    assert edge(TUNING, {"learning_rate": 0.03}) == []
    rows = [{"variant": "deep", "seed": 10000, "learning_rate": 0.1, "status": "FINISHED", "solved": 0, "budget": 30}]
    censored = tuning_table(rows, TUNING | {"metric": "episodes_to_solve"}, ["deep"])
    assert censored.episodes_to_solve.tolist() == [30.0]  # never solved: censored at its own budget


def test_the_tuned_report(tuned, tmp_path, monkeypatch):
    _, uri = tuned
    folder = build_report("tuned", tracking_uri=uri, out_root=tmp_path, attach=False).folder
    text = (folder / "report.md").read_text()
    tuning = text.split(". Tuning (generated)")[1].split("\n### ")[0]
    assert "0.01, 0.03, 0.1 (base value 0.03)" in tuning and "2 per candidate (10000, 10001)" in tuning
    assert "area under the curve (AUC), higher is better" in tuning and TUNING["rule"] in tuning
    assert "Short horizon" in tuning  # tuning ran 30 episodes, the evaluation 40
    assert "| baseline | 0.1 |" in tuning and "at the highest candidate" in tuning
    assert "course (learning rate 0.001)" in tuning and "set by the variant" in tuning
    figure = re.search(r"Figure (\d+) shows each variant's metric", tuning)
    assert figure and f"*Figure {figure.group(1)}. Sensitivity to learning rate" in text
    assert (folder / "figures" / "tuning_sensitivity.png").stat().st_size > 5000
    table = pd.read_csv(folder / "tables" / "tuning.csv")
    assert (
        list(table.columns) == ["ablation", "env_id", "variant", "seed", "learning_rate", "auc", "status"]
        and len(table) == 12
    )
    assert set(pd.read_csv(folder / "tables" / "trials.csv").seed) == set(EVAL_SEEDS)
    depends = text.split("Does the finding depend on the learning rate? (generated)")[1].split("\n### ")[0]
    assert "deep vs baseline on area under the curve (AUC) (flips)" in depends
    (line,) = [x for x in depends.splitlines() if x.startswith("- deep vs baseline, area under")]
    assert "**exploratory: better**" in line.split("; at the chosen")[0]
    assert "**exploratory: worse**" in line.split("; at the chosen")[1]
    assert "One training setting for all architectures" not in text and "Tuned over 3 candidates" in text
    # every cross-reference resolved in the model (text.Refs), none left as a token or pointing nowhere
    assert not re.search(r"\{(appendix:|parameters|sensitivity|next)", text) and "Appendix –" not in text
    letter = re.search(r"^### ([A-Z])\. Tuning", text, flags=re.M).group(1)
    assert f"Tuned per variant (see Appendix {letter})" in text and f"(Appendix {letter} flags choices" in text


def test_every_trial_the_report_uses_is_in_load_trials_with_its_stage_and_settings(tuned, tmp_path):
    # The trials at the shared base value (the "depends on the learning rate?" section's data) were in no table,
    # and a trial's settings were not columns: one parsed the variant's name or read MLflow's params.
    import io

    import ablate

    _, uri = tuned
    ablation = load_ablation("tuned", uri)
    trials = ablate.load("tuned", tracking_uri=uri).trials
    assert set(trials.key) == set(ablation.trials.key) | set(ablation.untuned.trials.key)
    assert len(trials) == len(set(trials.key))  # a trial at both values is one row
    rates = trials.groupby(["variant", "stage"]).learning_rate.unique().map(list).to_dict()
    assert rates == {
        ("baseline", "eval"): [0.1],  # at its chosen value
        ("baseline", "base"): [0.03],  # at the shared base value only
        ("course", "eval"): [0.001],
        ("deep", "eval"): [0.03],  # chosen = base: one trial serves both comparisons
    }
    assert set(trials[trials.at_base_values].key) == set(ablation.untuned.trials.key)
    deep, baseline = trials[trials.variant == "deep"].iloc[0], trials[trials.variant == "baseline"].iloc[0]
    assert (deep.hidden_sizes, deep.depth, deep.width) == ((8, 8), 2, 8)  # issue 46: a tuple, not "[8, 8]"
    assert (baseline.hidden_sizes, baseline.depth, baseline.width) == ((32,), 1, 32)
    assert set(trials.episodes_per_update) == {4} and set(trials.gamma) == {0.95}
    folder = build_report("tuned", tracking_uri=uri, out_root=tmp_path, attach=False, pdf=False).folder
    written = pd.read_csv(folder / "tables" / "trials.csv")
    pd.testing.assert_frame_equal(pd.read_csv(io.StringIO(trials.to_csv(index=False))), written)
