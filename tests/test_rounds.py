"""Seeds in rounds (``seeds = { start, step, max }``): the keys, their bad input, and launches whose rounds a
fake scheduler runs with planted results: a real difference decided early, a null run to ``max``, a resume
across rounds, ``--only``, a time budget, the dry run."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from ablate.config import ConfigError
from ablate.experiment import load_experiment
from ablate.launch.grid import expand
from ablate.launch.tracking import Tracker
from ablate.reporting.reader import RunReader

VARIANTS = """
[base]
env_id = "CartPole-v1"
max_episodes = 1000
[[variants]]
name = "baseline"
[[variants]]
name = "fast"
hidden_sizes = [64]
[[variants]]
name = "null"
hidden_sizes = [16]
"""
ROUNDS = 'name = "rounds"\nseeds = { start = 5, step = 5, max = 15 }\n' + VARIANTS


def _experiment(tmp_path, text=ROUNDS, name="exp.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_experiment(path)


def test_a_fixed_seed_count_keeps_its_keys_and_a_table_starts_with_the_same_trials(tmp_path):
    fixed = _experiment(tmp_path, 'name = "rounds"\nseeds = 5\n' + VARIANTS, "fixed.toml")
    assert fixed.rounds is None and fixed.seeds == (0, 1, 2, 3, 4)
    one_round = _experiment(tmp_path, 'name = "rounds"\nseeds = { start = 5, max = 5 }\n' + VARIANTS, "one.toml")
    rounds = _experiment(tmp_path)
    keys = [t.key for t in expand(fixed)]
    assert [t.key for t in expand(one_round)] == keys and one_round.rounds is None
    assert [t.key for t in expand(rounds)] == keys  # round 1 is exactly the fixed design's trials
    assert rounds.rounds.looks == (5, 10, 15) and rounds.seeds == (0, 1, 2, 3, 4)
    assert keys[0] == "baseline-s0-" + keys[0].rsplit("-", 1)[1] and len(keys) == 15
    every = expand(rounds, every_round=True)  # every seed the rounds may add, round 1's keys first among them
    assert len(every) == 45 and {t.key for t in expand(rounds)} <= {t.key for t in every}
    listed = _experiment(tmp_path, 'name = "rounds"\nseeds = [3, 7]\n' + VARIANTS, "listed.toml")
    assert [t.seed for t in expand(listed)][:2] == [3, 7] and listed.rounds is None


def test_a_variant_lists_its_own_seeds(tmp_path):
    text = ROUNDS.replace('name = "null"\n', 'name = "null"\nseeds = 3\n')
    text = text.replace('name = "fast"\n', 'name = "fast"\nseeds = { start = 2, step = 2, max = 6 }\n')
    experiment = _experiment(tmp_path, text)
    by_variant = {v.name: v for v in experiment.variants}
    assert experiment.seeds_of(by_variant["null"]) == (0, 1, 2) and experiment.rounds_of(by_variant["null"]) is None
    assert experiment.max_seeds_of(by_variant["fast"]) == tuple(range(6))
    assert experiment.max_seeds_of(by_variant["baseline"]) == tuple(range(15))
    assert [t.seed for t in expand(experiment) if t.variant == "fast"] == [0, 1]


BAD_SEEDS = [
    ("seeds = { start = 5, step = 5 }", "seeds.max: missing"),
    ("seeds = { start = 0, max = 10 }", "seeds.start = 0 is invalid; valid: a count of seeds in [1, 1000]"),
    ("seeds = { start = 5, max = 3 }", "seeds.max = 3 is invalid; valid: a count of seeds in [start = 5, 1000]"),
    ("seeds = { start = 5, max = 2000 }", "seeds.max = 2000 is invalid; valid: a count of seeds in [start = 5, 1000]"),
    ("seeds = { start = 5, max = 'x' }", "seeds.max = 'x' is invalid; valid: a count of seeds in [start = 5, 1000]"),
    ("seeds = { start = 5, step = 0, max = 10 }", "seeds.step = 0 is invalid"),
    ("seeds = { start = 5, max = 10, max_minutes = -1 }", "seeds.max_minutes = -1 is invalid"),
    ("seeds = { start = 5, max = 10, stop = 3 }", "seeds.stop: unknown key; valid keys of a seeds table"),
    ("seeds = { start = 5.5, max = 10 }", "seeds.start = 5.5 is invalid"),
    ("seeds = 'five'", "seeds = 'five' is invalid; valid: a count in [1, 1000], a list"),
    ("seeds = { start = 5, max = 10, growth = 0.5 }", "seeds.growth = 0.5 is invalid; valid: a factor in [1, 10]"),
]


def test_a_growing_schedule_doubles_the_seeds_each_round_and_the_claims_judge_at_the_same_looks(tmp_path):
    from ablate.claims import Design

    experiment = _experiment(
        tmp_path, 'name = "rounds"\nseeds = { start = 10, step = 10, max = 500, growth = 2 }\n' + VARIANTS
    )
    assert experiment.rounds.looks == (10, 20, 40, 80, 160, 320, 500)
    assert Design.of(experiment.rounds).looks == experiment.rounds.looks
    # growth 1 (the default) is the additive schedule, its looks unchanged
    plain = _experiment(tmp_path, 'name = "rounds"\nseeds = { start = 5, step = 10, max = 30 }\n' + VARIANTS)
    assert plain.rounds.looks == (5, 15, 25, 30) == Design(5, 10, 30).looks


@pytest.mark.parametrize(("line", "message"), BAD_SEEDS)
def test_a_bad_seeds_table_is_one_error_naming_file_and_key(tmp_path, line, message):
    with pytest.raises(ConfigError) as error:
        _experiment(tmp_path, f'name = "rounds"\n{line}\n' + VARIANTS)
    assert str(tmp_path / "exp.toml") in str(error.value) and message in str(error.value)
    assert "\n" not in str(error.value)


def test_a_variants_bad_seeds_and_the_cli_exit_2_with_nothing_tracked(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(ROUNDS.replace('name = "null"\n', 'name = "null"\nseeds = { start = 2 }\n'))
    db = tmp_path / "mlflow.db"
    proc = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "run", str(path), "--tracking-uri", f"sqlite:///{db}"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert f"{path}: variants[2].seeds.max: missing" in proc.stderr
    assert not db.exists()


def test_the_dry_run_prints_the_first_round_and_the_most(tmp_path, capsys):
    from ablate.cli import main

    path = tmp_path / "exp.toml"
    path.write_text(ROUNDS.replace("max = 15 }", "max = 15, max_minutes = 20 }"))
    assert main(["run", str(path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "rounds: 15 of 15 trials" in out  # round 1: 3 variants x 5 seeds, each listed with its key
    assert "round 1 runs 5 seeds per variant" in out and "get 5 more, up to 15 seeds" in out
    assert "at most 3 rounds and 45 evaluation trials; no round that would end after 20 minutes" in out
    assert all(f"-s{seed}-" in out for seed in range(5)) and "-s5-" not in out
    assert not (tmp_path / "mlflow.db").exists()
    # No store: the two figures from a guess per episode of budget, the most held to the rounds' max_minutes.
    first = out.splitlines()[0]
    assert "(15 trials and at most 30 more in later rounds; no earlier run in the store: a guess at" in first, first
    assert re.match(r"time: ~\d+:\d\d, at most ~\d+:\d\d in all: trials ~\d+:\d\d for round 1", first), first
    assert "max_minutes" not in first  # 20 minutes is more than every round takes
    path.write_text(ROUNDS.replace("max = 15 }", "max = 15, max_minutes = 1 }"))  # less: the rounds stop there
    assert main(["run", str(path), "--dry-run", "--no-report"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert re.search(r"at most ~\d:\d\d \(max_minutes = 1: no round starts that would end later\) in all", first)


# --- launches: a fake scheduler, planted results, the report's own sequential rule ----------------------------


def _planted(trial) -> dict:
    """Episodes to solve by variant and seed: ``fast`` far below the others; ``null`` and ``baseline`` from the
    same wide distribution (never separated, never shown equivalent within 10%)."""
    rng = np.random.default_rng([trial.seed, {"baseline": 1, "fast": 2, "null": 3}[trial.variant]])
    episodes = 40.0 + rng.uniform(0, 5) if trial.variant == "fast" else float(rng.uniform(100, 900))
    return {"solved": 1.0, "episodes_to_solve": episodes, "episodes_run": episodes, "auc": 400.0}


at_most: list = []


def _fake_scheduler(monkeypatch, ran, interrupt_at=None):
    """Ray replaced by a loop that finishes every trial with its planted result; ``ran``: each call's trials.
    ``interrupt_at``: the call (0 = the first) that raises Ctrl-C after finishing half its trials."""
    import ablate.launch.scheduler as scheduler

    def run_trials(plan, events, options, run_name, **_):
        trials = [t for p in plan for t in p.members]
        ran.append(trials)
        at_most.append((events.state.round, events.state.at_most_more))  # the progress line's "at most N more"
        for i, trial in enumerate(trials):
            if interrupt_at == len(ran) - 1 and i == len(trials) // 2:
                raise KeyboardInterrupt
            events.started(trial.key)
            events.finished(trial.key, _planted(trial), None, "node-1")

    monkeypatch.setattr(scheduler, "ensure_ray", lambda address: False)
    monkeypatch.setattr(scheduler, "largest_node_cpus", lambda: 2.0)
    monkeypatch.setattr(scheduler, "run_trials", run_trials)


def _run(experiment, tracking_uri, **kwargs):
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan
    from ablate.reporting.rounds import judge_for

    return run_plan(
        LaunchPlan(experiment, tracking_uri=tracking_uri, show_progress=False, judge=judge_for(experiment), **kwargs)
    )


def _seeds(ran) -> dict[str, list[int]]:
    out: dict[str, list[int]] = {}
    for call in ran:
        for t in call:
            out.setdefault(t.variant, []).append(t.seed)
    return {k: sorted(v) for k, v in out.items()}


def test_a_planted_difference_is_decided_early_and_a_null_runs_to_max(tmp_path, tracking_uri, monkeypatch, capsys):
    ran: list = []
    at_most.clear()
    _fake_scheduler(monkeypatch, ran)
    experiment = _experiment(tmp_path)
    outcome = _run(experiment, tracking_uri)
    assert outcome.exit_code == 0
    document = outcome.rounds
    # The most the later rounds may add falls as rounds decide: 30 (3 variants to 15), 15 (round 3 of all three),
    # then none once round 3 (only null and its reference) runs; at the end, nothing may follow.
    assert at_most == [(1, 30), (2, 15), (3, 0)] and outcome.view.state.possible == []
    assert document["variants"]["fast"] == {"seeds": 10, "verdict": "better", "why": "decided at round 2"}
    assert document["variants"]["null"] == {"seeds": 15, "verdict": "undetermined", "why": "reached max"}
    assert document["variants"]["baseline"]["seeds"] == 15 and document["round"] == 3
    assert document["stopped"] == "max"
    # Round 1: every variant's 5 seeds; round 2: all three to 10; round 3: only the open null and its reference.
    assert [sorted({t.variant for t in call}) for call in ran] == [
        ["baseline", "fast", "null"],
        ["baseline", "fast", "null"],
        ["baseline", "null"],
    ]
    assert _seeds(ran) == {"baseline": list(range(15)), "fast": list(range(10)), "null": list(range(15))}
    # Seed k's key is the same whichever round ran it: round 1's keys are expand()'s.
    assert {t.key for t in ran[0]} == {t.key for t in expand(experiment)}
    # The launch records the rounds and lists every trial it ran in grid.json (the report reads both).
    tracker = RunReader(tracking_uri, "rounds")
    launch = tracker.client.search_runs([tracker.experiment_id()], "tags.`ablate.role` = 'launch'")[0]
    grid = json.loads(tracker.load_text(launch.info.run_id, "grid.json"))
    assert len(grid["trials"]) == 40
    assert tracker.load_json(launch.info.run_id, "rounds.json") == document  # as the report reads it
    # Each trial's round is a tag of its run: seeds 10-14 of null ran in round 3.
    trials = tracker.client.search_runs([tracker.experiment_id()], "tags.`ablate.role` = 'trial'", max_results=1000)
    rounds_of = {
        (r.data.tags["ablate.variant"], int(r.data.tags["ablate.seed"])): r.data.tags["ablate.round"] for r in trials
    }
    assert rounds_of[("null", 12)] == "3" and rounds_of[("fast", 7)] == "2" and rounds_of[("baseline", 0)] == "1"
    # ablate status: each variant's seeds, of the most it may get.
    from ablate.cli import main

    assert main(["status", str(experiment.path), "--tracking-uri", tracking_uri]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^  fast\s+10\s+10 of 15$", out, re.M) and re.search(r"^  null\s+15\s+15 of 15$", out, re.M), out
    # A rerun re-judges from the store and runs nothing: every question is answered or at its cap.
    again: list = []
    _fake_scheduler(monkeypatch, again)
    rerun = _run(experiment, tracking_uri)
    assert again == [] and rerun.launch_run_id is None and rerun.rounds["variants"] == document["variants"]


def test_ctrl_c_in_round_2_then_a_rerun_finishes_the_rounds_running_no_trial_twice(tmp_path, tracking_uri, monkeypatch):
    ran: list = []
    _fake_scheduler(monkeypatch, ran, interrupt_at=1)
    experiment = _experiment(tmp_path)
    first = _run(experiment, tracking_uri)
    assert first.interrupted and first.exit_code == 130
    done_before = {t.key for call in ran for t in call} - {t.key for t in ran[1][len(ran[1]) // 2 :]}
    again: list = []
    _fake_scheduler(monkeypatch, again)
    second = _run(experiment, tracking_uri)
    assert second.exit_code == 0
    assert not done_before & {t.key for call in again for t in call}  # no finished trial runs again
    assert second.rounds["variants"]["fast"]["why"] == "decided at round 2"
    assert second.rounds["variants"]["null"]["seeds"] == 15
    finished = [r for r in Tracker(tracking_uri, "rounds").trial_runs() if r.status == "FINISHED"]
    assert len(finished) == len({r.key for r in finished}) == 40


def test_only_runs_its_variants_rounds_and_a_time_budget_stops_them(tmp_path, tracking_uri, monkeypatch):
    from ablate.launch.grid import select

    ran: list = []
    _fake_scheduler(monkeypatch, ran)
    experiment = _experiment(tmp_path)
    only = select(expand(experiment), ["baseline,fast"], None)
    outcome = _run(experiment, tracking_uri, only=only)
    # The comparisons whose both sides have trials are judged: fast against baseline, decided in round 2.
    assert outcome.exit_code == 0 and _seeds(ran) == {"baseline": list(range(10)), "fast": list(range(10))}
    assert outcome.rounds["stopped"] == "decided" and outcome.rounds["variants"]["null"] == {"seeds": 0}

    timed = _experiment(tmp_path, ROUNDS.replace("max = 15 }", "max = 15, max_minutes = 0.0001 }"), "timed.toml")
    timed_ran: list = []
    _fake_scheduler(monkeypatch, timed_ran)
    outcome = _run(timed, fresh_store_uri(tmp_path))
    assert len(timed_ran) == 1 and outcome.rounds["stopped"] == "time budget"
    assert outcome.rounds["variants"]["null"]["why"] == "time budget"


def fresh_store_uri(tmp_path):
    from stores import fresh_store

    return fresh_store(tmp_path / "timed.db")


def test_the_report_section_says_each_variants_seeds_and_why_it_stopped():
    from ablate.reporting.blocks import number_tables
    from ablate.reporting.render import markdown
    from ablate.reporting.rounds import rounds_section

    document = {
        "design": {"start": 5, "step": 5, "max": 15, "max_minutes": None},
        "round": 3,
        "variants": {
            "baseline": {"seeds": 15, "verdict": None},
            "fast": {"seeds": 10, "verdict": "better", "why": "decided at round 2"},
            "null": {"seeds": 15, "verdict": "undetermined", "why": "reached max"},
        },
    }
    text = markdown(number_tables(rounds_section(document)))
    assert "5 per variant first, then 5 more per round" in text and "up to 15" in text and "3 rounds ran" in text
    assert "| fast | 10 | better, decided at round 2 |" in text and "*Table 1. Seeds in rounds*" in text
    assert "| null | 15 | reached the most seeds (max) undecided |" in text
    assert "| baseline | 15 | the reference of the others |" in text
    assert rounds_section(None) == []


def test_train_from_names_a_seed_a_later_round_runs(tmp_path):
    import argparse

    from ablate.train_from import trial_from

    experiment = _experiment(tmp_path)
    args = argparse.Namespace(from_experiment=experiment.path, variant="fast", seed=12, stage=None, preset="default")
    chosen = trial_from(args, {"seed": 12}, ("record_video", "video_max_frames"))
    assert chosen.trial.key in {t.key for t in expand(experiment, every_round=True)} and chosen.trial.seed == 12
    with pytest.raises(ConfigError, match="--seed 15 is not a seed"):
        trial_from(argparse.Namespace(**{**vars(args), "seed": 15}), {"seed": 15}, ())


def test_the_default_cartpole_experiment_adds_seeds_in_growing_rounds_into_the_hundreds(tmp_path):
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "experiments" / "cartpole.toml"
    experiment = load_experiment(path)
    rounds = experiment.rounds
    assert rounds is not None and rounds.start == 10 and rounds.growth == 2  # issue 55: seeds by the hundred
    assert rounds.max >= 300 and len(rounds.looks) <= 8 and rounds.max_minutes is not None  # few looks, a budget
    text = re.sub(r"^seeds = \{.*\}$", "seeds = 10", path.read_text(), flags=re.M)
    fixed = tmp_path / "cartpole.toml"
    fixed.write_text(text)
    assert [t.key for t in expand(load_experiment(fixed))] == [t.key for t in expand(experiment)]


def test_train_from_a_tuned_experiment_reruns_a_later_rounds_seed_at_the_chosen_value(tmp_path, monkeypatch):
    import argparse
    from dataclasses import replace

    from ablate.experiment import load_experiment
    from ablate.launch.grid import trial_key
    from ablate.train_from import trial_from

    path = tmp_path / "tuned.toml"
    path.write_text(
        'name = "tuned"\nseeds = { start = 2, step = 2, max = 6 }\n[base]\nmax_episodes = 40\n'
        '[[variants]]\nname = "a"\n[[variants]]\nname = "b"\nhidden_sizes = [8]\n'
        "[tune]\nlearning_rate = [0.01, 0.1]\nseeds = 1\n"
    )
    monkeypatch.setattr("ablate.train_from.store_choices", lambda *a: ({"b": {"learning_rate": 0.1}}, "a store"))
    args = argparse.Namespace(from_experiment=str(path), variant="b", seed=5, stage=None, preset="default")
    chosen = trial_from(args, {"seed": 5}, ())
    variant = next(v for v in load_experiment(path).variants if v.name == "b")
    expected = replace(variant.config, seed=5, learning_rate=0.1)
    assert (chosen.stage, chosen.trial.seed, chosen.trial.key) == ("eval", 5, trial_key("b", expected))


class _Judgment:
    """A judge's answer, as ``reporting.claims.Round`` gives it: a look made, who needs seeds, who is open."""

    def __init__(self, look, seeds, needs, done=False):
        self.look, self.seeds, self.done, self.needs_seeds, self.verdicts = look, seeds, done, tuple(needs), ()

    @property
    def open(self):
        return self.needs_seeds


