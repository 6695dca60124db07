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
    from ablate.launch.runner import run_experiment
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
                outcome = run_experiment(
                    load_experiment(folder / f"{kind}.toml"),
                    tracking_uri=uri,
                    storage_path=str(folder / "ray"),
                    show_progress=False,
                    started_at=started,
                    log_estimates=True,
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
    remained until the last of them ended (a phase: the trials the view knew of together, ``view.phases``: a
    launch's stages, then each round of seeds, which no estimate before it can know of); the bound is the
    issue's: +-30% or +-20 s, whichever is larger."""
    points, phases, quarter_at = [], [], None
    firsts = [first for first, _ in view.phases[1:]] + [len(view.estimates)]
    for (first, keys), last in zip(view.phases, firsts, strict=True):
        ended_at = [view.trials[k].ended_at for k in keys if view.trials[k].ended_at is not None]
        if not ended_at or first >= len(view.estimates):
            continue
        end, before = max(ended_at) - view.start, view.estimates[first][1]
        mine = [
            (t, est, end - t)
            for t, ended, est in view.estimates[first:last]
            if est is not None and t < end and ended - before >= len(keys) / 4
        ]
        quarter_at = (
            quarter_at
            if quarter_at is not None
            else next((t for t, ended, _ in view.estimates[first:last] if ended - before >= len(keys) / 4), None)
        )
        within = sum(abs(est - truth) <= max(0.3 * truth, 20.0) for _, est, truth in mine)
        phases.append({"trials": len(keys), "points": len(mine), "within_bound": within})
        points += mine
    if not points:
        return {"points": 0, "phases": phases}
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
        "trials_end_s": view.trials_end - view.start,
        "phases": phases,
    }


def _eta_figure(label: str, view) -> dict:
    """The time-left estimates of one launch against the truth: its trace and its errors, printed."""
    errors = _eta_errors(view)
    trace = [(round(t, 2), ended, None if est is None else round(est, 2)) for t, ended, est in view.estimates]
    print(f"  trace (s since start, trials ended, estimate s): {json.dumps(trace)}", flush=True)
    if not errors["points"]:
        print(f"  {label}: no estimate after a quarter of the trials", flush=True)
        return {**errors, "trace": trace}
    e = errors
    print(
        f"  {label}: {len(view.trials)} trials ended at {e['trials_end_s']:.0f} s (a quarter "
        f"at {e['quarter_at_s']:.0f} s); {e['within_bound']}/{e['points']} estimates after a quarter "
        f"within +-30% or +-20 s; worst {e['worst_over_bound']:.2f} of the bound (said "
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
    from ablate.launch.runner import run_experiment

    folder = Path(tempfile.mkdtemp(prefix="ablate-bench-eta-"))
    figures = {}
    try:
        for path in experiments:
            experiment = load_experiment(path)
            store = folder / experiment.name
            store.mkdir()
            for launch in launches:
                started = time.monotonic()
                outcome = run_experiment(
                    experiment,
                    tracking_uri=f"sqlite:///{store / 'mlflow.db'}",
                    storage_path=str(store / "ray"),
                    show_progress=False,
                    fresh=launch == "warm",
                    started_at=started,
                    log_estimates=True,
                )
                assert outcome.exit_code == 0 and outcome.view is not None, outcome.failed
                figures[f"{experiment.name}/{launch}"] = _eta_figure(f"{path} {launch}", outcome.view)
        worst = max(f.get("worst_over_bound", 0.0) for f in figures.values())
        print(f"eta: worst error after 25% of the trials: {worst:.2f} of the bound (+-30% or +-20 s; <= 1.00 keeps it)")
        RESULTS["eta"] = figures
    finally:
        shutil.rmtree(folder, ignore_errors=True)
