"""Which runs of a generation the plan counts: stage 2 as recorded or recognised, earlier keys counted apart."""

from types import SimpleNamespace

from ablate.launch.mlflow_store import TrialRun
from ablate.reporting.planned import answers, earlier_trials, stage_two

TUNING = {"knobs": {"learning_rate": [0.01, 0.1]}, "seeds": [10_000], "base": {"learning_rate": 0.01}}
GRID = {"trials": [{"key": "lab-s0-new", "variant": "lab", "seed": 0}], "tune_trials": []}


def _run(key, seed, lr, source, stage="eval"):
    params = {"seed": str(seed), "learning_rate": str(lr), "model.factory_hash": source, "gamma": "0.99"}
    return SimpleNamespace(key=key, variant="lab", seed=seed, params=params, tags={"ablate.stage": stage})


def test_a_key_is_answered_by_its_newest_finished_run_else_its_newest_run():
    def run(key, status, start):
        return TrialRun(f"id-{key}-{start}", key, "v", 0, status, {}, {}, {}, start)

    runs = [run("a", "KILLED", 1), run("a", "FINISHED", 2), run("b", "FAILED", 1), run("b", "RUNNING", 3)]
    runs += [run("c", "FINISHED", 1), run("c", "KILLED", 2), run("d", "KILLED", 5)]
    runs += [run("e", "FINISHED", 1), run("e", "FINISHED", 4)]
    assert {k: r.run_id for k, r in answers(runs).items()} == {
        "a": "id-a-2",
        "b": "id-b-3",
        "c": "id-c-1",
        "d": "id-d-5",
        "e": "id-e-4",
    }


def test_stage_two_is_the_recorded_keys_else_the_runs_with_the_planned_settings_but_the_tuned_knobs():
    runs = {
        "lab-s0-new": _run("lab-s0-new", 0, 0.01, "new"),  # planned, at the base value
        "lab-s1-new-lr": _run("lab-s1-new-lr", 1, 0.1, "new"),  # stage 2 of the current network
        "lab-s1-old-lr": _run("lab-s1-old-lr", 1, 0.1, "old"),  # stage 2 of the network before an edit
        "lab-s10000-new": _run("lab-s10000-new", 10_000, 0.1, "new", stage="tune"),  # no evaluation trial
    }
    assert [t["key"] for t in stage_two(TUNING, GRID, runs)] == ["lab-s1-new-lr"]
    recorded = [{"key": "lab-s1-new-lr", "variant": "lab", "seed": 1}]
    assert stage_two(TUNING | {"trials": recorded}, GRID, {}) == recorded


def test_earlier_trials_are_counted_once_per_key():
    runs = [_run("lab-s0-old", 0, 0.01, "old"), _run("lab-s0-old", 0, 0.01, "old"), _run("lab-s0-new", 0, 0.01, "new")]
    earlier = earlier_trials(runs, {"lab-s0-new"}, ["lab", "other"])
    assert earlier == {"lab": 1}


def test_a_tuned_launch_without_its_choice_yet_has_no_plan_to_call_a_run_earlier():
    from ablate.reporting.planned import plan_keys

    tuned = GRID | {"tune_trials": [{"key": "lab-s10000-new", "variant": "lab", "seed": 10_000, "stage": "tune"}]}
    assert plan_keys(tuned, None, {}) is None  # interrupted in stage 1: stage 2 unknown
    assert plan_keys(GRID, None, {}) == {"lab-s0-new"}  # untuned: the grid is the plan
    recorded = TUNING | {"trials": [{"key": "lab-s1-new-lr", "variant": "lab", "seed": 1}]}
    assert plan_keys(tuned, recorded, {}) == {"lab-s0-new", "lab-s10000-new", "lab-s1-new-lr"}
