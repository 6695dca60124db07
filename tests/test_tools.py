"""The tools a developer runs by hand still run: ``tools/gpu_check.py`` (the device check, on a lent GPU machine
only) is run here on the CPU in its shortest form, so that a rename in ``ablate`` cannot leave it broken until the
next GPU is lent."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_gpu_check_runs_its_short_form_on_the_cpu():
    command = [sys.executable, "tools/gpu_check.py", "--episodes", "1", "--members", "2", "--cartpole-episodes", "2"]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "raw ALE/Pong-v5:" in done.stdout
    assert "cnn:" in done.stdout and "mlp:" in done.stdout
    assert "CartPole population of 2:" in done.stdout


@pytest.mark.parametrize("tool", sorted(p.name for p in (ROOT / "tools").glob("*.py")))
def test_every_tool_imports_and_answers_help(tool):
    """A tool imported a name that moved (mlflow_screenshots's VARIANTS_FILTER) and nothing ran it: each one's
    --help at least imports it."""
    done = subprocess.run([sys.executable, str(ROOT / "tools" / tool), "--help"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