def test_the_trials_later_rounds_may_add_are_every_open_variant_to_max_round_by_round(tmp_path):
    from ablate.launch.rounds import Rounds

    experiment = _experiment(tmp_path)  # looks 5, 10, 15; three variants
    answers = []
    rounds = Rounds(experiment, ["baseline", "fast", "null"], lambda samples: answers.pop())
    known = {t.key for t in expand(experiment)}  # round 1's trials: seeds 0-4
    before = rounds.possible({}, known)  # no look yet: every variant may run to max
    assert [sorted({(t.variant, t.seed) for t in r}) for r in before] == [
        [(v, s) for v in ("baseline", "fast", "null") for s in range(5, 10)],
        [(v, s) for v in ("baseline", "fast", "null") for s in range(10, 15)],
    ]
    answers.append(_Judgment(0, 5, ["baseline", "null"]))  # fast decided at the first look; null still open
    finished = {t.key: {"auc": 1.0} for t in expand(experiment)}
    round_2 = rounds.next_round({}, finished)
    assert {t.variant for t in round_2} == {"baseline", "null"} and len(round_2) == 10
    after = rounds.possible({}, known | {t.key for t in round_2})  # round 2 planned: round 3 alone may follow
    assert [sorted({(t.variant, t.seed) for t in r}) for r in after] == [
        [(v, s) for v in ("baseline", "null") for s in range(10, 15)]
    ]
    answers.append(_Judgment(1, 10, [], done=True))
    assert rounds.next_round({}, finished | {t.key: {"auc": 1.0} for t in round_2}) == []
    assert rounds.possible({}, known) == []  # decided: nothing more can come


