"""Seeds added in rounds (``seeds = { start, step, max }``): after each round the primary comparisons are judged
on the finished trials, and the variants whose comparison is still open (and their references) get ``step``
more evaluation seeds, until every comparison is decided, ``max`` is reached or the next round would end after
the time budget (``max_minutes``, at the pace of the rounds so far).

The judge is passed in by the layer above (``ablate.reporting.rounds.judge_for``: the report's own sequential
rule), so this layer never imports the report's. Pure: no Ray, no MLflow, no file.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, Protocol

from ablate.experiment import Experiment
from ablate.launch.grid import GridTrial, chosen_trials
from ablate.launch.tuning import Choice
from ablate.seeds import SeedRounds, added_words


@dataclass(frozen=True)
class Primary:
    """One finished primary trial as the judge reads it: its seed, summary metrics and episode budget."""

    seed: int
    metrics: Mapping[str, float]
    budget: int


class Verdict(Protocol):
    variant: str
    verdict: str
    look: int

    @property
    def decided(self) -> bool: ...


class Judgment(Protocol):
    """What a judge answers (``reporting.claims.Round`` is one): the last look the data reach (-1: none), the
    seeds per variant there, whether the family is done, who needs more seeds, who is still open."""

    look: int
    seeds: int
    done: bool
    needs_seeds: tuple[str, ...]
    verdicts: tuple[Verdict, ...]

    @property
    def open(self) -> tuple[str, ...]: ...


Judge = Callable[[Mapping[str, Sequence[Primary]]], Judgment]
"""Finished primary trials per variant (every variant of the experiment, in seed order) -> the family's judgment."""

DECIDED, AT_MAX, TIME_BUDGET, FAILED, NOT_ASKED = "decided", "max", "time budget", "trials failed", "not asked"


