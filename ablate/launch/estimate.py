"""The time-left estimate of a launch's state (``launch.state``): the time left in the current round and the most
the launch can still take. Its rules, in words: ``docs/running.md`` ("Progress").

Pure: it reads the state (holding its lock is the caller's part) and draws nothing."""

from __future__ import annotations

import bisect
import heapq
import math
import statistics
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from ablate.launch.state import LaunchState, TrialProgress

PACE_WINDOW_S = 60.0
"""Seconds of a running trial's own clock that its pace against its peers (``TimeLeft._pace``) is measured
over, and the least it must have run to have one: a machine's load changes over minutes, while over seconds a
pace measures the trial's own noise (a CartPole agent's episodes growing, its population's mates leaving)."""


def makespan(running_left_s: Sequence[float], pending_cost_s: Sequence[float], slots: int) -> float:
    """Seconds until the last trial ends when ``pending_cost_s`` (in scheduling order) each take the next free
    one of ``slots`` trial slots, the running trials holding theirs for ``running_left_s``."""
    free_at = sorted([max(s, 0.0) for s in running_left_s] + [0.0] * max(slots - len(running_left_s), 0))
    if not free_at:
        free_at = [0.0]
    heapq.heapify(free_at)
    for cost in pending_cost_s:
        heapq.heappush(free_at, heapq.heappop(free_at) + cost)
    return max(free_at)


def expected_max(samples: Sequence[Sequence[float]]) -> float:
    """The expected longest of independent draws, one from each sample (its values equally likely): what a
    population of members with these costs holds its slot for. Each distinct sample counts once, raised to its
    members (a population of 60 seeds, each drawing from 900 finished peers, took seconds counted one by one)."""
    counts: dict[tuple[float, ...], int] = {}
    for sample in samples:
        key = tuple(sorted(sample))
        counts[key] = counts.get(key, 0) + 1
    total = below = 0.0
    for x in sorted({v for sample in counts for v in sample}):
        # P(every draw <= x)
        p = math.prod((bisect.bisect_right(sample, x) / len(sample)) ** n for sample, n in counts.items())
        total, below = total + x * (p - below), p
    return total


def at_budget(cost: float, ran: int, budget: int, rate: float | None, wanted: int) -> float:
    """A finished trial's seconds carried over to an episode budget of ``wanted``."""
    if ran < budget and ran <= wanted:
        return cost
    if wanted <= ran:
        return cost * wanted / max(ran, 1)
    return cost + (wanted - budget) * (rate if rate is not None else cost / max(budget, 1))


@dataclass(frozen=True)
class CostsSeen:
    means: dict[tuple[str, int], float]
    """Mean seconds of the finished trials per (variant, episode budget)."""
    peers: dict[tuple[str, str], list[tuple[float, int, int, float | None]]]
    """The finished trials per ``settings``: (seconds, episodes run, budget, recent seconds per episode)."""
    rates: dict[str | None, float]
    """Mean seconds per episode per variant (``None``: over every variant)."""
    prior_scale: float
    """This launch's seconds over the earlier runs' seconds, for the trials both finished; 1 before one has."""
    overhead_s: float
    """What a trial costs beside its training (median over the finished trials that paid no worker start)."""
    profiled: dict[tuple[tuple[str, str], int], list[TrialProgress]] = field(default_factory=dict)
    """The finished trials with a ``profile``, per (``settings``, budget)."""
    paces: dict[str, float] = field(default_factory=dict)
    """Each running trial's ``TimeLeft._pace``, by key, where it has one."""
    pace: float = 1.0
    """How fast the launch runs now against the finished trials it is held to: the running trials' median
    pace (2: half as fast), 1 while none has one."""


