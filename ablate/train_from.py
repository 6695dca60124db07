"""``ablate train --from EXPERIMENT --variant V --seed S``: the trial of an experiment that its report shows, to
rerun in this process. By default the evaluation trial, at the values tuning chose (read from the store); a
tuning trial with ``--stage tune``; the untuned trial at the base values with ``--stage base``."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

from ablate.config import ConfigError, TrialConfig, apply_knobs
from ablate.experiment import Experiment, load_experiment
from ablate.launch.grid import GridTrial, chosen_trials, expand, tuning_trials

STAGES = ("eval", "tune", "base")
"""``eval``: the trial the report's claims use (at the chosen values when tuned); ``tune``: a stage-1 trial;
``base``: the evaluation seed at the shared base values (the report's "does it depend on the learning rate")."""


@dataclass(frozen=True)
class Chosen:
    config: TrialConfig
    trial: GridTrial
    stage: str
    values: dict[str, Any]
    """The tuned knobs' values this trial runs at (empty for an untuned experiment)."""
    words: str
    """Which trial it is, for the line printed before it runs."""


def _value(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _values(values: dict[str, Any]) -> str:
    return ", ".join(f"{k.replace('_', ' ')} {_value(v)}" for k, v in values.items())


def store_choices(experiment: Experiment, tracking_uri: str | None) -> tuple[dict[str, dict[str, Any]], str]:
    """Each variant's chosen values as the newest launch of ``experiment`` recorded them (``tuning.json``), and the
    store as shown; ``{}`` where no launch finished tuning. A missing store is a ``ConfigError``."""
    from ablate.reporting.reader import RunReader
    from ablate.reporting.results import _tuning_document, check_store

    uri = check_store(tracking_uri)
    tracker = RunReader(uri, experiment.name)
    if tracker.experiment_id(create=False) is None:
        return {}, tracker.shown_uri
    for launch in tracker.launches():  # newest first
        document = _tuning_document(tracker, launch.info.run_id)
        if document and document.get("choices"):
            return {name: dict(c.get("values", {})) for name, c in document["choices"].items()}, tracker.shown_uri
    return {}, tracker.shown_uri


def trial_from(args: argparse.Namespace, knobs: dict[str, Any], not_in_key: tuple[str, ...]) -> Chosen:
    """The trial ``--from EXPERIMENT --variant V --seed S [--stage S]`` names, with only the knobs that leave its
    key alone (``not_in_key``), and with ``--stage tune`` the tuned knobs that pick one candidate."""
    experiment = load_experiment(args.from_experiment)
    stage = getattr(args, "stage", None) or "eval"
    spec = experiment.tune
    evaluation = expand(experiment, every_round=True)  # a seed a later round ran is the report's too
    variants = ", ".join(dict.fromkeys(t.variant for t in evaluation))
    tuned_names = spec.knob_names if spec is not None else ()
    if args.variant is None or args.seed is None:
        seeds = ", ".join(map(str, (spec.seeds if spec is not None and stage == "tune" else experiment.seeds)))
        raise ConfigError(
            f"--from {args.from_experiment} needs --variant (one of {variants}) and --seed (one of {seeds})"
        )
    if args.variant not in variants.split(", "):
        raise ConfigError(f"--variant {args.variant!r} is not a variant of {args.from_experiment}; valid: {variants}")
    picking = tuned_names if stage == "tune" else ()
    changed = sorted(k for k in knobs if k not in (*not_in_key, "seed", *picking))
    if changed or args.preset != "default":
        flags = ", ".join(f"--{k.replace('_', '-')}" for k in changed) or "--preset"
        also = f", {', '.join('--' + k.replace('_', '-') for k in tuned_names)} with --stage tune" if spec else ""
        raise ConfigError(
            f"{flags}: not with --from, which trains the experiment's trial as it is (its key names its config); "
            f"valid with --from: --no-video, --video-max-frames, --out, --stage{also}"
        )
    extra = {k: v for k, v in knobs.items() if k in not_in_key}
    if spec is None:
        if stage == "tune":
            raise ConfigError(f"--stage tune: {args.from_experiment} has no [tune] table, so no tuning trials")
        trial = _one(evaluation, args, experiment)
        return Chosen(apply_knobs(trial.config, extra), trial, "eval", {}, "the evaluation trial (no [tune])")
    variant = next(v for v in experiment.variants if v.name == args.variant)
    own = not spec.tuned_knobs(variant)  # it sets every tuned knob itself: one trial per seed, never tuned
    if stage == "tune":
        if own:
            raise ConfigError(f"--stage tune: {args.variant} sets {', '.join(tuned_names)} itself and is not tuned")
        mine = [t for t in tuning_trials(experiment) if t.variant == args.variant]
        if args.seed not in spec.seeds:
            raise ConfigError(
                f"--seed {args.seed} is not a tuning seed of {args.from_experiment}; valid: "
                + ", ".join(map(str, spec.seeds))
            )
        wanted = {k: knobs[k] for k in picking if k in knobs}
        found = [t for t in mine if t.seed == args.seed and all(getattr(t.config, k) == v for k, v in wanted.items())]
        if len(found) != 1:
            candidates = "; ".join(
                _values({k: getattr(t.config, k) for k in spec.tuned_knobs(variant)})
                for t in mine
                if t.seed == args.seed
            )
            raise ConfigError(
                f"--stage tune: pass the candidate with {' and '.join('--' + k.replace('_', '-') for k in picking)}"
                f"; {args.variant}'s candidates: {candidates}"
            )
        trial = found[0]
        values = {k: getattr(trial.config, k) for k in spec.tuned_knobs(variant)}
        words = f"stage 1 (tuning) at {_values(values)}, budget {trial.config.max_episodes:,} episodes"
        return Chosen(apply_knobs(trial.config, extra), trial, "tune", values, words)
    base_trial = _one(evaluation, args, experiment)
    if stage == "base" or own:
        values = {k: getattr(base_trial.config, k) for k in tuned_names}
        why = "its own value: the variant sets it, tuning never did" if own else "the shared base value, untuned"
        words = f"the evaluation trial at {_values(values)} ({why})"
        return Chosen(apply_knobs(base_trial.config, extra), base_trial, "eval" if own else "base", values, words)
    choices, shown = store_choices(experiment, getattr(args, "tracking_uri", None))
    if args.variant not in choices:
        raise ConfigError(
            f"no tuning choice for {args.variant} in the MLflow store {shown}: the evaluation trial's "
            f"{', '.join(k.replace('_', ' ') for k in tuned_names)} is chosen by `ablate run {args.from_experiment}` "
            "(stage 1); pass --tracking-uri the store it wrote, or --stage base (the base value) or --stage tune"
        )
    values = {k: choices[args.variant].get(k, getattr(base_trial.config, k)) for k in tuned_names}
    trial = _one(chosen_trials(experiment, {args.variant: values}, every_round=True), args, experiment)
    words = f"stage 2 (evaluation) at {_values(values)}, the value tuning chose (recorded in {shown})"
    return Chosen(apply_knobs(trial.config, extra), trial, "eval", values, words)


def _one(trials: list[GridTrial], args: argparse.Namespace, experiment: Experiment) -> GridTrial:
    trial = next((t for t in trials if t.variant == args.variant and t.seed == args.seed), None)
    if trial is None:
        seeds = sorted({s for v in experiment.variants for s in experiment.max_seeds_of(v)})  # its rounds' too
        raise ConfigError(
            f"--seed {args.seed} is not a seed of {args.from_experiment}; valid: {', '.join(map(str, seeds))}"
        )
    return trial
