"""The Python API a notebook uses: ``run`` an experiment, ``load`` its results as DataFrames and figures,
write its ``report``. The CLI is a thin layer over the same calls.

Importing this module is light: torch, Ray and MLflow load only when a function needs them.
"""

from __future__ import annotations

import contextlib
import sys
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

from ablate.config import DEFAULT_POPULATION
from ablate.experiment import Experiment, load_experiment
from ablate.launch.store import StoreNotFound  # noqa: F401 - public: `ablate.api.StoreNotFound` (docs/python.md)

if TYPE_CHECKING:  # only for the annotations: the real imports are inside the functions
    import pandas as pd
    from matplotlib.figure import Figure as MplFigure

    from ablate.launch.plan import LaunchPlan
    from ablate.launch.runner import RunOutcome
    from ablate.reporting.document import ReportResult
    from ablate.reporting.results import Ablation


def experiment_name(name_or_file: str | Path | Experiment) -> str:
    """An experiment's name from itself, its file (``*.toml`` or an existing path) or its plain name."""
    if isinstance(name_or_file, Experiment):
        return name_or_file.name
    text = str(name_or_file)
    if text.endswith(".toml") or Path(text).is_file():
        return load_experiment(text).name
    return text


def run(
    experiment: str | Path | Experiment,
    *,
    tracking_uri: str | None = None,
    address: str | None = None,
    only: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    fresh: bool = False,
    max_concurrent: int | None = None,
    report: bool = True,
    reports_folder: str | Path = "reports",
    progress: bool = True,
    storage_path: str = "ray_results",
    population: int = DEFAULT_POPULATION,
    allow_insecure_http: bool = False,
) -> RunOutcome:
    """Run an experiment's trials on Ray and track them in MLflow, as ``ablate run`` does.

    ``experiment``: an experiment file (``experiments/smoke.toml``) or a loaded ``Experiment``.
    ``tracking_uri``: the MLflow store (default: ``MLFLOW_TRACKING_URI`` as the CLI reads it, else
    ``sqlite:///mlflow.db`` in the current folder: ``launch.store.resolve_uri``, the one definition).
    ``address``: an existing Ray cluster (``host:port``); ``None`` starts a local one for this call.
    ``only`` / ``seeds``: run a part of the grid (variant names, evaluation seeds).
    ``fresh``: start a new generation instead of resuming the last one.
    ``report``: write ``reports_folder/<experiment>/`` afterwards (when no trial was interrupted).
    ``population``: train up to this many trials of a variant together as one batched population (1: each alone);
    members are their trials alone, bit for bit, on a CPU.
    ``allow_insecure_http``: let an MLflow login go over plain ``http://`` to another machine (in clear);
    without it that is a ``TrackingError`` before anything is tracked: put the server behind HTTPS.

    Trials that already finished in the store are not run again. Returns the launch's ``RunOutcome``
    (``finished``, ``failed``, ``skipped``, ``exit_code``, ...); ``outcome.report_folder`` is the report's
    folder, or ``None``. Bad input raises ``ConfigError`` before anything is tracked.
    """
    from ablate.checks import check_experiment
    from ablate.launch.plan import LaunchPlan
    from ablate.launch.store import insecure_http

    loaded = experiment if isinstance(experiment, Experiment) else load_experiment(experiment)
    check_experiment(loaded)
    plan = LaunchPlan.of(
        loaded, list(only) if only is not None else None, list(seeds) if seeds else None,
        tracking_uri=tracking_uri, address=address, fresh=fresh, max_concurrent=max_concurrent,
        storage_path=storage_path, show_progress=progress, population=population,
        command=f"ablate.run({loaded.path!r})",
    )  # fmt: skip
    with insecure_http(allow_insecure_http):  # the store is opened, and the report written, inside
        outcome = launch(plan, seeds, report, reports_folder)
    if outcome.report:
        _notes(outcome.report, pdf=True)
    return outcome


