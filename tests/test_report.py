"""The report: from a tiny real ablation (Ray + MLflow), its numbers against the tracked metrics, its HTML in
headless Chromium and its PDF typeset by the typst wheel; from small synthetic stores (the tracker's own writes, no
training), Pong without a threshold, one seed, escaping, generations, variant selection, and the cases that must
write nothing."""

import hashlib
import json
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from devtools import DevTools, chromium_flags
from scipy import stats
from stores import fresh_store

from ablate.cli import main
from ablate.experiment import load_experiment
from ablate.launch.curve import CurveReducer
from ablate.launch.tracking import Tracker
from ablate.reporting.document import build_report
from ablate.reporting.reader import RunReader
from ablate.reporting.typeset import page_counts

ARTIFACTS = Path(__file__).parent / "artifacts"
EXPERIMENT = """
name = "reportable"
seeds = 3
baseline = "small"
[base]
env_id = "CartPole-v1"
max_episodes = 40
episodes_per_update = 8
solve_window = 8
solve_threshold = 25.0
video_max_frames = 40
[[variants]]
name = "small"
hidden_sizes = [8]
[[variants]]
name = "big"
hidden_sizes = [64, 64]
"""


@pytest.fixture(scope="module")
def built_report(run_quiet, tmp_path_factory):
    folder = tmp_path_factory.mktemp("report")
    uri = fresh_store(folder / "mlflow.db")
    path = folder / "reportable.toml"
    path.write_text(EXPERIMENT)
    outcome = run_quiet(load_experiment(path), folder, uri)
    assert outcome.exit_code == 0
    return build_report("reportable", tracking_uri=uri, out_root=folder / "reports").folder, uri


def test_report_files(built_report):
    folder, _ = built_report
    for name in ("report.md", "report.html", "tables/convergence.csv", "tables/comparisons.csv", "tables/trials.csv"):
        assert (folder / name).is_file(), name
    figures = ("learning_curves_episodes", "learning_curves_by_variant", "learning_curves_wallclock")
    for figure in (*figures, "episodes_to_solve", "performance_vs_parameters"):
        assert (folder / "figures" / f"{figure}.png").stat().st_size > 5000, figure
        assert (folder / "figures" / f"{figure}.svg").is_file()
    assert list((folder / "videos").glob("small-seed*.mp4")) and list((folder / "videos").glob("big-seed*.mp4"))
    text = (folder / "report.md").read_text()
    body, appendix = text.split("\n## Appendix\n")
    for section in ("Question", "Method", "Claims", "Figures", "Limitations"):
        assert f"## {section} (generated)" in body, section
    assert "## Discussion" in body and "## References" in body
    for section in ("Method in detail", "Results", "Every comparison", "More figures", "Videos", "Every limitation"):
        assert re.search(rf"^### [A-Z]\. {section}", appendix, flags=re.M), section
    assert "Reproducibility (generated)" in appendix and ". Glossary" in appendix
    assert "Williams, R. J. (1992)" in text and "Agarwal, R." in text and "MIT 6.S191" in text
    findings = text.split("Every comparison (generated)")[1].split("\n### ")[0].strip().splitlines()[2:]
    for line in (x for x in findings if x.startswith("    - ")):  # no claim without an interval
        assert "CI" in line or "exploratory: too few seeds" in line, line
    figure_numbers = [int(n) for n in re.findall(r"^\*Figure (\d+)\. ", text, flags=re.M)]
    assert figure_numbers == list(range(1, len(figure_numbers) + 1)) and len(figure_numbers) >= 5
    assert "(baseline)" not in text and "baseline (reference)" in text
    assert "one greedy episode" in text and "contended" in text


def test_report_tables_match_the_tracked_metrics(built_report):
    folder, uri = built_report
    table = pd.read_csv(folder / "tables" / "convergence.csv").set_index("variant")
    runs = Tracker(uri, "reportable").trial_runs()
    assert len(runs) == 6
    for variant in ("small", "big"):
        mine = [r for r in runs if r.variant == variant]
        solved = [r for r in mine if r.metrics["solved"] == 1]
        censored = [r.metrics["episodes_to_solve"] if r.metrics["solved"] == 1 else 40 for r in mine]
        row = table.loc[variant]
        assert row.seeds_run == 3 and row.solved == len(solved)
        assert row.fraction_solved == pytest.approx(len(solved) / 3)
        assert row.episodes_median == pytest.approx(np.median(censored))
        assert row.episodes_iqm == pytest.approx(stats.trim_mean(censored, 0.25))
        finals = [r.metrics["final_rolling_mean"] for r in mine]
        assert row.final_rolling_mean_iqm == pytest.approx(stats.trim_mean(finals, 0.25))
        assert row.parameter_count == mine[0].metrics["parameter_count"]
        if solved:
            steps = [r.metrics["env_steps_to_solve"] for r in solved]
            assert row.env_steps_to_solve_median == pytest.approx(np.median(steps))


def test_html_is_self_contained(built_report):
    folder, _ = built_report
    page = (folder / "report.html").read_text()
    assert page.count("<img") >= 5 and "<video" in page
    assert not re.search(r'src="(?!data:)', page), "every src is a data URI"


def test_report_is_attached_to_the_launch_run(built_report):
    folder, uri = built_report
    tracker = RunReader(uri, "reportable")
    launch = tracker.launches()[0].info.run_id
    attached = {a.path for a in tracker.client.list_artifacts(launch, "report")}
    assert {"report/report.md", "report/report.html", "report/figures", "report/tables"} <= attached
    assert "report/videos" in attached  # recorded by the report (a launch's trial runs hold none)


