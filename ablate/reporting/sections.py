"""What the report's sections say, besides the findings: the method (environment, algorithm, seeds, variants),
the results tables, what each comparison changes, and the limitations."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ablate.config import ARCHITECTURE_KNOBS, KNOBS, SETTING_KNOBS, TUNABLE_KNOBS, freeze
from ablate.design import ALPHA, CONFIDENCE, percent
from ablate.measures import INITIAL_EPISODES
from ablate.reporting.blocks import Block, Paragraph, Table
from ablate.reporting.comparisons import LOO_MAX_SEEDS
from ablate.reporting.figures import ablation_window
from ablate.reporting.networks import architecture
from ablate.reporting.results import Ablation
from ablate.reporting.settings import own_changes
from ablate.reporting.statistics import N_RESAMPLES, SEPARATED
from ablate.reporting.text import NO_REFS, Refs, _interval, esc, fmt, joined, setting_value


def _setting_groups(overrides: dict) -> list[str]:
    """The separate settings a variant changes (an architecture's knobs count as one)."""
    groups = sorted({"architecture" if k in ARCHITECTURE_KNOBS else k for k in overrides})
    return groups


def _set_away(base: dict, knob: str, default: object) -> bool:
    """Whether the base sets ``knob`` to other than its declared default (an env's own knobs are shown then)."""
    return knob in base and freeze(base[knob]) != freeze(default)


def _extends(ablation: Ablation) -> list[str]:
    """The variants compared with another variant than the baseline, because they extend its changes."""
    return [v for v in ablation.variants if v != ablation.baseline and ablation.reference(v) != ablation.baseline]


def _role(ablation: Ablation, variant: str) -> str:
    if variant == ablation.baseline:
        return "baseline (reference)"
    users = [v for v in ablation.variants if v != variant and ablation.reference(v) == variant]
    role = [f"compared with {esc(ablation.reference(variant))}"]
    return "; ".join(role + ([f"reference of {', '.join(map(esc, users))}"] if users else []))


def _episodes(count) -> str:
    """``1 episode``, ``32 episodes``."""
    return f"{count} episode{'' if str(count) == '1' else 's'}"


def _seed_ranges(seeds: list[int]) -> str:
    """``0-4, 10``: consecutive seeds as ranges."""
    ranges: list[list[int]] = []
    for seed in sorted(seeds):
        if ranges and seed == ranges[-1][1] + 1:
            ranges[-1][1] = seed
        else:
            ranges.append([seed, seed])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in ranges)


def _seeds_ran(ablation: Ablation, planned: list[int]) -> str:
    """The evaluation seeds that ran, per variant: ``5 per variant (0-4)``, or with rounds ``15 to 30 per variant
    (0-29: 5 at first, more in rounds while one was open)``; the file's seeds where none finished."""
    done = ablation.finished
    if not len(done):
        return f"{len(planned)} per variant ({_seed_ranges(planned)})"
    fewest, most = ablation.seed_span
    seeds = _seed_ranges([int(s) for s in done.seed.unique()])
    if fewest == most:
        return f"{most} per variant ({seeds})"
    if not ablation.launch.get("rounds"):
        return f"{fewest} to {most} per variant ({seeds})"
    return f"{fewest} to {most} per variant ({seeds}: {len(planned)} at first, more in rounds while one was open)"


