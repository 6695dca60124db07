"""Write ``reports/<experiment>/``: report.md, a self-contained report.html, figures, tables and videos.

Reads only from the tracking store (through ``results``), so it works from any machine that reaches it.
"""

from __future__ import annotations

import argparse
import base64
import html
import re
import shutil
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import markdown  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ablate.config import load_experiment  # noqa: E402
from ablate.results import (  # noqa: E402
    Ablation,
    NoResults,
    comparisons,
    convergence_table,
    curve_band,
    load_ablation,
)
from ablate.tracking import Tracker  # noqa: E402

COLOURS = plt.get_cmap("tab10").colors


def _pct(x: float) -> str:
    return f"{int(round(100 * x))}%"


def _fmt(x: float, digits: int = 0) -> str:
    return "–" if x is None or (isinstance(x, float) and np.isnan(x)) else f"{x:,.{digits}f}"


# --- figures -------------------------------------------------------------------------------------------
def _save(fig, folder: Path, name: str) -> str:
    fig.tight_layout()
    for ext in ("png", "svg"):
        fig.savefig(folder / f"{name}.{ext}", dpi=110)
    plt.close(fig)
    return f"figures/{name}.png"


def figure_learning_curves(ablation: Ablation, folder: Path) -> tuple[str, str]:
    budget = int(ablation.finished.budget.max())
    threshold = _threshold(ablation)
    episode_grid = np.unique(np.linspace(1, budget, 200).astype(int)).astype(float)
    wall_max = float(ablation.curves.wall_s.max()) if len(ablation.curves) else 1.0
    wall_min = float(ablation.curves.wall_s[ablation.curves.wall_s > 0].min()) if len(ablation.curves) else 0.01
    wall_grid = np.geomspace(wall_min, wall_max, 200)
    paths = []
    for x, grid, label, name in (
        ("episode", episode_grid, "episode", "learning_curves_episodes"),
        ("wall_s", wall_grid, "wall-clock seconds, log scale (one CPU per trial)", "learning_curves_wallclock"),
    ):
        fig, ax = plt.subplots(figsize=(10, 5.2))
        for i, variant in enumerate(ablation.variants):
            curves = ablation.curves[ablation.curves.variant == variant]
            if curves.empty:
                continue
            centre, low, high = curve_band(curves, x, grid)
            colour = COLOURS[i % len(COLOURS)]
            width = 2.6 if variant == ablation.baseline else 1.4
            ax.plot(grid, centre, color=colour, linewidth=width, label=variant)
            ax.fill_between(grid, low, high, color=colour, alpha=0.15, linewidth=0)
        if threshold is not None:
            ax.axhline(threshold, color="black", linestyle="--", linewidth=0.8, label=f"solved ({threshold:g})")
        if x == "wall_s":
            ax.set_xscale("log")  # variants differ ten-fold in speed: a linear axis hides the fast ones
        ax.set_xlabel(label)
        ax.set_ylabel(f"rolling mean return ({_window(ablation)} episodes)")
        ax.set_title("Learning curves: IQM across seeds, 95% bootstrap band")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        paths.append(_save(fig, folder, name))
    return paths[0], paths[1]


def figure_episodes_to_solve(ablation: Ablation, folder: Path) -> str:
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(ablation.variants) + 1.5))
    rng = np.random.default_rng(0)
    budget = ablation.finished.budget.max()
    for i, variant in enumerate(ablation.variants):
        done = ablation.finished[ablation.finished.variant == variant]
        jitter = rng.uniform(-0.15, 0.15, len(done))
        solved = done.solved.to_numpy() == 1
        y = np.full(len(done), i) + jitter
        ax.scatter(done.censored_episodes[solved], y[solved], color=COLOURS[i % 10], s=36, zorder=3)
        ax.scatter(
            done.censored_episodes[~solved] * (1 + rng.uniform(0.005, 0.04, (~solved).sum())),
            y[~solved],
            facecolors="none",
            edgecolors=COLOURS[i % 10],
            s=36,
            zorder=3,
            marker="s",
        )
        if len(done):
            ax.plot([np.median(done.censored_episodes)] * 2, [i - 0.3, i + 0.3], color="black", linewidth=1.5)
    ax.axvline(budget, color="grey", linestyle=":", linewidth=1)
    ax.text(budget, len(ablation.variants) - 0.4, " budget", color="grey", fontsize=8, va="bottom")
    ax.set_yticks(range(len(ablation.variants)), ablation.variants)
    ax.invert_yaxis()
    ax.set_xlabel("episodes to solve (every seed; hollow squares: unsolved, censored at the budget; bar: median)")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, folder, "episodes_to_solve")


