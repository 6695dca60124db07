"""Screenshots of an ablation in the MLflow UI, for docs/mlflow-ui.md: the runs table filtered to the variant runs
(one row per variant, its verdict) and their chart view (one curve per variant), taken in headless Chromium.

    python tools/mlflow_screenshots.py --tracking-uri sqlite:///mlflow.db --experiment cartpole

Serves the store with ``mlflow ui`` on loopback, drives Debian's ``chromium`` over its DevTools pipe and waits on what
the page shows (every variant's name on the page), never on a fixed delay.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the DevTools client the report's browser tests use

from devtools import DevTools, chromium_flags  # noqa: E402

from ablate.launch.mlflow_store import VARIANTS_FILTER  # noqa: E402

COLUMNS = [
    "tags.`ablate.verdict`",
    "tags.`ablate.reference`",
    "metrics.`claim/change`",
    "metrics.`claim/low`",
    "metrics.`claim/high`",
    "metrics.`convergence/fraction_solved`",
    "metrics.`convergence/episodes_iqm`",
    "metrics.`convergence/auc_iqm`",
]
"""The columns docs/mlflow-ui.md tells a reader to add (the Columns menu), set here as the UI stores that choice."""
SHOTS = (
    ("mlflow-variants-table.png", {}),
    ("mlflow-variants-chart.png", {"compareRunsMode": "CHART"}),
)


def serve(tracking_uri: str, port: int, timeout_s: float = 120) -> subprocess.Popen:
    """``mlflow ui`` on 127.0.0.1:``port``, returned once it answers."""
    mlflow = Path(sys.executable).with_name("mlflow")
    command = [str(mlflow), "ui", "--backend-store-uri", tracking_uri, "--host", "127.0.0.1", "--port", str(port)]
    server = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2) as reply:
                if reply.status == 200:
                    return server
        except OSError:
            pass
        if server.poll() is not None or time.monotonic() > deadline:
            server.kill()
            raise SystemExit(f"mlflow ui on port {port} did not start")
        time.sleep(0.5)


def variant_names(tracking_uri: str, experiment: str) -> tuple[str, list[str]]:
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri)
    found = client.get_experiment_by_name(experiment)
    if found is None:
        raise SystemExit(f"{tracking_uri}: no experiment {experiment!r}")
    runs = client.search_runs([found.experiment_id], filter_string=VARIANTS_FILTER)
    if not runs:
        raise SystemExit(f"{experiment}: no variant runs (build the report first: ablate report ...)")
    return found.experiment_id, sorted(r.data.tags["ablate.variant"] for r in runs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tracking-uri", default="sqlite:///mlflow.db")
    parser.add_argument("--experiment", default="cartpole")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    parser.add_argument("--port", type=int, default=5077)
    parser.add_argument("--browser", default=shutil.which("chromium") or "chromium")
    args = parser.parse_args(argv)
    experiment_id, names = variant_names(args.tracking_uri, args.experiment)
    args.out.mkdir(parents=True, exist_ok=True)
    server = serve(args.tracking_uri, args.port)
    profile = Path(tempfile.mkdtemp(prefix="ablate-shots-"))
    browser = DevTools(args.browser, chromium_flags(profile), timeout_s=600)
    try:
        browser.call(
            "Emulation.setDeviceMetricsOverride",
            session=True,
            width=1600,
            height=1000,
            deviceScaleFactor=1,
            mobile=False,
        )
        _choose_view(browser, args.port, experiment_id)
        for filename, extra in SHOTS:
            query = urllib.parse.urlencode({"searchFilter": VARIANTS_FILTER, **extra})
            url = f"http://127.0.0.1:{args.port}/#/experiments/{experiment_id}/runs?{query}"
            browser.open("about:blank")  # a change of the URL's #fragment alone fires no load event
            browser.open(url)
            _wait_shown(browser, names, extra)
            if extra:
                _search_charts(browser, "curve/")
            browser.screenshot(args.out / filename, 1600, 1000)
            print(f"wrote {args.out / filename}")
    finally:
        browser.close()
        server.terminate()
        server.wait()
        shutil.rmtree(profile, ignore_errors=True)
    return 0


def _choose_view(browser: DevTools, port: int, experiment_id: str) -> None:
    """What a reader does once in the UI, stored where the UI keeps it (this browser profile's localStorage): the
    columns of ``COLUMNS`` shown, every run drawn in the chart view (the UI draws the first 10 by default, and the
    launch run counts as one, which hid the tenth variant), the assistant's panel closed."""
    browser.open(f"http://127.0.0.1:{port}/")
    state = {"searchFilter": VARIANTS_FILTER, "selectedColumns": COLUMNS, "runsHiddenMode": "SHOW_ALL"}
    stored = {
        f'MLflowLocalStorage-1.1-ExperimentPage-["{experiment_id}"]-ReactComponentState': json.dumps(state),
        "mlflow.assistant.fab.autoOpenedOnFirstLoad_v1": "true",
        "mlflow.assistant.panelOpen_v1": "false",
    }
    browser.evaluate(
        f"(() => {{ for (const [k, v] of Object.entries({json.dumps(stored)})) localStorage.setItem(k, v) }})()"
    )


def _search_charts(browser: DevTools, text: str, timeout_s: float = 60) -> None:
    """Type ``text`` into the chart view's search box (only the learning curves stay), then wait for its charts."""
    box = "document.querySelector('input[placeholder=\"Search metric charts\"]')"
    setter = "Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set"
    browser.evaluate(
        f"(() => {{ const box = {box}; {setter}.call(box, {text!r}); "
        "box.dispatchEvent(new Event('input', {bubbles: true})) })()"
    )
    shown = "document.body.innerText.includes('curve/iqm') && !document.body.innerText.includes('claim/change')"
    deadline = time.monotonic() + timeout_s
    while not browser.evaluate(f"Boolean({shown})"):
        if time.monotonic() > deadline:
            raise SystemExit(f"the chart view's search for {text!r} showed no curve in {timeout_s:.0f} s")
        browser.evaluate("new Promise(done => setTimeout(done, 250))")
    browser.evaluate("new Promise(done => setTimeout(done, 1000))")  # the charts' draw after the filter settles


def _wait_shown(browser: DevTools, names: list[str], extra: dict, timeout_s: float = 120) -> None:
    """Until every variant's name is on the page (and, for the chart view, a chart has drawn). The variant runs are
    nested under their launch run, which the table shows folded: its expander is clicked once, as a reader would."""
    check = " && ".join(f"document.body.innerText.includes({name!r})" for name in names)
    if extra:
        check += " && document.querySelectorAll('canvas, svg .main-svg, .js-plotly-plot').length > 0"
    expander = "document.querySelector('button[data-component-id*=runnamecellrenderer]')"
    unfolded = bool(extra)  # the chart view lists every run: nothing to unfold
    deadline = time.monotonic() + timeout_s
    while not browser.evaluate(f"Boolean({check})"):
        if time.monotonic() > deadline:
            failed = Path(tempfile.gettempdir()) / "mlflow-screenshot-failed.png"
            browser.screenshot(failed, 1600, 1000)
            raise SystemExit(f"the MLflow UI did not show {names} in {timeout_s:.0f} s (what it showed: {failed})")
        if not unfolded and browser.evaluate(f"Boolean({expander})"):
            browser.evaluate(f"{expander}.click()")
            unfolded = True
        browser.evaluate("new Promise(done => setTimeout(done, 250))")  # let the page work, then look again
    browser.evaluate("new Promise(done => requestAnimationFrame(() => requestAnimationFrame(done)))")


if __name__ == "__main__":
    raise SystemExit(main())
