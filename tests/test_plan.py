"""A launch's plan of populations, and a launch that trains its trials as populations through real Ray: each
member recorded as its own trial, one that fails failing alone, a population whose process died retried."""

from dataclasses import replace

import pytest
from stores import fresh_store

from ablate.agent.trainer import run_trial
from ablate.config import DEFAULT, ModelConfig
from ablate.experiment import load_experiment
from ablate.launch.grid import PLOTTED_SEEDS, GridTrial, expand, trial_key
from ablate.launch.plan import Population, plan_populations, population_size
from ablate.launch.tracking import Tracker
from ablate.reporting.reader import RunReader

SEEDS = """
name = "pops"
seeds = 6
[base]
env_id = "CartPole-v1"
max_episodes = 20
episodes_per_update = 10
record_video = false
[[variants]]
name = "narrow"
hidden_sizes = [8]
[[variants]]
name = "narrow_fast"
hidden_sizes = [8]
learning_rate = 0.1
[[variants]]
name = "cnn"
architecture = "cnn"
"""


def _trials(tmp_path, text=SEEDS):
    path = tmp_path / "pops.toml"
    path.write_text(text)
    experiment = load_experiment(path)
    return experiment, expand(experiment)


def test_a_cap_of_one_plans_every_trial_alone_in_order(tmp_path):
    _, trials = _trials(tmp_path)
    plan = plan_populations(trials, cap=1, slots=2)
    assert [p.members for p in plan] == [(t,) for t in trials]
    assert [p.key for p in plan] == [t.key for t in trials]  # a population of one is named by its trial


def test_members_share_by_network_and_stage(tmp_path):
    _, trials = _trials(tmp_path)
    plan = plan_populations(trials, cap=4, slots=2)
    shared = [p for p in plan if len(p.members) > 1]
    assert sum(len(p.members) for p in plan) == len(trials) and len({p.key for p in plan}) == len(plan)
    # narrow and narrow_fast (one network; learning rates differ) share: 12 trials in 3 populations of 4.
    dense = [p for p in shared if p.members[0].variant != "cnn"]
    assert sorted(len(p.members) for p in dense) == [4, 4, 4]
    assert all({t.variant for t in p.members} == {"narrow", "narrow_fast"} for p in dense)
    # cnn (another network) shares only with cnn: its 6 trials in 2 populations of 3.
    cnn = [p for p in plan if any(t.variant == "cnn" for t in p.members)]
    assert [len(p.members) for p in cnn] == [3, 3] and all({t.variant for t in p.members} == {"cnn"} for p in cnn)
    tune = [replace(t, stage="tune", key=t.key + "t") for t in trials if t.variant == "narrow"]
    mixed = plan_populations([*trials[:6], *tune], cap=16, slots=1)
    assert all(len({t.stage for t in p.members}) == 1 for p in mixed)  # stages never share


def test_populations_are_sized_so_no_slot_idles():
    assert population_size(12, slots=2, cap=16) == 6  # two populations for two slots, not one of 12
    assert population_size(100, slots=2, cap=16) == 16
    assert population_size(3, slots=8, cap=16) == 1
    assert population_size(50, slots=4, cap=1) == 1


def test_groups_split_into_balanced_populations_in_start_order(tmp_path):
    _, trials = _trials(tmp_path)
    narrow = [t for t in trials if t.variant == "narrow"]
    plan = plan_populations(narrow, cap=4, slots=1)
    assert [len(p.members) for p in plan] == [3, 3]  # 6 as 3 + 3, not 4 + 2
    assert plan[0].members[0] == narrow[0]


def test_a_population_key_is_stable_and_names_its_members():
    config = replace(DEFAULT, max_episodes=5)
    members = tuple(GridTrial(trial_key("v", replace(config, seed=s)), "v", s, replace(config, seed=s)) for s in (0, 1))
    assert Population(members).key == Population(members).key != Population(members[::-1]).key
    assert Population(members).key.startswith(f"pop2-{members[0].key}-")


@pytest.mark.slow
def test_a_launch_of_populations_records_every_member_as_its_own_trial(run_quiet, tmp_path):
    """Through real Ray and MLflow: 12 CartPole trials in two populations of 6 (each with members that raise
    after their first update, and members whose process dies at the start, once), 6 CNN trials in one. Each
    member is a trial of its own key and one run, its curve and artifacts a trial's; its first update's episodes
    are those of its trial run alone."""
    marker = tmp_path / "crashed"
    text = SEEDS.replace('name = "narrow_fast"', 'name = "narrow_fast"\nfault = "raise"', 1).replace(
        'name = "narrow"\n', f'name = "narrow"\nfault = "crash_once"\nfault_marker = "{marker}"\n', 1
    )
    experiment, trials = _trials(tmp_path, text)
    assert [len(p.members) for p in plan_populations(trials, cap=6, slots=2)] == [6] * 3
    uri = fresh_store(tmp_path / "mlflow.db")
    outcome = run_quiet(experiment, tmp_path, uri, population=6)
    assert marker.exists()  # the populations holding a narrow trial died once at their start, and were retried
    raising = {t.key for t in trials if t.variant == "narrow_fast"}
    assert set(outcome.failed) == raising and all("injected fault" in m for m in outcome.failed.values())
    assert sorted(outcome.finished) == sorted(t.key for t in trials if t.key not in raising)
    reader = RunReader(uri, "pops")
    runs = {r.key: r for r in reader.trial_runs()}
    assert set(runs) == {t.key for t in trials}
    by_key = {t.key: t for t in trials}
    for key, run in runs.items():
        if key in raising:
            assert run.status == "FAILED"
            continue
        assert run.status == "FINISHED" and run.metrics["episodes_run"] == 20
        drawn = {"learning_curve.png"} if run.seed < PLOTTED_SEEDS else set()  # a variant's first seeds only
        artifacts = {a.path for a in reader.client.list_artifacts(run.run_id)}
        assert artifacts == {"episodes.csv", "weights.pt", "config.json"} | drawn
        returns = [
            v
            for _, v in sorted(
                (m.step, m.value) for m in reader.client.get_metric_history(run.run_id, "episode/return")
            )
        ]
        assert len(returns) == 20
        alone = run_trial(by_key[key].config)
        assert returns[:10] == alone.returns[:10]
    assert Tracker(uri, "pops").running_runs() == []
    assert len(reader.trial_runs()) == len(trials)  # a retried population's members: one run each


