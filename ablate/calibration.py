"""``ablate calibrate EXPERIMENT``: an A/A test of the report's claims rule. Runs (or reuses from the store) many
seeds of the experiment's reference variant, deals them into reports of the experiment's own design in which
every "variant" is that same configuration, and prints the share of those reports that claim any difference,
under the primary-claims rule (ablate/claims/) and under the rule the findings used before it.

The seeds are a derived experiment, ``<name>-calibrate`` (built in memory from the experiment), run through
``ablate.run``: the baseline at the value tuning chose where the experiment tunes, seeds from 20,000 up.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from typing import Any

from ablate.config import ConfigError, apply_knobs
from ablate.design import ALPHA, CONFIDENCE, percent
from ablate.experiment import Experiment, load_experiment
from ablate.launch.store import resolve_uri
from ablate.measures import FINAL_RETURN, measure, return_at
from ablate.seeds import SeedRounds

SEED_START = 20_000
"""The calibration's seeds start here: above the evaluation seeds and the tuning seeds (10,000 up)."""
MIN_SEEDS, MIN_REPORTS = 60, 200
DEAL_SEED = 2025


def add_parser(commands: Any) -> argparse.ArgumentParser:
    """``ablate calibrate``'s own arguments (``ablate.cli.build_parser`` adds the launch flags it shares with run)."""
    calibrate = commands.add_parser(
        "calibrate",
        help="A/A test: how often a report of identical variants claims a difference, new rule and old",
        description="Run (or reuse from the store) at least 60 seeds of the experiment's reference variant, at its "
        "tuned value where the experiment tunes, deal them into A/A reports of the experiment's own design (its "
        "variants and seeds, every one the same configuration), and print the share of reports claiming any "
        "difference under the primary-claims rule and under the old per-comparison bootstrap rule, with "
        f"{percent(CONFIDENCE)} intervals. Its seeds are the experiment <name>-calibrate, seeds 20000 up.",
    )
    calibrate.add_argument("experiment", help="experiment file, e.g. experiments/cartpole.toml")
    calibrate.add_argument("--pool", type=int, default=MIN_SEEDS, help="seeds of the reference to run (>= 60)")
    calibrate.add_argument("--reports", type=int, default=MIN_REPORTS, help="A/A reports to deal (>= 200)")
    calibrate.add_argument(
        "--seeds", dest="design_seeds", type=int, help="seeds per variant in each report (default: the experiment's)"
    )
    return calibrate


# --- the derived experiment ---------------------------------------------------------------------------------


def derived_experiment(experiment: Experiment, tuned: dict[str, Any], pool: int) -> Experiment:
    """The calibration's experiment, built in memory: the reference variant alone at the ``tuned`` values, on
    ``pool`` seeds that collide with none of the experiment's own (evaluation or tuning). Its path stays the
    experiment's file, which the launch records beside it."""
    own = [*experiment.seeds, *(experiment.tune.seeds if experiment.tune else ())]
    own += [s for v in experiment.variants for s in experiment.max_seeds_of(v)]  # every seed rounds may add
    start = max(SEED_START, max(own) + 1)
    variant = next(v for v in experiment.variants if v.name == experiment.baseline)
    config = apply_knobs(variant.config, tuned, f"{experiment.path}: tuned ")
    return replace(
        experiment,
        name=experiment.name + "-calibrate",
        description=f"A/A calibration: {experiment.baseline} of {experiment.name}",
        variants=(
            replace(variant, overrides=(*variant.overrides, *tuned.items()), config=config, seeds=None, rounds=None),
        ),
        seeds=tuple(range(start, start + pool)),
        tune=None,
        rounds=None,
    )


