"""`make bench` sections on tuning and the time-left estimate: `tuning` (tuned vs untuned default ablation;
each launch's estimate scored), `eta` (the estimate against the time that actually remained)."""

from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

from bench_results import RESULTS


def without_tune(text: str) -> str:
    """An experiment file's text without its ``[tune]`` table (its header up to the next table header): the
    same ablation, untuned."""
    kept, inside = [], False
    for line in text.splitlines(keepends=True):
        if line.startswith("["):
            inside = line.strip() == "[tune]"
        if not inside:
            kept.append(line)
    return "".join(kept)


def bench_tuning(repeats: int = 3, path: str = "experiments/cartpole.toml") -> None:
    """The tuned default ablation end to end (both stages, base-value trials included) against the same file
    without ``[tune]``, each into a fresh store on one running Ray, alternating, medians of ``repeats``;
    the ratio's target is at most 3x (issue 19). Each launch's time-left estimates are logged and scored as
    in ``eta``: every launch here is cold (a fresh store, no earlier costs), the estimate's hardest case."""
    import shutil
    import tempfile

    from ablate.experiment import load_experiment
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan
    from ablate.launch.scheduler import ensure_ray
    from ablate.launch.tracking import Tracker

    ensure_ray(None)
    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-"))
    text = Path(path).read_text()
    (folder / "tuned.toml").write_text(text)
    (folder / "untuned.toml").write_text(without_tune(text))
    tuned_experiment = load_experiment(folder / "tuned.toml")
    assert tuned_experiment.tune is not None, f"{path} has no [tune] table"
    walls: dict[str, list[float]] = {"untuned": [], "tuned": []}
    counts: dict[str, int] = {}
    etas: dict[str, dict] = {}
    try:
        for i in range(repeats):
            for kind in ("untuned", "tuned"):
                store = folder / f"{kind}-{i}"
                store.mkdir()
                uri = f"sqlite:///{store / 'mlflow.db'}"
                Tracker(uri, "warm").experiment_id()  # the store's tables exist, as in a user's store
                started = time.monotonic()
                outcome = run_plan(
                    LaunchPlan(
                        load_experiment(folder / f"{kind}.toml"),
                        tracking_uri=uri,
                        storage_path=str(folder / "ray"),
                        show_progress=False,
                        started_at=started,
                        log_estimates=True,
                    )
                )
                walls[kind].append(time.monotonic() - started)
                assert outcome.exit_code == 0 and outcome.view is not None, outcome.failed
                counts[kind] = len(outcome.finished)
                # Each launch is a cold one (a fresh store, no earlier costs): the time-left estimate's hardest case.
                etas[f"{kind}-{i}"] = _eta_figure(f"{kind} launch {i}", outcome.view)
            print(
                f"  {counts['untuned']} untuned trials {walls['untuned'][-1]:.0f} s; tuned launch {counts['tuned']} "
                f"trials {walls['tuned'][-1]:.0f} s (ratio {walls['tuned'][-1] / walls['untuned'][-1]:.2f}x)",
                flush=True,
            )
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    untuned, tuned = statistics.median(walls["untuned"]), statistics.median(walls["tuned"])
    print(
        f"tuning: {path} end to end, median of {repeats}: untuned {untuned:.0f} s, tuned {tuned:.0f} s "
        f"(both stages, base-value trials included): {tuned / untuned:.2f}x (target <= 3x)"
    )
    worst = max(f.get("worst_over_bound", 0.0) for f in etas.values())
    print(
        f"tuning/eta: the time-left estimate's worst error after 25% of the trials over these {len(etas)} cold "
        f"launches: {worst:.2f} of the bound (+-30% or +-20 s; <= 1.00 keeps it)"
    )
    RESULTS["tuning"] = {"untuned_s": walls["untuned"], "tuned_s": walls["tuned"], "ratio": tuned / untuned}
    RESULTS["tuning"]["eta"] = etas


def _eta_errors(view) -> dict:
    """Each estimate logged once a quarter of its phase's trials had ended, against the time that actually
    remained until the last of them ended (a phase: the trials the view knew of together, ``state.phases``: a
    launch's stages, then each round of seeds, which no estimate before it can know of); the bound is the
    issue's: +-30% or +-20 s, whichever is larger. Then the launch's bound (``bound``)."""
    state = view.state
    points, phases, quarter_at = [], [], None
    for number, keys in enumerate(state.phases):
        ended_at = [state.trials[k].ended_at for k in keys if state.trials[k].ended_at is not None]
        logged = [e for e in view.estimates if e[4] == number]
        if not ended_at or not logged:
            continue
        end, before = max(ended_at) - state.start, logged[0][1]
        mine = [
            (t, est, end - t)
            for t, ended, est, _, _ in logged
            if est is not None and t < end and ended - before >= len(keys) / 4
        ]
        if quarter_at is None:
            quarter_at = next((t for t, ended, *_ in logged if ended - before >= len(keys) / 4), None)
        within = sum(abs(est - truth) <= max(0.3 * truth, 20.0) for _, est, truth in mine)
        phases.append({"trials": len(keys), "points": len(mine), "within_bound": within})
        points += mine
    if not points:
        return {"points": 0, "phases": phases, **bound(view)}
    over = [(abs(est - truth) / max(0.3 * truth, 20.0), t, est, truth) for t, est, truth in points]
    worst = max(over)
    relative = max(points, key=lambda p: abs(p[1] - p[2]) / p[2] if p[2] > 0 else 0)
    return {
        "points": len(points),
        "within_bound": sum(o <= 1 for o, *_ in over),
        "worst_over_bound": worst[0],
        "worst_at_s": worst[1],
        "worst_estimate_s": worst[2],
        "worst_truth_s": worst[3],
        "worst_relative_error": (relative[1] - relative[2]) / relative[2] if relative[2] > 0 else 0.0,
        "quarter_at_s": quarter_at,
        "trials_end_s": state.trials_end - state.start,
        "phases": phases,
        **bound(view),
    }