def test_what_more_seeds_would_cost_is_read_from_this_launchs_rounds():
    import pandas as pd

    from ablate.claims import primary_question
    from ablate.reporting.findings import claim_line
    from ablate.reporting.rounds import seconds_per_trial

    document = {
        "rounds_run": [{"round": 2, "trials": 40, "started_s": 30.0}, {"round": 3, "trials": 80, "started_s": 50.0}],
        "elapsed_s": 90.0,
    }
    assert seconds_per_trial(document) == pytest.approx(60 / 120)  # rounds 2-3: 60 s for 120 trials
    assert seconds_per_trial({"rounds_run": [], "elapsed_s": 5.0}) is None and seconds_per_trial(None) is None
    row = pd.Series(
        {
            "variant": "deep",
            "reference": "baseline",
            "metric": "episodes_to_solve",
            "verdict": "undetermined",
            "change": 12.0,
            "change_low": -8.0,
            "change_high": 30.0,
            "bound": "",
            "variant_value": 600.0,
            "reference_value": 540.0,
            "n_variant": 40,
            "n_reference": 40,
            "level": 0.004,
            "margin": 10.0,
            "seeds_needed": 160.0,
            "seeds_cap": 1000,
            "reason": "neither",
            "seeds_first": 0,
            "censored": 0.05,
        }
    )
    line = claim_line(row, primary_question("episodes_to_solve", 0.1, 1500.0), 0.5)
    assert "about 160 seeds per variant would decide it" in line
    assert "240 more trials: about 2 min on this machine at this launch's pace" in line  # 2 x (160 - 40) x 0.5 s