def _chromium() -> str | None:
    """Chromium and poppler-utils (pdftoppm renders the PDF's pages), installed with apt-get when missing."""
    if not (shutil.which("chromium") and shutil.which("pdftoppm")) and shutil.which("apt-get"):
        install = "apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium poppler-utils"
        subprocess.run(["bash", "-c", install], capture_output=True, timeout=900)
    return shutil.which("chromium")


CHECK_SCRIPT = """
<script>
window.addEventListener('load', () => {
  const media = [...document.querySelectorAll('video')];
  const waits = media.map(v => new Promise(done => {
    if (v.readyState >= 1) return done();
    v.addEventListener('loadedmetadata', () => done(), {once: true});
    v.addEventListener('error', () => done(), {once: true});
    v.load();
  }));
  Promise.all(waits).then(() => {
    const images = [...document.querySelectorAll('img')];
    const badImages = images.filter(i => !(i.complete && i.naturalWidth > 0)).length;
    const badVideos = media.filter(v => v.readyState < 1 || v.error).length;
    const figures = [...document.querySelectorAll('figure[id^="figure-"]')];
    const numbered = figures.filter((f, i) => f.querySelector('img') &&
      (f.querySelector('figcaption')?.textContent || '').startsWith(`Figure ${i + 1}. `) &&
      f.querySelector('figcaption').textContent.length > 80).length;
    const unframed = images.filter(i => !i.closest('figure')).length;
    const table = document.querySelector('table');
    const column = [...table.querySelectorAll('th')].findIndex(th => th.textContent.trim() === 'variant');
    const align = getComputedStyle(table.querySelectorAll('tbody tr')[0].children[column]).textAlign;
    const out = document.createElement('pre');
    out.id = 'media-check';
    out.textContent = `images=${images.length} bad_images=${badImages} videos=${media.length} ` +
      `bad_videos=${badVideos} figures=${figures.length} numbered=${numbered} unframed=${unframed} align=${align}`;
    document.body.appendChild(out);
  });
});
</script>
"""


def test_html_in_headless_chromium(built_report, tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip("Chromium is missing and apt-get could not install it (no root or no Debian mirror)")
    folder, uri = built_report
    probe = tmp_path / "probe.html"
    probe.write_text((folder / "report.html").read_text().replace("</body>", CHECK_SCRIPT + "</body>"))
    # Over DevTools, the check waits for the page's own answer (every video's metadata or error), not for
    # a --virtual-time-budget: media loads do not hold virtual time, so a loaded machine dumped the page
    # before the videos answered and the check found nothing.
    browser_session = DevTools(browser, chromium_flags(tmp_path / "profile"), timeout_s=300)
    try:
        browser_session.open(probe.as_uri())
        check = browser_session.evaluate(
            "new Promise(done => { const look = () => { const out = document.getElementById('media-check'); "
            "if (out) done(out.textContent); else setTimeout(look, 50); }; look(); })"
        )
        ARTIFACTS.mkdir(exist_ok=True)
        shot = ARTIFACTS / "report_screenshot.png"
        browser_session.open((folder / "report.html").as_uri())
        browser_session.screenshot(shot, 1200, 2400)
    finally:
        browser_session.close()
    found = re.search(
        r"images=(\d+) bad_images=(\d+) videos=(\d+) bad_videos=(\d+) figures=(\d+) "
        r"numbered=(\d+) unframed=(\d+) align=(\w+)",
        check or "",
    )
    assert found, f"the check script did not report: {check!r}"
    images, bad_images, videos, bad_videos, figures, numbered, unframed = map(int, found.groups()[:7])
    assert images >= 5 and bad_images == 0
    assert videos >= 2 and bad_videos == 0
    assert figures == images and numbered == figures and unframed == 0, found.group(0)
    assert found.group(8) == "left"  # the variant column
    assert shot.is_file() and shot.stat().st_size > 10_000


def test_the_pdf_is_typeset_from_pip_installed_parts(built_report):
    """report.pdf comes from the typst wheel alone (no browser): a body of at most 4 pages before the appendix,
    page numbers, every figure and table numbered as report.md numbers them; its pages render to PNG."""
    folder, _ = built_report
    pdf = folder / "report.pdf"
    assert pdf.is_file() and pdf.read_bytes().startswith(b"%PDF")
    body, total = page_counts(folder / "report.typ")
    assert body is not None and 1 <= body <= 4 and total > body, (body, total)
    text = (folder / "report.md").read_text()
    figures = [int(n) for n in re.findall(r"^\*Figure (\d+)\. ", text, flags=re.M)]
    tables = [int(n) for n in re.findall(r"^\*Table (\d+)\. ", text, flags=re.M)]
    assert figures == list(range(1, len(figures) + 1)) and tables == list(range(1, len(tables) + 1))
    assert len(tables) >= 5
    if shutil.which("pdftotext") is None:
        _chromium()  # installs poppler-utils with Chromium where apt-get can
    if shutil.which("pdftotext") is None or shutil.which("pdftoppm") is None:
        pytest.skip("the PDF was typeset; pdftotext/pdftoppm (poppler-utils) are missing to read it back")
    printed = subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True, text=True, timeout=60).stdout
    for number in figures:
        assert f"Figure {number}." in printed, number
    for number in tables:
        assert f"Table {number}." in printed, number
    assert re.search(rf"^1 ?/ ?{total}$", printed, flags=re.M) and re.search(rf"^{total} ?/ ?{total}$", printed, re.M)
    for old in ARTIFACTS.glob("report_pdf-*.png"):
        old.unlink()
    ARTIFACTS.mkdir(exist_ok=True)
    subprocess.run(["pdftoppm", "-r", "40", "-png", str(pdf), str(ARTIFACTS / "report_pdf")], check=True, timeout=120)
    pages = sorted(ARTIFACTS.glob("report_pdf-*.png"))
    assert len(pages) == total and all(p.stat().st_size > 3_000 for p in pages)