def method_blocks(ablation: Ablation, table: pd.DataFrame, refs: Refs = NO_REFS) -> list[Block]:
    """Appendix A: the environment, algorithm, seeds, variants (a table), base settings (a table), statistics."""
    base = ablation.grid["base"]
    threshold = ablation.threshold
    seeds = ablation.grid["seeds"]
    budget = int(base.get("max_episodes", 0))
    if threshold is not None:
        env = (
            f"**Environment.** `{esc(base['env_id'])}`. Solved when the mean return over "
            f"{ablation_window(ablation)} consecutive episodes reaches {threshold:g}; a trial stops then, or at "
            f"its budget of {budget:,} episodes."
        )
    else:
        env = (
            f"**Environment.** `{esc(base['env_id'])}`. No solve threshold: every trial runs its whole budget of "
            f"{budget:,} episodes, and variants are compared on their returns (area under the curve, the return "
            "after fixed budgets, episodes to reach return levels, the improvement over the untrained policy)."
        )
    reset = " The discounted return restarts at every point scored." if ablation.profile.resets_on_score else ""
    blocks: list[Block] = [
        Paragraph(env),
        Paragraph(
            "**Algorithm.** REINFORCE (Williams, 1992), the vanilla policy gradient: actions sampled from the softmax "
            "of the policy's logits; each episode's rewards discounted (gamma "
            f"{base.get('gamma', '?')}), the returns normalised by mean and standard deviation across the update's "
            "batch; loss = softmax cross-entropy of the taken actions weighted by those returns; one Adam step per "
            f"update of {_episodes(base.get('episodes_per_update', '?'))}. L2 is a loss term over weight matrices; "
            f"dropout is active in updates and off while acting.{reset}"
        ),
        Paragraph(
            f"**Seeds.** {_seeds_ran(ablation, seeds)}: each seeds torch, the action sampler and the environment."
        ),
        Paragraph("**Variants.** Each changes the listed knobs over the base; every other knob is the base's."),
    ]
    rows = []
    for variant in ablation.grid["variants"]:
        params = ablation.params.get(variant["name"], {})
        count = table.loc[table.variant == variant["name"], "parameter_count"]
        changed = own_changes(ablation.grid, variant["name"])  # by value: a knob at the base's value is no change
        overrides = ", ".join(f"{k} = {v}" for k, v in changed.items()) or "nothing (the base)"
        rows.append(
            {
                "variant": esc(variant["name"]),
                "role": _role(ablation, variant["name"]),
                "changes": esc(overrides),
                "policy": esc(architecture(params, ablation.env_id)) if params else "–",
                "parameters": fmt(count.iloc[0]) if len(count) and not pd.isna(count.iloc[0]) else "–",
            }
        )
    blocks += [Table(pd.DataFrame(rows), "Variants"), Paragraph("**Base hyper-parameters.**")]
    keep = [*SETTING_KNOBS, *(k for k, knob in KNOBS.items() if knob.env and _set_away(base, k, knob.default))]
    blocks.append(Table(pd.DataFrame([{k: base[k] for k in keep if k in base}]), "Base hyper-parameters"))
    if ablation.tuning:
        tuned_knobs = ", ".join(k.replace("_", " ") for k in ablation.tuning.get("knobs", {}))
        blocks.append(
            Paragraph(
                f"Tuned per variant (see {refs.appendix('tuning')}): {esc(tuned_knobs)}; the base value above is "
                "the untuned one."
            )
        )
    blocks.append(
        Paragraph(
            "**Statistics.** Every number is over seeds: interquartile means (IQM) and medians with "
            f"{percent(CONFIDENCE)} percentile "
            f"bootstrap intervals ({N_RESAMPLES:,} resamples, seeded). Unsolved seeds are censored at the budget, "
            "never dropped: a statistic that uses one is a lower bound, marked ≥. "
            f"{refs.appendix('glossary')} defines each term."
            + (
                " With fewer than 4 seeds the IQM trims nothing: it is the plain mean, and the findings call it so."
                if len(ablation.finished) and ablation.finished.groupby("variant").size().min() < 4
                else ""
            )
        )
    )
    return blocks


def _episodes_cell(row: pd.Series, stat: str) -> str:
    value, low, high = row[f"episodes_{stat}"], row[f"episodes_{stat}_ci_low"], row[f"episodes_{stat}_ci_high"]
    bound = "≥ " if row[f"{stat}_censored"] else ""
    return f"{bound}{fmt(value)} {_interval(low, high, 0, int(row.seeds_run))}"


def _stat_cell(row: pd.Series, prefix: str, digits: int = 1, low_key: str = "", high_key: str = "") -> str:
    low = row.get(low_key or f"{prefix}_ci_low", np.nan)
    high = row.get(high_key or f"{prefix}_ci_high", np.nan)
    return f"{fmt(row.get(prefix, np.nan), digits)} {_interval(low, high, digits, int(row.seeds_run))}"