def bound(view) -> dict:
    """The launch's promise (issue 37): from a quarter of its first trials on, the true end lies between the
    current round's estimate (-30%) and the most the launch can still take (+30%), or within 20 s of them."""
    state = view.state
    first = len(state.phases[0])
    end = state.trials_end - state.start
    scored = [
        (t, left, most, end - t)
        for t, ended, left, most, _ in view.estimates
        if left is not None and most is not None and ended >= first / 4 and t < end
    ]
    inside = [min(0.7 * left, left - 20.0) <= truth <= max(1.3 * most, most + 20.0) for _, left, most, truth in scored]
    out = [s for s, ok in zip(scored, inside, strict=True) if not ok]
    return {
        "bound_points": len(scored),
        "bound_within": sum(inside),
        "bound_worst": [round(x, 1) for x in out[0]] if out else None,
    }


def _eta_figure(label: str, view) -> dict:
    """The time-left estimates of one launch against the truth: its trace and its errors, printed."""
    errors = _eta_errors(view)
    trace = [
        (round(t, 2), ended, None if est is None else round(est, 2), None if most is None else round(most, 2))
        for t, ended, est, most, _ in view.estimates
    ]
    print(f"  trace (s since start, trials ended, round estimate s, at most s): {json.dumps(trace)}", flush=True)
    if errors["bound_points"]:
        print(
            f"  {label}: the true end between the round's estimate (-30%) and the upper figure (+30%), or within "
            f"20 s: {errors['bound_within']}/{errors['bound_points']} estimates after a quarter"
            + (
                f"; first outside (s, said, at most, remained): {errors['bound_worst']}"
                if errors["bound_worst"]
                else ""
            ),
            flush=True,
        )
    if not errors["points"]:
        print(f"  {label}: no estimate after a quarter of the trials", flush=True)
        return {**errors, "trace": trace}
    e = errors
    print(
        f"  {label}: {len(view.state.trials)} trials ended at {e['trials_end_s']:.0f} s (a quarter "
        f"at {e['quarter_at_s']:.0f} s); {e['within_bound']}/{e['points']} estimates after a quarter "
        f"within +-30% or +-20 s of their round's end; worst {e['worst_over_bound']:.2f} of the bound (said "
        f"{e['worst_estimate_s']:.0f} s at {e['worst_at_s']:.0f} s, {e['worst_truth_s']:.0f} s remained); "
        f"worst relative error {100 * e['worst_relative_error']:+.0f}%",
        flush=True,
    )
    if len(e["phases"]) > 1:  # a launch in rounds of seeds: each held to its own end
        for number, phase in enumerate(e["phases"], 1):
            name = "stages 1 and 2" if number == 1 else f"round {number}"
            print(f"    {name}: {phase['trials']} trials, {phase['within_bound']}/{phase['points']} within", flush=True)
    return {**errors, "trace": trace}


def bench_eta(
    experiments: tuple[str, ...] = ("experiments/cartpole.toml", "experiments/pong-smoke.toml"),
    launches: tuple[str, ...] = ("cold", "warm"),
) -> None:
    """The time-left estimate against the truth: each experiment run twice into a fresh store, cold (no
    earlier launch to learn costs from) then warm (``--fresh`` on the same store: the first launch's costs
    are the prior), every estimate logged. Printed: the worst error after a quarter of the trials ended, as a
    fraction of the bound (<= 1.00 keeps the promise) and as a relative error."""
    import shutil
    import tempfile

    from ablate.experiment import load_experiment
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import run_plan

    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-eta-"))
    figures = {}
    try:
        for path in experiments:
            experiment = load_experiment(path)
            store = folder / experiment.name
            store.mkdir()
            for launch in launches:
                started = time.monotonic()
                outcome = run_plan(
                    LaunchPlan(
                        experiment,
                        tracking_uri=f"sqlite:///{store / 'mlflow.db'}",
                        storage_path=str(store / "ray"),
                        show_progress=False,
                        fresh=launch == "warm",
                        started_at=started,
                        log_estimates=True,
                    )
                )
                assert outcome.exit_code == 0 and outcome.view is not None, outcome.failed
                figures[f"{experiment.name}/{launch}"] = _eta_figure(f"{path} {launch}", outcome.view)
        worst = max(f.get("worst_over_bound", 0.0) for f in figures.values())
        print(f"eta: worst error after 25% of the trials: {worst:.2f} of the bound (+-30% or +-20 s; <= 1.00 keeps it)")
        RESULTS["eta"] = figures
    finally:
        shutil.rmtree(folder, ignore_errors=True)
