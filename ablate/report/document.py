"""Write ``reports/<experiment>/``: report.md, a self-contained report.html, report.pdf, figures, tables, videos.

Reads only from the tracking store (through ``results``), so it works from any machine that reaches it. A
report is built in a temporary folder and swapped in whole: a failed build never replaces a good report.
"""

from __future__ import annotations

import argparse
import base64
import html
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import markdown
import numpy as np
import pandas as pd

from ablate.config import ConfigError, load_experiment
from ablate.report.figures import (
    Figure,
    ablation_window,
    figure_improvement,
    figure_observation,
    figure_overview,
    figure_parameters,
    figure_per_seed,
    figure_small_multiples,
    figure_wallclock,
)
from ablate.report.figures import esc as _esc
from ablate.report.figures import fmt as _fmt
from ablate.report.reader import RunReader
from ablate.report.results import (
    BETTER,
    CONFIDENCE,
    INITIAL_EPISODES,
    N_RESAMPLES,
    NO_CLAIM,
    WORSE,
    Ablation,
    NoResults,
    comparisons,
    convergence_table,
    load_ablation,
    select,
    smallest_p_value,
)

# Knobs that together make one architecture: a variant changing several of them changes one thing.
ARCHITECTURE_KNOBS = {"architecture", "hidden_sizes", "depth", "width", "history", "conv_channels", "kernel_size"}


def _pct(x: float) -> str:
    return f"{int(round(100 * x))}%"


def _signed(x: float, digits: int = 1) -> str:
    return "–" if pd.isna(x) else f"{x:+,.{digits}f}"


def _signed_pct(x: float) -> str:
    if pd.isna(x):
        return "–"
    value = int(round(100 * x))
    return f"{value:+d}%" if value else "0%"


def _interval(low: float, high: float, digits: int = 0, n: int | None = None) -> str:
    if pd.isna(low) or pd.isna(high):
        return "[no interval: 1 seed]" if n == 1 else "[no interval]"
    return f"[{_fmt(low, digits)}, {_fmt(high, digits)}]"


# --- text ------------------------------------------------------------------------------------------------
def _is_text(values) -> bool:
    """A column of words (left-aligned) rather than of numbers, intervals and counts (right-aligned)."""
    return any(re.search(r"[A-Za-z]", re.sub(r"\[[^\]]*\]|\([^)]*\)", "", str(v))) for v in values)