def convergence_blocks(ablation: Ablation, table: pd.DataFrame) -> list[Block]:
    """The Results appendix: episodes to solve, returns, episodes to reach return levels, one table each."""
    parts: list[Block] = []
    ran = table[table.seeds_run > 0]
    if ablation.threshold is not None and len(ran):
        rows = [
            {
                "variant": esc(row.variant),
                "seeds": int(row.seeds_run),
                "solved": f"{int(row.solved)}/{int(row.seeds_run)}",
                f"episodes to solve, median [{percent(CONFIDENCE)} CI]": _episodes_cell(row, "median"),
                f"episodes to solve, IQM [{percent(CONFIDENCE)} CI]": _episodes_cell(row, "iqm"),
                "env steps to solve (median of solved)": fmt(row.env_steps_to_solve_median),
                "seconds to solve (median of solved)": fmt(row.wall_s_to_solve_median, 1),
            }
            for _, row in ran.iterrows()
        ]
        parts += [
            Paragraph(
                "**Episodes to solve.** Unsolved seeds count as the budget (censored); a statistic that uses such a "
                "value is a lower bound, marked ≥, and its interval's upper end is no bound at all. Steps and "
                "seconds are over solved seeds only (– where none solved); seconds come from CPUs the trials shared."
            ),
            Table(pd.DataFrame(rows), "Episodes to solve"),
        ]
    budgets = ablation.budgets
    rows = []
    for _, row in ran.iterrows():
        entry = {
            "variant": esc(row.variant),
            f"untrained (first {INITIAL_EPISODES} episodes)": fmt(row.get("initial_return_iqm", np.nan), 1),
        }
        for episodes in budgets:
            entry[f"after {episodes:,} episodes [{percent(CONFIDENCE)} CI]"] = _stat_cell(
                row, f"return_at_{episodes}_iqm"
            )
        entry[f"improvement over untrained [{percent(CONFIDENCE)} CI]"] = _stat_cell(row, "improvement_iqm")
        entry[f"AUC [{percent(CONFIDENCE)} CI]"] = _stat_cell(
            row, "auc_iqm", low_key="auc_ci_low", high_key="auc_ci_high"
        )
        rows.append(entry)
    parts += [
        Paragraph(
            f"**Returns.** IQM over seeds of the rolling mean return ({ablation_window(ablation)} episodes) of the "
            "untrained policy, after fixed episode budgets (a seed that stopped because it solved keeps its last "
            "value), the improvement over the untrained policy, and the area under the learning curve (AUC: the mean "
            "rolling return over the whole budget, which rewards learning early)."
        ),
        Table(pd.DataFrame(rows), "Returns"),
    ]
    if ablation.levels and len(ran):
        rows = []
        for _, row in ran.iterrows():
            entry = {"variant": esc(row.variant)}
            for level in ablation.levels:
                key = f"episodes_to_{level:g}"
                if f"{key}_median" not in row or pd.isna(row[f"{key}_median"]):
                    entry[f"episodes to reach {level:g}"] = "–"
                    continue
                bound = "≥ " if row[f"{key}_median_censored"] else ""
                entry[f"episodes to reach {level:g} (median; seeds that reached it)"] = (
                    f"{bound}{fmt(row[f'{key}_median'])} ({int(row[f'{key}_reached'])}/{int(row.seeds_run)})"
                )
            rows.append(entry)
        parts += [
            Paragraph(
                "**Episodes to reach a return level.** The first episode at which the rolling mean return reaches the "
                "level; a seed that never does counts as the budget (censored, ≥)."
            ),
            Table(pd.DataFrame(rows), "Episodes to reach a return level"),
        ]
    return parts


def changed_settings(ablation: Ablation, variant: str) -> list[str]:
    """What ``variant`` runs differently from its reference, in words: each knob it sets otherwise, and each tuned
    knob whose chosen values differ (``learning rate 0.03 against 0.1``): a comparison at two tuned values changes
    the tuned knob too."""
    reference = ablation.reference(variant)
    words = [k.replace("_", " ") for k in ablation.changes(variant, reference)]
    if ablation.tuning:
        from ablate.reporting.tuning import chosen_values, same_value

        mine, theirs = chosen_values(ablation.tuning, variant), chosen_values(ablation.tuning, reference)
        for knob, value in mine.items():
            if knob in ablation.changes(variant, reference) or same_value(value, theirs.get(knob)):
                continue
            words.append(f"{knob.replace('_', ' ')} ({setting_value(value)} against {setting_value(theirs.get(knob))})")
    return words


