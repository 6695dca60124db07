"""Replay a finished launch from its MLflow store through the time-left estimate, offline, in a second.

Each trial run's start, its logged curve points (their timestamps) and its end become the live view's events
at the times they happened, planned into populations as the runner planned them, and its rounds of seeds added
as the runner added them, so the estimate is scored exactly as ``bench.py eta`` scores a live launch: every
estimate once a quarter of its phase's trials had ended (the launch's stages, then each round), against the
time that actually remained until they ended (bound: +-30% or +-20 s, whichever is larger). A launch measured
once can then be replayed against any change to the estimate.

    python benchmarks/replay_eta.py EXPERIMENT_FILE --tracking-uri sqlite:///path/mlflow.db
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from unittest import mock

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_estimate import _eta_figure  # noqa: E402

from ablate.experiment import load_experiment  # noqa: E402
from ablate.launch import progress  # noqa: E402
from ablate.launch.grid import GridTrial, expand, schedule_order, trial_key, tuning_trials  # noqa: E402
from ablate.launch.mlflow_store import population_sizes  # noqa: E402
from ablate.launch.plan import plan_populations  # noqa: E402
from ablate.launch.tuning import StagePlan, unique  # noqa: E402


def _events(
    db: Path, experiment: str
) -> tuple[float, list[tuple], dict[str, dict], dict[str, tuple[float, int]], dict[str, dict[str, str]]]:
    """The newest launch's start (s), its trials' events ``(t, kind, key, payload)`` by time, each trial's
    summary metrics, the seconds and episodes each trial key took in a run finished before that launch
    (what the runner gives the estimate of earlier launches), and each of its trials' tags, read
    straight from an SQLite store (read-only)."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    (exp_id,) = con.execute("select experiment_id from experiments where name = ?", (experiment,)).fetchone()
    tags = {}
    for run, key, value in con.execute(
        "select t.run_uuid, t.key, t.value from tags t join runs r on r.run_uuid = t.run_uuid "
        "where r.experiment_id = ?",
        (exp_id,),
    ):
        tags.setdefault(run, {})[key] = value
    runs = con.execute(
        "select run_uuid, start_time, end_time, status from runs where experiment_id = ?", (exp_id,)
    ).fetchall()
    launch = max((r for r in runs if tags.get(r[0], {}).get("ablate.role") == "launch"), key=lambda r: r[1])
    generation = tags[launch[0]].get("ablate.generation")
    events, summaries, earlier, trial_tags = [], {}, {}, {}
    for run, start, end, status in sorted(runs, key=lambda r: r[1]):
        t = tags.get(run, {})
        if t.get("ablate.role") == "trial" and status == "FINISHED" and end and start < launch[1]:
            ran = con.execute("select value from latest_metrics where run_uuid = ? and key = 'episodes_run'", (run,))
            # The newest earlier run counts, as the runner's: (seconds, episodes run).
            earlier[t["ablate.trial_key"]] = ((end - start) / 1000, int(next(iter(ran.fetchone() or []), 0)))
        if t.get("ablate.role") == "launch" or t.get("ablate.generation") != generation or status != "FINISHED":
            continue
        key = t["ablate.trial_key"]
        metrics = dict(
            con.execute("select key, value from latest_metrics where run_uuid = ? and key not like 'episode/%'", (run,))
        )
        summaries[key] = metrics
        trial_tags[key] = t
        events.append((start / 1000, "started", key, None))
        points: dict[int, dict] = {}
        for name, step, stamp, value in con.execute(
            "select key, step, timestamp, value from metrics where run_uuid = ? and key in "
            "('episode/rolling_mean', 'episode/wall_s', 'episode/env_steps')",
            (run,),
        ):
            point = points.setdefault(step, {"episode": step, "stamp": stamp / 1000})
            point[name.removeprefix("episode/")] = value
        by_stamp: dict[float, list] = {}
        for point in sorted(points.values(), key=lambda p: p["episode"]):
            by_stamp.setdefault(point["stamp"], []).append(SimpleNamespace(**point))
        events += [(stamp, "episodes", key, rows) for stamp, rows in by_stamp.items()]
        events.append((end / 1000, "finished", key, metrics))
    order = {"started": 0, "episodes": 1, "finished": 2}
    events.sort(key=lambda e: (e[0], order[e[1]]))
    return launch[1] / 1000, events, summaries, earlier, trial_tags


