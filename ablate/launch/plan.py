"""A launch's plan: its trials grouped into populations (``agent.trainer``), the unit the scheduler runs.

A population is one Ray task that trains its members together; each member is still a trial, with its own
key, MLflow run, curve, checkpoints and result. Members share a population when their configs allow it
(``stacked.population_group``: one network and batch shape; seeds and tuning candidates that differ only in
optimisation knobs) and they are in the same stage. Pure: no Ray, no MLflow.
"""

from __future__ import annotations

import hashlib
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from ablate.agent.sharing import crowd, member_cost, population_group, population_share
from ablate.launch.estimate import makespan
from ablate.launch.grid import GridTrial


@dataclass(frozen=True)
class Population:
    """Trials trained together in one process. ``key``: stable for the same members (Tune's trial name)."""

    members: tuple[GridTrial, ...]

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


HEDGE = 2.0
"""How much more a group whose cost nothing has shown yet (no earlier run, no finished peer) may cost than
the plan's other trials: the plan is made to hold up if it does (a Pong CNN member costs about twice an MLP
member, and a launch's first stage knows neither)."""

GAIN = 0.90
"""More populations are planned than the fewest the cap allows only where the plan predicts they end at least
10% sooner. Each split loses what a population shares (``agent.sharing.SHARED_COST``), and the prediction is a
model: on the default CartPole ablation, splits it put at 6% sooner (the last rounds' 7 populations of 5 on 2
slots as 8) made those rounds no faster, measured over two launches each way (docs/performance.md)."""


def plan_populations(
    trials: Sequence[GridTrial], cap: int = 1, slots: int = 1, work: Mapping[str, float] | None = None
) -> list[Population]:
    """``trials`` (in the order they start) as populations of at most ``cap`` members that keep ``slots`` trial
    slots busy to the end. Trials of one ``population_group`` and stage share; a group of n splits into at
    least ceil(n / size) populations (``population_size``), members placed by their cost so that populations
    of a group cost alike, and into more where that ends the plan sooner on ``slots``: a group that costs
    more than its share of the slots' time spreads over several, so no core idles while one long population
    runs on. ``work``: each trial's expected cost alone (seconds, by key: an earlier run's, or what its
    finished peers took); a trial without one costs its group's median, else the plan's, and a group with
    none at all may cost ``HEDGE`` times that. Populations start in the order of their first member
    (``grid.schedule_order`` puts trials known to be slow first). ``cap`` 1: every trial alone, in order."""
    if cap <= 1:
        return [Population((t,)) for t in trials]
    groups: dict[tuple, list[GridTrial]] = {}
    for position, trial in enumerate(trials):
        # A test's blocked trial waits for a file before it trains: it would hold its population-mates too.
        group = population_group(trial.config) if trial.config.fault != "block" else None
        key = (trial.stage, group) if group is not None else ("alone", position)
        groups.setdefault(key, []).append(trial)
    shareable = sum(len(g) for k, g in groups.items() if k[0] != "alone")
    size = population_size(shareable, slots, cap)
    order = {t.key: i for i, t in enumerate(trials)}
    costs, unknown = _member_costs(groups, work or {})
    shares = {k: population_share(g[0].config) for k, g in groups.items()}
    fewest = {k: 1 if k[0] == "alone" else math.ceil(len(g) / size) for k, g in groups.items()}
    # Each group (that could share) whose cost is unknown, HEDGE times the rest: the plan must hold up in each.
    hedged = [k for k in unknown if k[0] != "alone"]
    scenarios = [{}] + ([{k: HEDGE} for k in hedged] if len(groups) > 1 else [])

    def planned(counts: Mapping[tuple, int]) -> tuple[float, list[Population]]:
        populations = []
        for k, members in groups.items():
            for part in _split(members, counts[k], costs):
                base = sum(costs[t.key] for t in part) * member_cost(shares[k], len(part))
                populations.append((min(order[t.key] for t in part), base, k, Population(part)))
        populations.sort(key=lambda item: item[0])
        longest = max(
            makespan([], [base * scenario.get(k, 1.0) for _, base, k, _ in populations], slots)
            for scenario in scenarios
        )
        return longest, [population for *_, population in populations]

    fewest_s, best = planned(fewest)
    best_s = fewest_s * GAIN  # what a plan of more populations must beat
    # Candidate plans: every group split so that none of its populations costs more than a bound, for each
    # bound at which some group's count changes (its cost over 1, 2, ... n). Counts only grow as the bound
    # falls, and with them what the populations cost in all (each split pays again for what its members
    # shared): once that over the slots cannot beat the best, no later candidate can.
    seen = {tuple(fewest.values())}
    totals = {k: sum(costs[t.key] for t in g) for k, g in groups.items()}
    bounds = sorted(
        {totals[k] / j for k, g in groups.items() if k[0] != "alone" for j in range(1, len(g) + 1)}, reverse=True
    )
    for bound in bounds:
        counts = {k: min(len(g), max(fewest[k], math.ceil(totals[k] / bound - 1e-9))) for k, g in groups.items()}
        if tuple(counts.values()) in seen:
            continue
        seen.add(tuple(counts.values()))
        # At least what they cost in all (populations of ceil(n / count) members, the larger ones), over the slots.
        least = sum(totals[k] * member_cost(shares[k], math.ceil(len(g) / counts[k])) for k, g in groups.items())
        if least / max(slots, 1) >= best_s:
            break
        seconds, plan = planned(counts)
        if seconds < best_s:
            best_s, best = seconds, plan
    return best


def alone_cost(seconds: float, trial: GridTrial, members: int) -> float:
    """What ``trial`` costs alone, from ``seconds`` it took as one of ``members`` in a population: M members of
    equal cost c take ``c * M * member_cost(share, M)`` (``agent.sharing.SHARED_COST``), each its population's
    clock."""
    return seconds / crowd(trial.config, members)


def _member_costs(
    groups: Mapping[tuple, Sequence[GridTrial]], work: Mapping[str, float]
) -> tuple[dict[str, float], list[tuple]]:
    """Each trial's expected cost alone (``work``; else its group's median, else the plan's, else 1), and the
    groups that had none (``HEDGE``)."""
    known = {t.key: work[t.key] for g in groups.values() for t in g if 0 < work.get(t.key, 0) < math.inf}
    fill = statistics.median(known.values()) if known else 1.0
    costs, unknown = {}, []
    for k, members in groups.items():
        mine = [known[t.key] for t in members if t.key in known]
        if not mine:
            unknown.append(k)
        for t in members:
            costs[t.key] = known.get(t.key, statistics.median(mine) if mine else fill)
    return costs, unknown


def _split(members: Sequence[GridTrial], count: int, costs: Mapping[str, float]) -> list[tuple[GridTrial, ...]]:
    """``members`` as ``count`` populations of balanced size, each member (costliest first) in the cheapest one
    with room: of equal costs, round-robin, so each population holds every kind of member the group has
    (seeds, candidates). Members keep their start order within a population."""
    room = math.ceil(len(members) / count)
    parts: list[list[GridTrial]] = [[] for _ in range(count)]
    loads = [0.0] * count
    position = {t.key: i for i, t in enumerate(members)}
    for t in sorted(members, key=lambda t: (-costs[t.key], position[t.key])):
        part = min((i for i in range(count) if len(parts[i]) < room), key=lambda i: (loads[i], len(parts[i]), i))
        parts[part].append(t)
        loads[part] += costs[t.key]
    return [tuple(sorted(p, key=lambda t: position[t.key])) for p in parts if p]