def comparison_intro(ablation: Ablation, full: bool = False) -> list[str]:
    """What each comparison changes. ``full``: the findings' opening (each variant against what); otherwise only
    the sentence naming the comparisons that change more than one knob, or nothing when there are none."""
    others = [v for v in ablation.variants if v != ablation.baseline]
    several = {v: changed_settings(ablation, v) for v in others}
    several = {v: words for v, words in several.items() if len(words) > 1}
    confounded = (
        [
            f"{len(several)} comparison{'s change' if len(several) > 1 else ' changes'} more than one knob, so "
            f"{'their differences' if len(several) > 1 else 'its difference'} cannot be put down to one of them: "
            + "; ".join(
                f"{esc(v)} against {esc(ablation.reference(v))} changes {joined(words)}" for v, words in several.items()
            )
            + "."
        ]
        if several
        else []
    )
    if not full:
        return confounded
    extends = _extends(ablation)
    if not extends:
        head = f"Each variant against {esc(ablation.baseline)}"
    else:
        pairs = ", ".join(f"{esc(v)} against {esc(ablation.reference(v))}" for v in extends)
        head = (
            f"Each variant against its reference: {esc(ablation.baseline)}, or, for a variant that adds one change "
            f"to another variant's, that variant ({pairs})"
        )
    if confounded:
        return [confounded[0], head]
    return [head]