def figure_improvement(ablation: Ablation, table: pd.DataFrame, folder: Path) -> str | None:
    if table.empty:
        return None
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(table) + 1.5))
    y = np.arange(len(table))
    low = table.p_improvement - table.p_improvement_ci_low
    high = table.p_improvement_ci_high - table.p_improvement
    ax.errorbar(table.p_improvement, y, xerr=[low, high], fmt="o", color="tab:blue", capsize=3)
    ax.axvline(0.5, color="black", linestyle="--", linewidth=0.8)
    ax.set_yticks(y, table.variant)
    ax.invert_yaxis()
    ax.set_xlim(-0.02, 1.02)
    ax.set_xlabel(f"P(variant solves in fewer episodes than {ablation.baseline}), 95% bootstrap CI")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, folder, "probability_of_improvement")


# --- text ------------------------------------------------------------------------------------------------
def _threshold(ablation: Ablation) -> float | None:
    for params in ablation.params.values():
        value = params.get("solve_threshold", "None")
        if value not in ("None", ""):
            return float(value)
    env = ablation.grid["base"].get("env_id", "")
    return {"CartPole-v0": 195.0, "CartPole-v1": 475.0}.get(env)


def _window(ablation: Ablation) -> int:
    return int(ablation.grid["base"].get("solve_window", 100))


def _episodes_cell(row: pd.Series, stat: str) -> str:
    value, low, high = row[f"episodes_{stat}"], row[f"episodes_{stat}_ci_low"], row[f"episodes_{stat}_ci_high"]
    bound = "≥ " if row[f"{stat}_censored"] else ""
    return f"{bound}{_fmt(value)} [{_fmt(low)}, {_fmt(high)}]"


def findings(ablation: Ablation, table: pd.DataFrame, compare: pd.DataFrame) -> list[str]:
    """Sentences from the statistics, each citing its interval; no claim without one. Where unsolved seeds
    are censored the difference is a bound, and the sentence says which way ("at least")."""
    sentences = []
    base = ablation.baseline
    for _, row in compare.iterrows():
        reduction, low, high = row.episodes_reduction, row.episodes_reduction_ci_low, row.episodes_reduction_ci_high
        poi = (
            f"P(fewer episodes) = {row.p_improvement:.2f} "
            f"[{row.p_improvement_ci_low:.2f}, {row.p_improvement_ci_high:.2f}]"
        )
        auc = (
            f"area under the learning curve {_signed_pct(row.auc_change)} (95% CI {_signed_pct(row.auc_change_ci_low)}"
            f" to {_signed_pct(row.auc_change_ci_high)})"
        )
        if np.isnan(low):
            sentences.append(f"**{row.variant}** vs {base}: too few seeds for an interval; no claim.")
        elif low > 0:
            # Better. Censoring in the baseline only hides how much slower it is: the gain is a lower bound.
            bound = "at least " if row.baseline_censored and not row.variant_censored else ""
            caveat = " (unsolved seeds on both sides counted at the budget)" if row.variant_censored else ""
            sentences.append(
                f"**{row.variant}** solves in {bound}{_pct(reduction)} fewer episodes than {base} (IQM; 95% CI "
                f"{_pct(low)} to {_pct(high)}){caveat}; {poi}; {auc}."
            )
        elif high < 0:
            bound = "at least " if row.variant_censored and not row.baseline_censored else ""
            caveat = " (unsolved seeds on both sides counted at the budget)" if row.baseline_censored else ""
            sentences.append(
                f"**{row.variant}** needs {bound}{_pct(-reduction)} more episodes than {base} (IQM; 95% CI "
                f"{_pct(-high)} to {_pct(-low)} more){caveat}; {poi}; {auc}."
            )
        else:
            sentences.append(
                f"**{row.variant}** vs {base}: the data do not separate them on episodes to solve (change "
                f"{_signed_pct(-reduction)}, 95% CI {_signed_pct(-high)} to {_signed_pct(-low)}; {poi}); {auc}."
            )
    for _, row in table.iterrows():
        if row.seeds_run and row.solved < row.seeds_run:
            sentences.append(
                f"**{row.variant}**: {row.seeds_run - row.solved} of {row.seeds_run} seeds did not solve within "
                f"{_fmt(row.budget)} episodes."
            )
    return sentences


def _signed_pct(x: float) -> str:
    value = int(round(100 * x))
    return f"{value:+d}%" if value else "0%"


