"""The progress view: per-variant figures over seeds, the rows of running trials, the stage lines; and the
view itself in a real terminal (tmux) during a real `ablate run` (its estimate: test_estimate.py)."""

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from stores import fresh_store
from views import Watched
from views import grid_trials as _trials
from views import row as _row

from ablate.launch.clock import stage


def test_variant_figure_is_the_median_of_seeds_not_the_best_seed(clock):
    view = Watched("x", _trials(variants=("dropout",), seeds=(0, 1, 2)), 0, enabled=False)
    for seed, mean in ((0, 466.0), (1, 150.0), (2, 215.6)):
        view.started(f"dropout-s{seed}")
        view.episodes(f"dropout-s{seed}", [_row(5, 500.0), _row(10, mean)])  # the newest, not the highest
    text = _text(view)
    row = next(line for line in text.splitlines() if line.startswith("dropout ") and "0/3" in line)
    assert "215.6" in row and "150.0 to 466.0" in row and "500" not in row
    for seed, mean in ((0, "466.0"), (1, "150.0"), (2, "215.6")):  # a row per running trial
        assert re.search(rf"^dropout\s+{seed}\s+10/100\s+{mean}\s", text, re.M), text


def test_running_rows_and_total_line(clock):
    view = Watched("x", _trials(variants=("a",), seeds=(0, 1)), 0, enabled=False, start=clock.now)
    clock.now += 9
    view.started("a-s1")
    clock.now += 5
    view.episodes("a-s1", [_row(40, 12.5)])
    assert re.search(r"a\s+1\s+40/100\s+12\.5\s+0:05", _text(view))
    view.finished("a-s1", solved=False)
    view.failed("a-s0")
    assert "all trials ended" in view.headline()
    clock.now += 7
    assert view.total_line(report_s=7) == "total 0:21 (until the first trial started 0:09, trials 0:05, report 0:07)"


def test_before_a_quarter_of_the_trials_end_the_time_left_is_not_a_figure(clock):
    """The first trials' costs are guesses (a launch of 36 read ~0:55 where 2:08 remained): until a quarter of
    them have ended the line says it is estimating, though the estimate (which ``make bench`` scores) exists."""
    view = Watched("x", _trials(variants=("a", "b"), seeds=(0, 1, 2, 3)), 0, enabled=False, slots=2)
    for key in ("a-s0", "b-s0"):
        view.started(key)
    clock.now += 10
    view.episodes("a-s0", [_row(50, 20.0), _row(100, 30.0)])
    view.finished("a-s0", solved=False)
    assert view.seconds_left() is not None
    assert view.headline().endswith("elapsed, time left: estimating until a quarter of the trials have ended (1 of 8)")
    view.failed("b-s0")  # 2 of 8 ended, failed or not: a figure from here
    assert re.search(r"elapsed, ~\d+:\d\d left$", view.headline()), view.headline()


def test_stage_without_a_terminal_prints_a_line_before_and_after(capsys):
    with stage("writing the report") as seconds:
        assert capsys.readouterr().out == "writing the report ...\n"
    assert len(seconds) == 1 and seconds[0] >= 0
    assert re.fullmatch(r"writing the report: done in \d+\.\d s\n", capsys.readouterr().out)


def _text(view) -> str:
    from rich.console import Console

    console = Console(width=160, record=True, file=open(os.devnull, "w"))  # noqa: SIM115
    console.print(view.render())
    return console.export_text()


# --- the view in a real terminal -------------------------------------------------------------------

SLOW_TINY = """
name = "tmuxview"
seeds = [0, 1, 2]
[base]
env_id = "CartPole-v1"
max_episodes = 100000
episodes_per_update = 1
learning_rate = 0.00001
solve_threshold = 100000
record_video = false
[[variants]]
name = "narrow"
hidden_sizes = [8]
[[variants]]
name = "other"
hidden_sizes = [4]
"""


def _tmux() -> str | None:
    found = shutil.which("tmux")
    if found or shutil.which("apt-get") is None or os.geteuid() != 0:
        return found
    install = "apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq tmux"
    subprocess.run(["bash", "-c", install], capture_output=True, timeout=600)
    return shutil.which("tmux")