def limitations(
    ablation: Ablation,
    table: pd.DataFrame,
    compare: pd.DataFrame | None = None,
    videos: bool = True,
    refs: Refs = NO_REFS,
) -> list[tuple[str, str]]:
    """What the experiment's design itself limits, read off the grid and the results: (kind, text) pairs, the
    kind naming the limitation (``seeds``, ``tuning``, ``shared``, ``capacity``, ``confound``, ``censoring``,
    ``threshold``, ``wallclock``, ``videos``, ``scope``) so the body can print the ones that matter. ``videos``:
    whether the report shows any (no limitation of videos there are none of)."""
    base, variants = ablation.grid["base"], ablation.grid["variants"]
    out: list[tuple[str, str]] = []
    fewest, seeds = ablation.seed_span
    checked = (
        compare is not None
        and len(compare) > 0
        and "loo_checked" in compare
        and bool(compare[compare.verdict.isin(list(SEPARATED))].loo_checked.astype(bool).any())
    )
    claims = compare is not None and len(compare) > 0 and bool(compare.verdict.isin(list(SEPARATED)).any())
    if checked:
        survive = (
            "the exploratory comparisons in the appendix say whether each survives leaving out any one seed; the "
            "primary claims rest on every seed, under the family's correction."
        )
    elif claims and seeds > LOO_MAX_SEEDS:
        survive = (
            f"with more than {LOO_MAX_SEEDS} seeds a side, one seed is under {percent(1 / LOO_MAX_SEEDS)} of a sample, "
            "and the check of "
            "leaving each out is not made: each claim rests on every seed, under the family's correction."
        )
    elif claims:
        survive = (
            "leaving out one of so few seeds leaves too few for any claim, so no claim here was checked that way: "
            "each rests on every seed."
        )
    else:
        survive = "no comparison here reached a claim, so no claim was checked by leaving out a seed."
    out.append(
        (
            "seeds",
            (
                f"**{seeds} seed{'s' if seeds != 1 else ''} per variant.** "
                if fewest == seeds
                else f"**{fewest} to {seeds} seeds per variant**"
                + (
                    " (in rounds: until its primary comparison was decided or the cap was reached). "
                    if ablation.launch.get("rounds")
                    else ". "
                )
            )
            + "Percentile bootstrap intervals (the exploratory ones) over few seeds are too narrow more often than "
            f"{percent(ALPHA)} "
            "of the time, and one unusual seed can move an IQM; "
            + survive
            + (" With one seed no interval can be computed and no comparison is claimed." if seeds < 2 else ""),
        )
    )
    tuned = [k for k in TUNABLE_KNOBS if k in base]
    touched = [v["name"] for v in variants if any(k in v["overrides"] for k in tuned)]
    architectures = [v for v in variants if "architecture" in _setting_groups(v["overrides"])]
    if ablation.tuning:
        tuning = ablation.tuning
        n_candidates = max((len(c) for c in tuning.get("knobs", {}).values()), default=0)
        n_seeds = len(tuning.get("seeds", []))
        out.append(
            (
                "tuning",
                f"**Tuned over {n_candidates} candidates on {n_seeds} tuning seed{'s' if n_seeds != 1 else ''}.** "
                "Each variant's choice is the best of a few candidates on a few seeds: a value between or beyond them "
                f"could do better ({refs.appendix('tuning')} flags choices at the edge of the grid), and so few seeds "
                "choose "
                "noisily. The evaluation seeds never took part in the choice. Knobs not tuned are the base's for "
                "every variant.",
            )
        )
    elif tuned and architectures and len(touched) < len(variants):
        knobs = ", ".join(f"{k.replace('_', ' ')} {base[k]}" for k in tuned)
        out.append(
            (
                "shared",
                "**One training setting for all architectures.** Every variant"
                + (f" except {', '.join(esc(t) for t in touched)}" if touched else "")
                + f" trains with the base {knobs}, chosen for the baseline and not tuned per architecture: one that "
                "would learn better at its own learning rate is judged at the baseline's.",
            )
        )
    counts = table.parameter_count.dropna()
    if len(counts) and counts.min() > 0 and counts.max() / counts.min() >= 10:
        out.append(
            (
                "capacity",
                f"**Parameter counts span {fmt(counts.min())} to {fmt(counts.max())}** "
                f"({counts.max() / counts.min():,.0f}x): a difference between architectures mixes capacity with "
                "optimisation (one learning rate moves small and large networks differently); "
                f"{refs.figure('performance_vs_parameters')} plots performance against size.",
            )
        )
    for variant in ablation.variants:
        reference = ablation.reference(variant)
        words = changed_settings(ablation, variant)
        if variant != ablation.baseline and len(words) > 1:
            out.append(
                (
                    "confound",
                    f"**{esc(variant)} changes {len(words)} knobs at once** against {esc(reference)} "
                    f"({joined(words)}): its difference from {esc(reference)} cannot be attributed to any one of them.",
                )
            )
    finished = ablation.finished
    if ablation.threshold is not None and len(finished) and (finished.solved != 1).any():
        unsolved = int((finished.solved != 1).sum())
        out.append(
            (
                "censoring",
                f"**Censoring.** {unsolved:,} of {len(finished):,} trials did not solve within the budget; for them "
                "episodes to solve is only known to exceed it, so statistics that use them are bounds, and a longer "
                "budget could reorder those variants.",
            )
        )
    if ablation.threshold is None:
        out.append(
            (
                "threshold",
                "**No solve threshold.** No trial stops early; comparisons rest on returns within this budget, and a "
                "longer budget could reorder variants that are still improving.",
            )
        )
    out.append(
        (
            "wallclock",
            "**Wall-clock times come from contended CPUs.** Trials ran several at a time on "
            f"{esc(ablation.launch.get('environment', {}).get('machine', 'the machine'))}, beside the driver and "
            "its tracking; seconds move between runs and machines. Compare variants on episodes; read seconds as "
            "rough cost.",
        )
    )
    if videos and ablation.profile.sampling_video:
        out.append(
            (
                "videos",
                "**Videos show one stretch of play** per chosen seed (the trained policy sampling its actions, up to "
                f"{fmt(base.get('video_max_frames', 500))} frames): a single sample, not an average.",
            )
        )
    elif videos:
        out.append(
            (
                "videos",
                "**Videos show one greedy episode** per chosen seed (the most likely action at every step, after "
                "training): a single episode, not an average, and not the sampling policy that was trained.",
            )
        )
    out.append(
        (
            "scope",
            f"**One environment and budget** ({esc(ablation.env_id)}, {fmt(base.get('max_episodes'))} "
            "episodes): the findings say nothing about other tasks or longer training.",
        )
    )
    return out
