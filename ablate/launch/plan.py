"""A launch's plan: what ``ablate run`` or ``ablate.run`` asked for (``LaunchPlan``), and its trials grouped into
populations (``agent.trainer``), the unit the scheduler runs.

A population is one Ray task that trains its members together; each member is still a trial, with its own
key, MLflow run, curve, checkpoints and result. Members share a population when their configs allow it
(``config.population_group``) and they are in the same stage. Pure: no Ray, no MLflow.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING

from ablate.config import DEFAULT_POPULATION, ConfigError, population_group
from ablate.experiment import Experiment
from ablate.launch.grid import GridTrial, chosen_trials, expand, select, tuning_trials
from ablate.launch.tuning import Choice, choose_all, unique

if TYPE_CHECKING:
    from ablate.launch.rounds import Judge


@dataclass(frozen=True)
class LaunchPlan:
    """One launch as the command line or the API asks for it, handed whole to the runner (``runner.run_plan``):
    the experiment as loaded and its grid as expanded (each once), the part of it to run, and how; its stages:
    stage 1 (tuning) and the evaluation trials known now, the rest of stage 2 (each variant at its chosen
    values) once stage 1 is done."""

    experiment: Experiment
    only: Sequence[GridTrial] | None = None
    """The part of the grid to run (``grid.select``); ``None``: all of it."""
    tracking_uri: str | None = None
    address: str | None = None
    """An existing Ray cluster (``host:port``); ``None`` starts a local one."""
    fresh: bool = False
    """A new generation instead of resuming the last one."""
    max_concurrent: int | None = None
    storage_path: str = "ray_results"
    show_progress: bool = True
    command: str = ""
    """The command, as recorded and shown (``secrets.shown_command``)."""
    started_at: float | None = None
    """The command's ``time.monotonic()`` start, for the progress view's clock."""
    log_estimates: bool = False
    """Keep every time-left estimate in ``outcome.view.estimates`` (``make bench``)."""
    population: int = DEFAULT_POPULATION
    """At most this many trials train together as one population; 1: each alone."""
    judge: Judge | None = None
    """With seeds in rounds (``experiment.rounds``), the sequential rule that decides after each round who gets
    more seeds (``reporting.rounds.judge_for``); ``None``: round 1 only."""
    grid: tuple[GridTrial, ...] = ()
    """Every trial of the experiment (variants x seeds): expanded here, once, unless given."""

    def __post_init__(self) -> None:
        for option, value in (("max-concurrent", self.max_concurrent), ("population", self.population)):
            if value is not None and value < 1:  # one check for `ablate run` and `ablate.run`
                raise ConfigError(f"--{option} = {value} is invalid; valid: an integer >= 1")
        if not self.grid:
            object.__setattr__(self, "grid", tuple(expand(self.experiment)))

    @classmethod
    def of(cls, experiment: Experiment, variants: list[str] | None, seeds: list[int] | None, **how) -> LaunchPlan:
        """The plan of running the trials of ``variants`` x ``seeds`` (``grid.select``; ``None``: all), ``how``."""
        plan = cls(experiment, **how)
        return replace(plan, only=select(list(plan.grid), variants, seeds))

    @property
    def trials(self) -> list[GridTrial]:
        """The trials it evaluates: ``only``, else the whole grid; in a tuned launch, the base-value trials."""
        return list(self.grid if self.only is None else self.only)

    @cached_property
    def tuning(self) -> list[GridTrial]:
        """Stage 1's trials (``grid.tuning_trials``) of the variants it evaluates (``--seeds`` never narrows it)."""
        wanted = {t.variant for t in self.trials}
        return [t for t in tuning_trials(self.experiment) if t.variant in wanted]

    def chosen(self, choices: Mapping[str, Choice]) -> list[GridTrial]:
        """Stage 2 at the chosen values, for the variants and evaluation seeds asked for."""
        pairs = {(t.variant, t.seed) for t in self.trials}
        values = {name: c.values for name, c in choices.items() if c.tuned}
        return [t for t in chosen_trials(self.experiment, values) if (t.variant, t.seed) in pairs]

    def choices(self, finished: Mapping[str, Mapping[str, float]], so_far: bool = False) -> dict[str, Choice]:
        """Choices of the variants whose stage 1 has finished (``finished``: key -> summary metrics; ``so_far``:
        see ``tuning.choose_all``)."""
        if not self.tuning:
            return {}
        return choose_all(self.experiment, self.tuning, finished, so_far)

    def provisional(self, finished: Mapping[str, Mapping[str, float]], skip: set[str]) -> list[GridTrial]:
        """Stage 2 as it would be if stage 1 ended now, for the time-left estimate: each tuned variant at its
        best candidate so far (its choice once its stage 1 is complete), without the trials in ``skip``; a
        variant with no finished tuning trial yet stands in with its evaluation trials (as many, at the base
        values)."""
        choices = self.choices(finished, so_far=True)
        unseen = [name for name in dict.fromkeys(t.variant for t in self.tuning) if name not in choices]
        stand_ins = [t for name in unseen for t in self.trials if t.variant == name]
        return unique(self.chosen(choices), skip) + stand_ins


