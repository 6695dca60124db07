"""ablate.api: the notebook runs a small tuned ablation through ``ablate.run`` (its seeds solve) and is committed
with its outputs; ``ablate.load`` reads back the same tables ``ablate report`` writes; a Python caller's errors
name Python parameters."""

from __future__ import annotations

import io
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import pandas as pd
import pytest
from nbclient import NotebookClient
from stores import fresh_store

import ablate
from ablate.api import StoreNotFound
from ablate.cli import main
from ablate.reporting.tables import convergence_long

ROOT = Path(__file__).resolve().parents[1]


def test_import_is_light_and_sets_the_allocator_variable():
    code = (
        "import os, sys, ablate; "
        "heavy = ('torch', 'ray', 'mlflow', 'pandas'); "
        "print(os.environ['THP_MEM_ALLOC_ENABLE'], sorted(m for m in heavy if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["1", "[]"]


def test_public_functions_have_docstrings():
    for function in (ablate.run, ablate.load, ablate.report, ablate.Results.figure):
        assert function.__doc__ and len(function.__doc__.split()) > 20, function


def test_load_from_a_missing_store_names_the_uri_and_the_path_it_looked_at(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(StoreNotFound) as error:
        ablate.load("smoke")
    message = str(error.value)
    assert "'sqlite:///mlflow.db'" in message and str(tmp_path / "mlflow.db") in message
    assert "\n" not in message
    assert not (tmp_path / "mlflow.db").exists()  # reading never creates an empty store


@pytest.fixture(scope="module")
def notebook_run(tmp_path_factory, ray_address):
    """examples/quickstart.ipynb executed in a copy of the repository's layout (examples/ beside experiments/),
    its kernel joining the session's Ray (``RAY_ADDRESS``, as a notebook on a cluster would) to spare a start."""
    top = tmp_path_factory.mktemp("quickstart")
    (top / "experiments").mkdir()
    shutil.copy(ROOT / "experiments" / "quickstart.toml", top / "experiments")
    fresh_store(top / "examples" / "quickstart-mlflow.db")  # what its first run would create, minus 5 s
    notebook = nbformat.read(ROOT / "examples" / "quickstart.ipynb", as_version=4)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RAY_ADDRESS", ray_address)  # the kernel inherits it
        NotebookClient(
            notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(top / "examples")}}
        ).execute()
    return notebook, top / "examples"


def test_quickstart_notebook_runs_and_shows_a_table_and_a_figure(notebook_run):
    notebook, folder = notebook_run
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert any("text/html" in o.get("data", {}) and "episodes_median" in o["data"]["text/html"] for o in outputs)
    assert any("image/png" in o.get("data", {}) for o in outputs)  # the figure, inline
    assert (folder / "quickstart-mlflow.db").is_file()
    # issue 27: a result, not the mechanics: a tuned ablation whose seeds all solve
    results = ablate.load("quickstart", tracking_uri=f"sqlite:///{folder / 'quickstart-mlflow.db'}")
    assert (results.convergence.solved == results.convergence.seeds_run).all() and len(results.tuning) == 6
    # issue 46: tidy tables: each claim's sides' settings, real values, curves by trial and stage
    claim = results.claims.iloc[0]
    assert claim["variant.hidden_sizes"] == (32,) and claim["reference.hidden_sizes"] == (8,)
    assert results.trials.hidden_sizes.map(type).eq(tuple).all()
    assert set(results.curves.stage) == {"eval", "base"} and set(results.curves.key) == set(results.trials.key)
    assert {"budget", "episode", "return_iqm"} <= set(results.convergence.columns)
    assert (
        results.ablation.tuning["choices"]["narrow"]["values"] != results.ablation.tuning["choices"]["wide"]["values"]
    )


