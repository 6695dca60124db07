"""A launch's plan: its trials grouped into populations (``agent.trainer``), the unit the scheduler runs.

A population is one Ray task that trains its members together; each member is still a trial, with its own
key, MLflow run, curve, checkpoints and result. Members share a population when their configs allow it
(``stacked.population_group``: one network and batch shape; seeds and tuning candidates that differ only in
optimisation knobs) and they are in the same stage. Pure: no Ray, no MLflow.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass

from ablate.config import population_group
from ablate.launch.grid import GridTrial


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


def population_keys(trials: Sequence[GridTrial], cap: int = 1, slots: int = 1) -> list[list[str]]:
    """The keys of each population ``plan_populations`` makes of ``trials``: how the estimate sees them."""
    return [p.keys for p in plan_populations(trials, cap=cap, slots=slots)]
