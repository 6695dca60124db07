"""The report, built from a tiny real ablation (Ray + MLflow): its numbers against the tracked metrics,
its HTML opened in headless Chromium, and the empty cases."""

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from ablate.config import load_experiment
from ablate.report import write_report
from ablate.tracking import Tracker

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
    uri = f"sqlite:///{folder / 'mlflow.db'}"
    path = folder / "reportable.toml"
    path.write_text(EXPERIMENT)
    outcome = run_quiet(load_experiment(path), folder, uri)
    assert outcome.exit_code == 0
    return write_report("reportable", tracking_uri=uri, out_root=folder / "reports"), uri


def test_report_files(built_report):
    folder, _ = built_report
    for name in ("report.md", "report.html", "tables/convergence.csv", "tables/comparisons.csv", "tables/trials.csv"):
        assert (folder / name).is_file(), name
    for figure in ("learning_curves_episodes", "learning_curves_wallclock", "episodes_to_solve"):
        assert (folder / "figures" / f"{figure}.png").stat().st_size > 5000
        assert (folder / "figures" / f"{figure}.svg").is_file()
    assert list((folder / "videos").glob("small-best-seed*.mp4")) and list((folder / "videos").glob("big-*.mp4"))
    text = (folder / "report.md").read_text()
    for section in ("## Method", "## Convergence", "## Findings", "## Figures", "## Videos", "## Reproducibility"):
        assert section in text
    for line in text.split("## Findings")[1].split("## Figures")[0].strip().splitlines():
        assert "CI" in line or "did not solve" in line or "no claim" in line, line  # no claim without interval


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
    assert page.count("<img") >= 3 and "<video" in page
    assert not re.search(r'src="(?!data:)', page), "every src is a data URI"


def _chromium() -> str | None:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found:
        return found
    if shutil.which("apt-get") is None:
        return None
    install = "apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium"
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
    const out = document.createElement('pre');
    out.id = 'media-check';
    out.textContent = `images=${images.length} bad_images=${badImages} videos=${media.length} bad_videos=${badVideos}`;
    document.body.appendChild(out);
  });
});
</script>
"""


def test_html_in_headless_chromium_loads_every_image_and_video(built_report, tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip("Chromium is not installed and could not be installed with apt-get (no root or no Debian mirror)")
    folder, _ = built_report
    probe = tmp_path / "probe.html"
    probe.write_text((folder / "report.html").read_text().replace("</body>", CHECK_SCRIPT + "</body>"))
    flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}",
    ]
    dom = subprocess.run(
        [browser, *flags, "--virtual-time-budget=20000", "--dump-dom", probe.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
    ).stdout
    found = re.search(r"images=(\d+) bad_images=(\d+) videos=(\d+) bad_videos=(\d+)", dom)
    assert found, "the check script did not run: " + dom[-500:]
    images, bad_images, videos, bad_videos = map(int, found.groups())
    assert images >= 3 and bad_images == 0
    assert videos >= 2 and bad_videos == 0
    ARTIFACTS.mkdir(exist_ok=True)
    shot = ARTIFACTS / "report_screenshot.png"
    subprocess.run(
        [browser, *flags, "--window-size=1200,2400", f"--screenshot={shot}", (folder / "report.html").as_uri()],
        capture_output=True,
        timeout=120,
    )
    assert shot.is_file() and shot.stat().st_size > 10_000


def test_report_with_no_runs_says_so(tmp_path, tracking_uri):
    folder = write_report("never-ran", tracking_uri=tracking_uri, out_root=tmp_path)
    text = (folder / "report.md").read_text()
    assert "No results to report" in text and "ablate run" in text


def test_report_with_only_failed_runs_says_so(run_quiet, tmp_path, tracking_uri):
    path = tmp_path / "broken.toml"
    path.write_text(
        'name = "broken"\nseeds = 2\n[base]\nmax_episodes = 8\nepisodes_per_update = 8\nrecord_video = false\n'
        '[[variants]]\nname = "boom"\nfault = "raise"\n'
    )
    outcome = run_quiet(load_experiment(path), tmp_path, tracking_uri)
    assert outcome.exit_code == 1
    folder = write_report("broken", tracking_uri=tracking_uri, out_root=tmp_path / "reports")
    text = (folder / "report.md").read_text()
    assert "No results to report" in text and "failed" in text and "injected fault" in text
