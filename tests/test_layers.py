"""The house stands: every module's imports (top level and inside functions) point down the data flow, Ray is
imported only by the scheduler and MLflow only by the tracking writer and reader."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "ablate"

# Lower number = lower layer. A module may import its own layer and any lower one, never a higher one.
LAYERS = {
    "config": 0,
    "schema": 0,
    "sources": 0,
    "experiment": 0,
    "design": 0,
    "seeds": 0,
    "claims": 0,
    "env_spec": 0,
    "envs": 0,
    "videos": 0,
    "measures": 0,
    "agent": 1,
    "checks": 2,
    "trial_files": 2,
    "launch": 2,
    "reporting": 3,
    "api": 4,
    "__init__": 4,
    "commands": 5,
    "dry_run": 5,
    "train_from": 5,
    "cli": 5,
    "calibration": 5,
}
# launch/patches.py: the one module that changes a library's private internals (test_patches), for both.
RAY_ALLOWED = {"launch/scheduler.py", "launch/patches.py"}
MLFLOW_ALLOWED = {
    "launch/tracking.py",
    "launch/mlflow_store.py",
    "launch/variant_runs.py",
    "reporting/reader.py",
    "launch/patches.py",
}


def _layer(module: str) -> int:
    """``ablate.launch.grid`` -> the launch layer; ``ablate`` (the package itself) -> the API's."""
    parts = module.split(".")
    return LAYERS[parts[1] if len(parts) > 1 else "__init__"]


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    names: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
            if node.module == "ablate":  # `from ablate import config`: the names are modules too
                names += [f"ablate.{alias.name}" for alias in node.names if alias.name in LAYERS]
    return names


MODULES = sorted(p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob("*.py"))


def test_every_module_belongs_to_a_layer():
    for relative in MODULES:
        assert relative.split("/")[0].removesuffix(".py") in LAYERS, relative


@pytest.mark.parametrize("relative", MODULES)
def test_imports_point_down(relative):
    own = LAYERS[relative.split("/")[0].removesuffix(".py")]
    for name in _imports(PACKAGE / relative):
        top = name.split(".")[0]
        if top == "ablate" and name != "ablate":
            assert _layer(name) <= own, f"{relative} imports {name}, a layer above it"
        if top == "ray":
            assert relative in RAY_ALLOWED, f"{relative} imports Ray; only {RAY_ALLOWED} may"
        if top == "mlflow":
            assert relative in MLFLOW_ALLOWED, f"{relative} imports MLflow; only {MLFLOW_ALLOWED} may"


def test_the_check_sees_an_upward_import(tmp_path):
    """The scan itself can fail: an agent module that imports the launch layer inside a function is caught."""
    bad = tmp_path / "trial.py"
    bad.write_text("def f():\n    from ablate.launch.tracking import Tracker\n    import mlflow\n")
    names = _imports(bad)
    assert "ablate.launch.tracking" in names and "mlflow" in names
    assert _layer("ablate.launch.tracking") > LAYERS["agent"]


def test_no_module_is_over_500_lines():
    long = {m: n for m in MODULES if (n := len((PACKAGE / m).read_text().splitlines())) > 520}
    assert not long, f"modules over ~500 lines (each likely two jobs): {long}"