def tuned_values(experiment: Experiment, tracking_uri: str, run_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The values the reference is evaluated at: tuning's choice for it, read from the store; where the store
    has none, the experiment's tuning stage is run for the reference alone first (``ablate.run --only``)."""
    if experiment.tune is None:
        return {}
    variant = next(v for v in experiment.variants if v.name == experiment.baseline)
    if not experiment.tune.tuned_knobs(variant):
        return {}

    import ablate.api as api

    def read() -> dict[str, Any] | None:
        from ablate.reporting.results import NoResults

        try:
            tuning = api.load(experiment, tracking_uri=tracking_uri).ablation.tuning or {}
        except (NoResults, ConfigError):
            return None
        values = tuning.get("choices", {}).get(experiment.baseline, {}).get("values")
        return dict(values) if values else None

    values = read()
    if values is None:
        print(f"calibrate: no tuning choice for {experiment.baseline!r} in the store; tuning it first", flush=True)
        api.run(experiment, only=[experiment.baseline], report=False, tracking_uri=tracking_uri, **run_kwargs)
        values = read()
        if values is None:
            raise ConfigError(f"calibrate: tuning {experiment.baseline!r} left no choice in {tracking_uri}")
    return values


# --- the A/A reports ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Share:
    """How many of ``reports`` claimed any difference, with a 95% Wilson interval."""

    claims: int
    reports: int

    @property
    def rate(self) -> float:
        return self.claims / self.reports

    def words(self) -> str:
        from scipy import stats  # not at import: ``ablate --help`` builds this command's parser

        low, high = stats.binomtest(self.claims, self.reports).proportion_ci(CONFIDENCE, method="wilson")
        interval = f"{percent(CONFIDENCE)} CI {low:.1%} to {high:.1%}"
        return f"{self.claims} of {self.reports} reports, {self.rate:.1%} ({interval})"


@dataclass(frozen=True)
class Calibration:
    new: Share
    old: Share
    old_per_metric: dict[str, float]
    """The old rule's per-comparison share of "better"/"worse", metric by metric."""
    equivalent: Share
    """Reports in which the new rule called some variant equivalent (a true claim in an A/A report)."""


def aa_reports(
    trials: Any,
    metric_names: list[str],
    primary: str,
    variants: int,
    seeds: int,
    reports: int,
    smallest_effect: float,
    rounds: SeedRounds | None = None,
) -> Calibration:
    """Deal the reference's seeds (``trials``: one row per finished seed, the report's columns) into ``reports``
    disjoint A/A reports of ``variants`` groups of ``seeds`` (group 0 the baseline), and judge each by the
    primary-claims rule on ``primary`` and by the old rule (a 95% bootstrap interval excluding 0, with the
    censoring care) on each of ``metric_names``. ``rounds``: the experiment's seed rounds, replayed by the
    new rule on each report's first seeds (``seeds`` is then ``max``); the old rule judges all ``seeds``."""
    import numpy as np

    from ablate.claims import BETTER, EQUIVALENT, WORSE, Design, Sample, decide, primary_question
    from ablate.reporting.statistics import SEPARATED, exploratory_comparison

    trials = trials.sort_values("seed").reset_index(drop=True)
    if len(trials) < variants * seeds:
        raise ConfigError(
            f"calibrate: {len(trials)} finished seeds cannot fill {variants} variants x {seeds} seeds; valid: --pool "
            f">= {variants * seeds}"
        )
    entries = {m: measure(m) for m in dict.fromkeys([*metric_names, primary])}
    columns = {m: trials[e.column].to_numpy(float) for m, e in entries.items()}
    unreached = {
        m: (trials[e.reached] != 1).to_numpy() if e.reached in trials else np.zeros(len(trials), bool)
        for m, e in entries.items()
    }
    budget = float(trials.budget.max()) if "budget" in trials else None
    question = primary_question(primary, smallest_effect, budget)
    auc = trials["auc"].to_numpy(float) if "auc" in trials and question.fallback else None
    pool = Sample(columns[primary], unreached[primary] if entries[primary].censored else None, auc)  # every seed
    references = {f"v{i}": "v0" for i in range(1, variants)}
    design = Design.of(rounds) if rounds else Design.fixed(seeds)
    rng = np.random.default_rng(DEAL_SEED)
    new = old = equivalent = 0
    per_metric = dict.fromkeys(metric_names, 0)
    for _ in range(reports):
        order = rng.permutation(len(trials))[: variants * seeds].reshape(variants, seeds)
        samples = {f"v{i}": pool[order[i]] for i in range(variants)}
        result = decide(samples, references, question, design, intervals=False, estimate_seeds=False)
        new += any(v.verdict in (BETTER, WORSE) for v in result.verdicts)
        equivalent += any(v.verdict == EQUIVALENT for v in result.verdicts)
        claimed = False
        for metric in metric_names:
            values, flags, y = columns[metric], unreached[metric], order[0]
            for x in order[1:]:
                censored = (flags[x], flags[y]) if entries[metric].censored else ()
                verdict = exploratory_comparison(values[x], values[y], *censored)[3]
                hit = verdict in SEPARATED
                per_metric[metric] += hit
                claimed |= hit
        old += claimed
    comparisons = reports * (variants - 1)
    return Calibration(
        Share(new, reports),
        Share(old, reports),
        {m: n / comparisons for m, n in per_metric.items()},
        Share(equivalent, reports),
    )


def cmd_calibrate(args: argparse.Namespace) -> int:
    """``ablate calibrate``: 0 with the shares printed; 2 for bad input; 1 when the seeds could not be run."""
    experiment = load_experiment(args.experiment)
    variants = len(experiment.variants)
    rounds = experiment.rounds if not args.design_seeds else None
    seeds = args.design_seeds or (rounds.max if rounds else len(experiment.seeds))
    if seeds < 2:
        raise ConfigError(f"--seeds = {seeds} is invalid; valid: at least 2 seeds per variant")
    pool = max(args.pool, MIN_SEEDS, variants * seeds)
    if args.reports < MIN_REPORTS:
        raise ConfigError(f"--reports = {args.reports} is invalid; valid: at least {MIN_REPORTS}")
    if args.population < 1:
        raise ConfigError(f"--population = {args.population} is invalid; valid: an integer >= 1")
    run_kwargs = {"address": args.address, "max_concurrent": args.max_concurrent, "population": args.population}
    tracking_uri = resolve_uri(args.tracking_uri)
    tuned = tuned_values(experiment, tracking_uri, run_kwargs)
    derived = derived_experiment(experiment, tuned, pool)
    import ablate.api as api

    shown = ", ".join(f"{k} {v}" for k, v in tuned.items())
    print(
        f"calibrate {experiment.name}: {pool} seeds of {experiment.baseline}"
        f"{' at ' + shown if shown else ''} (seeds {derived.seeds[0]}-{derived.seeds[-1]})",
        flush=True,
    )
    outcome = api.run(derived, tracking_uri=tracking_uri, report=False, **run_kwargs)
    if outcome.interrupted or outcome.error or outcome.failed:
        print(f"calibrate: the seeds did not all finish ({outcome.error or 'interrupted or failed'})")
        return 1
    from ablate.reporting.comparisons import comparison_metrics

    ablation = api.load(derived, tracking_uri=tracking_uri).ablation
    metrics = comparison_metrics(ablation)
    primary = experiment.primary_metric
    if measure(primary) is FINAL_RETURN:
        primary = return_at(ablation.budgets[-1]).name
    result = aa_reports(
        ablation.finished,
        metrics,
        primary,
        variants,
        seeds,
        args.reports,
        experiment.smallest_effect,
        rounds,
    )
    print(print_calibration(experiment, ablation, result, variants, seeds, primary, metrics))
    return 0


def print_calibration(experiment, ablation, result: Calibration, variants, seeds, primary, metrics) -> str:
    done = ablation.finished
    solved = int((done.solved == 1).sum()) if "solved" in done else 0
    words = [measure(m).words for m in metrics]
    per = "; ".join(f"{measure(m).words} {share:.1%}" for m, share in result.old_per_metric.items())
    return "\n".join(
        [
            f"{len(done)} seeds finished ({solved} solved); {result.new.reports} A/A reports of {variants} variants x "
            f"{seeds} seeds, each variant the same configuration, dealt from them without overlap",
            f"  new rule (permutation test of the IQM difference on {measure(primary).words}, Holm over "
            f"{variants - 1} comparisons at {percent(ALPHA)}): any better/worse in {result.new.words()}",
            f"  old rule (a {percent(CONFIDENCE)} bootstrap interval excluding 0 on {', '.join(words)}): any "
            "better/worse in "
            f"{result.old.words()}; per comparison: {per}",
            f"  (the new rule called some variant equivalent in {result.equivalent.words()}: true in an A/A test)",
        ]
    )
