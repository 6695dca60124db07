"""The report's figures: each drawn from an ``Ablation`` into PNG and SVG, with a caption that says what is
plotted and how its bands are computed (the report numbers them).

Matplotlib with the Agg backend. Captions carry user text (variant names) escaped for Markdown and HTML.
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import matplotlib

if not os.environ.get("MPLBACKEND"):  # Jupyter sets its inline backend there: keep it, so figures show
    matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ablate.design import CONFIDENCE, percent  # noqa: E402
from ablate.reporting.prose import say  # noqa: E402
from ablate.reporting.reader import RunReader  # noqa: E402
from ablate.reporting.results import Ablation  # noqa: E402
from ablate.reporting.statistics import N_RESAMPLES, curve_band  # noqa: E402
from ablate.reporting.text import Refs, esc, fmt  # noqa: E402
from ablate.reporting.tuning import chosen_values, knobs, metric_words, same_value, sensitivity  # noqa: E402

# tab10 without its grey, which is the baseline's
COLOURS = [c for i, c in enumerate(plt.get_cmap("tab10").colors) if i != 7]
BASELINE_COLOUR = "0.35"


@dataclass
class Figure:
    path: str
    caption: str | Callable[[Refs], str]
    """A caption that names other figures is a function of their numbers, written by ``resolve``."""
    alt: str
    number: int = 0

    def resolve(self, refs: Refs) -> None:
        """Write the caption that names other figures, now that every figure has its number."""
        if callable(self.caption):
            self.caption = self.caption(refs)


_kept: list[list] = []
"""While ``keep_figures`` is open: where ``_save`` also hands each figure it saved."""


@contextlib.contextmanager
def keep_figures() -> Iterator[list]:
    """The matplotlib figures drawn inside this block (the Python API returns them to a notebook). Each is closed
    once saved all the same: a report holds no memory, a notebook does not show it twice."""
    kept: list = []
    _kept.append(kept)
    try:
        yield kept
    finally:
        _kept.remove(kept)


# --- figures -------------------------------------------------------------------------------------------
def _save(fig, folder: Path, name: str) -> str:
    fig.tight_layout()
    for ext in ("png", "svg"):
        fig.savefig(folder / f"{name}.{ext}", dpi=110)
    if _kept:
        _kept[-1].append(fig)
    plt.close(fig)
    return f"figures/{name}.png"


def _colour(ablation: Ablation, variant: str):
    if variant == ablation.baseline:
        return BASELINE_COLOUR
    others = [v for v in ablation.variants if v != ablation.baseline]
    return COLOURS[others.index(variant) % len(COLOURS)]


def episode_grid(ablation: Ablation) -> np.ndarray:
    """The episodes the learning curves are drawn at: ~200 over the budget, the report's resolution."""
    budget = int(ablation.finished.budget.max())
    return np.unique(np.linspace(1, budget, 200).astype(int)).astype(float)


def variant_band(ablation: Ablation, variant: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``variant``'s learning curve at ``episode_grid``: the IQM over seeds and its band (``curve_band``), computed
    once for the figure, the variant's MLflow run and its picture there; None without curves."""
    if variant not in ablation.bands:
        curves = ablation.curves[ablation.curves.variant == variant]
        ablation.bands[variant] = curve_band(curves, "episode", episode_grid(ablation)) if len(curves) else None
    return ablation.bands[variant]


def ablation_window(ablation: Ablation) -> int:
    return int(ablation.grid["base"].get("solve_window", 100))


def _every_variant(ablation: Ablation, x: str, grid: np.ndarray, **axes: str):
    """Every variant's IQM curve against ``x`` (no bands), the baseline thick, the solve threshold dashed, the
    legend beside the plot; ``axes``: its scale and labels (``Axes.set``)."""
    fig, ax = plt.subplots(figsize=(10, 5))
    for variant in ablation.variants:
        curves = ablation.curves[ablation.curves.variant == variant]
        if curves.empty:
            continue
        centre, _, _ = curve_band(curves, x, grid, band=False)
        baseline = variant == ablation.baseline
        ax.plot(grid, centre, color=_colour(ablation, variant), linewidth=2.8 if baseline else 1.4, label=variant)
    if ablation.threshold is not None:
        ax.axhline(ablation.threshold, color="black", linestyle="--", linewidth=0.8, label="solved")
    ax.set(**axes)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return fig


def _panels(count: int, **share: bool):
    """A figure of ``count`` panels, three to a row, the unused ones hidden."""
    columns = min(3, count)
    rows = int(np.ceil(count / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.0 * rows), squeeze=False, **share)
    for ax in axes.flat[count:]:
        ax.set_visible(False)
    return fig, axes


def _label_edges(axes: np.ndarray, xlabel: str, ylabel: str) -> None:
    for ax in axes[-1]:
        ax.set_xlabel(xlabel)
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel)