def launch(
    plan: LaunchPlan,
    seeds: Sequence[int] | None = None,
    report: bool = True,
    reports_folder: str | Path = "reports",
    said: Callable[[RunOutcome], object] = lambda outcome: None,
) -> RunOutcome:
    """``run``'s work and ``ablate run``'s: ``plan``'s trials (``said`` is told their outcome), then the report,
    its seconds recorded for the next ``--dry-run``."""
    from ablate.launch.clock import stage
    from ablate.launch.runner import run_plan
    from ablate.reporting.document import NoResults, build_report
    from ablate.reporting.rounds import judge_for

    experiment = plan.experiment
    outcome = run_plan(replace(plan, judge=judge_for(experiment, seeds)))
    said(outcome)
    if not report or outcome.interrupted or outcome.error:
        return outcome
    try:
        with stage(f"writing the report into {reports_folder}/{experiment.storage_name}/") as seconds:
            outcome.report = build_report(
                experiment.name, plan.tracking_uri, Path(reports_folder), command=plan.command
            )
    except NoResults as error:  # every trial failed: say so, and leave the last good report in place
        outcome.report_note = f"no report: {error}"
        return outcome
    outcome.report_folder, outcome.report_seconds = outcome.report.folder, seconds[0]
    if outcome.launch_run_id:
        from ablate.launch.tracking import Tracker

        with contextlib.suppress(Exception):  # a courtesy for the next --dry-run: the report stands without it
            Tracker(plan.tracking_uri, experiment.name).record_report_time(outcome.launch_run_id, seconds[0])
    return outcome


def report(
    name_or_file: str | Path | Experiment,
    *,
    tracking_uri: str | None = None,
    reports_folder: str | Path = "reports",
    pdf: bool = True,
    variants: Sequence[str] | None = None,
    baseline: str | None = None,
    generation: str | None = None,
    allow_insecure_http: bool = False,
) -> Path:
    """Write the report of an experiment from its MLflow store into ``reports_folder/<name>/`` (``report.md``,
    ``report.html``, ``report.typ`` and the ``report.pdf`` typeset from it, ``discussion.md`` (yours: created
    once, never overwritten), ``tables/``, ``figures/``, ``videos/``), as ``ablate report`` does, and return that
    folder. Where no PDF could be written, one line on stderr says why.

    ``name_or_file``: the experiment's name or its file. ``variants`` / ``baseline``: report a part of the
    ablation against another reference. ``allow_insecure_http``: as in ``run``. Raises ``NoResults`` when nothing
    finished, ``ConfigError`` for a bad name, store or variant; nothing is written then. Finished trials whose
    files the store cannot give are left out of the curves and figures, said in one line on stderr.
    """
    from ablate.launch.secrets import shown
    from ablate.launch.store import insecure_http
    from ablate.reporting.document import build_report

    with insecure_http(allow_insecure_http):
        result = build_report(
            experiment_name(name_or_file),
            tracking_uri=tracking_uri,
            out_root=Path(reports_folder),
            generation=generation,
            variants=list(variants) if variants else None,
            baseline=baseline,
            pdf=pdf,
            command=shown(f"ablate.report({str(getattr(name_or_file, 'path', name_or_file))!r})"),
        )
    _notes(result, pdf)
    return result.folder


def _notes(result: ReportResult, pdf: bool) -> None:
    """A report's notes on stderr, where a notebook shows them: the trials left out, and why no PDF if asked."""
    if result.missing_note:  # written without some trials' files: say which, in one line
        print(result.missing_note, file=sys.stderr)
    if result.pdf_note and pdf:  # asked for a PDF and got none: say why, in one line
        print(result.pdf_note, file=sys.stderr)


