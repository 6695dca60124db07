"""A fresh MLflow store in ~0.1 s: creating a SQLite store runs MLflow's schema migrations (~5 s on 2 cores),
so each test process makes one empty store once and copies it wherever a test needs a new one. A copy is what
a first launch would have created there (``ablate`` gives each experiment its own artifact folder)."""

import atexit
import shutil
import tempfile
from pathlib import Path

_template: Path | None = None


def fresh_store(path: Path) -> str:
    """An empty, fully migrated store at ``path`` (its folder made); returns its tracking URI."""
    global _template
    if _template is None:
        from mlflow import MlflowClient

        folder = Path(tempfile.mkdtemp(prefix="ablate-test-store-"))
        atexit.register(shutil.rmtree, folder, True)
        MlflowClient(f"sqlite:///{folder / 'mlflow.db'}").search_experiments()
        _template = folder / "mlflow.db"
    path.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(_template, path)
    return f"sqlite:///{path}"