# --- synthetic stores ------------------------------------------------------------------------------------------
def make_store(folder: Path, name: str, variants: dict[str, dict], seeds=(0, 1, 2), budget: int = 40, **options) -> str:
    """One launch of ``name`` in ``folder/mlflow.db``, written by the tracker as a run would. ``variants`` maps a
    name to ``curve(seed) -> returns`` and optionally ``architecture``, ``hidden``, ``parameters``. Options:
    ``env_id``, ``threshold`` (None: no solve threshold), ``window``, ``description``, ``generation``, ``failed``
    (keys recorded FAILED), ``only`` (keys to run; the rest are not run), ``observation`` (log observation.png),
    ``base`` (more of grid.json's base: ``{"model.activation": "relu"}``), ``stopped_at`` (the solve threshold
    the trials stopped at and recorded as ``env.solve_threshold``, the file's ``threshold`` unset)."""
    env_id, threshold = options.get("env_id", "CartPole-v1"), options.get("threshold", 25.0)
    stopped_at = options.get("stopped_at", threshold)
    record = {"env.id": env_id, "env.solve_threshold": str(stopped_at)} if "stopped_at" in options else None
    window, generation = options.get("window", 8), options.get("generation", "gen1")
    db = folder / "mlflow.db"
    uri = f"sqlite:///{db}" if db.exists() else fresh_store(db)  # several experiments may share one store
    tracker = Tracker(uri, name)
    base = {"env_id": env_id, "max_episodes": budget, "solve_window": window, "solve_threshold": threshold}
    base |= {"learning_rate": 0.03, "gamma": 0.95, "episodes_per_update": 4} | options.get("base", {})
    trials = [{"key": f"{v}-s{s}", "variant": v, "seed": s} for v in variants for s in seeds]
    grid = {"experiment": name, "description": options.get("description", "synthetic"), "seeds": list(seeds)}
    grid |= {"baseline": next(iter(variants)), "base": base, "trials": trials}
    grid["variants"] = [{"name": v, "overrides": spec.get("overrides", {})} for v, spec in variants.items()]
    environment = {"python": "3.11", "packages": {}, "machine": "a test machine", "cpu_model": "Test CPU 9000"}
    environment["torch_cpu_capability"] = "AVX2"
    files = {"grid.json": json.dumps(grid), "environment.json": json.dumps(environment)}
    launch = tracker.start_launch(generation, name, {"ablate.command": f"ablate run {name}.toml"}, files)
    for trial in trials:
        if trial["key"] not in options.get("only", {trial["key"]}):
            continue
        spec = variants[trial["variant"]]
        params = {"variant": trial["variant"], "model.architecture": spec.get("architecture", "mlp")}
        params |= {"model.hidden_sizes": json.dumps(spec.get("hidden", [8])), "model.activation": "relu"}
        if record is not None:  # the file's threshold, unset: not tracked (``launch.records.tracked_params``)
            params["solve_threshold"] = threshold
        write_trial(
            tracker,
            (launch, generation),
            trial,
            spec["curve"](trial["seed"]),
            params,
            (budget, window, stopped_at),
            parameters=spec.get("parameters", 58),
            failed=trial["key"] in options.get("failed", ()),
            observation=options.get("observation", False),
            record=record,
        )
    tracker.finish_launch(launch, "FINISHED", {})
    return uri


def write_trial(
    tracker, launch, trial, returns, params, budget, parameters=58, failed=False, observation=False, record=None
):
    """One finished (or failed) trial run as the driver writes it: curve points, summary metrics, episodes.csv.
    ``launch``: (launch run id, generation); ``budget``: (episodes, solve window, threshold or None); ``record``:
    the ``env.*`` params a trial records of the env it ran against."""
    (launch_id, generation), (episodes, window, threshold) = launch, budget
    returns = np.asarray(returns, float)
    rolling = [returns[max(0, i - window + 1) : i + 1].mean() for i in range(len(returns))]
    params = {"max_episodes": episodes, "solve_window": window, "solve_threshold": threshold} | params
    params = {k: v for k, v in params.items() if v is not None}
    run_id = tracker.start_trial(launch_id, generation, trial["key"], trial["variant"], trial["seed"], params, "abc123")
    if "stage" in trial:
        tracker.client.set_tag(run_id, "ablate.stage", trial["stage"])
    rows = [
        SimpleNamespace(
            episode=i + 1,
            update=i // 4 + 1,
            episode_return=r,
            rolling_mean=rolling[i],
            loss=0.1,
            entropy=0.5,
            wall_s=0.01 * (i + 1),
            length=10,
            env_steps=10 * (i + 1),
        )
        for i, r in enumerate(returns)
    ]
    reducer = CurveReducer(episodes)
    tracker.log_points(trial["key"], reducer.add(rows) + reducer.flush())
    if failed:
        tracker.fail_trial(trial["key"], "injected fault <b>boom</b>")
        return
    hits = [i + 1 for i in range(window - 1, len(rolling)) if threshold is not None and rolling[i] >= threshold]
    summary = {"solved": float(bool(hits)), "episodes_run": float(len(returns)), "final_rolling_mean": rolling[-1]}
    summary |= {"env_steps": 10.0 * len(returns), "wall_s": 0.01 * len(returns), "steps_per_s": 1000.0}
    summary["parameter_count"] = float(parameters)
    if hits:
        summary |= {"episodes_to_solve": hits[0], "env_steps_to_solve": 10.0 * hits[0], "wall_s_to_solve": 0.1}
    artifacts = Path(tempfile.mkdtemp(prefix="artifacts-"))
    pd.DataFrame([vars(row) for row in rows]).to_csv(artifacts / "episodes.csv", index=False)  # what it reads
    if observation:
        (artifacts / "observation.png").write_bytes(ARTIFACT_PNG)
    tracker.finish_trial(trial["key"], summary, artifacts, params=record)
    shutil.rmtree(artifacts, ignore_errors=True)