def test_cnn_configs_stack_apart_from_dense_ones():
    from ablate.config import population_group

    cnn = population_group(replace(DEFAULT, model=ModelConfig("cnn")))
    assert cnn is not None and cnn != population_group(DEFAULT)


def test_a_blocked_trial_runs_alone(tmp_path):
    """A test's ``block`` fault waits on a file before its trial trains: in a population it would hold the others."""
    _, trials = _trials(tmp_path)
    blocked = replace(trials[0], config=replace(trials[0].config, fault="block", fault_marker="x"))
    plan = plan_populations([blocked, *trials[1:6]], cap=8, slots=1)
    assert [len(p.members) for p in plan] == [1, 5] and plan[0].members == (blocked,)


WHOLE = """
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


def _experiment(folder, text: str):
    path = folder / "exp.toml"
    path.write_text(text)
    return load_experiment(path)


def _returns(reader: RunReader) -> dict[str, list[float]]:
    return {
        r.key: [
            v
            for _, v in sorted((m.step, m.value) for m in reader.client.get_metric_history(r.run_id, "episode/return"))
        ]
        for r in reader.trial_runs()
        if r.status == "FINISHED"
    }


def _populations(reader: RunReader) -> set[str]:
    """The populations (processes) the launch's trials trained in, by the tag each run carries."""
    return {r.tags["ablate.population"] for r in reader.trial_runs()}


def test_a_population_is_tracked_as_its_members_exactly_as_each_trial_alone(run_quiet, tmp_path):
    experiment = _experiment(tmp_path, WHOLE)
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
    for population, (reader, _) in stores.items():  # its size, as a tag of its own
        assert {r.tags["ablate.population_size"] for r in reader.trial_runs()} == {str(population)}


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
        history = sorted(
            (m.step, m.value)
            for m in reader.client.get_metric_history(
                next(r.run_id for r in runs if r.key == trial.key), "episode/return"
            )
        )
        assert [step for step, _ in history] == list(range(1, trial.config.max_episodes + 1))  # each episode once


def test_a_variant_draws_the_curves_of_its_first_seeds_and_the_plan_carries_them(tmp_path):
    from ablate.launch.grid import plotted_seeds

    experiment, trials = _trials(tmp_path, SEEDS.replace("seeds = 6", "seeds = [9, 3, 7, 1, 0, 5, 2]"))
    assert plotted_seeds(experiment) == {v: frozenset({9, 3, 7, 1, 0}) for v in ("narrow", "narrow_fast", "cnn")}
    plotted = {t.key for t in trials if t.seed in plotted_seeds(experiment)[t.variant]}
    plan = plan_populations(trials, cap=6, slots=2, plotted=plotted)
    assert set().union(*(p.plotted for p in plan)) == plotted and all(p.plotted <= set(p.keys) for p in plan)
    assert all(p.plotted is None for p in plan_populations(trials, cap=6, slots=2))  # no bound given: every one


def test_ablate_run_hands_one_plan_its_experiment_read_and_its_grid_expanded_once(tmp_path, monkeypatch):
    """The command line's options reach the runner as one ``LaunchPlan``: the experiment file read once, its grid
    expanded once, the part to run selected from that grid."""
    from ablate import cli
    from ablate import experiment as experiment_module
    from ablate.launch import plan as plan_module
    from ablate.launch import runner
    from ablate.launch.runner import RunOutcome

    calls = {"load": 0, "expand": 0}

    def counted(name, function):
        def call(*args, **kwargs):
            calls[name] += 1
            return function(*args, **kwargs)

        return call

    load = counted("load", experiment_module.load_experiment)
    monkeypatch.setattr(experiment_module, "load_experiment", load)
    monkeypatch.setattr(cli, "load_experiment", load)  # the name the command line reads the file through
    monkeypatch.setattr(plan_module, "expand", counted("expand", plan_module.expand))
    handed = []

    def run_plan(plan):
        handed.append(plan)
        return RunOutcome(plan.experiment.name, "g", None, skipped=len(plan.trials), total=len(plan.trials), ui_link="")

    monkeypatch.setattr(runner, "run_plan", run_plan)  # what ablate.api.launch calls
    path = tmp_path / "pops.toml"
    path.write_text(SEEDS)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    argv = ["run", str(path), "--only", "narrow", "--seeds", "0,1", "--tracking-uri", uri, "--no-report"]
    assert cli.main([*argv, "--population", "3"]) == 0
    (plan,) = handed
    assert calls == {"load": 1, "expand": 1}
    assert len(plan.grid) == 18 and [t.key for t in plan.trials] == [t.key for t in plan.grid[:2]]
    assert plan.tracking_uri == uri and plan.population == 3 and plan.judge is None  # no rounds: no judge