def _panel(ax, ablation: Ablation, variant: str) -> None:
    """``variant``'s learning curve and band beside its reference's (grey; the baseline has none)."""
    grid = episode_grid(ablation)
    reference = ablation.reference(variant) if variant != ablation.baseline else None
    drawn = [(reference, BASELINE_COLOUR, 1.6, 0.18)] if reference else []
    for name, colour, width, alpha in [*drawn, (variant, _colour(ablation, variant), 1.8, 0.25)]:
        band = variant_band(ablation, name)
        if band is not None:
            centre, low, high = band
            ax.plot(grid, centre, color=colour, linewidth=width, label=name)
            ax.fill_between(grid, low, high, color=colour, alpha=alpha, linewidth=0)
    if ablation.threshold is not None:
        ax.axhline(ablation.threshold, color="black", linestyle="--", linewidth=0.7)
    ax.set_title(f"{variant} vs {reference}" if reference else variant, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")


def figure_overview(ablation: Ablation, folder: Path) -> Figure:
    ylabel = f"rolling mean return ({ablation_window(ablation)} episodes), IQM over seeds"
    fig = _every_variant(ablation, "episode", episode_grid(ablation), xlabel="episode", ylabel=ylabel)
    facts = {"baseline": ablation.baseline, "window": ablation_window(ablation), "threshold": ablation.threshold}

    def caption(refs: Refs) -> str:
        return say("figures.overview", figure=refs.figure("learning_curves_by_variant"), **facts)

    return Figure(_save(fig, folder, "learning_curves_episodes"), caption, "Learning curves of every variant")


def figure_small_multiples(ablation: Ablation, folder: Path) -> Figure | None:
    others = [v for v in ablation.variants if v != ablation.baseline]
    if not others:
        return None
    fig, axes = _panels(len(others), sharex=True, sharey=True)
    for ax, variant in zip(axes.flat, others, strict=False):
        _panel(ax, ablation, variant)
    _label_edges(axes, "episode", "rolling mean return")
    extends = [v for v in others if ablation.reference(v) != ablation.baseline]
    seeds, window = len(ablation.grid["seeds"]), ablation_window(ablation)
    facts = {"baseline": ablation.baseline, "seeds": seeds, "window": window, "resamples": N_RESAMPLES // 4}
    caption = say("figures.by_variant", extends=bool(extends), **facts)
    title = "Each variant against its reference" if extends else "Each variant against the baseline"
    return Figure(_save(fig, folder, "learning_curves_by_variant"), caption, title)


def variant_band_png(ablation: Ablation, variant: str) -> bytes | None:
    """``variant``'s panel of Figure "each variant against its reference" as PNG bytes, for its MLflow run (whose
    charts draw no bands); None without curves."""
    if variant_band(ablation, variant) is None:
        return None
    fig, ax = plt.subplots(figsize=(5.2, 3.4))
    _panel(ax, ablation, variant)
    ax.set(xlabel="episode", ylabel=f"rolling mean return (IQM, {percent(CONFIDENCE)} band)")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    plt.close(fig)
    return buffer.getvalue()


def figure_wallclock(ablation: Ablation, folder: Path) -> Figure | None:
    wall = ablation.curves.wall_s.dropna()
    wall = wall[wall > 0]
    if wall.empty:
        return None
    grid = np.geomspace(float(wall.min()), float(wall.max()), 200)
    xlabel = "wall-clock seconds since the trial started (log scale; trials shared the CPUs)"
    ylabel = "rolling mean return, IQM over seeds"
    # a log axis: variants differ ten-fold in speed, and a linear one hides the fast ones
    fig = _every_variant(ablation, "wall_s", grid, xscale="log", xlabel=xlabel, ylabel=ylabel)

    def caption(refs: Refs) -> str:
        episodes = refs.figures_of("learning_curves_episodes", "learning_curves_by_variant")
        return (
            "Learning curves against wall-clock time (log axis), IQM across seeds, no bands. Caveat: trials ran "
            "several at a time on shared CPUs beside the driver process, so their clocks include contention and "
            f"move between runs and machines; compare variants on episodes ({episodes}), and read this figure for "
            "rough cost only. A curve stops where fewer than half its seeds are still running."
        )

    return Figure(_save(fig, folder, "learning_curves_wallclock"), caption, "Learning curves against wall-clock")


def per_seed_points(ablation: Ablation) -> pd.DataFrame:
    """What Figure "every seed's outcome" draws: per finished seed its variant, seed, x (episodes to solve, or
    the final rolling return where no seed solved) and ``bound``: a seed that never solved is drawn at the
    budget, as a bound (its true value is only known to be larger), never beyond the budget line."""
    episodes = ablation.any_solved
    done = ablation.finished
    x = done.censored_episodes if episodes else done.final_rolling_mean
    bound = (done.solved != 1) if episodes else pd.Series(False, index=done.index)
    return pd.DataFrame({"variant": done.variant, "seed": done.seed, "x": x.astype(float), "bound": bound.astype(bool)})


def figure_per_seed(ablation: Ablation, folder: Path) -> Figure:
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(ablation.variants) + 1.6))
    rng = np.random.default_rng(0)
    episodes = ablation.any_solved
    budget = ablation.finished.budget.max()
    points = per_seed_points(ablation)
    for i, variant in enumerate(ablation.variants):
        mine = points[points.variant == variant]
        y = np.full(len(mine), i) + rng.uniform(-0.15, 0.15, len(mine))
        colour = _colour(ablation, variant)
        exact, bound = ~mine.bound.to_numpy(), mine.bound.to_numpy()
        ax.scatter(mine.x[exact], y[exact], color=colour, s=36, zorder=3)
        # never solved: at the budget, a hollow right-pointing triangle ("more than this"), jittered only upwards
        ax.scatter(mine.x[bound], y[bound], facecolors="none", edgecolors=colour, s=48, zorder=3, marker=">")
        if len(mine):
            ax.plot([np.median(mine.x)] * 2, [i - 0.3, i + 0.3], color="black", linewidth=1.5)
    if episodes:
        ax.axvline(budget, color="grey", linestyle=":", linewidth=1)
        ax.text(budget, len(ablation.variants) - 0.4, " budget", color="grey", fontsize=8, va="bottom")
        ax.set_xlabel("episodes to solve")
        caption = (
            "Episodes to solve, every seed of every variant (filled dots: solved; hollow triangles: never solved, "
            f"drawn at the budget of {fmt(budget)} episodes as bounds: their true value is only known to be larger). "
            "Black bar: the median over seeds, censored values included (≥ where it is one of them)."
        )
    else:
        ax.set_xlabel(f"final rolling mean return ({ablation_window(ablation)} episodes)")
        caption = (
            "Final rolling mean return of every seed (no seed reached a solve threshold, so episodes to solve "
            "cannot rank the variants). Black bar: the median over seeds."
        )
    ax.set_yticks(range(len(ablation.variants)), ablation.variants)
    ax.invert_yaxis()
    ax.grid(axis="x", alpha=0.3)
    name = "episodes_to_solve" if episodes else "final_return"
    return Figure(_save(fig, folder, name), caption, "Every seed's outcome")