# a 1x1 PNG: what the report does with the trial's observation figure does not depend on its pixels
ARTIFACT_PNG = bytes.fromhex(
    "89504e470d0a1a0a0000000d4948445200000001000000010806000000"
    "1f15c4890000000d49444154789c6360606060000000050001a5f645400000000049454e44ae426082"
)


def rising(start, stop, n=40):
    return lambda seed: np.linspace(start, stop, n) + np.sin(np.arange(n) + seed)


EVIL = "<img src=x onerror=alert(1)>"


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """One SQLite store with several experiments (creating a store costs seconds; reading it does not)."""
    folder = tmp_path_factory.mktemp("synthetic")
    pong = {
        "cnn": {"curve": rising(-21, -12, 60), "architecture": "cnn", "hidden": [64], "parameters": 97_414},
        "mlp": {"curve": rising(-21, -17, 60), "hidden": [64], "parameters": 410_118},
    }
    options = {"env_id": "ALE/Pong-v5", "threshold": None, "window": 10, "observation": True}
    uri = make_store(folder, "pong", pong, seeds=(0,), budget=60, **options)
    evil = {"base<script>alert(1)</script>": {"curve": rising(5, 30)}, EVIL: {"curve": rising(5, 20)}}
    make_store(folder, "evil", evil, description="<script>alert('description')</script> & more")
    make_store(folder, "single", {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 12)}}, seeds=(0,))
    l2 = {"l2": 0.001}
    knobs = {
        "cnn": {"curve": rising(-21, -12, 60), "architecture": "cnn"},
        "cnn-l2": {"curve": rising(-21, -13, 60), "architecture": "cnn", "overrides": l2},
        "mlp": {"curve": rising(-21, -17, 60), "overrides": {"architecture": "mlp"}},
        "mlp-l2": {"curve": rising(-21, -18, 60), "overrides": {"architecture": "mlp"} | l2},
    }
    make_store(folder, "knobs", knobs, seeds=(0, 1, 2), budget=60, **(options | {"observation": False}))
    make_store(folder, "broken", {"boom": {"curve": rising(5, 10)}}, seeds=(0, 1), failed={"boom-s0", "boom-s1"})
    cartpole = {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 25)}, "c": {"curve": rising(5, 12)}}
    make_store(folder, "gens", cartpole, generation="complete1")
    make_store(folder, "gens", cartpole, generation="partial2", only={"a-s0", "b-s0"})
    return folder, uri


def test_pong_report_without_a_threshold_and_with_one_seed(store, tmp_path, monkeypatch):
    # issue 9: `TypeError: unsupported format string passed to NoneType` (no threshold) and
    # `ValueError: cannot convert float NaN to integer` (one seed)
    monkeypatch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test", raising=False)
    _, uri = store
    folder = build_report("pong", tracking_uri=uri, out_root=tmp_path).folder
    text = (folder / "report.md").read_text()
    assert "No solve threshold" in text and "[no interval: 1 seed]" in text
    assert "1 seed gives no interval" in text  # no claim from one seed
    assert "2-D CNN over the 80×80 frame difference" in text and "97,414" in text
    assert "MLP over the 6,400 pixels" in text and "410,118" in text
    assert "episodes to reach -15" in text and "improvement over untrained" in text
    assert "One observation of ALE/Pong-v5" in text and (folder / "figures" / "observation.png").is_file()
    videos = text.split(". Videos")[1].split("\n### ")[0]  # this store recorded none: no promise of any
    assert "No videos were recorded." in videos and "Videos show" not in text and "greedy episode" not in text
    from ablate.reporting.results import load_ablation
    from ablate.reporting.sections import limitations
    from ablate.reporting.tables import convergence_table

    ablation = load_ablation("pong", uri)  # with videos, Pong's are of the sampling policy, not greedy
    said = dict(limitations(ablation, convergence_table(ablation), None, videos=True))
    assert said["videos"].startswith("**Videos show one stretch of play**") and "greedy" not in said["videos"]
    convergence = pd.read_csv(folder / "tables" / "convergence.csv").set_index("variant")
    assert {"return_at_60_iqm", "auc_iqm", "improvement_iqm", "episodes_to_-15_median"} <= set(convergence.columns)
    assert convergence.loc["cnn", "auc_iqm"] > convergence.loc["mlp", "auc_iqm"]


