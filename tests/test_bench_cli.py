"""`benchmarks/bench.py` refuses bad arguments with one line and exit 2, before measuring anything."""

import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).parent.parent / "benchmarks" / "bench.py"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["nope"],
            "unknown section 'nope'; valid: core, runner, ablation, tracking, cluster, pong, pong-memory, tuning, eta",
        ),
        (["ablation", "--ablation-repeats", "0"], "--ablation-repeats must be at least 1, got 0"),
        (["eta", "--eta-launches", "hot"], "--eta-launches: 'hot' is not a launch; valid: cold, warm"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(args, message):
    done = subprocess.run([sys.executable, str(BENCH), *args], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].endswith(message)
    assert "Traceback" not in done.stderr and "== " not in done.stdout  # nothing ran