def _markdown_table(frame: pd.DataFrame) -> str:
    """A Markdown table: text columns left-aligned, numbers right-aligned."""
    header = "| " + " | ".join(frame.columns) + " |"
    rule = "| " + " | ".join(":---" if _is_text(frame[c]) else "---:" for c in frame.columns) + " |"
    rows = ["| " + " | ".join(str(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join([header, rule, *rows])


def _sizes(params: dict[str, str], key: str = "model.hidden_sizes") -> list[int]:
    text = params.get(key, "[]").strip("[]() ")
    return [int(x) for x in text.replace(",", " ").split()]


def architecture(params: dict[str, str], env_id: str) -> str:
    """The policy in words, as ``policies.py`` builds it for ``env_id``."""
    arch = params.get("model.architecture", "mlp")
    activation = params.get("model.activation", "relu")
    hidden = _sizes(params)
    dense = f"dense {' → '.join(map(str, hidden))} ({activation})" if hidden else "no hidden layer"
    if env_id.startswith("ALE/Pong"):
        if arch == "cnn":
            text = (
                f"2-D CNN over the 80×80 frame difference: conv 16@7×7 stride 4, 32@5×5 stride 2, "
                f"48@3×3 stride 2 ({activation}), then {dense}"
            )
        elif hidden:
            text = f"MLP over the 6,400 pixels of the 80×80 frame difference: {dense}"
        else:
            text = "linear policy over the 6,400 pixels of the 80×80 frame difference (no hidden layer)"
        actions = {"all": "6 actions", "move": "2 actions (up, down)"}.get(params.get("action_set", ""), "")
        text += f"; {actions}" if actions else ""
    elif arch == "cnn":
        conv = _sizes(params, "model.conv_channels")
        text = (
            f"1-D CNN over the last {params.get('model.history')} observations: conv "
            f"{', '.join(map(str, conv))} channels, kernel {params.get('model.kernel_size')} along time "
            f"({activation}), then {dense}"
        )
    else:
        text = f"MLP, {dense}" if hidden else "linear policy: observation → action logits, no hidden layer"
    if float(params.get("model.dropout", 0) or 0) > 0:
        text += f"; dropout {params['model.dropout']}"
    if float(params.get("l2", 0) or 0) > 0:
        text += f"; L2 {params['l2']}"
    return text


def _setting_groups(overrides: dict) -> list[str]:
    """The separate settings a variant changes (an architecture's knobs count as one)."""
    groups = sorted({"architecture" if k in ARCHITECTURE_KNOBS else k for k in overrides})
    return groups


def _sampling_videos(ablation: Ablation) -> bool:
    """Pong's end-of-trial videos are of the sampling policy (``trial.record_pong_episode``), others greedy."""
    return ablation.env_id.startswith("ALE/Pong")


def _extends(ablation: Ablation) -> list[str]:
    """The variants compared with another variant than the baseline, because they extend its changes."""
    return [v for v in ablation.variants if v != ablation.baseline and ablation.reference(v) != ablation.baseline]


def _role(ablation: Ablation, variant: str) -> str:
    if variant == ablation.baseline:
        return "baseline (reference)"
    users = [v for v in ablation.variants if v != variant and ablation.reference(v) == variant]
    role = [f"compared with {_esc(ablation.reference(variant))}"] if variant in _extends(ablation) else []
    return "; ".join(role + ([f"reference of {', '.join(map(_esc, users))}"] if users else []))


def _findings_intro(ablation: Ablation) -> str:
    extends = _extends(ablation)
    if not extends:
        return f"Each variant against {_esc(ablation.baseline)}"
    pairs = ", ".join(f"{_esc(v)} against {_esc(ablation.reference(v))}" for v in extends)
    return (
        f"Each variant against its reference: {_esc(ablation.baseline)}, or, for a variant that adds one change to "
        f"another variant's, that variant, so each comparison isolates one change ({pairs})"
    )


def _method(ablation: Ablation, table: pd.DataFrame) -> str:
    base = ablation.grid["base"]
    threshold = ablation.threshold
    seeds = ablation.grid["seeds"]
    budget = int(base.get("max_episodes", 0))
    if threshold is not None:
        env = (
            f"**Environment.** `{_esc(base['env_id'])}`. Solved when the mean return over "
            f"{ablation_window(ablation)} consecutive episodes reaches {threshold:g}; a trial stops then, or at "
            f"its budget of {budget:,} episodes."
        )
    else:
        env = (
            f"**Environment.** `{_esc(base['env_id'])}`. No solve threshold: every trial runs its whole budget of "
            f"{budget:,} episodes, and variants are compared on their returns (area under the curve, the return "
            "after fixed budgets, episodes to reach return levels, the improvement over the untrained policy)."
        )
    reset = (
        " Pong's discounted return restarts at every point scored." if ablation.env_id.startswith("ALE/Pong") else ""
    )
    lines = [
        env,
        "",
        "**Algorithm.** REINFORCE (Williams, 1992), the vanilla policy gradient: actions sampled from the softmax "
        "of the policy's logits; each episode's rewards discounted (gamma "
        f"{base.get('gamma', '?')}), the returns normalised by mean and standard deviation across the update's "
        "batch; loss = softmax cross-entropy of the taken actions weighted by those returns; one Adam step per "
        f"update of {base.get('episodes_per_update', '?')} episodes. L2 is a loss term over weight matrices; "
        f"dropout is active in updates and off while acting.{reset}",
        "",
        f"**Seeds.** {len(seeds)} per variant ({', '.join(map(str, seeds))}): each seeds torch, the action sampler "
        "and the environment.",
        "",
        "**Variants.** Each changes the listed knobs over the base; every other knob is the base's.",
        "",
    ]
    rows = []
    for variant in ablation.grid["variants"]:
        params = ablation.params.get(variant["name"], {})
        count = table.loc[table.variant == variant["name"], "parameter_count"]
        overrides = ", ".join(f"{k} = {v}" for k, v in variant["overrides"].items()) or "nothing (the base)"
        rows.append(
            {
                "variant": _esc(variant["name"]),
                "role": _role(ablation, variant["name"]),
                "changes": _esc(overrides),
                "policy": _esc(architecture(params, ablation.env_id)) if params else "–",
                "parameters": _fmt(count.iloc[0]) if len(count) and not pd.isna(count.iloc[0]) else "–",
            }
        )
    lines.append(_markdown_table(pd.DataFrame(rows)))
    lines += ["", "**Base hyper-parameters.**", ""]
    keep = ("learning_rate", "gamma", "episodes_per_update", "max_episodes", "solve_window", "l2")
    if ablation.env_id.startswith("ALE/Pong"):
        keep += ("action_set", "frameskip", "max_episode_steps")
    lines.append(_markdown_table(pd.DataFrame([{k: base[k] for k in keep if k in base}])))
    lines += [
        "",
        "**Statistics.** Every number is over seeds: interquartile means (IQM) and medians with 95% percentile "
        f"bootstrap intervals ({N_RESAMPLES:,} resamples, seeded). Unsolved seeds are censored at the budget, never "
        "dropped: a statistic that uses one is a lower bound, marked ≥. The glossary at the end defines each term.",
    ]
    return "\n".join(lines)


def _episodes_cell(row: pd.Series, stat: str) -> str:
    value, low, high = row[f"episodes_{stat}"], row[f"episodes_{stat}_ci_low"], row[f"episodes_{stat}_ci_high"]
    bound = "≥ " if row[f"{stat}_censored"] else ""
    return f"{bound}{_fmt(value)} {_interval(low, high, 0, int(row.seeds_run))}"


def _stat_cell(row: pd.Series, prefix: str, digits: int = 1, low_key: str = "", high_key: str = "") -> str:
    low = row.get(low_key or f"{prefix}_ci_low", np.nan)
    high = row.get(high_key or f"{prefix}_ci_high", np.nan)
    return f"{_fmt(row.get(prefix, np.nan), digits)} {_interval(low, high, digits, int(row.seeds_run))}"


def _convergence_markdown(ablation: Ablation, table: pd.DataFrame) -> str:
    parts = []
    ran = table[table.seeds_run > 0]
    if ablation.threshold is not None and len(ran):
        rows = [
            {
                "variant": _esc(row.variant),
                "seeds": int(row.seeds_run),
                "solved": f"{int(row.solved)}/{int(row.seeds_run)}",
                "episodes to solve, median [95% CI]": _episodes_cell(row, "median"),
                "episodes to solve, IQM [95% CI]": _episodes_cell(row, "iqm"),
                "env steps to solve (median of solved)": _fmt(row.env_steps_to_solve_median),
                "seconds to solve (median of solved)": _fmt(row.wall_s_to_solve_median, 1),
            }
            for _, row in ran.iterrows()
        ]
        parts += [
            "**Episodes to solve.** Unsolved seeds count as the budget (censored); a statistic that uses such a "
            "value is a lower bound, marked ≥, and its interval's upper end is no bound at all. Steps and "
            "seconds are over solved seeds only (– where none solved); seconds come from CPUs the trials shared.",
            "",
            _markdown_table(pd.DataFrame(rows)),
            "",
        ]
    budgets = ablation.budgets
    rows = []
    for _, row in ran.iterrows():
        entry = {
            "variant": _esc(row.variant),
            f"untrained (first {INITIAL_EPISODES} episodes)": _fmt(row.get("initial_return_iqm", np.nan), 1),
        }
        for episodes in budgets:
            entry[f"after {episodes:,} episodes [95% CI]"] = _stat_cell(row, f"return_at_{episodes}_iqm")
        entry["improvement over untrained [95% CI]"] = _stat_cell(row, "improvement_iqm")
        entry["AUC [95% CI]"] = _stat_cell(row, "auc_iqm", low_key="auc_ci_low", high_key="auc_ci_high")
        rows.append(entry)
    parts += [
        f"**Returns.** IQM over seeds of the rolling mean return ({ablation_window(ablation)} episodes) of the "
        f"untrained policy, after fixed episode budgets (a seed that stopped because it solved keeps its last value), "
        "the improvement over the untrained policy, and the area under the learning curve (AUC: the mean rolling "
        "return over the whole budget, which rewards learning early).",
        "",
        _markdown_table(pd.DataFrame(rows)),
        "",
    ]
    if ablation.levels and len(ran):
        rows = []
        for _, row in ran.iterrows():
            entry = {"variant": _esc(row.variant)}
            for level in ablation.levels:
                key = f"episodes_to_{level:g}"
                if f"{key}_median" not in row or pd.isna(row[f"{key}_median"]):
                    entry[f"episodes to reach {level:g}"] = "–"
                    continue
                bound = "≥ " if row[f"{key}_median_censored"] else ""
                entry[f"episodes to reach {level:g} (median; seeds that reached it)"] = (
                    f"{bound}{_fmt(row[f'{key}_median'])} ({int(row[f'{key}_reached'])}/{int(row.seeds_run)})"
                )
            rows.append(entry)
        parts += [
            "**Episodes to reach a return level.** The first episode at which the rolling mean return reaches the "
            "level; a seed that never does counts as the budget (censored, ≥).",
            "",
            _markdown_table(pd.DataFrame(rows)),
            "",
        ]
    return "\n".join(parts)


METRIC_NAMES = {"episodes_to_solve": "episodes to solve", "auc": "area under the curve (AUC)"}


def _metric_name(metric: str) -> str:
    if metric.startswith("return_at_"):
        return f"return after {int(metric.removeprefix('return_at_')):,} episodes"
    if metric.startswith("episodes_to_") and metric != "episodes_to_solve":
        return f"episodes to reach a rolling return of {metric.removeprefix('episodes_to_')}"
    return METRIC_NAMES.get(metric, metric)


def _no_claim_reason(n: int, m: int) -> str:
    if min(n, m) < 2:
        return f"{min(n, m)} seed{'s give' if min(n, m) != 1 else ' gives'} no interval"
    return (
        f"with {n} and {m} seeds no ordering of the seeds can reach 95% confidence (smallest possible "
        f"p = {smallest_p_value(n, m):.2f})"
    )


def _suggestion(row: pd.Series) -> str:
    """What the seeds suggest when too few of them support a claim: the estimate and its bootstrap interval,
    worded as a direction only where the interval excludes no difference (a percentile bootstrap over 3 seeds
    runs narrow, so it is a pointer for the next, larger run, never a result)."""
    if any(np.isnan(v) for v in (row.point, row.low, row.high)):
        return ""
    if row.bound == "censored":
        return " Both IQMs count seeds that never got there as the budget: episodes cannot separate them."
    if row.bound:  # one side censored: the estimate is a bound, and a bound on a suggestion says too little
        return ""
    if row.metric.startswith("episodes_to_"):
        estimate = (
            f"IQM {_fmt(row.variant_value)} vs {_fmt(row.reference_value)} episodes, change {_signed_pct(-row.point)} "
            f"(95% bootstrap CI {_signed_pct(-row.high)} to {_signed_pct(-row.low)})"
        )
        better, worse = "fewer episodes", "more episodes"
    else:
        estimate = (
            f"IQM {_fmt(row.variant_value, 1)} vs {_fmt(row.reference_value, 1)}, {_signed(row.point)} "
            f"(95% bootstrap CI {_signed(row.low)} to {_signed(row.high)})"
        )
        better, worse = "higher", "lower"
    if row.low > 0:
        direction = f"the seeds suggest {better} for {_esc(row.variant)}"
    elif row.high < 0:
        direction = f"the seeds suggest {worse} for {_esc(row.variant)}"
    else:
        direction = "the interval includes no difference"
    return f" Estimate: {estimate}; {direction}, to be confirmed with more seeds."


def _stability(row: pd.Series) -> str:
    if row.verdict not in (BETTER, WORSE):
        return ""
    if row.fragile_seeds:
        seeds = str(row.fragile_seeds).split()
        return (
            f" **Fragile:** the claim does not survive leaving out seed{'s' if len(seeds) > 1 else ''} "
            f"{', '.join(seeds)}."
        )
    return " Holds leaving out any one seed."


def finding(row: pd.Series, ablation: Ablation, table: pd.DataFrame) -> str:
    """One metric's comparison in words: what may be claimed, sized as an estimate or as a bound, with its
    interval and whether it survives leaving out any one seed."""
    base, metric, name = _esc(row.reference), row.metric, _metric_name(row.metric)
    n, m = int(row.n_variant), int(row.n_reference)
    if row.verdict == NO_CLAIM:
        return f"{name}: no claim; {_no_claim_reason(n, m)}.{_suggestion(row)}"
    if metric.startswith("episodes_to_"):
        x, y = _fmt(row.variant_value), _fmt(row.reference_value)
        unsolved = (
            (lambda v: int(table.loc[table.variant == v, "unsolved_censored"].iloc[0]))
            if metric == "episodes_to_solve"
            else None
        )
        counts = ""
        if unsolved is not None:
            counts = (
                f"{unsolved(row.variant)} of {n} {_esc(row.variant)} seeds and {unsolved(row.reference)} of {m} "
                f"{base} seeds never solved"
            )
        if row.bound == "censored":
            return (
                f"{name}: cannot separate them: both IQMs count unsolved seeds as the budget ({counts}), so both are "
                "lower bounds; see the returns below."
            )
        change = f"IQM {'≥ ' if row.bound and row.verdict == WORSE else ''}{x} vs {y}"
        if row.verdict == BETTER and row.bound:
            return (
                f"{name}: **at least {_pct(row.point)} fewer** than {base} ({change}; a bound: {base}'s IQM counts "
                f"unsolved seeds as the budget ({counts}), so the true gap is larger; 95% lower bound "
                f"{_pct(row.low)} fewer).{_stability(row)}"
            )
        if row.verdict == WORSE and row.bound:
            return (
                f"{name}: **at least {_pct(-row.point)} more** than {base} ({change}; a lower bound, since unsolved "
                f"seeds count as the budget: {counts}; 95% lower bound {_pct(-row.high)} more; no upper bound can be "
                f"given).{_stability(row)}"
            )
        if row.verdict == BETTER:
            return (
                f"{name}: **{_pct(row.point)} fewer** than {base} ({change}; 95% CI {_pct(row.low)} to "
                f"{_pct(row.high)} fewer).{_stability(row)}"
            )
        if row.verdict == WORSE:
            return (
                f"{name}: **{_pct(-row.point)} more** than {base} ({change}; 95% CI {_pct(-row.high)} to "
                f"{_pct(-row.low)} more).{_stability(row)}"
            )
        bound = ", the variant's IQM a lower bound" if row.bound else ""
        return (
            f"{name}: not separated ({change}{bound}; change {_signed_pct(-row.point)}, 95% CI "
            f"{_signed_pct(-row.high)} to {_signed_pct(-row.low)}{'; ' + counts if counts else ''})."
        )
    x, y = _fmt(row.variant_value, 1), _fmt(row.reference_value, 1)
    interval = f"95% CI {_signed(row.low)} to {_signed(row.high)}"
    if row.verdict == BETTER:
        return f"{name}: **higher**, {x} vs {y} ({_signed(row.point)}; {interval}).{_stability(row)}"
    if row.verdict == WORSE:
        return f"{name}: **lower**, {x} vs {y} ({_signed(row.point)}; {interval}).{_stability(row)}"
    return f"{name}: not separated, {x} vs {y} ({_signed(row.point)}; {interval})."


def findings(ablation: Ablation, table: pd.DataFrame, compare: pd.DataFrame) -> list[str]:
    """Per variant, one line per metric; no claim without an interval, bounds worded as bounds."""
    lines = []
    for variant in ablation.variants:
        rows = compare[compare.variant == variant] if len(compare) else compare
        if rows.empty:
            continue
        lines.append(f"- **{_esc(variant)}** vs {_esc(ablation.reference(variant))}:")
        for _, row in rows.iterrows():
            text = finding(row, ablation, table)
            if row.metric == "episodes_to_solve" and not pd.isna(row.p_improvement):
                text += (
                    f" P(fewer episodes) = {row.p_improvement:.2f} "
                    f"{_interval(row.p_improvement_ci_low, row.p_improvement_ci_high, 2)}."
                )
            lines.append(f"    - {text}")
    for _, row in table.iterrows():
        if row.seeds_run and ablation.threshold is not None and row.solved < row.seeds_run:
            lines.append(
                f"- **{_esc(row.variant)}**: {int(row.seeds_run - row.solved)} of {int(row.seeds_run)} seeds did "
                f"not solve within {_fmt(row.budget)} episodes."
            )
    return lines


def _rank_key(ablation: Ablation, row: pd.Series) -> tuple:
    if ablation.any_solved:
        return (row.episodes_iqm, -row.auc_iqm)
    return (-row.auc_iqm if not pd.isna(row.auc_iqm) else np.inf,)


def summary(ablation: Ablation, table: pd.DataFrame, compare: pd.DataFrame) -> str:
    """Variants ranked on the primary metric (episodes to solve where seeds solved, else AUC), with intervals
    and the verdict against each variant's reference (the baseline unless the variant extends another)."""
    ran = table[table.seeds_run > 0]
    ranked = sorted(ran.iterrows(), key=lambda item: _rank_key(ablation, item[1]))
    primary = "episodes_to_solve" if ablation.any_solved else "auc"
    extends = _extends(ablation)
    rows = []
    for rank, (_, row) in enumerate(ranked, 1):
        verdict = "reference" if row.variant == ablation.baseline else "–"
        match = compare[(compare.variant == row.variant) & (compare.metric == primary)] if len(compare) else compare
        if len(match):
            first = match.iloc[0]
            if first.verdict in (BETTER, WORSE):
                notes = (["a bound"] if first.bound else []) + (["fragile"] if first.fragile_seeds else [])
                word = {BETTER: "better", WORSE: "worse"}[first.verdict]
                verdict = word + (f" ({'; '.join(notes)})" if notes else "")
            elif first.verdict == NO_CLAIM and not first.bound and first.low > 0:
                verdict = "no claim; the seeds suggest better"
            elif first.verdict == NO_CLAIM and not first.bound and first.high < 0:
                verdict = "no claim; the seeds suggest worse"
            else:
                verdict = first.verdict
            if extends:
                verdict = f"vs {_esc(ablation.reference(row.variant))}: {verdict}"
        entry = {"rank": rank, "variant": _esc(row.variant)}
        if ablation.threshold is not None:
            entry["solved"] = f"{int(row.solved)}/{int(row.seeds_run)}"
        if ablation.any_solved:
            entry["episodes to solve, IQM [95% CI]"] = _episodes_cell(row, "iqm")
        entry["AUC, IQM [95% CI]"] = _stat_cell(row, "auc_iqm", low_key="auc_ci_low", high_key="auc_ci_high")
        against = "its reference" if extends else _esc(ablation.baseline)
        entry[f"vs {against} on {_metric_name(primary)}"] = verdict
        rows.append(entry)
    how = (
        "fewest episodes to solve (IQM, censored), ties by AUC"
        if ablation.any_solved
        else "highest area under the learning curve (IQM)"
    )
    return "\n".join(
        [
            f"Variants ranked by {how}. A rank orders point estimates only: where intervals overlap, the seeds do not "
            "separate the variants, and the last column says what the data support against the "
            + ("variant's reference" if extends else "baseline")
            + " (Findings "
            "gives each comparison with its interval).",
            "",
            _markdown_table(pd.DataFrame(rows)),
        ]
    )


def limitations(ablation: Ablation, table: pd.DataFrame) -> list[str]:
    """What the experiment's design itself limits, read off the grid and the results."""
    base, variants = ablation.grid["base"], ablation.grid["variants"]
    out = []
    seeds = len(ablation.grid["seeds"])
    out.append(
        f"**{seeds} seed{'s' if seeds != 1 else ''} per variant.** Percentile bootstrap intervals over so few seeds "
        "are too narrow more often than 5% of the time, and one unusual seed can move an IQM; each finding says "
        "whether it survives leaving out any one seed."
        + (" With one seed no interval can be computed and no comparison is claimed." if seeds < 2 else "")
    )
    tuned = [k for k in ("learning_rate", "episodes_per_update", "gamma") if k in base]
    touched = [v["name"] for v in variants if any(k in v["overrides"] for k in tuned)]
    architectures = [v for v in variants if "architecture" in _setting_groups(v["overrides"])]
    if tuned and architectures and len(touched) < len(variants):
        knobs = ", ".join(f"{k.replace('_', ' ')} {base[k]}" for k in tuned)
        out.append(
            "**One training setting for all architectures.** Every variant"
            + (f" except {', '.join(_esc(t) for t in touched)}" if touched else "")
            + f" trains with the base {knobs}, chosen for the baseline and not tuned per architecture: one that "
            "would learn better at its own learning rate is judged at the baseline's."
        )
    counts = table.parameter_count.dropna()
    if len(counts) and counts.min() > 0 and counts.max() / counts.min() >= 10:
        out.append(
            f"**Parameter counts span {_fmt(counts.min())} to {_fmt(counts.max())}** "
            f"({counts.max() / counts.min():,.0f}x): a difference between architectures mixes capacity with "
            "optimisation (one learning rate moves small and large networks differently); Figure "
            "{parameters} plots performance against size."
        )
    for variant in ablation.variants:
        reference = ablation.reference(variant)
        groups = _setting_groups(ablation.changes(variant, reference))
        if variant != ablation.baseline and len(groups) > 1:
            out.append(
                f"**{_esc(variant)} changes {len(groups)} settings at once** against {_esc(reference)} "
                f"({', '.join(groups)}): its difference from {_esc(reference)} cannot be attributed to any one of "
                "them."
            )
    finished = ablation.finished
    if ablation.threshold is not None and len(finished) and (finished.solved != 1).any():
        unsolved = int((finished.solved != 1).sum())
        out.append(
            f"**Censoring.** {unsolved} of {len(finished)} trials did not solve within the budget; for them episodes "
            "to solve is only known to exceed it, so statistics that use them are bounds, and a longer budget could "
            "reorder those variants."
        )
    if ablation.threshold is None:
        out.append(
            "**No solve threshold.** No trial stops early; comparisons rest on returns within this budget, and a "
            "longer budget could reorder variants that are still improving."
        )
    out.append(
        "**Wall-clock times come from contended CPUs.** Trials ran several at a time on "
        f"{_esc(ablation.launch.get('environment', {}).get('machine', 'the machine'))}, beside the driver and "
        "its tracking; seconds move between runs and machines. Compare variants on episodes; read seconds as rough "
        "cost."
    )
    if _sampling_videos(ablation):
        out.append(
            "**Videos show one stretch of play** per chosen seed (the trained policy sampling its actions, up to "
            f"{_fmt(base.get('video_max_frames', 500))} frames): a single sample, not an average."
        )
    else:
        out.append(
            "**Videos show one greedy episode** per chosen seed (the most likely action at every step, after "
            "training): a single episode, not an average, and not the sampling policy that was trained."
        )
    out.append(
        f"**One environment and budget** ({_esc(ablation.env_id)}, {_fmt(base.get('max_episodes'))} "
        "episodes): the findings say nothing about other tasks or longer training."
    )
    return out


GLOSSARY = [
    ("Return", "The sum of an episode's rewards (CartPole: steps balanced; Pong: points won minus points lost)."),
    ("Rolling mean return", "The mean return of the last W episodes (W = the solve window); learning curves plot it."),
    (
        "Solved; episodes to solve",
        "The first episode at which the rolling mean over a full window reaches the threshold; the trial stops there.",
    ),
    (
        "Censored (≥)",
        "A seed that never solved has an episodes-to-solve value only known to exceed the budget; it "
        "is counted as the budget. A median or IQM that uses such a value is a lower bound, written ≥, and the upper "
        "end of its interval is no bound on the truth.",
    ),
    (
        "At least",
        "A difference sized by a bound: censoring can only make the true gap larger, so the report gives "
        "its lower end (and the 95% lower bound of that), never an upper end.",
    ),
    (
        "IQM (interquartile mean)",
        "The mean of the middle 50% of the seeds' values (25% trimmed from each end): "
        "less sensitive to one outlying seed than the mean, more efficient than the median (Agarwal et al., 2021).",
    ),
    (
        "95% CI (percentile bootstrap)",
        f"Resample the seeds with replacement {N_RESAMPLES:,} times (seeded), "
        "recompute the statistic each time, and take the 2.5th and 97.5th percentiles. Two variants are resampled "
        "independently. With few seeds these intervals are optimistic.",
    ),
    (
        "AUC (area under the curve)",
        "The mean rolling return over the whole budget; a trial that stopped because it "
        "solved keeps its last value. Higher is better; it rewards learning early and separates variants that never "
        "solve.",
    ),
    (
        "Return after E episodes",
        "The rolling mean return at episode E, compared at the same budgets for every variant.",
    ),
    (
        "Improvement over the untrained policy",
        f"Final rolling mean return minus the mean return of the first "
        f"{INITIAL_EPISODES} episodes (before the policy has learnt much).",
    ),
    (
        "Probability of improvement",
        "P(X < Y) + P(X = Y)/2 for X a random seed of the variant and Y one of the "
        "baseline, on episodes to solve (Agarwal et al., 2021); 0.5 means no difference. Where every pair is ordered "
        "the same way the bootstrap collapses to a point (1.00 [1.00, 1.00]), which only says the sample has no other "
        "pair; there the interval is the exact Clopper-Pearson bound for min(n, m) successes in min(n, m) trials.",
    ),
    (
        "No claim",
        "When a rank test could not reach 95% confidence even with the seeds perfectly ordered "
        f"(smallest two-sided p = 2 / C(n+m, n) > {1 - CONFIDENCE:.2f}, e.g. 3 seeds against 3), or one side has one "
        "seed, the report makes no claim.",
    ),
    (
        "Leave-one-seed-out",
        "Each claim is recomputed with every seed in turn removed from all variants; a claim "
        "that disappears for some seed is marked fragile.",
    ),
]

REFERENCES = [
    "Williams, R. J. (1992). Simple statistical gradient-following algorithms for connectionist reinforcement "
    "learning. *Machine Learning*, 8(3-4), 229-256. (REINFORCE.)",
    "Agarwal, R., Schwarzer, M., Castro, P. S., Courville, A., & Bellemare, M. G. (2021). Deep reinforcement "
    "learning at the edge of the statistical precipice. *Advances in Neural Information Processing Systems 34*. "
    "(IQM, bootstrap intervals, probability of improvement.)",
    "Efron, B., & Tibshirani, R. J. (1993). *An Introduction to the Bootstrap*. Chapman & Hall. (Percentile "
    "intervals.)",
    "Mnih, V., et al. (2015). Human-level control through deep reinforcement learning. *Nature*, 518, 529-533. "
    "(Atari pre-processing and frame-based policies.)",
]


def _video_picks(ablation: Ablation, done: pd.DataFrame) -> list[tuple[pd.Series, str]]:
    """The best and the median seed, with why each was chosen."""
    if ablation.any_solved:
        ordered = done.sort_values(["censored_episodes", "final_rolling_mean"], ascending=[True, False])
        why_best, why_median = "fewest episodes to solve", "median seed by episodes to solve"
    else:
        ordered = done.sort_values(["auc"], ascending=False)
        why_best, why_median = "highest AUC", "median seed by AUC"
    picks = [(ordered.iloc[0], f"the seed with the {why_best} of {len(done)}")]
    median = ordered.iloc[(len(ordered) - 1) // 2]
    if median.run_id != picks[0][0].run_id:
        picks.append((median, f"the {why_median}"))
    return picks


def _videos(ablation: Ablation, tracker: RunReader, folder: Path) -> list[dict[str, str]]:
    chosen = []
    folder.mkdir(parents=True, exist_ok=True)
    for variant in ablation.variants:
        done = ablation.finished[ablation.finished.variant == variant]
        if done.empty:
            continue
        for row, why in _video_picks(ablation, done):
            safe = re.sub(r"[^A-Za-z0-9_.,=-]", "_", variant)
            target = folder / f"{safe}-seed{row.seed}.mp4"
            try:
                downloaded = tracker.download(row.run_id, "video.mp4")
            except Exception:  # noqa: BLE001 - a run without a video (record_video = false)
                continue
            shutil.copyfile(downloaded, target)
            outcome = (
                f"solved at episode {int(row.episodes_to_solve)}"
                if row.solved == 1
                else f"not solved after {int(row.episodes_run)} episodes"
                if ablation.threshold is not None
                else f"{int(row.episodes_run)} episodes, final rolling return {row.final_rolling_mean:.1f}"
            )
            greedy = (
                f"; greedy return {row.greedy_return:.0f} in this one episode" if not pd.isna(row.greedy_return) else ""
            )
            chosen.append(
                {
                    "variant": variant,
                    "path": f"videos/{target.name}",
                    "caption": f"{variant}, seed {row.seed}: {why}; {outcome}{greedy}",
                }
            )
    return chosen


def _reproducibility(ablation: Ablation, command: str) -> str:
    tags = ablation.launch["tags"]
    environment = ablation.launch["environment"]
    versions = environment.get("packages", {})
    cpu = environment.get("cpu_model", "not recorded")
    capability = environment.get("torch_cpu_capability", "not recorded")
    lines = [
        f"- Command: <code>{_esc(tags.get('ablate.command') or 'ablate run ' + tags.get('ablate.experiment_file', ''))}"
        "</code>",
        f"- Code version (git commit): <code>{_esc(tags.get('mlflow.source.git.commit', 'unknown'))}</code>",
        f"- Machine: {_esc(environment.get('machine', 'unknown'))}; CPU model: {_esc(cpu)}; torch CPU capability "
        f"(the vector kernels torch picked): {_esc(capability)}",
        f"- Python {_esc(environment.get('python', '?'))}; "
        + ", ".join(f"{_esc(k)} {_esc(v)}" for k, v in versions.items()),
        f"- MLflow launch run: <code>{_esc(ablation.launch['run_id'])}</code> (generation "
        f"<code>{_esc(tags.get('ablate.generation', ''))}</code>); this report is attached to it as artifacts.",
        f"- Report written {time.strftime('%Y-%m-%d %H:%M')}, from the tracking store only: "
        f"<code>{_esc(command)}</code>",
        "",
        '**What "the same results" means here.** A trial is deterministic given its config and seed on one '
        "machine: the test suite runs a trial twice and checks identical returns. Nothing else was verified. Float "
        "kernels differ between CPU models and torch CPU capabilities, so on a machine other than the one above "
        f"(CPU model {_esc(cpu)}, capability {_esc(capability)}, the package versions above) a seed can follow "
        "another trajectory and the numbers here will differ; the leave-one-seed-out check in the findings shows how "
        "much each conclusion depends on any one seed.",
    ]
    return "\n".join(lines)


def _generation_note(ablation: Ablation) -> str:
    generations = ablation.launch.get("generations", [])
    current = ablation.launch["tags"].get("ablate.generation", "")
    total = len(ablation.grid["trials"])
    done = len(ablation.finished)
    if done >= total:
        return ""
    others = [g for g in generations if g["generation"] != current and g["finished"] > done]
    note = f"> This report covers generation {_esc(current)}, where {done} of {total} trials finished."
    if others:
        note += (
            f" Generation {_esc(others[0]['generation'])} has {others[0]['finished']} finished trials: "
            f"<code>ablate report {_esc(ablation.name)} --generation {_esc(others[0]['generation'])}</code> reports it."
        )
    return note


def build_markdown(
    ablation: Ablation,
    figures: list[Figure],
    videos: list[dict[str, str]],
    table: pd.DataFrame,
    compare: pd.DataFrame,
    command: str = "",
) -> tuple[str, str]:
    """The report in Markdown, and the HTML-ready variant (``<figure>`` and ``<video>`` blocks)."""
    description = ablation.grid.get("description") or ""
    failed = ablation.trials[ablation.trials.status.isin(["FAILED", "KILLED", "NOT RUN"])]
    numbers = {Path(f.path).stem: f.number for f in figures}
    parts = [f"# Ablation report: {_esc(ablation.name)}", "", _esc(description), ""]
    note = _generation_note(ablation)
    if note:
        parts += [note, ""]
    if len(failed):
        parts += [
            f"> {len(failed)} of {len(ablation.trials)} trials did not finish (failed, killed or not run); "
            "they are left out of the statistics and listed at the end.",
            "",
        ]
    parts += ["## Summary", "", summary(ablation, table, compare), ""]
    parts += ["## Method", "", _method(ablation, table), ""]
    parts += [
        "## Results",
        "",
        _convergence_markdown(ablation, table),
        "Tables as CSV: tables/convergence.csv, tables/comparisons.csv, tables/trials.csv.",
        "",
        "## Findings",
        "",
        _findings_intro(ablation)
        + ", on "
        + ", ".join(_metric_name(m) for m in dict.fromkeys(compare.metric) if isinstance(m, str))
        + ". Episodes: the relative change of the IQM; returns: the difference of the IQMs; each with its 95% "
        "interval, sized as a bound where censoring makes it one, and checked by leaving out each seed in turn.",
        "",
        *findings(ablation, table, compare),
        "",
        "## Figures",
        "",
    ]
    for f in figures:
        parts += [f"FIGURE:{f.number}", ""]
    if _sampling_videos(ablation):
        frames = int(ablation.grid["base"].get("video_max_frames", 500))
        parts += [
            "## Videos of the trained agent",
            "",
            "Each video is the trained policy sampling its actions, as in training, on a seed training never used: "
            f"up to {frames:,} frames ({frames / 30:.0f} s at 30 frames/s), for two seeds per variant chosen as the "
            "captions say. Not greedy: a Pong agent that has not learnt much holds one button for the whole video "
            "when it always takes its most likely action. Each trial's MLflow run also holds videos of it playing "
            "during training (`videos/`).",
            "",
        ]
    else:
        parts += [
            "## Videos of the greedy agent",
            "",
            "Each video is one greedy episode (the most likely action at every step) of a trained agent, for two "
            "seeds per variant chosen as the captions say.",
            "",
        ]
    parts += [
        "VIDEOS_PLACEHOLDER",
        "",
    ]
    if len(failed):
        parts += ["## Trials that did not finish", ""]
        parts += [
            f"- {_esc(r.key)}: {r.status}{(' — ' + _esc(r.error)) if isinstance(r.error, str) and r.error else ''}"
            for r in failed.itertuples()
        ]
        parts.append("")
    parts += ["## Limitations", "", *[f"- {line}" for line in limitations(ablation, table)], ""]
    parts += ["## Reproducibility", "", _reproducibility(ablation, command), ""]
    parts += ["## Glossary", "", *[f"- **{term}.** {text}" for term, text in GLOSSARY], ""]
    parts += ["## References", "", *[f"- {ref}" for ref in REFERENCES], ""]
    text = "\n".join(parts).replace("Figure {parameters}", f"Figure {numbers.get('performance_vs_parameters', '–')}")
    md_text, html_text = text, text
    for f in figures:
        md_text = md_text.replace(
            f"FIGURE:{f.number}\n", f"![{f.alt}]({f.path})\n\n*Figure {f.number}. {f.caption}*\n", 1
        )
        html_text = html_text.replace(
            f"FIGURE:{f.number}\n",
            f'<figure id="figure-{f.number}"><img src="{f.path}" alt="{html.escape(f.alt)}">'
            f"<figcaption><strong>Figure {f.number}.</strong> {f.caption}</figcaption></figure>\n",
            1,
        )
    links = "\n".join(f"- [{_esc(v['caption'])}]({v['path']})" for v in videos) or "No videos were recorded."
    blocks = "\n".join(
        f'<figure class="video"><video controls muted loop preload="metadata" src="{html.escape(v["path"])}">'
        f"</video><figcaption>{html.escape(v['caption'])}</figcaption></figure>"
        for v in videos
    )
    html_text = html_text.replace("VIDEOS_PLACEHOLDER", f'<div class="videos">\n{blocks}\n</div>' if videos else links)
    return md_text.replace("VIDEOS_PLACEHOLDER", links), html_text


CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222;
       line-height: 1.45; }
table { border-collapse: collapse; font-size: 0.85em; margin: 1em 0; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: top; }
img { max-width: 100%; }
figure { margin: 1.5em 0; break-inside: avoid; }
figcaption { font-size: 0.9em; color: #333; margin-top: 0.3em; }
.videos { display: flex; flex-wrap: wrap; gap: 12px; }
figure.video { margin: 0; width: 260px; font-size: 0.8em; }
figure.video video { width: 260px; }
blockquote { background: #fff4e0; border-left: 4px solid #f0a000; margin: 1em 0; padding: 0.5em 1em; }
@media print {
  body { max-width: none; margin: 0; font-size: 10pt; }
  video { display: none; }
  figure.video { width: 45%; }
  table { font-size: 8pt; }
  h2 { break-after: avoid; }
  tr { break-inside: avoid; }
}
"""


def _inline(html_text: str, folder: Path) -> str:
    """Replace relative ``src`` references with data URIs, so report.html is one self-contained file."""
    mime = {".png": "image/png", ".svg": "image/svg+xml", ".mp4": "video/mp4"}

    def replace(match: re.Match) -> str:
        path = folder / html.unescape(match.group(2))
        if not path.is_file():
            return match.group(0)
        data = base64.b64encode(path.read_bytes()).decode()
        return f'{match.group(1)}="data:{mime.get(path.suffix, "application/octet-stream")};base64,{data}"'

    return re.sub(r'(src)="((?:figures|videos)/[^"]+)"', replace, html_text)


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        found = shutil.which(name)
        if found:
            return found
    return None


def chromium_flags(profile: Path) -> list[str]:
    return [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={profile}",
    ]


def print_pdf(html_path: Path, pdf_path: Path, timeout_s: float = 180) -> str | None:
    """Print ``html_path`` to ``pdf_path`` with headless Chromium; the reason it could not, or None."""
    browser = find_chromium()
    if browser is None:
        return "no PDF: Chromium not found (Debian: apt-get install chromium)"
    with tempfile.TemporaryDirectory(prefix="ablate-chromium-") as profile:
        try:
            subprocess.run(
                [
                    browser,
                    *chromium_flags(Path(profile)),
                    "--no-pdf-header-footer",
                    f"--print-to-pdf={pdf_path}",
                    html_path.resolve().as_uri(),
                ],
                capture_output=True,
                timeout=timeout_s,
                check=False,
            )
        except (OSError, subprocess.TimeoutExpired) as error:
            return f"no PDF: Chromium failed ({error})"
    if not pdf_path.is_file() or pdf_path.stat().st_size == 0:
        return "no PDF: Chromium wrote nothing"
    return None


def report_folder(name: str, out_root: Path) -> Path:
    """``out_root/name``, refusing any name that is not one plain folder name inside ``out_root``."""
    if not name or name in (".", "..") or "/" in name or "\\" in name or name.startswith(".") or "\0" in name:
        raise ConfigError(
            f"experiment name {name!r} is invalid; valid: letters, digits, '-' and '_' (a folder in {out_root}/)"
        )
    folder = out_root / name
    if folder.resolve().parent != out_root.resolve():
        raise ConfigError(f"experiment name {name!r} is invalid: {folder} is outside {out_root}/")
    return folder


@dataclass
class ReportResult:
    folder: Path
    pdf_note: str | None
    """Why no PDF was written (None when it was)."""
    attach_note: str | None
    """Why the report was not attached to the launch run (None when it was)."""
    generation_note: str


def write_report(
    name: str,
    tracking_uri: str | None = None,
    out_root: Path = Path("reports"),
    generation: str | None = None,
    variants: list[str] | None = None,
    baseline: str | None = None,
    pdf: bool = True,
    attach: bool = True,
    command: str = "",
) -> Path:
    """Build the report of experiment ``name`` into ``out_root/name/`` and return that folder. Raises
    ``ConfigError`` (bad name, store, generation, variant) or ``NoResults`` before anything is written."""
    return build_report(name, tracking_uri, out_root, generation, variants, baseline, pdf, attach, command).folder


def build_report(
    name: str,
    tracking_uri: str | None = None,
    out_root: Path = Path("reports"),
    generation: str | None = None,
    variants: list[str] | None = None,
    baseline: str | None = None,
    pdf: bool = True,
    attach: bool = True,
    command: str = "",
) -> ReportResult:
    folder = report_folder(name, Path(out_root))
    ablation = select(load_ablation(name, tracking_uri, generation), variants, baseline)
    if ablation.finished.empty:
        raise NoResults(
            f"none of the {len(ablation.trials)} trials of generation "
            f"{ablation.launch['tags'].get('ablate.generation')}"
            " finished ("
            + ", ".join(
                f"{r.key}: {r.status} {r.error if isinstance(r.error, str) else ''}".strip()
                for r in ablation.trials.head(3).itertuples()
            )
            + (", ..." if len(ablation.trials) > 3 else "")
            + "); see the MLflow runs for their errors"
        )
    command = command or f"ablate report {name}"
    Path(out_root).mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{name}.new-", dir=out_root))
    try:
        tracker = RunReader(tracking_uri, name)
        pdf_note = _build(ablation, tracker, staging, pdf, command)
        _swap(staging, folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    attach_note = None
    if attach:
        try:
            tracker.attach_report(ablation.launch["run_id"], folder)
        except Exception as error:  # noqa: BLE001 - a read-only or remote store: the report on disk stands
            attach_note = f"not attached to the launch run: {str(error).splitlines()[0][:200]}"
    return ReportResult(folder, pdf_note, attach_note, _generation_note(ablation))


def _swap(staging: Path, folder: Path) -> None:
    """Replace ``folder`` by ``staging`` with two renames, so a reader never sees a half-written report."""
    old = None
    if folder.exists():
        old = folder.parent / f".{folder.name}.old-{time.time_ns()}"
        folder.rename(old)
    staging.rename(folder)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _build(ablation: Ablation, tracker: RunReader, folder: Path, pdf: bool, command: str) -> str | None:
    for sub in ("figures", "tables", "videos"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    table = convergence_table(ablation)
    compare = comparisons(ablation)
    table.to_csv(folder / "tables" / "convergence.csv", index=False)
    compare.to_csv(folder / "tables" / "comparisons.csv", index=False)
    ablation.trials.to_csv(folder / "tables" / "trials.csv", index=False)
    figures_folder = folder / "figures"
    candidates = [
        figure_overview(ablation, figures_folder),
        figure_small_multiples(ablation, figures_folder),
        figure_wallclock(ablation, figures_folder),
        figure_per_seed(ablation, figures_folder),
        figure_improvement(ablation, compare, figures_folder),
        figure_parameters(ablation, table, figures_folder),
        figure_observation(ablation, tracker, figures_folder),
    ]
    figures = [f for f in candidates if f is not None]
    for number, figure in enumerate(figures, 1):
        figure.number = number
        figure.caption = figure.caption.replace("{next}", str(number + 1))
        figure.caption = figure.caption.replace("Figures 1-2", f"Figures 1-{min(2, len(figures))}")
    videos = _videos(ablation, tracker, folder / "videos")
    text, html_md = build_markdown(ablation, figures, videos, table, compare, command)
    (folder / "report.md").write_text(text)
    body = markdown.markdown(html_md, extensions=["tables"])
    page = (
        f"<!doctype html><html><head><meta charset='utf-8'><title>Ablation report: {html.escape(ablation.name)}"
        f"</title><style>{CSS}</style></head><body>{body}</body></html>"
    )
    (folder / "report.html").write_text(_inline(page, folder))
    if not pdf:
        return "no PDF (--no-pdf)"
    return print_pdf(folder / "report.html", folder / "report.pdf")


def terminal_summary(folder: Path) -> str:
    """The convergence table in a few lines, for the end of ``ablate run``."""
    path = folder / "tables" / "convergence.csv"
    if not path.is_file():
        return f"no report in {folder}"
    table = pd.read_csv(path)
    lines = [f"{'variant':<16} {'solved':>7} {'episodes to solve (median)':>28} {'final rolling mean (IQM)':>26}"]
    for row in table.itertuples():
        seeds = int(row.seeds_run) if not pd.isna(row.seeds_run) else 0
        if not seeds:
            lines.append(f"{row.variant:<16} {'no finished seeds':>7}")
            continue
        median = ("≥ " if row.median_censored else "") + _fmt(row.episodes_median)
        lines.append(
            f"{row.variant:<16} {int(row.solved):>3}/{seeds:<3} {median:>28} {_fmt(row.final_rolling_mean_iqm, 1):>26}"
        )
    return "\n".join(lines)


def _names(text: str | None) -> list[str] | None:
    return [v.strip() for v in text.split(",") if v.strip()] if text else None


def cmd_report(args: argparse.Namespace) -> int:
    """``ablate report``: exit 0 with the report written; 1 with nothing to report; 2 for bad input. Nothing
    is written (and no store created) unless the whole report could be built."""
    name = args.experiment
    if name.endswith(".toml"):
        name = load_experiment(name).name  # a bad file is a ConfigError: one line, exit 2
    command = "ablate report " + " ".join(
        [name]
        + ([f"--generation {args.generation}"] if getattr(args, "generation", None) else [])
        + ([f"--variants {args.variants}"] if getattr(args, "variants", None) else [])
        + ([f"--baseline {args.baseline}"] if getattr(args, "baseline", None) else [])
    )
    try:
        result = build_report(
            name,
            args.tracking_uri,
            args.out,
            generation=getattr(args, "generation", None),
            variants=_names(getattr(args, "variants", None)),
            baseline=getattr(args, "baseline", None),
            pdf=getattr(args, "pdf", True),
            command=command,
        )
    except NoResults as error:
        sys.stderr.write(f"ablate report: nothing to report: {error}; nothing written\n")
        return 1
    except OSError as error:  # a read-only or full reports folder: an environment problem, not a bug
        where = error.filename or args.out
        sys.stderr.write(f"ablate report: cannot write the report under {args.out}: {error.strerror} ({where})\n")
        return 1
    written = "report.md, report.html" + ("" if result.pdf_note else " and report.pdf")
    print(f"wrote {result.folder}/: {written}")
    for note in (result.generation_note, result.pdf_note, result.attach_note):
        if note and note != "no PDF (--no-pdf)":
            print(re.sub(r"</?code>|^> ", "", html.unescape(note)))
    return 0