@pytest.mark.e2e  # it samples a terminal's clock while Ray starts: make test-e2e runs it with nothing beside it
def test_progress_view_in_tmux_clock_runs_before_any_trial_ends_and_running_rows_appear(tmp_path):
    tmux = _tmux()
    if tmux is None:
        pytest.skip("tmux is not installed and could not be installed with apt-get (no root or no Debian mirror)")
    (tmp_path / "exp.toml").write_text(SLOW_TINY)
    fresh_store(tmp_path / "mlflow.db")
    socket = f"ablate-test-{os.getpid()}"
    # bash, not sh: after Ctrl-C it waits for ablate to exit (130) and then echoes the code.
    (tmp_path / "run.sh").write_text(
        f"{sys.executable} -m ablate.cli run exp.toml --only narrow --seeds 0,1 --no-report "
        f"--tracking-uri sqlite:///{tmp_path / 'mlflow.db'} --max-concurrent 2\necho EXIT=$?\nsleep 600\n"
    )
    # pytest-xdist's workers set COLUMNS=80 and LINES=24: inherited, they would size rich's console in place of
    # the 150-column pane, and the header, once it shows an estimate, would wrap out of the regex below.
    env = {k: v for k, v in os.environ.items() if not k.startswith("TMUX") and k not in ("COLUMNS", "LINES")}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])

    def tmux_run(*args: str, check: bool = True) -> str:
        proc = subprocess.run([tmux, "-L", socket, *args], capture_output=True, text=True, env=env, timeout=30)
        if check:
            assert proc.returncode == 0, proc.stderr
        return proc.stdout

    tmux_run("new-session", "-d", "-s", "view", "-x", "150", "-y", "40", "-c", str(tmp_path), "bash run.sh")
    clocks_before_any_start: set[str] = set()  # while Ray starts
    clocks_before_any_end: set[str] = set()
    screens: list[str] = []
    running_row = None
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and running_row is None:
            screen = tmux_run("capture-pane", "-p", "-t", "view")
            screens.append(screen)
            assert "Traceback" not in screen and "EXIT=" not in screen, screen
            head = re.search(
                r"tmuxview: (\d+) done, (\d+) running, \d+ pending, \d+ failed \(of (\d+);.*\| (\d+:\d\d)", screen
            )
            if head:
                done, running, total, elapsed = head.groups()
                assert total == "2", screen  # --only narrow --seeds 0,1: two trials
                if done == "0":
                    clocks_before_any_end.add(elapsed)
                    if running == "0":
                        clocks_before_any_start.add(elapsed)
            if len(clocks_before_any_end) >= 2:
                running_row = re.search(r"^narrow\s+[01]\s+[\d,]+/100,000\s+\d+\.\d\s+\d+:\d\d", screen, re.M)
            time.sleep(0.25)  # a polling interval; every assertion waits on what the screen shows
        assert len(clocks_before_any_end) >= 2, "the clock did not advance before a trial ended:\n" + screens[-1]
        assert len(clocks_before_any_start) >= 2, "the clock stood still while Ray started:\n" + "\n".join(screens)
        assert running_row is not None, "no row of a running trial with its episode:\n" + screens[-1]
        # Ctrl-C: the run stops its trials and Ray, and exits 130.
        tmux_run("send-keys", "-t", "view", "C-c")
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and "EXIT=" not in (screen := tmux_run("capture-pane", "-p", "-t", "view")):
            time.sleep(0.25)
        assert "EXIT=130" in screen, screen
        assert re.search(r"^total \d+:\d\d \(until the first trial started \d+:\d\d, trials", screen, re.M), screen
    finally:
        tmux_run("kill-server", check=False)


def test_schedule_order_interleaves_seeds_across_variants_and_keeps_every_key():
    from ablate.launch.grid import schedule_order

    trials = _trials(variants=("a", "slow", "c"), seeds=(0, 1))
    ordered = schedule_order(trials)
    assert [t.key for t in ordered] == ["a-s0", "slow-s0", "c-s0", "a-s1", "slow-s1", "c-s1"]
    assert sorted(ordered, key=trials.index) == trials  # the same trials, keys untouched
    # Known slow trials first within a round, so none starts last and runs alone.
    costs = {"slow-s0": 30.0, "slow-s1": 30.0, "c-s1": 5.0}
    assert [t.key for t in schedule_order(trials, costs)] == ["slow-s0", "a-s0", "c-s0", "slow-s1", "c-s1", "a-s1"]
