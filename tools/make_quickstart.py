"""Write examples/quickstart.ipynb from the cells below, so the notebook's source stays reviewable as Python.

Run: .venv/bin/python tools/make_quickstart.py            # the cells only, no outputs
     .venv/bin/python tools/make_quickstart.py --execute  # run them (about a minute) and commit the outputs too

``--execute`` runs the notebook in a scratch copy of the repository's layout (examples/ beside experiments/),
so no store is left behind, and writes it back with its outputs: the committed notebook shows a result."""

import argparse
import shutil
import tempfile
from pathlib import Path

import nbformat

ROOT = Path(__file__).resolve().parent.parent

CELLS = [
    (
        "markdown",
        "# ablate quickstart\n\n"
        "A small tuned ablation of REINFORCE on CartPole-v1, run on a local Ray and tracked in an MLflow store "
        "next to this notebook: two hidden-layer widths (8 and 32 units) x 3 seeds, each width at the learning "
        "rate tuning chose for it on a seed of its own (`experiments/quickstart.toml`; about a minute). Solved "
        "means a rolling mean return of 100 over 20 episodes, a lower bar than the full task's 475, so every "
        "seed gets there. Then the results as DataFrames and a figure.\n\n"
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
        "experiment = root / 'experiments' / 'quickstart.toml'\n"
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
        "What tuning chose: each width's learning rate, on its tuning seed (10000), from 0.01, 0.03 and 0.1.",
    ),
    (
        "code",
        "results = ablate.load('quickstart', tracking_uri=store)\n"
        "results.tuning.pivot_table(index='variant', columns='learning_rate', values='auc')",
    ),
    (
        "markdown",
        "The result, on the 3 evaluation seeds at the chosen rates: how many seeds solved, and in how many episodes.",
    ),
    (
        "code",
        "# long form: a row per variant and episode budget; here, at the full budget\n"
        "results.convergence.query('episode == budget')[['variant', 'seeds_run', 'solved', 'episodes_median', "
        "'episodes_iqm', 'return_iqm']]",
    ),
    (
        "markdown",
        "The claim, as the report's Claims section makes it, with each side's settings beside it "
        "(`variant.*`, `reference.*`: the learning rate each one ran at, its layers as a tuple). With 3 seeds "
        "against 3 no ordering of the seeds can reach 95%, so the verdict is *undetermined* whatever the data: "
        "`seeds_needed` says how many seeds per variant would decide it.",
    ),
    (
        "code",
        "results.claims[['variant', 'reference', 'verdict', 'change', 'seeds_needed', 'variant.hidden_sizes', "
        "'reference.hidden_sizes', 'variant.learning_rate', 'reference.learning_rate']]",
    ),
    (
        "markdown",
        "Every metric, each variant against its reference on its own, in the report's sign and units (`change`: + "
        "is more episodes): exploratory, not claims, so each verdict says so (`exploratory: too few seeds` here); "
        "the estimate is a pointer for a larger run.",
    ),
    (
        "code",
        "results.comparisons[['variant', 'reference', 'metric', 'change', 'change_low', 'change_high', "
        "'change_unit', 'verdict', 'seeds_needed']]",
    ),
    ("code", "results.figure('curves')"),
    (
        "markdown",
        "`ablate.report('quickstart', tracking_uri=store)` writes the whole report (Markdown, HTML, PDF) into "
        "`reports/quickstart/`, with a `discussion.md` for your own words; `help(ablate.Results)` lists every "
        "column above.",
    ),
]


def build() -> nbformat.NotebookNode:
    notebook = nbformat.v4.new_notebook()
    notebook.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    for kind, source in CELLS:
        cell = nbformat.v4.new_markdown_cell(source) if kind == "markdown" else nbformat.v4.new_code_cell(source)
        notebook.cells.append(cell)
    for i, cell in enumerate(notebook.cells):
        cell["id"] = f"cell-{i}"  # stable ids: regenerating leaves the file unchanged
    return notebook


def execute(notebook: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """Run ``notebook`` as a user would, in a scratch copy of the layout it expects."""
    from nbclient import NotebookClient

    with tempfile.TemporaryDirectory(prefix="ablate-quickstart-") as top:
        (Path(top) / "experiments").mkdir()
        (Path(top) / "examples").mkdir()
        shutil.copy(ROOT / "experiments" / "quickstart.toml", Path(top) / "experiments")
        client = NotebookClient(
            notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(Path(top) / "examples")}}
        )
        client.execute()
    for cell in notebook.cells:
        cell.get("metadata", {}).pop("execution", None)  # timestamps: a rerun would differ for no reason
    return notebook


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--execute", action="store_true", help="run the cells and keep their outputs")
    args = parser.parse_args()
    path = ROOT / "examples" / "quickstart.ipynb"
    notebook = build()
    if args.execute:
        notebook = execute(notebook)
    nbformat.write(notebook, path)
    print(f"wrote {path}")