def test_each_architectures_knobs_are_compared_with_that_architecture(store, tmp_path, monkeypatch):
    # the Pong ablation had mlp-l2 against cnn: two changes at once, and a limitation that said so
    monkeypatch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test", raising=False)
    _, uri = store
    folder = build_report("knobs", tracking_uri=uri, out_root=tmp_path).folder
    text = (folder / "report.md").read_text()
    findings = text.split("Every comparison (generated)")[1].split("\n### ")[0]
    assert "mlp-l2 against mlp" in findings.splitlines()[2]
    headers = [line for line in findings.splitlines() if line.startswith("- **")]
    assert headers == ["- **cnn-l2** vs cnn:", "- **mlp** vs cnn:", "- **mlp-l2** vs mlp:"]
    assert "knobs at once" not in text and "more than one knob" not in text
    assert "| primary claim |" in text and "| vs mlp: " in text and "**mlp-l2** vs mlp: **undetermined**" in text
    assert "| mlp |  | architecture = mlp |" not in text and "reference of mlp-l2" in text
    assert "mlp-l2 vs mlp" not in text  # the figure's panel titles are in the PNG, its caption says how
    assert "its reference (grey)" in text
    compare = pd.read_csv(folder / "tables" / "comparisons.csv")
    assert dict(zip(compare.variant, compare.reference, strict=False)) == {
        "cnn-l2": "cnn",
        "mlp": "cnn",
        "mlp-l2": "mlp",
    }
    auc = compare[(compare.variant == "mlp-l2") & (compare.metric == "auc")].iloc[0]
    table = pd.read_csv(folder / "tables" / "convergence.csv").set_index("variant")
    assert auc.reference_value == pytest.approx(table.loc["mlp", "auc_iqm"])


def test_report_of_one_seed_with_a_threshold(store, tmp_path, monkeypatch):
    # issue 9: `ValueError: cannot convert float NaN to integer` with one seed
    monkeypatch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test", raising=False)
    _, uri = store
    folder = build_report("single", tracking_uri=uri, out_root=tmp_path).folder
    text = (folder / "report.md").read_text()
    assert "[no interval: 1 seed]" in text and "1 seed gives no interval" in text
    # issue 18 item 7: counts and flags were written as floats (solved 1.0, episodes_run 1000.0)
    trials = pd.read_csv(folder / "tables" / "trials.csv", dtype=str)
    assert set(trials.solved) <= {"0", "1"} and set(trials.episodes_run) == {"40"}, trials
    assert set(trials.budget) == {"40"} and set(trials.parameter_count) == {"58"}
    assert trials.final_rolling_mean.str.contains(".").all()  # measures stay floats


def test_the_report_names_the_threshold_a_registered_env_stopped_at(tmp_path, monkeypatch):
    """Issue 44: trials of an env whose spec says ``reward_threshold=100`` stopped at 100; the report said "no
    solve threshold" and made AUC primary. The threshold named is the one the trials recorded."""
    monkeypatch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test", raising=False)
    variants = {"a": {"curve": rising(40, 130)}, "b": {"curve": rising(40, 110)}}
    options = {"env_id": "AblateReportThreshold100-v0", "threshold": None, "stopped_at": 100.0}
    uri = make_store(tmp_path / "store", "threshold100", variants, seeds=(0, 1, 2, 3), **options)
    folder = build_report("threshold100", tracking_uri=uri, out_root=tmp_path / "reports").folder
    text = (folder / "report.md").read_text()
    assert "reaches 100" in text and "no solve threshold" not in text.lower(), text[:3000]
    from ablate.reporting.results import load_ablation

    ablation = load_ablation("threshold100", uri)
    assert ablation.threshold == 100.0 and ablation.primary_metric == "episodes_to_solve" and ablation.any_solved


