"""Write examples/quickstart.ipynb (unexecuted) from the cells below, so the notebook's source stays reviewable
as Python. Run: .venv/bin/python tools/make_quickstart.py"""

from pathlib import Path

import nbformat

CELLS = [
    (
        "markdown",
        "# ablate quickstart\n\n"
        "Run the two-minute smoke ablation (2 variants x 2 seeds of REINFORCE on CartPole) on a local Ray, "
        "tracked in an MLflow store in this folder, then read its results as DataFrames and draw a figure.\n\n"
        "`import ablate` first, before anything imports torch: it sets `THP_MEM_ALLOC_ENABLE` (huge pages for "
        "PyTorch's CPU allocator), which torch reads once. A notebook that imported torch first still runs, "
        "only Pong's CNN updates are slower.",
    ),
    (
        "code",
        "from pathlib import Path\n\n"
        "import ablate\n\n"
        "# The repository's experiments/ folder: this notebook lives in examples/, one level below it.\n"
        "root = next(p for p in [Path.cwd(), *Path.cwd().parents] if (p / 'experiments').is_dir())\n"
        "experiment = root / 'experiments' / 'smoke.toml'\n"
        "store = 'sqlite:///quickstart-mlflow.db'  # a store of this notebook's own, next to it",
    ),
    (
        "code",
        "outcome = ablate.run(experiment, tracking_uri=store, report=False, progress=False)\n"
        "print(f'{len(outcome.finished)} trials finished now, {outcome.skipped} before; "
        "exit code {outcome.exit_code}')",
    ),
    (
        "markdown",
        "The ablation, read back from the store: one row per variant, then each variant against its reference.",
    ),
    (
        "code",
        "results = ablate.load('smoke', tracking_uri=store)\n"
        "results.convergence[['variant', 'seeds_run', 'solved', 'episodes_median', 'final_rolling_mean_iqm']]",
    ),
    ("code", "results.comparisons.head()"),
    ("code", "results.figure('curves')"),
    (
        "markdown",
        "`ablate.report('smoke', tracking_uri=store)` writes the whole report (Markdown, HTML, PDF) into "
        "`reports/smoke/`; `help(ablate.load)` lists what else `results` holds.",
    ),
]


def build() -> nbformat.NotebookNode:
    notebook = nbformat.v4.new_notebook()
    notebook.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    for kind, source in CELLS:
        cell = nbformat.v4.new_markdown_cell(source) if kind == "markdown" else nbformat.v4.new_code_cell(source)
        notebook.cells.append(cell)
    return notebook


if __name__ == "__main__":
    path = Path(__file__).resolve().parent.parent / "examples" / "quickstart.ipynb"
    notebook = build()
    for i, cell in enumerate(notebook.cells):
        cell["id"] = f"cell-{i}"  # stable ids: regenerating leaves the file unchanged
    nbformat.write(notebook, path)
    print(f"wrote {path}")
