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


def _make_dry_run(*args: str) -> str:
    out = subprocess.run(
        ["make", "--no-print-directory", "-C", str(ROOT), "-n", *args], capture_output=True, text=True, check=True
    )
    return out.stdout


def test_make_report_takes_the_experiment_as_a_variable():
    """`make report` rebuilt only reports/cartpole/ (issue 18 item 7): EXPERIMENT names any experiment."""
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    mine = _make_dry_run("report", "EXPERIMENT=experiments/mine.toml").splitlines()[-1]
    assert re.search(r"ablate report experiments/mine\.toml( |$)", mine), mine
    default = _make_dry_run("report").splitlines()[-1]
    assert re.search(r"ablate report experiments/cartpole\.toml( |$)", default), default


@pytest.mark.parametrize(
    "name",
    ["mlflow.db", "mlflow.db.cartpole.lock", "mlflow.db.my-own_3.lock", "mlflow.db.实验é.lock", "other.db.mine.lock"],
)
def test_runtime_state_and_launch_locks_are_ignored_by_git(name):
    """`ablate run` leaves `<store>.<experiment>.lock` beside an SQLite store: runtime state, never committed."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "--no-index", "-q", name], capture_output=True)
    assert out.returncode == 0, f"{name} is not in .gitignore"


def test_gitignore_keeps_other_lock_files_tracked():
    """The lock rule is narrow: a package manager's lock file (say uv.lock) may still be committed."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "--no-index", "-q", "uv.lock"], capture_output=True)
    assert out.returncode == 1


def test_mlflow_screenshots_takes_any_ablation_and_an_output_folder():
    """It was fixed to the cartpole experiment and to docs/images (issue 56)."""
    out = subprocess.run(
        ["make", "--no-print-directory", "-n", "-C", str(ROOT), "mlflow-screenshots", "ABLATION=mine", "SHOTS=/tmp/x"],
        capture_output=True,
        text=True,
    ).stdout
    assert "--experiment mine --out /tmp/x" in out.splitlines()[-1]