def _rounds(events: list[tuple], before: set[str], pool: dict) -> list[list[str]]:
    """The keys of the trials that started after ``before``'s (stages 1 and 2), as rounds of seeds (by the
    experiment's ``seeds = { start, step, max }``: round 2 runs seeds start .. start + step - 1), each in the
    order its trials started. ``pool``: every trial the rounds may add, by key (``_every_seed``)."""
    starts = {e[2]: e[0] for e in events if e[1] == "started" and e[2] not in before}
    rounds: dict[int, list[str]] = {}
    for key in sorted(starts, key=starts.get):
        trial = pool[key]
        seeds = trial.rounds
        rounds.setdefault((trial.seed - seeds.start) // seeds.step, []).append(key)
    return [rounds[r] for r in sorted(rounds)]


def _every_seed(experiment, choices) -> dict:
    """Every trial the rounds may add, by key: each variant on every seed it may run, at its chosen values."""
    trials = {}
    for variant in experiment.variants:
        for seed in experiment.max_seeds_of(variant):
            choice = choices.get(variant.name)
            config = replace(variant.config, seed=seed, **(choice.values if choice and choice.tuned else {}))
            trial = GridTrial(trial_key(variant.name, config), variant.name, seed, config)
            trials[trial.key] = SimpleNamespace(trial=trial, seed=seed, rounds=experiment.rounds_of(variant))
    return trials


def _population_cap(tags: dict[str, dict[str, str]]) -> int:
    """The most members a population of the launch's trials had (their runs' tags, by key: ``population_sizes``)."""
    return max(population_sizes(tags).values(), default=1)


def replay(path: str, tracking_uri: str, slots: int = 2, population: int | None = None) -> dict:
    """The scored estimates of the newest launch of ``path``'s experiment in the store at ``tracking_uri``, its
    trials planned as the runner planned them: populations of at most ``population`` (``None``: the largest the
    store's tags show) on ``slots`` population slots."""
    experiment = load_experiment(path)
    db = Path(tracking_uri.removeprefix("sqlite:///"))
    start, events, summaries, earlier, trial_tags = _events(db, experiment.name)
    cap = _population_cap(trial_tags) if population is None else population

    def populations(trials):  # the runner's plan
        return [p.keys for p in plan_populations(trials, cap=cap, slots=slots)]

    evaluation = expand(experiment)
    plan = StagePlan(experiment, evaluation, tuning_trials(experiment))
    todo = unique([*plan.tuning, *evaluation], set())
    prior = {t.key: earlier[t.key][0] for t in todo if t.key in earlier}  # the runner's: stage 1's keys
    todo = schedule_order(todo, prior)
    stage1 = {t.key for t in todo}

    def provisional(summaries):  # as the runner asks it
        return plan.provisional(summaries, stage1)

    clock = SimpleNamespace(now=start)
    with mock.patch.object(progress.time, "monotonic", lambda: clock.now):
        view = progress.ProgressView(
            experiment.name,
            todo,
            0,
            enabled=False,
            slots=slots,
            start=start,
            prior_costs=prior,
            prior_episodes={key: earlier[key][1] for key in prior if earlier[key][1]},
            log_estimates=True,
            later=provisional({}),
            provisional=provisional if plan.tuning else None,
            populations=populations if cap > 1 else None,
        )
        left, stage_two_known = set(stage1), not plan.tuning
        pool = _every_seed(experiment, {})
        rounds = [] if plan.tuning else _rounds(events, stage1, pool)  # with tuning: once stage 2 is known
        for t, kind, key, payload in events:
            clock.now = t
            if key not in view.trials and kind == "started" and stage_two_known:  # a round of seeds begins
                keys = [k for k in rounds if key in k][0]
                costs = {k: earlier[k][0] for k in keys if k in earlier}  # as the runner gives them
                episodes = {k: earlier[k][1] for k in costs if earlier[k][1]}
                view.add_trials([pool[k].trial for k in keys], costs, episodes)  # its own phase (``view.phases``)
            if key not in view.trials:
                continue
            if kind == "started":
                view.started(key)
            elif kind == "episodes":
                view.episodes(key, payload)
            else:
                view.finished(key, bool(payload.get("solved")), payload.get("wall_s"), payload)
                left.discard(key)
                if not left and not stage_two_known:  # stage 1 over: stage 2 is known
                    choices = plan.choices({k: summaries[k] for k in stage1 if k in summaries})
                    chosen = unique(plan.chosen(choices), stage1)
                    costs = {t.key: earlier[t.key][0] for t in chosen if t.key in earlier}
                    episodes = {key: earlier[key][1] for key in costs if earlier[key][1]}
                    view.add_trials(schedule_order(chosen, costs), costs, episodes)
                    stage_two_known = True
                    pool = _every_seed(experiment, choices)
                    rounds = _rounds(events, set(view.trials), pool)
        view.trials_end = max(e[0] for e in events if e[1] == "finished")
    return _eta_figure(f"{path} (replayed from {db})", view)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("experiment")
    parser.add_argument("--tracking-uri", required=True)
    parser.add_argument(
        "--slots", type=int, default=2, help="trials (populations) that ran at once (default 2: a 2-core machine)"
    )
    parser.add_argument(
        "--population", type=int, help="the launch's --population (default: the largest population its tags show)"
    )
    args = parser.parse_args()
    replay(args.experiment, args.tracking_uri, args.slots, args.population)
    return 0


if __name__ == "__main__":
    sys.exit(main())