class Rounds:
    """The rounds of one launch: which trials the next round runs, and why the rounds stopped. ``wanted``: the
    variants this launch may run (``--only``); every variant is judged, as the report judges the family."""

    def __init__(
        self,
        experiment: Experiment,
        wanted: Iterable[str],
        judge: Judge,
        started_at: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        assert experiment.rounds is not None
        self.experiment, self.design, self.judge, self.clock = experiment, experiment.rounds, judge, clock
        self.wanted = set(wanted)
        self.started_at = clock() if started_at is None else started_at
        self.judgment: Judgment | None = None
        self.ran: list[dict[str, Any]] = []
        """This launch's rounds: ``{"round", "seeds", "variants", "open"}`` each."""
        self.stopped = ""
        """Why no further round: ``decided``, ``max``, ``time budget``, ``trials failed`` or ``not asked``."""
        self.attempted: set[str] = set()
        self.seeds_run: dict[str, int] = {}
        """Each variant's finished primary seeds when last judged."""
        self.judged_s = 0.0
        """Seconds from the launch's start to the last judgment (the end of the rounds, once they stop)."""
        self.projected_s: float | None = None
        """When the last round considered would have ended, at the last round's pace (``past_budget``)."""

    @property
    def round(self) -> int:
        """The round the finished trials have reached (1: the first; a look made is a round done)."""
        return 1 if self.judgment is None else max(self.judgment.look, 0) + 1

    def primary_trials(self, choices: Mapping[str, Choice]) -> dict[str, list[GridTrial]]:
        """Every variant's primary trials over every seed it may run: at its chosen values where it was tuned
        (``choices``: ``LaunchPlan.choices``), else at its own."""
        values = {name: c.values for name, c in choices.items() if c.tuned}
        values = {v.name: values.get(v.name, {}) for v in self.experiment.variants}
        trials = chosen_trials(self.experiment, values, every_round=True)
        return {name: [t for t in trials if t.variant == name] for name in values}

    def samples(
        self, choices: Mapping[str, Choice], finished: Mapping[str, Mapping[str, float]]
    ) -> dict[str, list[Primary]]:
        """Each variant's finished primary trials in seed order, up to its first seed not finished (a look uses a
        variant's first n seeds)."""
        out: dict[str, list[Primary]] = {}
        for name, trials in self.primary_trials(choices).items():
            out[name] = []
            for trial in trials:
                if trial.key not in finished:
                    break
                out[name].append(Primary(trial.seed, finished[trial.key], trial.config.max_episodes))
        return out

    def next_round(self, choices: Mapping[str, Choice], finished: Mapping[str, Mapping[str, float]]) -> list[GridTrial]:
        """Judge the finished trials; the trials of the next round (none: the rounds are over, ``stopped`` says
        why). ``finished``: trial key -> summary metrics, from the store and this launch."""
        self.judged_s = round(self.clock() - self.started_at, 3)
        samples = self.samples(choices, finished)
        self.seeds_run = {name: len(rows) for name, rows in samples.items()}
        judgment = self.judgment = self.judge(samples)
        if judgment.done:
            self.stopped = DECIDED if not judgment.open else AT_MAX
            return []
        if self.design.max_minutes is not None and self.clock() - self.started_at >= 60 * self.design.max_minutes:
            self.stopped = TIME_BUDGET
            return []
        looks = self.design.looks
        target = next((n for n in looks if n > judgment.seeds), looks[-1]) if judgment.look >= 0 else looks[0]
        primary = self.primary_trials(choices)  # each variant's up to its ``max``
        todo = []
        for name in judgment.needs_seeds:
            if name in self.wanted:
                todo += [t for t in primary[name][:target] if t.key not in finished]
        if not todo:
            self.stopped = NOT_ASKED if set(judgment.needs_seeds) - self.wanted else AT_MAX
            return []
        if self.attempted & {t.key for t in todo}:  # a round's trial failed: running it again would loop
            self.stopped = FAILED
            return []
        if self.past_budget(len(todo)):
            self.stopped = TIME_BUDGET
            return []
        self.attempted |= {t.key for t in todo}
        number = looks.index(target) + 1 if target in looks else self.round + 1
        self.ran.append(
            {
                "round": number,
                "seeds": target,
                "variants": sorted({t.variant for t in todo}),
                "open": list(judgment.open),
                "trials": len(todo),
                "started_s": round(self.clock() - self.started_at, 3),
            }
        )
        return todo

    def past_budget(self, trials: int) -> bool:
        """Whether a round of ``trials`` would end after ``max_minutes`` at the pace of the last round this launch
        ran (its trials over the seconds from its start to this judgment): a round that doubles the seeds late
        in the budget would otherwise overrun it by as much again. Round 2 has no pace yet: only the budget's
        own end stops it."""
        if self.design.max_minutes is None or not self.ran:
            return False
        last = self.ran[-1]
        pace = (self.judged_s - last["started_s"]) / max(last["trials"], 1)
        self.projected_s = round(self.judged_s + pace * trials, 1)
        return self.projected_s > 60 * self.design.max_minutes

    def possible(self, choices: Mapping[str, Choice], known: Collection[str]) -> list[list[GridTrial]]:
        """The trials later rounds may still add, round by round: those of every variant this launch may run
        whose comparison is still open (every variant before the first look; after one, those that need seeds:
        the open ones and their references), up to its ``max`` seeds, beyond the trials ``known`` (finished,
        running or planned). Every open comparison running to ``max``: the most the launch can still run. A
        variant not chosen yet stands in at its own values (``choices``: the chosen ones)."""
        judgment = self.judgment
        if self.stopped or (judgment is not None and judgment.done):
            return []
        asked = self.wanted if judgment is None else set(judgment.needs_seeds) & self.wanted
        looks = self.design.looks
        by_round: dict[int, list[GridTrial]] = {}
        for name, trials in self.primary_trials(choices).items():
            if name not in asked:
                continue
            for index, trial in enumerate(trials):
                if trial.key not in known:
                    look = next((k for k, n in enumerate(looks) if index < n), len(looks) - 1)
                    by_round.setdefault(look, []).append(trial)
        return [by_round[look] for look in sorted(by_round)]

    def finished_trials(
        self, choices: Mapping[str, Choice], finished: Mapping[str, Mapping[str, float]]
    ) -> list[GridTrial]:
        """The primary trials finished or run by this launch: what ``grid.json`` lists beyond round 1."""
        trials = self.primary_trials(choices).values()
        return [t for ts in trials for t in ts if t.key in finished or t.key in self.attempted]

    def announce(self, show: bool) -> tuple[str, int]:
        """Print the line of the round just planned (when ``show``); the progress view's name for it
        (``<experiment> round <r>``) and its number."""
        last = self.ran[-1]
        if show:
            print(
                f"round {last['round']} of at most {len(self.design.looks)}: seeds up to {last['seeds']} for "
                f"{', '.join(last['variants'])} (still open: {', '.join(last['open']) or 'none'})",
                flush=True,
            )
        return f"{self.experiment.name} round {last['round']}", last["round"]

    def document(self) -> dict[str, Any]:
        """``rounds.json`` of a launch run: the design, the rounds this launch ran, why they stopped, and each
        variant's seeds and why it got no more (``reporting.rounds`` words it for the report)."""
        design = self.design
        variants = {}
        judgment = self.judgment
        verdicts = {v.variant: v for v in judgment.verdicts} if judgment else {}
        for variant in self.experiment.variants:
            verdict = verdicts.get(variant.name)
            entry: dict[str, Any] = {"seeds": self.seeds_run.get(variant.name, 0)}
            if verdict is not None:
                entry["verdict"] = verdict.verdict
                if verdict.decided:
                    entry["why"] = f"decided at round {verdict.look + 1}"
                else:
                    entry["why"] = "reached max" if self.stopped in (AT_MAX, DECIDED) else self.stopped
            variants[variant.name] = entry
        return {
            "design": asdict(design),
            "looks": list(design.looks),
            "round": self.round,
            "rounds_run": self.ran,
            "elapsed_s": self.judged_s,
            "projected_s": self.projected_s,
            "stopped": self.stopped,
            "variants": variants,
        }


def dry_run_lines(experiment: Experiment, trials: Sequence[GridTrial]) -> list[str]:
    """``ablate run --dry-run``'s words on the rounds: the first round (the trials listed) and the most."""
    design: SeedRounds | None = experiment.rounds
    if design is None:
        return []
    wanted = {t.variant for t in trials}
    most = sum(len(experiment.max_seeds_of(v)) for v in experiment.variants if v.name in wanted)
    budget = f"; no round that would end after {design.max_minutes:g} minutes" if design.max_minutes else ""
    return [
        f"seeds in rounds: round 1 runs {design.start} seeds per variant (the trials below); after each round, the "
        f"variants whose primary comparison is still open (and their references) get "
        f"{added_words(design.step, design.growth)}, up to "
        f"{design.max} seeds: at most {len(design.looks)} rounds and {most} evaluation trials"
        f"{' at the chosen values' if experiment.tune else ''}{budget}"
    ]