class TimeLeft:
    """The estimate's arithmetic over a launch's state."""

    def __init__(self, state: LaunchState) -> None:
        self.state = state

    def units(self, trials: Sequence[TrialProgress], plan: Mapping[str, tuple[str, ...]]) -> list[list[TrialProgress]]:
        """``trials`` (in the order they start) gathered into what holds a slot: each population's members, in
        the order of their first; a population's slot frees when its last member ends."""
        units: dict[tuple[str, ...], list[TrialProgress]] = {}
        for t in trials:
            units.setdefault(plan.get(t.trial.key, (t.trial.key,)), []).append(t)
        return list(units.values())

    def _costs_seen(self, now: float) -> CostsSeen:
        """What this launch has shown so far of its trials' costs (once per estimate: the trials are many)."""
        by_group: dict[tuple[str, int], list[float]] = {}
        peers: dict[tuple[str, str], list[tuple[float, int, int, float | None]]] = {}
        rates: dict[str | None, list[float]] = {}
        observed = earlier = 0.0
        done = [t for t in self.state.trials.values() if t.state == "done" and t.started_at and t.ended_at]
        # What a trial costs beside its training (Tune, the driver's writes), from the trials that paid no
        # worker start; a trial that did pay one counts as its training time plus that.
        beside = [t.ended_at - t.started_at - t.wall_s for t in done if not t.first_on_worker and t.wall_s is not None]
        overhead = statistics.median(beside) if beside else 0.0
        for t in done:
            cost = t.ended_at - t.started_at  # type: ignore[operator]
            if t.first_on_worker and t.wall_s is not None:
                cost = min(cost, t.wall_s + max(overhead, 0.0))
            by_group.setdefault((t.trial.variant, t.budget), []).append(cost)
            ran = t.episodes_run if t.episodes_run is not None else t.episode
            if ran:  # a trial that reported no episode says nothing of a budget's cost
                peers.setdefault(t.settings, []).append((cost, ran, t.budget, t.seconds_per_episode(now)))
            if t.trial.key in self.state.prior:  # as the earlier launch measured it: start to end, a worker start too
                observed, earlier = observed + t.ended_at - t.started_at, earlier + self.state.prior[t.trial.key]  # type: ignore[operator]
        for t in self.state.trials.values():
            if (rate := t.seconds_per_episode(now)) is not None:
                rates.setdefault(t.trial.variant, []).append(rate)
                rates.setdefault(None, []).append(rate)
        profiled: dict[tuple[tuple[str, str], int], list[TrialProgress]] = {}
        for t in done:
            if t.profile and t.reports:
                profiled.setdefault((t.settings, t.budget), []).append(t)
        paces = {}
        for t in self.state.trials.values():
            if t.state != "running":
                continue
            held_to = profiled.get((t.settings, t.budget), [])
            seen_from = (len(t.profile), len(held_to))
            if t.pace_seen is None or t.pace_seen[0] != seen_from:
                t.pace_seen = (seen_from, self._pace(t, held_to))
            if t.pace_seen[1] is not None:
                paces[t.trial.key] = t.pace_seen[1]
        return CostsSeen(
            means={group: statistics.fmean(costs) for group, costs in by_group.items()},
            peers=peers,
            rates={variant: statistics.fmean(r) for variant, r in rates.items()},
            # How this launch's trials compare with their earlier runs (a busier machine, another CPU).
            prior_scale=observed / earlier if earlier > 0 else 1.0,
            overhead_s=max(overhead, 0.0),
            profiled=profiled,
            paces=paces,
            pace=statistics.median(paces.values()) if paces else 1.0,
        )

    @staticmethod
    def _pace(trial: TrialProgress, peers: Sequence[TrialProgress]) -> float | None:
        """How fast ``trial`` runs now against its finished ``peers``: its seconds per env step over the newest
        ``PACE_WINDOW_S`` of its own clock, over theirs between the same episodes (1: as fast, 2: half as fast).
        Per step, not per episode: a seed's episodes are its own (a Pong agent that returns the ball plays
        longer ones), its seconds per step are the machine's. ``None`` before it has run ``PACE_WINDOW_S``, or
        without a peer that ran that far."""
        if not trial.profile or trial.profile[-1][1] < PACE_WINDOW_S:
            return None
        e1, s1, n1 = trial.profile[-1]
        start = bisect.bisect_right(trial.profile, s1 - PACE_WINDOW_S, key=lambda point: point[1])
        e0, s0, n0 = trial.profile[start - 1] if start else (0, 0.0, 0)
        rates = []
        for peer in peers:
            a, b = peer.at(e0), peer.at(e1)
            if a is not None and b is not None and b[0] > a[0] and b[1] > a[1]:
                rates.append((b[0] - a[0]) / (b[1] - a[1]))
        if not rates or s1 <= s0 or n1 <= n0:
            return None
        return (s1 - s0) / (n1 - n0) / statistics.fmean(rates)

    @staticmethod
    def _same_budget(trial: TrialProgress, seen: CostsSeen) -> list[float]:
        """What its finished peers with the same settings took, at its budget, at the launch's pace now."""
        return [cost * seen.pace for cost, _, budget, _ in seen.peers.get(trial.settings, []) if budget == trial.budget]

    def _cost_sample(self, trial: TrialProgress, seen: CostsSeen) -> list[float] | None:
        """The costs a trial that has not started may take, equally likely: its finished peers', else
        ``_trial_cost``'s one figure."""
        same = [] if trial.trial.key in self.state.prior else self._same_budget(trial, seen)
        if same:
            return same
        cost = self._trial_cost(trial, seen)
        return None if cost is None else [cost]

    def _peer_cost(self, trial: TrialProgress, seen: CostsSeen) -> float | None:
        """What finished trials say a trial costs, at the launch's pace now (``None``: nothing yet)."""
        if trial.trial.key in self.state.prior:
            return self.state.prior[trial.trial.key] * seen.prior_scale
        same = self._same_budget(trial, seen)
        if same:
            return statistics.fmean(same)
        peers = seen.peers.get(trial.settings, [])
        variant_mean = seen.means.get((trial.trial.variant, trial.budget))
        if peers:
            carried = statistics.fmean(at_budget(*peer, trial.budget) for peer in peers)
            return (carried if variant_mean is None else (carried + variant_mean) / 2) * seen.pace
        return None if variant_mean is None else variant_mean * seen.pace

    def _trial_cost(self, trial: TrialProgress, seen: CostsSeen) -> float | None:
        """Expected seconds of a trial that has not started; ``None`` before any trial has reported an episode."""
        cost = self._peer_cost(trial, seen)
        if cost is not None:
            return cost
        rate = seen.rates.get(trial.trial.variant) or seen.rates.get(None)
        return None if rate is None else rate * trial.budget + seen.overhead_s

    def dispatch_s(self) -> float:
        """Mean seconds a slot stays idle between one trial's end and the next trial's start (Tune's loop, the
        driver's writes): with trials of a second or two, a third of the time."""
        return statistics.fmean(self.state.gaps) if self.state.gaps else 0.0

    def _left_by_profile(self, trial: TrialProgress, now: float, seen: CostsSeen) -> float | None:
        """What its finished peers that ran past its last episode took from there, at its pace against them
        (``_pace``), and from their last report to their end; ``None`` without such a peer or a pace."""
        pace = seen.paces.get(trial.trial.key)
        episode = trial.profile[-1][0] if trial.profile else None
        if pace is None or episode is None or not trial.reports:
            return None
        peers = seen.profiled.get((trial.settings, trial.budget), [])
        # Once it reported its last episode it stops there: what is left is what its peers took after their last.
        stops = trial.last_episode_reported
        held_to = peers if stops else [p for p in peers if p.profile[-1][0] > episode]
        if not held_to:
            return None
        rest = 0.0 if stops else statistics.fmean(p.profile[-1][1] - p.at(episode)[0] for p in held_to)  # type: ignore[index]
        tail = statistics.fmean(max(p.ended_at - p.reports[-1][0], 0.0) for p in held_to)  # type: ignore[operator]
        return max(pace * rest + tail - (now - trial.reports[-1][0]), 0.0)

    def _left_of_running(self, trial: TrialProgress, now: float, seen: CostsSeen) -> float | None:
        if trial.trial.key not in self.state.prior and (left := self._left_by_profile(trial, now, seen)) is not None:
            return left
        elapsed = now - (trial.started_at or now)
        expected = self._peer_cost(trial, seen)
        if expected is not None and expected > elapsed:
            return expected - elapsed
        if trial.last_episode_reported:  # not the rest of its budget: a solved trial stops where it solved
            return 0.0
        # Past its peers' mean but not past every peer: a seed that has not solved by now is one of the slower ones.
        longer = [c for c, _, b, _ in seen.peers.get(trial.settings, []) if b == trial.budget and c > elapsed]
        if longer and trial.trial.key not in self.state.prior:
            return statistics.fmean(longer) - elapsed
        # Past what its peers took (or none has ended): at its own recent pace to where its earlier run stopped, else
        # its budget's end, sooner where its rolling mean climbs to the threshold first (a CartPole agent near it
        # plays 500-step episodes: the rest of its budget at that pace would be many times what is left).
        rate = trial.seconds_per_episode(now) or seen.rates.get(None)
        if rate is None:
            return None
        stop = self.state.prior_episodes.get(trial.trial.key, trial.budget)
        left = (stop if trial.episode < stop else trial.budget) - trial.episode
        # An earlier run of the same seed that ran its whole budget says no climb now reaches the threshold.
        never_solved = trial.trial.key in self.state.prior_episodes and stop >= trial.budget
        climb = None if never_solved else trial.episodes_to_solve()
        return rate * max(left if climb is None else min(left, climb), 0)

    def _unit_left(self, unit: Sequence[TrialProgress], now: float, seen: CostsSeen) -> float | None:
        """Seconds until a population (or a trial alone) frees its slot: its longest member's, the members not
        started yet costed as the expected longest of them (a population waits for its slowest seed)."""
        running = [self._left_of_running(t, now, seen) for t in unit if t.state == "running"]
        samples = [self._cost_sample(t, seen) for t in unit if t.state != "running"]
        if None in running or None in samples:
            return None
        return max([*running, *([expected_max(samples)] if samples else [])])  # type: ignore[list-item, arg-type]

    def seconds_left(self, now: float | None = None, seen: CostsSeen | None = None) -> float | None:
        """Seconds until the last trial ends, or ``None`` while nothing is known of any trial's cost."""
        now = time.monotonic() if now is None else now
        units = self.units(
            [t for t in self.state.trials.values() if t.state in ("running", "pending")], self.state.population_of
        )
        if not units and not self.state.later:
            return 0.0
        seen = seen or self._costs_seen(now)
        running_left, costs = [], []
        for unit in units:
            (running_left if any(t.state == "running" for t in unit) else costs).append(
                self._unit_left(unit, now, seen)
            )
        later = [self._unit_left(u, now, seen) for u in self.units(self.state.later, self.state.later_population_of)]
        if any(x is None for x in [*running_left, *costs, *later]):
            return None
        slots = self.state.slots or max(self.state.max_running, 1)
        gap = self.dispatch_s()
        # Pending trials start in the order the scheduler was given them (``grid.schedule_order``); the later
        # stage once every one of them has ended.
        now_stage = makespan(running_left, [c + gap for c in costs], slots)  # type: ignore[misc, operator]
        return now_stage + (makespan([], [c + gap for c in later], slots) if later else 0.0)  # type: ignore[misc, operator]

    def figures(self, now: float | None = None) -> tuple[float | None, float | None]:
        """(``seconds_left``, that plus each round later rounds may still add, one after another)."""
        now = time.monotonic() if now is None else now
        seen = self._costs_seen(now)
        left = self.seconds_left(now, seen)
        if left is None or not self.state.possible:
            return left, left
        most = left
        slots = self.state.slots or max(self.state.max_running, 1)
        gap = self.dispatch_s()
        for trials in self.state.possible:
            costs = [self._unit_left(u, now, seen) for u in self.units(trials, self.state.possible_population_of)]
            if any(c is None for c in costs):
                return left, None
            most += makespan([], [c + gap for c in costs], slots)  # type: ignore[operator]
        return left, most


def estimate(state: LaunchState, now: float | None = None) -> tuple[float | None, float | None]:
    """(seconds left in the current round, the most the launch can still take), read under the state's lock."""
    with state.lock:
        return TimeLeft(state).figures(now)