def test_the_committed_notebook_shows_its_result():
    """examples/quickstart.ipynb is committed executed (tools/make_quickstart.py --execute): a reader on the web
    sees the table of solved seeds and the figure without running it; its cells are the generator's."""
    import sys

    sys.path.insert(0, str(ROOT / "tools"))
    from make_quickstart import build

    committed = nbformat.read(ROOT / "examples" / "quickstart.ipynb", as_version=4)
    assert [c.source for c in committed.cells] == [c.source for c in build().cells]
    outputs = [o for cell in committed.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert any("episodes_median" in o.get("data", {}).get("text/html", "") for o in outputs)
    assert any("image/png" in o.get("data", {}) for o in outputs)


def test_load_returns_the_tables_ablate_report_writes(notebook_run, tmp_path):
    _, folder = notebook_run
    store = f"sqlite:///{folder / 'quickstart-mlflow.db'}"
    assert main(["report", "quickstart", "--tracking-uri", store, "--out", str(tmp_path), "--no-pdf"]) == 0
    results = ablate.load("quickstart", tracking_uri=store)
    for frame, name in (
        (results.trials, "trials"),
        (results.convergence, "convergence"),
        (results.comparisons, "comparisons"),
        (results.claims, "claims"),
    ):
        written = pd.read_csv(tmp_path / "quickstart" / "tables" / f"{name}.csv")
        if name == "convergence":  # the file keeps one row per variant; the frame is its long form
            written = pd.read_csv(io.StringIO(convergence_long(written).to_csv(index=False)))
            written.insert(0, "env_id", "CartPole-v1")
            written.insert(0, "ablation", "quickstart")
        through_csv = pd.read_csv(io.StringIO(frame.to_csv(index=False)))  # the same text round trip
        pd.testing.assert_frame_equal(through_csv, written, check_exact=False, rtol=1e-12)
    assert (
        set(results.curves.variant) == {"narrow", "wide"} and len(results.trials[results.trials.stage == "eval"]) == 6
    )
    assert set(results.trials.stage) == {"eval", "base"}  # tuned: the shared base rate's trials are there too
    figure = results.figure("curves")
    assert figure.axes and figure.axes[0].get_lines()  # an open matplotlib figure with the curves drawn
    with pytest.raises(ValueError, match="valid: curves"):
        results.figure("nope")


def test_load_and_report_read_mlflow_tracking_uri_as_the_cli_does(tmp_path, monkeypatch):
    # issue 56: the API passed its own literal default, so a notebook on a team's server read a local file
    store = tmp_path / "team" / "mlflow.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{store}")
    monkeypatch.chdir(tmp_path)
    for call in (lambda: ablate.load("anything"), lambda: ablate.report("anything")):
        with pytest.raises(Exception) as error:
            call()
        assert str(store) in str(error.value), error.value  # the environment's store, not ./mlflow.db


def test_the_tables_of_two_ablations_with_other_envs_and_budgets_concatenate_into_the_same_columns(tmp_path):
    """An Acrobot-like and a CartPole ablation (other env, other budget): no table had the ablation or its env,
    ``trials`` had ``return_at_<E>`` columns per budget and ``curves`` no settings (3e01923)."""
    from test_report import make_store, rising

    variants = {
        "base": {"curve": rising(5, 30, 40)},
        "wide": {"curve": rising(5, 40, 40), "hidden": [64], "overrides": {"hidden_sizes": [64]}},
    }
    cartpole = make_store(tmp_path, "cart", variants, budget=40)
    acrobot = make_store(tmp_path, "acro", variants, budget=60, env_id="Acrobot-v1", threshold=None)
    one, two = (ablate.load(name, tracking_uri=uri) for name, uri in (("cart", cartpole), ("acro", acrobot)))
    for table in ("trials", "curves", "convergence", "claims", "comparisons", "tuning"):
        a, b = getattr(one, table), getattr(two, table)
        assert list(a.columns) == list(b.columns), table
        assert list(a.columns[:2]) == ["ablation", "env_id"], table
        if len(a):
            assert set(a.env_id) == {"CartPole-v1"} and set(b.ablation) == {"acro"}, table
    assert {"return_at_quarter", "return_at_half", "return_at_budget"} <= set(one.trials.columns)
    assert not [c for c in one.trials.columns if c.startswith("return_at_") and c[10:].isdigit()]
    curves = pd.concat([one.curves, two.curves])
    assert {"learning_rate", "hidden_sizes"} <= set(curves.columns) and curves.learning_rate.notna().all()
