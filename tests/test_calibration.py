"""ablate calibrate (ablate/calibration.py): the derived experiment, the dealing of A/A reports, the two rules'
shares and their Wilson intervals. The end-to-end figure for CartPole is in docs/report.md."""

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ablate.calibration import Share, aa_reports, derived_experiment
from ablate.experiment import load_experiment
from ablate.launch.grid import expand
from ablate.seeds import SeedRounds

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"


def test_shares_carry_wilson_intervals_at_known_points():
    assert Share(0, 200).words() == "0 of 200 reports, 0.0% (95% CI 0.0% to 1.9%)"  # 3.84 / (200 + 3.84)
    assert Share(108, 200).words() == "108 of 200 reports, 54.0% (95% CI 47.1% to 60.8%)"
    assert Share(10, 200).words().startswith("10 of 200 reports, 5.0% (95% CI 2.7% to 9.0%)")


def test_the_derived_experiment_is_the_tuned_baseline_on_seeds_of_its_own():
    experiment = load_experiment(EXPERIMENTS / "cartpole.toml")
    derived = derived_experiment(experiment, {"learning_rate": 0.1}, 60)
    assert derived.name == "cartpole-calibrate" and [v.name for v in derived.variants] == ["baseline"]
    assert len(derived.seeds) == 60 and min(derived.seeds) == 20_000 and derived.tune is derived.rounds is None
    assert not set(derived.seeds) & {*experiment.seeds, *experiment.tune.seeds}
    (trial,) = {t.config for t in expand(derived) if t.seed == 20_000}
    assert trial.learning_rate == 0.1 and trial.model.hidden_sizes == (32,) and trial.episodes_per_update == 32
    assert trial.max_episodes == 1500 and expand(derived)[0].key == "baseline-s20000-5566a51d3b"  # the file's key


def test_a_reference_with_its_own_network_and_model_args_is_calibrated_as_its_file_says():
    experiment = replace(load_experiment(EXPERIMENTS / "your-model.toml"), baseline="layernorm")
    derived = derived_experiment(experiment, {"learning_rate": 0.01}, 60)
    (trial,) = {t.config for t in expand(derived) if t.seed == 20_000}
    reference = next(v.config for v in experiment.variants if v.name == "layernorm")
    assert trial == replace(
        reference, learning_rate=0.01, seed=20_000
    )  # model_args = { width = 32 }, its factory beside it
    assert trial.model.factory_args == (("width", 32),) and trial.model.factory_hash


def _pool(rng, n=60, budget=1500):
    episodes = rng.lognormal(np.log(550), 0.5, n)
    solved = episodes < budget
    return pd.DataFrame(
        {
            "seed": np.arange(n),
            "censored_episodes": np.minimum(episodes, budget),
            "solved": solved.astype(int),
            "auc": rng.normal(300, 40, n),
            "return_at_1500": rng.normal(450, 60, n),
            "budget": budget,
        }
    )


def test_aa_reports_of_identical_seeds_claim_rarely_under_the_new_rule_often_under_the_old():
    trials = _pool(np.random.default_rng(0))
    metrics = ["episodes_to_solve", "auc", "return_at_1500"]
    result = aa_reports(trials, metrics, "episodes_to_solve", 10, 6, 40, 0.1)
    assert result.new.reports == result.old.reports == 40
    assert result.new.rate <= 0.1  # Holm over 9 at 6 seeds: claims possible, rarely made on identical seeds
    assert result.old.rate > 0.3  # 27 uncorrected bootstrap comparisons: about half the reports claim something
    assert set(result.old_per_metric) == set(metrics) and all(0 < r < 0.15 for r in result.old_per_metric.values())
    at_five = aa_reports(trials, ["auc"], "episodes_to_solve", 10, 5, 40, 0.1)
    assert at_five.new.claims == 0  # 5 seeds can reach no claim in a family of 9
    rounds = aa_reports(
        _pool(np.random.default_rng(2), 90), ["auc"], "episodes_to_solve", 3, 30, 40, 0.1, SeedRounds(10, 10, 30)
    )
    assert rounds.new.reports == 40 and rounds.new.rate <= 0.15  # the rounds' design, replayed per report


def test_a_pool_too_small_for_the_design_is_one_line_exit_2(tmp_path):
    with pytest.raises(Exception, match="cannot fill 10 variants x 8 seeds"):
        aa_reports(_pool(np.random.default_rng(1)), ["auc"], "auc", 10, 8, 200, 0.1)
    proc = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "calibrate", str(EXPERIMENTS / "cartpole.toml"), "--reports", "10"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert "--reports = 10 is invalid; valid: at least 200" in proc.stderr and not (tmp_path / "mlflow.db").exists()


def test_population_reaches_the_tuning_run_as_well_as_the_seeds_run(tmp_path, monkeypatch):
    import ablate.api as api
    from ablate.cli import main
    from ablate.reporting.results import NoResults

    calls = []

    def run(experiment, **kwargs):
        calls.append(kwargs)
        raise KeyboardInterrupt  # the first launch's arguments are what this test reads

    def load(*args, **kwargs):
        raise NoResults("an empty store")

    monkeypatch.setattr(api, "run", run)
    monkeypatch.setattr(api, "load", load)
    monkeypatch.chdir(tmp_path)
    assert main(["calibrate", str(EXPERIMENTS / "cartpole.toml"), "--population", "3"]) == 130  # interrupted
    assert calls[0]["only"] == ["baseline"] and calls[0]["population"] == 3  # the tuning stage of the reference