def load(
    name_or_file: str | Path | Experiment,
    *,
    tracking_uri: str | None = None,
    generation: str | None = None,
    variants: Sequence[str] | None = None,
    baseline: str | None = None,
    allow_insecure_http: bool = False,
) -> Results:
    """Read an ablation back from its MLflow store: its trials, curves, convergence table and comparisons as
    pandas DataFrames, its figures as matplotlib figures (see ``Results``). Reads only.

    ``name_or_file``: the experiment's name (``"smoke"``) or its file (``"experiments/smoke.toml"``).
    ``tracking_uri``: the store ``run`` wrote; a relative SQLite path is read from the current folder, so a
    notebook in another folder passes the path (``"sqlite:////abs/path/mlflow.db"`` or ``"sqlite:///../mlflow.db"``).
    ``generation``: an older generation (a prefix of its id) instead of the newest launch's.
    ``allow_insecure_http``: as in ``run``.
    """
    from ablate.launch.store import insecure_http
    from ablate.reporting.results import load_ablation, select

    with insecure_http(allow_insecure_http):
        ablation = load_ablation(experiment_name(name_or_file), tracking_uri, generation)
    return Results(select(ablation, list(variants) if variants else None, baseline))


@dataclass(frozen=True)
class Results:
    """One ablation as read from its store, the tables the report writes as DataFrames.

    ``claims``: the report's primary claims, one row per line of its Claims section, as ``tables/claims.csv``
    (docs/python.md has a table of its columns): ``variant``, ``reference``, ``metric``, ``verdict`` (better,
    worse, equivalent, undetermined), ``change``, ``change_low``, ``change_high`` (the simultaneous interval, in
    ``change_unit``), ``bound``, ``n_variant``, ``n_reference``, ``level`` (Holm's), ``seeds_needed``,
    ..., then each side's settings (``variant.learning_rate``, ``reference.hidden_sizes``, ...: the same settings
    as ``trials``).
    ``trials``: every evaluation trial the report uses, as ``tables/trials.csv``: variant, seed, ``stage``
    (``eval``: the claims' trials; ``base``: a tuned ablation's trials at the shared base values only),
    ``at_base_values`` (tuned: in the "depends on the learning rate?" comparison), the trial's settings
    (``learning_rate``, ``episodes_per_update``, ``gamma``, ``l2``, each knob a variant writes: ``hidden_sizes``,
    ``depth``, ``width``, ...; typed as the schema declares: ``hidden_sizes`` a tuple, a table knob one column per
    key, ``model_args.width``), status, episodes to solve, AUC, ...
    ``curves``: long form, one row per trial and episode (key, variant, seed, stage, episode, return, rolling_mean,
    wall_s). ``convergence``: long form of ``tables/convergence.csv``: per variant (solved seeds, episodes to solve
    with intervals, ``budget``, ...) one row per checkpoint, an ``episode`` (``return_iqm`` and its interval) or a
    ``return_level`` (``episodes_to_level_median``, ``reached``); no budget in a column's name.
    ``comparisons``: each variant against its reference, per metric, each judged on its own (exploratory, not
    claims), as ``tables/comparisons.csv``; its columns: ``variant``, ``reference``,
    ``metric``; ``point``, ``low``, ``high`` (positive is better: episodes 1 - IQM ratio, returns the IQM
    difference); ``change``, ``change_low``, ``change_high`` in ``change_unit`` (the report's sign and units:
    episodes the % change of the IQM, + is more episodes; returns the difference); ``verdict`` (exploratory:
    better, exploratory: worse, exploratory: not separated, exploratory: too few seeds); ``primary`` (on the
    primary metric) and ``claim`` (there, the family verdict of ``claims``; "" elsewhere); ``bound`` ("", "at
    least", "censored"); ``variant_value``, ``reference_value`` (the IQMs); ``n_variant``, ``n_reference``
    (seeds); ``loo_checked``, ``fragile_seeds`` (the leave-one-seed-out check); ``seeds_needed`` (primary rows:
    the claim's), ``seeds_needed_smallest`` (``inf``: more than ``seeds_cap``); ``seeds_cap``;
    ``p_improvement``, ``p_improvement_ci_low``, ``p_improvement_ci_high``.
    ``tuning``: a tuned launch's stage 1, one row per tuning trial (variant, seed, each tuned knob, the metric,
    status), as ``tables/tuning.csv``; empty for an untuned ablation. ``figure(name)``: one of the report's figures.
    """

    ablation: Ablation = field(repr=False)

    @property
    def name(self) -> str:
        return self.ablation.name

    @property
    def variants(self) -> list[str]:
        return self.ablation.variants

    @property
    def baseline(self) -> str:
        return self.ablation.baseline

    def _meeting(self, table: pd.DataFrame, settings: bool = False) -> pd.DataFrame:
        from ablate.reporting.tables import meeting

        return meeting(table, self.ablation, settings)

    @cached_property
    def trials(self) -> pd.DataFrame:
        from ablate.reporting.tables import trials_table

        return self._meeting(trials_table(self.ablation))

    @cached_property
    def curves(self) -> pd.DataFrame:
        from ablate.reporting.tables import curves_table

        return self._meeting(curves_table(self.ablation), settings=True)

    @cached_property
    def convergence(self) -> pd.DataFrame:
        from ablate.reporting.tables import convergence_long

        return self._meeting(convergence_long(self._convergence_by_variant))

    @cached_property
    def _convergence_by_variant(self) -> pd.DataFrame:
        """``tables/convergence.csv``: one row per variant, budgets and levels in the column names."""
        from ablate.reporting.tables import convergence_table

        return convergence_table(self.ablation)

    @property
    def tuning(self) -> pd.DataFrame:
        """``tables/tuning.csv``: one row per tuning trial; an untuned experiment's is empty, with its columns."""
        from ablate.reporting.tuning import tuning_table

        trials = self.ablation.tuning_trials
        if self.ablation.tuning and trials is not None:
            return self._meeting(trials)
        return self._meeting(tuning_table([], self.ablation.tuning or {}, self.variants))

    @property
    def claims(self) -> pd.DataFrame:
        return self._meeting(self._claims)

    @cached_property
    def _claims(self) -> pd.DataFrame:
        from ablate.reporting.comparisons import claims_table
        from ablate.reporting.tables import side_settings

        return side_settings(claims_table(self.ablation), self.ablation)

    @property
    def comparisons(self) -> pd.DataFrame:
        return self._meeting(self._comparisons)

    @cached_property
    def _comparisons(self) -> pd.DataFrame:
        from ablate.reporting.comparisons import comparisons

        return comparisons(self.ablation, claims=self._claims)

    def figure(self, name: str = "curves") -> MplFigure:
        """One of the report's figures as a matplotlib figure (a notebook shows it inline): ``curves``
        (every variant's learning curve), ``per_seed`` (episodes to solve per seed), ``improvement`` (each
        variant against its reference, with intervals), ``parameters`` (cost against size), ``wallclock``."""
        from ablate.reporting import figures

        draw = {
            "curves": lambda folder: figures.figure_overview(self.ablation, folder),
            "per_seed": lambda folder: figures.figure_per_seed(self.ablation, folder),
            "improvement": lambda folder: figures.figure_improvement(self.ablation, self._comparisons, folder),
            "parameters": lambda folder: figures.figure_parameters(self.ablation, self._convergence_by_variant, folder),
            "wallclock": lambda folder: figures.figure_wallclock(self.ablation, folder),
        }
        if name not in draw:
            raise ValueError(f"figure {name!r} is unknown; valid: {', '.join(draw)}")
        with tempfile.TemporaryDirectory() as folder, figures.keep_figures() as kept:
            if draw[name](Path(folder)) is None:
                raise ValueError(f"figure {name!r} does not apply to {self.name!r} (the report leaves it out too)")
        return kept[-1]
