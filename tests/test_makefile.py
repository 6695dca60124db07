"""`make help` lists every target of the Makefile, each with its description (from its `## ` comment)."""

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_make_help_lists_every_target_with_a_description():
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    text = (ROOT / "Makefile").read_text()
    targets = re.findall(r"^([A-Za-z0-9_.-]+):(?!=)", text, re.M)
    targets = [t for t in targets if not t.startswith(".")]  # .PHONY and the like are not targets to run
    assert {"help", "test", "ablation-cartpole", "report", "train"} <= set(targets)
    out = subprocess.run(["make", "--no-print-directory", "-C", str(ROOT), "help"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    described = dict(re.findall(r"^make (\S+)\s+(.+)$", out.stdout, re.M))
    assert sorted(described) == sorted(targets)
    assert all(len(description) > 10 for description in described.values()), described