@dataclass(frozen=True)
class Population:
    """Trials trained together in one process. ``key``: stable for the same members (Tune's trial name)."""

    members: tuple[GridTrial, ...]
    plotted: frozenset[str] | None = None
    """The members whose ``learning_curve.png`` the worker draws (``grid.PLOTTED_SEEDS``); ``None``: every one."""

    @property
    def key(self) -> str:
        if len(self.members) == 1:
            return self.members[0].key
        digest = hashlib.sha1(" ".join(t.key for t in self.members).encode()).hexdigest()[:10]
        return f"pop{len(self.members)}-{self.members[0].key}-{digest}"

    @property
    def keys(self) -> list[str]:
        return [t.key for t in self.members]


def population_size(trials: int, slots: int, cap: int) -> int:
    """Members per population for ``trials`` that could share one, on ``slots`` trial slots, at most ``cap``:
    as many as the cap allows, but never so many that fewer populations than slots are left (a core would
    idle while the rest run)."""
    if cap <= 1 or trials <= 1:
        return 1
    return max(1, min(cap, math.ceil(trials / max(slots, 1))))


def plan_populations(
    trials: Sequence[GridTrial], cap: int = 1, slots: int = 1, plotted: Collection[str] | None = None
) -> list[Population]:
    """``trials`` (in the order they start) as populations of at most ``cap`` members: those of one
    ``population_group`` and stage share; a group of n splits into ceil(n / size) populations of balanced size
    (``population_size``), so no population runs far longer than another for its size. The plan starts in the
    order of each population's first member. ``cap`` 1: every trial alone (today's launch, exactly).
    ``plotted``: the keys whose learning curve is drawn (``None``: every trial's)."""
    if cap <= 1:
        return [_population((t,), plotted) for t in trials]
    groups: dict[tuple, list[GridTrial]] = {}
    for position, trial in enumerate(trials):
        # A test's blocked trial waits for a file before it trains: it would hold its population-mates too.
        group = population_group(trial.config) if trial.config.fault != "block" else None
        key = (trial.stage, group) if group is not None else ("alone", position)
        groups.setdefault(key, []).append(trial)
    shareable = sum(len(g) for k, g in groups.items() if k[0] != "alone")
    size = population_size(shareable, slots, cap)
    plan: list[tuple[int, Population]] = []
    order = {t.key: i for i, t in enumerate(trials)}
    for members in groups.values():
        count = math.ceil(len(members) / size)
        for part in range(count):
            # Round-robin, so each population holds every kind of member the group has (seeds, candidates).
            chosen = tuple(members[part::count])
            plan.append((min(order[t.key] for t in chosen), _population(chosen, plotted)))
    return [population for _, population in sorted(plan, key=lambda item: item[0])]


def _population(members: tuple[GridTrial, ...], plotted: Collection[str] | None) -> Population:
    return Population(members, None if plotted is None else frozenset(t.key for t in members if t.key in plotted))