def figure_improvement(ablation: Ablation, compare: pd.DataFrame, folder: Path) -> Figure | None:
    table = compare[compare.metric == "episodes_to_solve"] if len(compare) else compare
    if table.empty:
        return None
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(table) + 1.6))
    y = np.arange(len(table))
    low = (table.p_improvement - table.p_improvement_ci_low).clip(lower=0).fillna(0)
    high = (table.p_improvement_ci_high - table.p_improvement).clip(lower=0).fillna(0)
    ax.errorbar(table.p_improvement, y, xerr=[low, high], fmt="o", color="tab:blue", capsize=3)
    ax.axvline(0.5, color="black", linestyle="--", linewidth=0.8)
    ax.set_yticks(y, table.variant)
    ax.invert_yaxis()
    varied = set(table.reference) != {ablation.baseline}
    against = "its reference" if varied else ablation.baseline
    ax.set(xlim=(-0.02, 1.02), xlabel=f"P(a seed of the variant solves in fewer episodes than a seed of {against})")
    ax.grid(axis="x", alpha=0.3)
    caption = say("figures.improvement", against=against, varied=varied)
    return Figure(_save(fig, folder, "probability_of_improvement"), caption, "Probability of improvement")


def figure_parameters(ablation: Ablation, table: pd.DataFrame, folder: Path) -> Figure | None:
    rows = table.dropna(subset=["parameter_count", "auc_iqm"]) if "auc_iqm" in table else table.iloc[:0]
    if rows.empty:
        return None
    fig, ax = plt.subplots(figsize=(8, 4.8))
    for _, row in rows.iterrows():
        low = row.auc_iqm - row.auc_ci_low if not pd.isna(row.auc_ci_low) else 0
        high = row.auc_ci_high - row.auc_iqm if not pd.isna(row.auc_ci_high) else 0
        colour = _colour(ablation, row.variant)
        ax.errorbar([row.parameter_count], [row.auc_iqm], yerr=[[low], [high]], fmt="o", color=colour, capsize=3)
        ax.annotate(
            row.variant, (row.parameter_count, row.auc_iqm), xytext=(5, 4), textcoords="offset points", fontsize=8
        )
    ax.set(
        xscale="log", xlabel="trainable parameters (log scale)", ylabel="area under the learning curve (IQM over seeds)"
    )
    ax.grid(alpha=0.3)
    caption = say("figures.parameters")
    return Figure(_save(fig, folder, "performance_vs_parameters"), caption, "Performance against parameter count")