def _markdown_table(frame: pd.DataFrame) -> str:
    header = "| " + " | ".join(frame.columns) + " |"
    rule = "| " + " | ".join("---" for _ in frame.columns) + " |"
    rows = ["| " + " | ".join(str(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join([header, rule, *rows])


def _architecture(params: dict[str, str]) -> str:
    sizes = params.get("model.hidden_sizes", "[]")
    text = f"{params.get('model.architecture', 'mlp')} hidden {sizes} {params.get('model.activation', '')}"
    if params.get("model.architecture") == "cnn":
        conv, kernel, history = (params.get(f"model.{k}") for k in ("conv_channels", "kernel_size", "history"))
        text += f", conv {conv} k={kernel} over {history} obs"
    if float(params.get("model.dropout", 0)) > 0:
        text += f", dropout {params['model.dropout']}"
    if float(params.get("l2", 0)) > 0:
        text += f", L2 {params['l2']}"
    return text


def _method(ablation: Ablation, table: pd.DataFrame) -> str:
    base = ablation.grid["base"]
    threshold = _threshold(ablation)
    seeds = ablation.grid["seeds"]
    lines = [
        f"**Environment.** `{base['env_id']}`. Solved when the mean return over {_window(ablation)} consecutive "
        f"episodes reaches {threshold:g}; a trial stops then, or at its budget of {base['max_episodes']:,} episodes.",
        "",
        "**Algorithm.** REINFORCE (vanilla policy gradient): actions sampled from the softmax of the policy's "
        "logits; each episode's rewards discounted, the returns normalised by mean and standard deviation "
        "across the update's batch; loss = softmax cross-entropy of the taken actions weighted by those returns; "
        "one Adam step per update. L2 is a loss term over weight matrices.",
        "",
        f"**Seeds.** {len(seeds)} per variant ({', '.join(map(str, seeds))}): each seeds torch, the action sampler "
        "and the environment.",
        "",
        "**Variants** (each changes the listed knobs over the base; hyper-parameters are those of the base unless "
        "listed):",
        "",
    ]
    rows = []
    for variant in ablation.grid["variants"]:
        params = ablation.params.get(variant["name"], {})
        count = table.loc[table.variant == variant["name"], "parameter_count"]
        overrides = ", ".join(f"{k} = {v}" for k, v in variant["overrides"].items()) or "(the base)"
        rows.append(
            {
                "variant": variant["name"] + (" (baseline)" if variant["name"] == ablation.baseline else ""),
                "changes": overrides,
                "architecture": _architecture(params) if params else "–",
                "parameters": _fmt(count.iloc[0]) if len(count) and not pd.isna(count.iloc[0]) else "–",
            }
        )
    lines.append(_markdown_table(pd.DataFrame(rows)))
    lines += ["", "**Base hyper-parameters.**", ""]
    keep = ("learning_rate", "gamma", "episodes_per_update", "max_episodes", "solve_window", "l2")
    lines.append(_markdown_table(pd.DataFrame([{k: base[k] for k in keep if k in base}])))
    return "\n".join(lines)


def _convergence_markdown(table: pd.DataFrame) -> str:
    rows = []
    for _, row in table.iterrows():
        if not row.seeds_run:
            rows.append({"variant": row.variant, "seeds": 0})
            continue
        rows.append(
            {
                "variant": row.variant,
                "seeds": int(row.seeds_run),
                "solved": f"{int(row.solved)}/{int(row.seeds_run)}",
                "episodes to solve, median [95% CI]": _episodes_cell(row, "median"),
                "episodes to solve, IQM [95% CI]": _episodes_cell(row, "iqm"),
                "env steps to solve (median, solved)": _fmt(row.env_steps_to_solve_median),
                "seconds to solve (median, solved)": _fmt(row.wall_s_to_solve_median, 1),
                "final rolling return (IQM)": _fmt(row.final_rolling_mean_iqm, 1),
                "AUC (IQM) [95% CI]": f"{_fmt(row.auc_iqm, 1)} [{_fmt(row.auc_ci_low, 1)}, {_fmt(row.auc_ci_high, 1)}]",
            }
        )
    return _markdown_table(pd.DataFrame(rows).fillna("–"))


def _videos(ablation: Ablation, tracker: Tracker, folder: Path) -> list[dict[str, str]]:
    """Best and median seed of each variant (by episodes to solve, then final rolling mean)."""
    chosen = []
    folder.mkdir(parents=True, exist_ok=True)
    for variant in ablation.variants:
        done = ablation.finished[ablation.finished.variant == variant].sort_values(
            ["censored_episodes", "final_rolling_mean"], ascending=[True, False]
        )
        if done.empty:
            continue
        picks = {"best": done.iloc[0], "median": done.iloc[(len(done) - 1) // 2]}
        for label, row in picks.items():
            if label == "median" and row.run_id == picks["best"].run_id and len(done) > 1:
                continue
            target = folder / f"{variant}-{label}-seed{row.seed}.mp4"
            try:
                downloaded = tracker.download(row.run_id, "video.mp4")
            except Exception:  # noqa: BLE001 - a run without a video (record_video = false)
                continue
            shutil.copyfile(downloaded, target)
            chosen.append(
                {
                    "variant": variant,
                    "label": label,
                    "seed": str(row.seed),
                    "path": f"videos/{target.name}",
                    "caption": f"{variant}, {label} seed ({row.seed}): "
                    + (
                        f"solved at episode {int(row.episodes_to_solve)}"
                        if row.solved == 1
                        else f"unsolved after {int(row.episodes_run)} episodes"
                    )
                    + (f", greedy return {row.greedy_return:.0f}" if not pd.isna(row.greedy_return) else ""),
                }
            )
    return chosen


def _reproducibility(ablation: Ablation) -> str:
    tags = ablation.launch["tags"]
    environment = ablation.launch["environment"]
    versions = environment.get("packages", {})
    lines = [
        f"- Command: `{tags.get('ablate.command') or 'ablate run ' + tags.get('ablate.experiment_file', '')}`",
        f"- Code version (git commit): `{tags.get('mlflow.source.git.commit', 'unknown')}`",
        f"- Machine: {environment.get('machine', 'unknown')}",
        f"- Python {environment.get('python', '?')}; " + ", ".join(f"{k} {v}" for k, v in versions.items()),
        f"- MLflow launch run: `{ablation.launch['run_id']}` (generation `{tags.get('ablate.generation', '')}`)",
        f"- Report written {time.strftime('%Y-%m-%d %H:%M')}, from the tracking store only: "
        f"`ablate report {ablation.name}`",
    ]
    return "\n".join(lines)


def build_markdown(
    ablation: Ablation,
    figures: dict[str, str | None],
    videos: list[dict[str, str]],
    table: pd.DataFrame,
    compare: pd.DataFrame,
) -> tuple[str, str]:
    """The report in Markdown, and the same with a ``<video>`` block in place of the video links (for HTML)."""
    description = ablation.grid.get("description") or ""
    failed = ablation.trials[ablation.trials.status.isin(["FAILED", "KILLED", "NOT RUN"])]
    parts = [f"# Ablation report: {ablation.name}", "", description, ""]
    if len(failed):
        parts += [
            f"> {len(failed)} of {len(ablation.trials)} trials did not finish (failed, killed or not run); "
            "they are left out of the statistics and listed at the end.",
            "",
        ]
    parts += ["## Method", "", _method(ablation, table), ""]
    parts += [
        "## Convergence",
        "",
        "Episodes to solve: unsolved seeds are **censored at the budget** (counted as the budget, a lower bound); "
        "a statistic that uses a censored value is marked ≥. Intervals are 95% percentile bootstrap intervals "
        "over seeds (SciPy). AUC is the mean rolling return over the whole budget (a solved trial keeps its last "
        "value).",
        "",
        _convergence_markdown(table),
        "",
        "Tables as CSV: `tables/convergence.csv`, `tables/comparisons.csv`, `tables/trials.csv`.",
        "",
        "## Findings",
        "",
        *[f"- {s}" for s in findings(ablation, table, compare)],
        "",
        "## Figures",
        "",
        f"![Learning curves against episodes]({figures['curves_episodes']})",
        "",
        f"![Learning curves against wall-clock time]({figures['curves_wall']})",
        "",
        f"![Episodes to solve per seed]({figures['spread']})",
        "",
    ]
    if figures.get("improvement"):
        parts += [f"![Probability of improvement over {ablation.baseline}]({figures['improvement']})", ""]
    parts += ["## Videos of the greedy agent", "", "VIDEOS_PLACEHOLDER", ""]
    if len(failed):
        parts += ["## Trials that did not finish", ""]
        parts += [
            f"- `{r.key}`: {r.status}{(' — ' + str(r.error)) if isinstance(r.error, str) and r.error else ''}"
            for r in failed.itertuples()
        ]
        parts.append("")
    parts += ["## Reproducibility", "", _reproducibility(ablation), ""]
    text = "\n".join(parts)
    links = "\n".join(f"- [{v['caption']}]({v['path']})" for v in videos) or "No videos were recorded."
    blocks = "\n".join(
        f'<figure class="video"><video controls muted loop preload="metadata" src="{v["path"]}"></video>'
        f"<figcaption>{html.escape(v['caption'])}</figcaption></figure>"
        for v in videos
    )
    html_md = text.replace("VIDEOS_PLACEHOLDER", f'<div class="videos">\n{blocks}\n</div>' if videos else links)
    return text.replace("VIDEOS_PLACEHOLDER", links), html_md


CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222; }
table { border-collapse: collapse; font-size: 0.85em; margin: 1em 0; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: right; }
th:first-child, td:first-child { text-align: left; }
img { max-width: 100%; }
.videos { display: flex; flex-wrap: wrap; gap: 12px; }
figure.video { margin: 0; width: 260px; font-size: 0.8em; }
figure.video video { width: 260px; }
blockquote { background: #fff4e0; border-left: 4px solid #f0a000; margin: 1em 0; padding: 0.5em 1em; }
"""


def _inline(html_text: str, folder: Path) -> str:
    """Replace relative ``src`` references with data URIs, so report.html is one self-contained file."""
    mime = {".png": "image/png", ".svg": "image/svg+xml", ".mp4": "video/mp4"}

    def replace(match: re.Match) -> str:
        path = folder / match.group(2)
        if not path.is_file():
            return match.group(0)
        data = base64.b64encode(path.read_bytes()).decode()
        return f'{match.group(1)}="data:{mime.get(path.suffix, "application/octet-stream")};base64,{data}"'

    return re.sub(r'(src)="((?:figures|videos)/[^"]+)"', replace, html_text)


def write_report(name: str, tracking_uri: str | None = None, out_root: Path = Path("reports")) -> Path:
    """Build the report of experiment ``name`` into ``out_root/name/`` and return that folder."""
    folder = out_root / name
    try:
        ablation = load_ablation(name, tracking_uri)
    except NoResults as error:
        return _write_empty(folder, name, str(error))
    if ablation.finished.empty:
        return _write_empty(
            folder,
            name,
            f"all {len(ablation.trials)} trials of the newest launch failed or did not run; see the MLflow runs "
            "for their errors:\n\n"
            + "\n".join(
                f"- `{r.key}`: {r.status} {r.error if isinstance(r.error, str) else ''}"
                for r in ablation.trials.itertuples()
            ),
        )
    for sub in ("figures", "tables", "videos"):
        shutil.rmtree(folder / sub, ignore_errors=True)
        (folder / sub).mkdir(parents=True, exist_ok=True)
    table = convergence_table(ablation)
    compare = comparisons(ablation)
    table.to_csv(folder / "tables" / "convergence.csv", index=False)
    compare.to_csv(folder / "tables" / "comparisons.csv", index=False)
    ablation.trials.to_csv(folder / "tables" / "trials.csv", index=False)
    curves_episodes, curves_wall = figure_learning_curves(ablation, folder / "figures")
    figures = {
        "curves_episodes": curves_episodes,
        "curves_wall": curves_wall,
        "spread": figure_episodes_to_solve(ablation, folder / "figures"),
        "improvement": figure_improvement(ablation, compare, folder / "figures"),
    }
    videos = _videos(ablation, Tracker(tracking_uri, name), folder / "videos")
    text, html_md = build_markdown(ablation, figures, videos, table, compare)
    (folder / "report.md").write_text(text)
    body = markdown.markdown(html_md, extensions=["tables"])
    page = (
        f"<!doctype html><html><head><meta charset='utf-8'><title>Ablation report: {html.escape(name)}</title>"
        f"<style>{CSS}</style></head><body>{body}</body></html>"
    )
    (folder / "report.html").write_text(_inline(page, folder))
    return folder


def terminal_summary(folder: Path) -> str:
    """The convergence table in a few lines, for the end of ``ablate run``."""
    path = folder / "tables" / "convergence.csv"
    if not path.is_file():
        return (folder / "report.md").read_text().strip().splitlines()[-1]
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


def _write_empty(folder: Path, name: str, reason: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    text = f"# Ablation report: {name}\n\n**No results to report.** {reason}\n"
    (folder / "report.md").write_text(text)
    page = f"<!doctype html><html><head><meta charset='utf-8'></head><body>{markdown.markdown(text)}</body></html>"
    (folder / "report.html").write_text(page)
    return folder


def cmd_report(args: argparse.Namespace) -> int:
    name = args.experiment
    if name.endswith(".toml") or "/" in name:
        name = load_experiment(name).name  # a bad file is a ConfigError: one line, exit 2
    folder = write_report(name, args.tracking_uri, args.out)
    text = (folder / "report.md").read_text()
    if "**No results to report.**" in text:
        print(text.split("**No results to report.**", 1)[1].strip().splitlines()[0])
        print(f"wrote {folder}/report.md (empty report)")
        return 1
    print(f"wrote {folder}/report.md and report.html")
    return 0