def test_a_claim_on_two_censored_sides_writes_both_iqms_as_bounds():
    import pandas as pd

    from ablate.claims import primary_question
    from ablate.reporting.findings import claim_line

    row = pd.Series(
        {
            "variant": "mine",
            "reference": "baseline",
            "metric": "episodes_to_solve",
            "verdict": "undetermined",
            "change": -12.0,
            "change_low": -40.0,
            "change_high": 20.0,
            "bound": "censored",
            "variant_value": 760.0,
            "reference_value": 863.0,
            "n_variant": 12,
            "n_reference": 12,
            "level": 0.05,
            "margin": 10.0,
            "seeds_needed": float("nan"),
            "seeds_cap": 1000,
            "reason": "both IQMs count unsolved seeds",
            "seeds_first": 0,
            "censored": 0.4,
        }
    )
    line = claim_line(row, primary_question("episodes_to_solve", 0.1, 1000.0))
    assert "≥ 760 vs ≥ 863" in line, line  # issue 56: the text dropped the bounds Table 1 shows


def test_a_pocock_boundary_lets_doubling_rounds_stop_early_and_is_recorded_for_the_report(tmp_path):
    from ablate.claims import Design
    from ablate.claims.boundaries import nominal_levels

    experiment = _experiment(
        tmp_path,
        'name = "rounds"\nseeds = { start = 10, step = 10, max = 640, growth = 2, spending = "pocock" }\n' + VARIANTS,
    )
    design = Design.of(experiment.rounds)
    assert design.spending == "pocock" and Design.of({"start": 10, "step": 10, "max": 640}).spending == (
        "obrien-fleming"
    )
    pocock = nominal_levels(design.fractions, 0.05 / 9, "pocock")
    fleming = nominal_levels(design.fractions, 0.05 / 9, "obrien-fleming")
    assert pocock[0] > 1e-4 and fleming[2] < 1e-10  # 10 seeds of 640 can decide under Pocock's, 40 not under OBF's
    with pytest.raises(ConfigError, match="spending = 'even' is invalid"):
        _experiment(tmp_path, 'name = "rounds"\nseeds = { start = 5, max = 10, spending = "even" }\n' + VARIANTS)