def figure_observation(ablation: Ablation, tracker: RunReader, folder: Path) -> Figure | None:
    """The trial's own picture of one observation (raw, pre-processed, frame difference), where it logged one."""
    lost = {key for _, key in ablation.missing}
    for run_id in ablation.finished[~ablation.finished.key.isin(lost)].run_id.dropna():
        try:
            downloaded = tracker.download(run_id, "observation.png")
        except Exception:  # noqa: BLE001 - trials of envs without such a picture (CartPole)
            return None
        shutil.copyfile(downloaded, folder / "observation.png")
        caption = (
            f"One observation of {esc(ablation.env_id)} as the policy sees it: the raw frame, the pre-processed "
            "frame (cropped, down-sampled to 80x80, background removed, binary) and the difference of two "
            "consecutive pre-processed frames, which is the policy's input (it shows motion)."
        )
        return Figure("figures/observation.png", caption, "Observation: raw, pre-processed, frame difference")
    return None


def figure_sensitivity(ablation: Ablation, folder: Path) -> Figure | None:
    """The tuning metric against every candidate, one panel per tuned variant: the mean over the tuning seeds
    (line), each seed (dots) and their spread (bar: lowest to highest), the choice marked."""
    tuning, table = ablation.tuning, ablation.tuning_trials
    if not tuning or table is None or table.empty:
        return None
    names, metric = knobs(tuning), tuning.get("metric", "auc")
    summary = sensitivity(table, tuning)
    variants = [v for v in ablation.variants if v in set(summary.variant)]
    if not variants:
        return None
    candidates = sorted({tuple(row) for row in summary[names].itertuples(index=False)})
    numeric = len(names) == 1 and all(isinstance(c[0], int | float) and c[0] > 0 for c in candidates)
    position = {c: (c[0] if numeric else i) for i, c in enumerate(candidates)}
    fig, axes = _panels(len(variants), sharey=True)
    done = table[table.status == "FINISHED"]
    for ax, variant in zip(axes.flat, variants, strict=False):
        colour = _colour(ablation, variant)
        mine = summary[summary.variant == variant]
        mine = mine.assign(x=[float(position[tuple(r)]) for r in mine[names].itertuples(index=False)]).sort_values("x")
        x, mean, low, high = (mine[column].to_numpy(float) for column in ("x", "mean", "low", "high"))
        ax.errorbar(x, mean, yerr=[mean - low, high - mean], color=colour, marker="o", capsize=3, linewidth=1.5)
        seeds = done[done.variant == variant]
        at = [position[tuple(r)] for r in seeds[names].itertuples(index=False)]
        ax.scatter(at, seeds[metric], color=colour, s=10, alpha=0.5, zorder=3)
        wanted = [chosen_values(tuning, variant)[n] for n in names]
        picked = [i for i, c in enumerate(mine[names].itertuples(index=False)) if all(map(same_value, c, wanted))]
        if picked:
            ax.scatter([x[picked[0]]], [mean[picked[0]]], marker="*", s=220, color="black", zorder=4)
        base = [tuning.get("base", {}).get(n) for n in names]
        if numeric and base[0] is not None:  # the untuned comparison's value, for reference
            ax.axvline(float(base[0]), color="grey", linestyle="--", linewidth=0.8)
        ax.set_title(variant, fontsize=10)
        ax.grid(alpha=0.3)
        if numeric:
            ax.set_xscale("log")
            ax.set_xticks([c[0] for c in candidates], [f"{c[0]:g}" for c in candidates])
            ax.minorticks_off()
        else:
            ax.set_xticks(range(len(candidates)), [", ".join(f"{v:g}" for v in c) for c in candidates], fontsize=7)
    words, direction = metric_words(tuning)
    _label_edges(axes, ", ".join(n.replace("_", " ") for n in names) + (" (log scale)" if numeric else ""), words)
    seeds = len(tuning.get("seeds", []))
    caption = (
        f"Sensitivity to {', '.join(esc(n.replace('_', ' ')) for n in names)}: the tuning metric ({esc(words)}, "
        f"{'higher' if direction == 'max' else 'lower'} is better) of each tuned variant at every candidate, on the "
        f"{seeds} tuning seed{'s' if seeds != 1 else ''} only. Line: the mean over the tuning seeds; bar: the lowest "
        "to the highest seed; dots: each seed; star: the value chosen for the evaluation; dashed: the base value "
        "(the untuned comparison's). A choice at the end of the axis may not be the best value."
    )
    return Figure(_save(fig, folder, "tuning_sensitivity"), caption, "Sensitivity to the tuned settings")
