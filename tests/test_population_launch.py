"""Populations through real Ray and a real MLflow store: each member is tracked as its own trial, exactly as the
same trial launched alone, and a population whose process dies resumes each member exactly."""

from dataclasses import replace
from pathlib import Path

import pytest
from stores import fresh_store

from ablate.agent.trial import run_trial
from ablate.experiment import load_experiment
from ablate.launch.grid import expand
from ablate.reporting.reader import RunReader

SEEDS = """
name = "pop"
seeds = 4
[base]
env_id = "CartPole-v1"
max_episodes = 24
episodes_per_update = 8
hidden_sizes = [8]
record_video = false
[[variants]]
name = "narrow"
"""

CRASH = """
name = "popcrash"
seeds = [0]
[base]
env_id = "CartPole-v1"
episodes_per_update = 8
hidden_sizes = [8]
record_video = false
checkpoint_every = 16
[[variants]]
name = "short"
max_episodes = 16
[[variants]]
name = "plain"
max_episodes = 48
learning_rate = 0.1
[[variants]]
name = "resumable"
max_episodes = 48
fault = "crash_after_checkpoint"
fault_marker = "{died}"
"""


def _experiment(folder: Path, text: str):
    path = folder / "exp.toml"
    path.write_text(text)
    return load_experiment(path)


def _returns(reader: RunReader) -> dict[str, list[float]]:
    return {
        r.key: [v for _, v in reader.metric_history(r.run_id, "episode/return")]
        for r in reader.trial_runs()
        if r.status == "FINISHED"
    }


def _populations(reader: RunReader) -> set[str]:
    """The populations (processes) the launch's trials trained in, by the tag each run carries."""
    return {r.tags["ablate.population"] for r in reader.trial_runs()}


def test_a_population_is_tracked_as_its_members_exactly_as_each_trial_alone(run_quiet, tmp_path):
    experiment = _experiment(tmp_path, SEEDS)
    stores = {}
    for population in (4, 1):
        folder = tmp_path / f"population-{population}"
        folder.mkdir()
        uri = fresh_store(folder / "mlflow.db")
        outcome = run_quiet(experiment, folder, uri, population=population, max_concurrent=1)
        assert outcome.exit_code == 0 and len(outcome.finished) == 4 and not outcome.failed
        stores[population] = RunReader(uri, "pop"), folder
    together, alone = (_returns(reader) for reader, _ in (stores[4], stores[1]))
    assert set(together) == {t.key for t in expand(experiment)} == set(alone)
    assert together == alone  # every episode of every member: the population changes nothing on a CPU
    for run in stores[4][0].trial_runs():
        assert run.status == "FINISHED" and run.metrics["episodes_run"] == 24
    # One Tune trial (one process) for the population; four for the trials alone.
    assert len(_populations(stores[4][0])) == 1 and _populations(stores[1][0]) == set(alone)


@pytest.mark.e2e  # a Ray worker process that dies mid-population, and Tune's retry of the population
def test_a_population_whose_process_died_resumes_each_member_exactly(run_quiet, tmp_path):
    died = tmp_path / "died-after-checkpoint"
    experiment = _experiment(tmp_path, CRASH.format(died=died))
    uri = fresh_store(tmp_path / "mlflow.db")
    outcome = run_quiet(experiment, tmp_path, uri, population=3, max_concurrent=1)
    assert died.exists()  # the process really died, with every member in it
    assert outcome.exit_code == 0 and len(outcome.finished) == 3 and not outcome.failed
    reader = RunReader(uri, "popcrash")
    assert len(_populations(reader)) == 1  # the three were one population
    runs = reader.trial_runs()
    assert len(runs) == 3 and {r.status for r in runs} == {"FINISHED"}
    tracked = _returns(reader)
    for trial in expand(experiment):
        unbroken = run_trial(replace(trial.config, fault="", fault_marker=""))
        assert tracked[trial.key] == unbroken.returns, trial.variant  # resumed exactly, or never disturbed
        history = reader.metric_history(next(r.run_id for r in runs if r.key == trial.key), "episode/return")
        assert [step for step, _ in history] == list(range(1, trial.config.max_episodes + 1))  # each episode once