@pytest.mark.parametrize("judged_at, runs", [(25.0, True), (40.0, False)])
def test_a_round_that_would_end_after_the_time_budget_at_the_last_rounds_pace_does_not_start(tmp_path, judged_at, runs):
    from ablate.launch.rounds import TIME_BUDGET, Rounds

    experiment = _experiment(tmp_path, ROUNDS.replace("max = 15 }", "max = 15, max_minutes = 1 }"))
    now = [10.0]
    answers = [_Judgment(1, 10, ["baseline", "null"]), _Judgment(0, 5, ["baseline", "null"])]
    rounds = Rounds(experiment, ["baseline", "fast", "null"], lambda samples: answers.pop(), 0.0, lambda: now[0])
    finished = {t.key: {"auc": 1.0} for t in expand(experiment)}
    round_2 = rounds.next_round({}, finished)  # no pace yet: 10 s into a 60 s budget, it runs
    assert len(round_2) == 10
    now[0] = judged_at  # round 2's 10 trials took 15 s (1.5 s each) or 30 s (3 s each)
    round_3 = rounds.next_round({}, finished | {t.key: {"auc": 1.0} for t in round_2})
    # round 3's 10 trials at that pace: ending at 40 s (within the 60) or at 70 s (after it)
    assert (len(round_3) == 10) is runs and rounds.projected_s == (40.0 if runs else 70.0)
    assert rounds.stopped == ("" if runs else TIME_BUDGET)
    assert rounds.document()["projected_s"] == rounds.projected_s
