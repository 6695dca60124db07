"""`benchmarks/bench.py` refuses bad arguments with one line and exit 2, before measuring anything."""

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).parent.parent / "benchmarks" / "bench.py"


@pytest.fixture(scope="module")
def bench():
    """The script as a module, in this process (its imports, torch's among them, are loaded here already)."""
    spec = importlib.util.spec_from_file_location("bench_cli_under_test", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["nope"],
            "unknown section 'nope'; valid: core, runner, ablation, tracking, cluster, pong, pong-memory, "
            "pong-population, pong-seeds, tuning, eta, population, seeds, trainer, start, launch",
        ),
        (["ablation", "--ablation-repeats", "0"], "--ablation-repeats must be at least 1, got 0"),
        (["eta", "--eta-launches", "hot"], "--eta-launches: 'hot' is not a launch; valid: cold, warm"),
        (["pong-memory", "--pong-memory-episodes", "-1"], "--pong-memory-episodes must be at least 0, got -1"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(bench, monkeypatch, capsys, args, message):
    monkeypatch.setattr(sys, "argv", [str(BENCH), *args])
    with pytest.raises(SystemExit) as done:
        bench.main()
    out, err = capsys.readouterr()
    assert done.value.code == 2
    assert err.strip().splitlines()[-1].endswith(message)
    assert "Traceback" not in err and "== " not in out  # nothing ran