def test_each_variant_is_a_run_under_the_launch_holding_the_reports_curve_and_claim(tmp_path):
    """Issue 46: MLflow's runs table and charts showed no variant. A report logs one run per variant under the
    launch run: its curve is the report's IQM over seeds at each episode, its claim and convergence row are the
    report's tables; a second report replaces them (one run per variant still), the trials untouched."""

    def noisy(start, stop):
        return lambda seed: np.linspace(start, stop, 40) + np.random.default_rng(seed).normal(0, 4, 40)

    variants = {"a": {"curve": noisy(5, 30)}, "b": {"curve": noisy(5, 60)}, "c": {"curve": noisy(5, 12)}}
    variants["b"]["overrides"] = {"hidden_sizes": [16]}
    uri = make_store(tmp_path / "store", "inmlflow", variants, seeds=tuple(range(8)))
    folder = build_report("inmlflow", tracking_uri=uri, out_root=tmp_path / "reports", pdf=False).folder
    reader = RunReader(uri, "inmlflow")
    launch = reader.launches()[0].info.run_id
    experiment = [reader.experiment_id()]

    def variant_runs():
        found = reader.client.search_runs(experiment, "tags.`ablate.role` = 'variant'")
        return {r.data.tags["ablate.variant"]: r for r in found}

    runs = variant_runs()
    assert sorted(runs) == ["a", "b", "c"]
    assert {r.info.run_name for r in runs.values()} == {"a", "b", "c"}  # the runs table names them
    assert all(r.data.tags["mlflow.parentRunId"] == launch and r.info.status == "FINISHED" for r in runs.values())
    # its settings as tables/trials.csv holds them: b's own hidden sizes, everyone's base learning rate
    assert runs["b"].data.params["hidden_sizes"] == "[16]" and runs["b"].data.params["width"] == "16"
    assert runs["a"].data.params["learning_rate"] == runs["b"].data.params["learning_rate"] == "0.03"
    assert runs["b"].data.tags["ablate.changes"] == "hidden_sizes = [16]"
    window = 8
    for variant, run in runs.items():
        curve = dict(sorted((m.step, m.value) for m in reader.client.get_metric_history(run.info.run_id, "curve/iqm")))
        assert sorted(curve) == list(range(1, 41))  # the report's episodes: 200 points over 40 episodes
        for episode in (1, 10, 25, 40):  # the IQM over seeds of each seed's rolling mean, by hand
            rolling = [np.mean(variants[variant]["curve"](s)[max(0, episode - window) : episode]) for s in range(8)]
            assert curve[episode] == pytest.approx(stats.trim_mean(rolling, 0.25), rel=1e-9)
        low = dict(sorted((m.step, m.value) for m in reader.client.get_metric_history(run.info.run_id, "curve/low")))
        high = dict(sorted((m.step, m.value) for m in reader.client.get_metric_history(run.info.run_id, "curve/high")))
        assert all(low[e] <= curve[e] <= high[e] for e in curve) and any(low[e] < high[e] for e in curve)
    claims = pd.read_csv(folder / "tables" / "claims.csv").set_index("variant")
    assert list(claims.verdict) == ["better", "worse"]  # b solves sooner; c never: its interval is "at least"
    for variant, claim in claims.iterrows():
        run = runs[variant]
        assert run.data.tags["ablate.verdict"] == claim.verdict and run.data.tags["ablate.reference"] == "a"
        metrics = run.data.metrics
        assert metrics["claim/change"] == pytest.approx(claim.change, rel=1e-9)
        for key, end in (("claim/low", claim.change_low), ("claim/high", claim.change_high)):
            assert metrics[key] == pytest.approx(end, rel=1e-9) if np.isfinite(end) else key not in metrics
        assert (metrics["claim/n_variant"], metrics["claim/n_reference"]) == (claim.n_variant, claim.n_reference)
    # c never solves: half the pooled seeds censored, so judged on the AUC (claims.CENSORED_SHARE), no bound
    assert claims.metric["c"] == "auc" and claims.censored["c"] == 0.5 and claims.change_high["c"] < 0
    assert runs["c"].data.tags.get("ablate.bound", "") == ""
    assert "ablate.verdict" not in runs["a"].data.tags  # the baseline claims nothing
    convergence = pd.read_csv(folder / "tables" / "convergence.csv").set_index("variant")
    for variant, row in convergence.iterrows():
        metrics = runs[variant].data.metrics
        for column in ("fraction_solved", "episodes_iqm", "auc_iqm", "seeds_run"):
            assert metrics[f"convergence/{column}"] == pytest.approx(row[column], rel=1e-9), (variant, column)

    trials_before = reader.trial_runs()
    build_report("inmlflow", tracking_uri=uri, out_root=tmp_path / "reports", pdf=False)
    again = variant_runs()
    assert (
        sorted(again) == ["a", "b", "c"]
        and len(reader.client.search_runs(experiment, "tags.`ablate.role` = 'variant'")) == 3
    )
    assert all(again[v].info.run_id != runs[v].info.run_id for v in again)  # replaced, not appended to
    assert len(reader.client.get_metric_history(again["b"].info.run_id, "curve/iqm")) == 40
    assert [(t.run_id, t.status) for t in reader.trial_runs()] == [(t.run_id, t.status) for t in trials_before]


def test_after_two_launches_mlflow_holds_one_set_of_variant_runs_the_second_reports(tmp_path):
    """Each launch kept its own set of variant runs: after launches at 3, 8, 12 and 42 seeds the store held 16
    runs for 4 variants and the UI mixed them (3e01923). Now the last report's set replaces every earlier one."""

    def noisy(start, stop):
        return lambda seed: np.linspace(start, stop, 40) + np.random.default_rng(seed).normal(0, 4, 40)

    variants = {"a": {"curve": noisy(5, 30)}, "b": {"curve": noisy(5, 60)}}
    uri = make_store(tmp_path / "store", "twice", variants, seeds=(0, 1, 2), generation="first")
    build_report("twice", tracking_uri=uri, out_root=tmp_path / "reports", pdf=False)
    make_store(tmp_path / "store", "twice", variants, seeds=tuple(range(8)), generation="second")
    folder = build_report("twice", tracking_uri=uri, out_root=tmp_path / "reports", pdf=False).folder
    reader = RunReader(uri, "twice")
    found = reader.client.search_runs([reader.experiment_id()], "tags.`ablate.role` = 'variant'")
    assert sorted(r.data.tags["ablate.variant"] for r in found) == ["a", "b"]  # one set, not two
    newest = reader.launches()[0].info.run_id
    assert {r.data.tags["mlflow.parentRunId"] for r in found} == {newest}
    claim = pd.read_csv(folder / "tables" / "claims.csv").set_index("variant").loc["b"]
    run = next(r for r in found if r.data.tags["ablate.variant"] == "b")
    assert run.data.metrics["claim/n_variant"] == claim.n_variant == 8
    assert run.data.tags["ablate.verdict"] == claim.verdict
    # the spread as a band, which MLflow's charts (three separate curve/ panels) cannot draw: a figure on the run
    for variant_run in found:
        assert [a.path for a in reader.client.list_artifacts(variant_run.info.run_id)] == ["learning_curve.png"]
    picture = reader.client.download_artifacts(run.info.run_id, "learning_curve.png", str(tmp_path))
    assert Path(picture).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and Path(picture).stat().st_size > 5000


