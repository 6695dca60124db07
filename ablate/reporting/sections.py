"""What the report's sections say, besides the findings: the method (environment, algorithm, seeds, variants),
the results tables, what each comparison changes, and the limitations."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ablate.config import ARCHITECTURE_KNOBS, KNOBS, SETTING_KNOBS, TUNABLE_KNOBS, freeze
from ablate.design import CONFIDENCE, percent
from ablate.measures import INITIAL_EPISODES
from ablate.reporting.blocks import Block, Paragraph, Table
from ablate.reporting.comparisons import LOO_MAX_SEEDS
from ablate.reporting.figures import ablation_window
from ablate.reporting.networks import architecture
from ablate.reporting.prose import say
from ablate.reporting.results import Ablation
from ablate.reporting.settings import own_changes
from ablate.reporting.statistics import N_RESAMPLES, SEPARATED
from ablate.reporting.text import NO_REFS, Refs, _interval, esc, fmt


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
    window, episodes = ablation_window(ablation), _episodes(base.get("episodes_per_update", "?"))
    gamma, resets = base.get("gamma", "?"), ablation.profile.resets_on_score
    blocks: list[Block] = [
        Paragraph(say("sections.environment", env=base["env_id"], window=window, threshold=threshold, budget=budget)),
        Paragraph(say("sections.algorithm", gamma=gamma, episodes=episodes, resets=resets)),
        Paragraph(say("sections.seeds", ran=_seeds_ran(ablation, seeds))),
        Paragraph(say("sections.variants")),
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
    # an env's own knobs are shown where the base sets them to other than their declared default
    away = [k for k, knob in KNOBS.items() if knob.env and k in base and freeze(base[k]) != freeze(knob.default)]
    keep = [*SETTING_KNOBS, *away]
    blocks.append(Table(pd.DataFrame([{k: base[k] for k in keep if k in base}]), "Base hyper-parameters"))
    if ablation.tuning:
        tuned_knobs = ", ".join(k.replace("_", " ") for k in ablation.tuning.get("knobs", {}))
        blocks.append(Paragraph(say("sections.tuned_knobs", appendix=refs.appendix("tuning"), knobs=tuned_knobs)))
    plain_mean = len(ablation.finished) and ablation.finished.groupby("variant").size().min() < 4
    glossary = refs.appendix("glossary")
    blocks.append(
        Paragraph(say("sections.statistics", resamples=N_RESAMPLES, glossary=glossary, plain_mean=plain_mean))
    )
    return blocks


def _episodes_cell(row: pd.Series, stat: str) -> str:
    value, low, high = row[f"episodes_{stat}"], row[f"episodes_{stat}_ci_low"], row[f"episodes_{stat}_ci_high"]
    bound = "≥ " if row[f"{stat}_censored"] else ""
    return f"{bound}{fmt(value)} {_interval(low, high, 0, int(row.seeds_run))}"


def _stat_cell(row: pd.Series, prefix: str, ci: str = "") -> str:
    low = row.get(f"{ci or prefix}_ci_low", np.nan)
    high = row.get(f"{ci or prefix}_ci_high", np.nan)
    return f"{fmt(row.get(prefix, np.nan), 1)} {_interval(low, high, 1, int(row.seeds_run))}"


def convergence_blocks(ablation: Ablation, table: pd.DataFrame) -> list[Block]:
    """The Results appendix: episodes to solve, returns, episodes to reach return levels, one table each."""
    parts: list[Block] = []
    ran = table[table.seeds_run > 0]
    ci = f"[{percent(CONFIDENCE)} CI]"  # every interval's column header
    if ablation.threshold is not None and len(ran):
        rows = [
            {
                "variant": esc(row.variant),
                "seeds": int(row.seeds_run),
                "solved": f"{int(row.solved)}/{int(row.seeds_run)}",
                f"episodes to solve, median {ci}": _episodes_cell(row, "median"),
                f"episodes to solve, IQM {ci}": _episodes_cell(row, "iqm"),
                "env steps to solve (median of solved)": fmt(row.env_steps_to_solve_median),
                "seconds to solve (median of solved)": fmt(row.wall_s_to_solve_median, 1),
            }
            for _, row in ran.iterrows()
        ]
        parts += [Paragraph(say("sections.episodes_to_solve")), Table(pd.DataFrame(rows), "Episodes to solve")]
    budgets = ablation.budgets
    rows = []
    for _, row in ran.iterrows():
        entry = {
            "variant": esc(row.variant),
            f"untrained (first {INITIAL_EPISODES} episodes)": fmt(row.get("initial_return_iqm", np.nan), 1),
        }
        for episodes in budgets:
            entry[f"after {episodes:,} episodes {ci}"] = _stat_cell(row, f"return_at_{episodes}_iqm")
        entry[f"improvement over untrained {ci}"] = _stat_cell(row, "improvement_iqm")
        entry[f"AUC {ci}"] = _stat_cell(row, "auc_iqm", ci="auc")
        rows.append(entry)
    parts += [
        Paragraph(say("sections.returns", window=ablation_window(ablation))),
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
        parts += [Paragraph(say("sections.levels")), Table(pd.DataFrame(rows), "Episodes to reach a return level")]
    return parts


def changed_settings(ablation: Ablation, variant: str) -> list[str]:
    """The knobs ``variant`` sets otherwise than its reference, in words. A tuned knob's chosen values are not among
    them where they differ: each variant running at its own chosen values is the design (Method), not a second
    change; Appendix B gives the values and the learning-rate appendix compares the variants at the shared one."""
    return [k.replace("_", " ") for k in ablation.changes(variant, ablation.reference(variant))]


def comparison_intro(ablation: Ablation, full: bool = False) -> list[str]:
    """What each comparison changes. ``full``: the findings' opening (each variant against what); otherwise only
    the sentence naming the comparisons that change more than one knob, or nothing when there are none."""
    others = [v for v in ablation.variants if v != ablation.baseline]
    several = {v: changed_settings(ablation, v) for v in others}
    several = [(v, ablation.reference(v), words) for v, words in several.items() if len(words) > 1]
    confounded = [say("sections.confounded", comparisons=several)] if several else []
    if not full:
        return confounded
    extends = [(v, ablation.reference(v)) for v in _extends(ablation)]
    return [*confounded, say("sections.against", baseline=ablation.baseline, extends=extends)]


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
    separated = compare[compare.verdict.isin(list(SEPARATED))] if compare is not None and len(compare) else []
    claims = len(separated) > 0
    checked = claims and "loo_checked" in compare and bool(separated.loo_checked.astype(bool).any())
    rounds = bool(ablation.launch.get("rounds"))
    facts = dict(fewest=fewest, most=seeds, rounds=rounds, checked=checked, claims=claims, loo=LOO_MAX_SEEDS)
    out.append(("seeds", say("sections.seeds_limitation", **facts)))
    tuned = [k for k in TUNABLE_KNOBS if k in base]
    touched = [v["name"] for v in variants if any(k in v["overrides"] for k in tuned)]
    architectures = [v for v in variants if any(k in ARCHITECTURE_KNOBS for k in v["overrides"])]
    if ablation.tuning:
        tuning = ablation.tuning
        n_candidates = max((len(c) for c in tuning.get("knobs", {}).values()), default=0)
        n_seeds = len(tuning.get("seeds", []))
        out.append(
            ("tuning", say("sections.tuning", candidates=n_candidates, seeds=n_seeds, appendix=refs.appendix("tuning")))
        )
    elif tuned and architectures and len(touched) < len(variants):
        knobs = ", ".join(f"{k.replace('_', ' ')} {base[k]}" for k in tuned)
        out.append(("shared", say("sections.shared", touched=touched, knobs=knobs)))
    counts = table.parameter_count.dropna()
    if len(counts) and counts.min() > 0 and counts.max() / counts.min() >= 10:
        figure = refs.figure("performance_vs_parameters")
        out.append(("capacity", say("sections.capacity", fewest=counts.min(), most=counts.max(), figure=figure)))
    for variant in ablation.variants:
        reference = ablation.reference(variant)
        words = changed_settings(ablation, variant)
        if variant != ablation.baseline and len(words) > 1:
            out.append(("confound", say("sections.confound", variant=variant, reference=reference, words=words)))
    finished = ablation.finished
    if ablation.threshold is not None and len(finished) and (finished.solved != 1).any():
        unsolved = int((finished.solved != 1).sum())
        out.append(("censoring", say("sections.censoring", unsolved=unsolved, trials=len(finished))))
    if ablation.threshold is None:
        out.append(("threshold", say("sections.threshold")))
    machine = ablation.launch.get("environment", {}).get("machine", "the machine")
    out.append(("wallclock", say("sections.wallclock", machine=machine)))
    if videos:
        frames = base.get("video_max_frames", 500)
        out.append(("videos", say("sections.videos", sampling=ablation.profile.sampling_video, frames=frames)))
    out.append(("scope", say("sections.scope", env=ablation.env_id, budget=base.get("max_episodes"))))
    return out