def test_the_record_shows_the_report_command_as_typed(store, tmp_path, monkeypatch):
    # issue 18 item 7: `ablate report experiments/activations.toml` was recorded as `ablate report activations`
    _, uri = store
    monkeypatch.chdir(tmp_path)
    (tmp_path / "experiments").mkdir()
    Path("experiments/single.toml").write_text('name = "single"\nseeds = 1\n[[variants]]\nname = "a"\n')
    assert main(["report", "experiments/single.toml", "--tracking-uri", uri, "--no-pdf"]) == 0
    text = (tmp_path / "reports" / "single" / "report.md").read_text()
    assert f"<code>ablate report experiments/single.toml --tracking-uri {uri} --no-pdf</code>" in text


def test_user_text_is_escaped_in_the_html(store, tmp_path, monkeypatch):
    monkeypatch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test", raising=False)
    _, uri = store
    folder = build_report("evil", tracking_uri=uri, out_root=tmp_path).folder
    page = (folder / "report.html").read_text()
    assert "<script>" not in page and "<img src=x" not in page
    assert "&lt;script&gt;alert(" in page and "&lt;img src=x onerror=alert(1)&gt;" in page


def _snapshot(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` with the hash of its bytes."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()
    }


@pytest.fixture
def good_report(tmp_path, monkeypatch):
    """A folder holding a good report of "cartpole" (and of the synthetic experiments' names)."""
    monkeypatch.chdir(tmp_path)
    for name in ("cartpole", "broken", "nope"):
        (tmp_path / "reports" / name / "figures").mkdir(parents=True)
        (tmp_path / "reports" / name / "report.md").write_text(f"# a good report of {name}\n")
        (tmp_path / "reports" / name / "figures" / "curve.png").write_bytes(b"png")
    return tmp_path


@pytest.mark.parametrize(
    ("argv", "code", "message"),
    [
        (["report", "cartpole", "--tracking-uri", "sqlite:///{tmp}/nonexist/x.db"], 2, "no MLflow store at"),
        (["report", "cartpole", "--tracking-uri", "sqlite:///{tmp}/absent.db"], 2, "no MLflow store at"),
        (["report", "nope", "--tracking-uri", "{store}"], 1, "no MLflow experiment named 'nope'"),
        (["report", "broken", "--tracking-uri", "{store}"], 1, "none of the 2 trials"),
        (["report", "..", "--tracking-uri", "{store}"], 2, "is invalid"),
        (["report", ".", "--tracking-uri", "{store}"], 2, "is invalid"),
        (["report", "../escape", "--tracking-uri", "{store}"], 2, "is invalid"),
        (["report", "a/b", "--tracking-uri", "{store}"], 2, "is invalid"),
        (["report", "gens", "--tracking-uri", "{store}", "--generation", "zzz"], 2, "no generation of 'gens'"),
        (["report", "gens", "--tracking-uri", "{store}", "--variants", "a,zz"], 2, "unknown variant 'zz'"),
        (["report", "gens", "--tracking-uri", "{store}", "--baseline", "zz"], 2, "--baseline 'zz'"),
    ],
)
def test_a_report_that_cannot_be_built_writes_nothing(store, good_report, capsys, argv, code, message):
    folder, uri = store
    argv = [a.format(tmp=good_report, store=uri) for a in argv]
    before_reports, before_store = _snapshot(good_report), _snapshot(folder)
    assert main(argv) == code
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert _snapshot(good_report) == before_reports  # nothing written, no database created
    assert _snapshot(folder) == before_store  # the store is as it was
    assert not (good_report / "nonexist").exists() and not (good_report / "absent.db").exists()
    assert not (good_report / "report.md").exists() and not (good_report / "escape").exists()


def test_generation_variants_and_baseline(store, tmp_path, monkeypatch, capsys):
    # after `--fresh` then Ctrl-C the newest generation is incomplete; the complete one can still be reported
    monkeypatch.setattr("ablate.reporting.document.print_pdf", lambda *a, **k: "no PDF in this test")
    _, uri = store
    assert main(["report", "gens", "--tracking-uri", uri, "--out", str(tmp_path), "--no-pdf"]) == 0
    out = capsys.readouterr().out
    assert "generation partial2, where 2 of 9 trials finished" in out and "--generation complete1" in out
    trials = pd.read_csv(tmp_path / "gens" / "tables" / "trials.csv")
    assert (trials.status == "FINISHED").sum() == 2 and (trials.status == "NOT RUN").sum() == 7
    argv = ["report", "gens", "--tracking-uri", uri, "--out", str(tmp_path), "--generation", "complete"]
    assert main([*argv, "--variants", "c,b", "--baseline", "b"]) == 0
    trials = pd.read_csv(tmp_path / "gens" / "tables" / "trials.csv")
    assert (trials.status == "FINISHED").sum() == 6 and set(trials.variant) == {"b", "c"}
    compare = pd.read_csv(tmp_path / "gens" / "tables" / "comparisons.csv")
    assert set(compare.variant) == {"c"} and set(compare.reference) == {"b"}
    text = (tmp_path / "gens" / "report.md").read_text()
    assert "--generation complete --variants c,b --baseline b" in text
    assert "did not finish" not in text


def test_report_help_names_every_option(capsys):
    with pytest.raises(SystemExit):
        main(["report", "--help"])
    out = capsys.readouterr().out
    for option in ("--tracking-uri", "--out", "--generation", "--variants", "--baseline", "--no-pdf"):
        help_line = out.split(option, 2)[-1].split("\n  -")[0]
        assert len(help_line.strip()) > 15, option


def test_a_read_only_reports_folder_is_one_line_and_exit_1(store, good_report, capsys):
    # issue 8: a read-only reports/ gave a PermissionError traceback from the temporary build folder
    if os.geteuid() == 0 and not shutil.which("chattr"):
        pytest.skip("running as root without chattr: nothing is read-only to root")
    folder, uri = store
    reports = good_report / "reports"
    before = _snapshot(good_report)

    def read_only(on: bool) -> None:
        if os.geteuid() == 0:  # file modes do not bind root; the immutable attribute does
            subprocess.run(["chattr", "+i" if on else "-i", str(reports)], check=True, capture_output=True)
        else:
            reports.chmod(0o555 if on else 0o755)

    read_only(True)
    try:
        code = main(["report", "single", "--tracking-uri", uri, "--out", str(reports), "--no-pdf"])
    finally:
        read_only(False)
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "cannot write" in err and str(reports) in err
    assert _snapshot(good_report) == before


def test_a_report_whose_trial_artifacts_were_removed_is_written_from_the_store_naming_what_is_missing(
    tmp_path, monkeypatch, capsys
):
    # issue 28: the artifact folder of one trial run removed (its metrics and params kept) ended `ablate report`
    # in one line, exit 1, with nothing written
    monkeypatch.chdir(tmp_path)
    variants = {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 12)}}
    uri = make_store(tmp_path / "store", "lossy", variants, observation=True)
    reader = RunReader(uri, "lossy")
    lost = next(r for r in reader.trial_runs() if r.key == "b-s1")
    artifacts = Path(reader.client.get_run(lost.run_id).info.artifact_uri.removeprefix("file://"))
    assert (artifacts / "episodes.csv").is_file()
    shutil.rmtree(artifacts)
    capsys.readouterr()  # MLflow's own lines from making the store
    code = main(["report", "lossy", "--tracking-uri", uri, "--no-pdf"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert "b-s1" in err and "episodes.csv" in err and "written from the tracked metrics" in err, err
    folder = tmp_path / "reports" / "lossy"
    assert "wrote" in out and (folder / "report.md").is_file() and (folder / "report.html").is_file()
    text = (folder / "report.md").read_text()
    assert "b-s1" in text and "could not be read" in text  # the report says what it left out
    trials = pd.read_csv(folder / "tables" / "trials.csv").set_index("key")
    assert (trials.status == "FINISHED").all() and len(trials) == 6  # the trial stays, from its tracked metrics
    assert trials.loc["b-s1", "episodes_run"] == 40 and pd.isna(trials.loc["b-s1", "auc"])
    assert not pd.isna(trials.loc["b-s0", "auc"])


def test_a_users_network_is_described_by_its_factory_not_by_built_in_knobs():
    from ablate.reporting.sections import architecture

    params = {
        "model.factory": "../examples/models/layernorm.py:create_model",
        "model.factory_args": '[["width", 32]]',
        "model.factory_hash": "10a11c309fa7",
        "model.hidden_sizes": "(32,)",
        "model.architecture": "mlp",
    }
    text = architecture(params, "CartPole-v1")
    assert text == "the user's own network: create_model of layernorm.py (source 10a11c309fa7), width=32"
    assert "MLP" not in architecture({**params, "model.factory_args": "()"}, "CartPole-v1")


def test_an_untuned_experiments_tuning_table_is_empty_with_its_columns(tmp_path):
    """``ablate.load(...).tuning`` of an experiment without ``[tune]``: no rows, and the columns a tuned one has
    (it was a 0 x 0 frame, which a notebook cannot filter or concatenate)."""
    import ablate

    uri = make_store(tmp_path, "plain", {"a": {"curve": rising(5, 30)}, "b": {"curve": rising(5, 10)}})
    tuning = ablate.load("plain", tracking_uri=uri).tuning
    assert len(tuning) == 0 and list(tuning.columns) == ["ablation", "env_id", "variant", "seed", "auc", "status"]


def test_a_file_edited_in_nothing_a_trial_ran_is_read_as_it_is_now(built_report, tmp_path):
    """The student removed or added a line that no trial key holds (a description, a knob at its default): the
    report reads the file as it is now and says so; an edit that changes a trial's settings is described from the
    launch's copy, with the way to run the file as it is."""
    report_folder, uri = built_report
    path = report_folder.parent.parent / "reportable.toml"
    edited = EXPERIMENT.replace('baseline = "small"\n', 'baseline = "small"\ndescription = "Depth and width."\n')
    edited = edited.replace("hidden_sizes = [64, 64]\n", 'hidden_sizes = [64, 64]\nactivation = "relu"\n')
    try:
        path.write_text(edited)
        text = (
            build_report("reportable", uri, tmp_path / "a", attach=False, pdf=False).folder / "report.md"
        ).read_text()
        assert "Depth and width. Does each change" in text
        (note,) = [line for line in text.splitlines() if "has changed since this launch ran it" in line]
        assert "in nothing a trial ran (every trial key is the same): this report reads it as it is now" in note
        path.write_text(edited.replace("hidden_sizes = [64, 64]", "hidden_sizes = [32]"))
        text = (
            build_report("reportable", uri, tmp_path / "b", attach=False, pdf=False).folder / "report.md"
        ).read_text()
        assert "Depth and width." not in text
        (note,) = [line for line in text.splitlines() if "has changed since this launch ran it" in line]
        assert "in the settings of its trials: this report describes the launch's copy" in note and "--fresh" in note
    finally:
        path.write_text(EXPERIMENT)
