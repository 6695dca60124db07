"""`ablate train` from the command line: bad input is one line and exit 2; good input writes its outputs."""

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from ablate.cli import main
from ablate.experiment import load_experiment
from ablate.launch.clock import clock

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            # Not Pong-v0: ale-py registers the old ids once imported (a Pong test earlier in this process), and
            # the default MLP on raw 210x160x3 frames then fills the memory instead of failing.
            ["--env", "Pong-v9"],
            "env_id = 'Pong-v9' is not a registered Gymnasium env",
        ),
        (["--gamma", "1.5"], "gamma = 1.5 is invalid; valid: a number in (0, 1]"),
        (["--gamma", "0"], "gamma = 0.0 is invalid; valid: a number in (0, 1]"),
        (["--dropout", "1"], "dropout = 1.0 is invalid; valid: a number in [0, 1)"),
        (["--dropout", "-0.1"], "dropout = -0.1 is invalid; valid: a number in [0, 1)"),
        (["--max-episodes", "-10"], "max_episodes = -10 is invalid; valid: an integer in [1, 1000000]"),
        (["--gamma", "high"], "argument --gamma: invalid float value: 'high'"),
    ],
)
def test_bad_train_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_info:
        raise SystemExit(main(["train", *argv, "--out", str(out)]))
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_bad_input_through_the_console_script_has_no_traceback(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "train", "--gamma", "2"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == "ablate train: gamma = 2.0 is invalid; valid: a number in (0, 1]"
    assert not list(tmp_path.iterdir())


def test_train_writes_curve_video_weights_and_metrics(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(
        [
            "train",
            "--env",
            "CartPole-v1",
            "--max-episodes",
            "40",
            "--episodes-per-update",
            "8",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"weights.pt", "config.json", "learning_curve.png", "video.mp4", "episodes.csv", "summary.json"}
    lines = (out / "episodes.csv").read_text().splitlines()
    assert len(lines) == 41 and lines[0].startswith("episode,episode_return,length")
    assert "not solved in 40 episodes" in capsys.readouterr().out


BAD_EXPERIMENTS = [
    ("name = 'x'\n[base\n", "not valid TOML"),
    ("[[variants]]\nname='a'\nwidht = 3\n", "variants[0].widht: unknown key"),
    ("[[variants]]\nname='a'\nlearning_rate = 'high'\n", "variants[0].learning_rate = 'high' is invalid"),
    (
        "[base]\nenv_id = 'Breakout'\n[[variants]]\nname='a'\n",
        "variant 'a': env_id = 'Breakout' is not a registered Gymnasium env",
    ),
    ("seeds = 2\n", "the grid is empty"),
    ("[[variants]]\nname='a'\ngamma = 1.2\n", "variants[0].gamma = 1.2 is invalid; valid: a number in (0, 1]"),
    ("[grid]\ndropout = [0.0, 1.5]\n", "grid.dropout = 1.5 is invalid; valid: a number in [0, 1)"),
    ("[[variants]]\nname='a'\n[[variants]]\nname='a'\n", "duplicate variant name 'a'"),
    # [tune] (issue 19): a refused knob, and a knob both compared and tuned
    ("[[variants]]\nname='a'\n[tune]\ndropout = [0.0, 0.2]\n", "tune.dropout: not tunable"),
    ("[grid]\nlearning_rate = [0.1]\n[tune]\nlearning_rate = [0.1]\n", "tune.learning_rate: also a [grid] axis"),
    # the primary question (issue 25): an unknown metric, and episodes to solve where nothing can solve
    ("primary = 'speed'\n[[variants]]\nname='a'\n", "primary = 'speed' is invalid; valid: one of episodes_to_solve"),
    (
        "primary = 'episodes_to_solve'\n[base]\nenv_id = 'ALE/Pong-v5'\n[[variants]]\nname='a'\n",
        "primary = 'episodes_to_solve' is invalid: ALE/Pong-v5 has no solve threshold",
    ),
    ("smallest_effect = 1.5\n[[variants]]\nname='a'\n", "smallest_effect = 1.5 is invalid; valid: a fraction"),
    # a Pong-only knob on another game (issue 56): refused, not silently ignored
    (
        "[base]\nenv_id = 'ALE/Breakout-v5'\naction_set = 'move'\n[[variants]]\nname='a'\n",
        "base.action_set = 'move' is invalid for env_id = 'ALE/Breakout-v5' (profile 'atari', which ignores it); "
        "valid: only with env_profile 'pong'",
    ),
]


@pytest.mark.parametrize(("text", "message"), BAD_EXPERIMENTS)
def test_bad_experiment_file_is_one_line_exit_2_and_no_mlflow_run(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    db = tmp_path / "mlflow.db"
    proc = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "run", str(path), "--tracking-uri", f"sqlite:///{db}"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert str(path) in proc.stderr and message in proc.stderr
    assert not db.exists()  # nothing was tracked


def test_missing_experiment_file_and_bad_concurrency(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "run", "nope.toml"], capture_output=True, text=True, cwd=tmp_path
    )
    assert proc.returncode == 2 and proc.stderr.strip() == "ablate run: nope.toml: no such experiment file"
    good = tmp_path / "ok.toml"
    good.write_text("[[variants]]\nname = 'a'\n")
    proc = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "run", str(good), "--max-concurrent", "0"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2 and "--max-concurrent = 0 is invalid; valid: an integer >= 1" in proc.stderr
    assert not (tmp_path / "mlflow.db").exists()


# --- help, flags, run --only/--seeds/--dry-run, train --from -------------------------------------------


def _subparsers(parser):
    import argparse

    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def test_every_option_of_every_command_has_a_help_text():
    from ablate.cli import build_parser

    parser = build_parser()
    missing = []
    for name, sub in _subparsers(parser).items():
        for action in sub._actions:
            if not action.help or not action.help.strip():
                missing.append(f"ablate {name} {'/'.join(action.option_strings) or action.dest}")
    assert not missing, missing


def test_run_and_calibrate_launch_with_the_same_flags_and_defaults():
    from ablate.cli import build_parser

    commands = _subparsers(build_parser())
    flags = ("--address", "--tracking-uri", "--max-concurrent", "--population")
    run, calibrate = (
        {a.option_strings[0]: a for a in commands[c]._actions if a.option_strings} for c in ("run", "calibrate")
    )
    for flag in flags:
        assert (run[flag].default, run[flag].help) == (calibrate[flag].default, calibrate[flag].help), flag
    assert calibrate["--tracking-uri"].default is None  # MLFLOW_TRACKING_URI, else sqlite:///mlflow.db, as run reads it


def test_top_level_help_describes_the_tool_not_the_module():
    proc = subprocess.run([sys.executable, "-m", "ablate.cli", "--help"], capture_output=True, text=True)
    assert proc.returncode == 0
    assert "architecture ablations of REINFORCE" in proc.stdout and "examples:" in proc.stdout
    for command in ("train", "run", "status", "report"):
        assert re.search(rf"^\s+{command}\s+\S", proc.stdout, re.M), command
    assert "Thin: parse" not in proc.stdout and "``" not in proc.stdout


def test_train_has_a_flag_for_every_knob_and_each_reaches_the_config():
    from ablate.cli import TEST_ONLY_KNOBS, TRAIN_KNOBS, build_parser
    from ablate.config import DEFAULT, KNOBS, SHORTHANDS, apply_knobs, flatten

    train = _subparsers(build_parser())["train"]
    dests = {a.dest for a in train._actions}
    assert set(KNOBS) - set(TEST_ONLY_KNOBS) | set(SHORTHANDS) <= dests
    own_network = {"model", "model_args"}  # a user's network: not beside the built-in network's knobs
    argv = shlex.split(
        "--env-id CartPole-v0 --learning-rate 0.5 --gamma 0.9 --l2 0.01 --episodes-per-update 4 --max-episodes 7 "
        "--solve-threshold 150 --solve-window 20 --seed 3 --no-record-video --video-max-frames 9 --architecture cnn "
        "--hidden-sizes 5,6 --activation tanh --dropout 0.25 --history 6 --conv-channels 3,4 --kernel-size 3 "
        "--env-profile gym --max-episode-steps 30 --num-envs 2 "
        "--video-every 5 --checkpoint-every 7 --env-module gymnasium.envs --env-args '{\"sutton_barto_reward\": true}' "
        "--layer-norm"
    )
    model = ROOT / "examples" / "models" / "layernorm.py"
    argv_own = ["--model", f"{model}:create_model", "--model-args", '{"width": 8}']

    def changed_knobs(argv: list[str]) -> dict:
        args = train.parse_args(argv)
        knobs = {k: getattr(args, k) for k in TRAIN_KNOBS if getattr(args, k) is not None}
        flat = flatten(apply_knobs(DEFAULT, knobs))
        by_column = {k.column: name for name, k in KNOBS.items()}
        return {by_column[c]: v for c, v in flat.items() if v != flatten(DEFAULT)[c] and c in by_column}

    changed = changed_knobs(argv)
    atari = {name for name, k in KNOBS.items() if k.profiles}  # refused on CartPole (config.apply_knobs): on Pong
    assert set(changed) == set(KNOBS) - set(TEST_ONLY_KNOBS) - own_network - atari  # every knob set by its flag
    pong = ["--env-id", "ALE/Pong-v5", "--action-set", "move", "--frameskip", "2", "--repeat-action-probability", "0.1"]
    assert changed_knobs(pong) == {
        "env_id": "ALE/Pong-v5",
        "action_set": "move",
        "frameskip": 2,
        "repeat_action_probability": 0.1,
    }
    assert changed["hidden_sizes"] == (5, 6) and changed["record_video"] is False and changed["gamma"] == 0.9
    assert changed["env_args"] == (("sutton_barto_reward", True),)
    assert changed_knobs(argv_own) == {"model": f"{model}:create_model", "model_args": (("width", 8),)}
    depth = train.parse_args(["--depth", "3", "--width", "7", "--env", "CartPole-v0"])
    assert apply_knobs(DEFAULT, {"depth": depth.depth, "width": depth.width}).model.hidden_sizes == (7, 7, 7)
    assert train.parse_args(["--hidden-sizes", "linear"]).hidden_sizes == []


TINY = """
name = "tiny"
seeds = [0, 1, 2]
[base]
env_id = "CartPole-v1"
max_episodes = 16
episodes_per_update = 8
video_max_frames = 20
[[variants]]
name = "narrow"
hidden_sizes = [8]
[[variants]]
name = "depth=2,width=8"
hidden_sizes = [8, 8]
[[variants]]
name = "wide"
hidden_sizes = [64]
"""


def test_run_dry_run_lists_the_chosen_trials_and_starts_nothing(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    code = (
        "import sys; from ablate.cli import main; "
        f"rc = main(['run', {str(path)!r}, '--only', 'depth=2,width=8,wide', '--seeds', '0,2', '--dry-run']); "
        "print('RAY IMPORTED' if 'ray' in sys.modules else 'NO RAY', 'MLFLOW IMPORTED' if 'mlflow' in sys.modules "
        "else 'NO MLFLOW'); sys.exit(rc)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("time: ") and lines[1] == "tiny: 4 of 9 trials (dry run: nothing started or written)"
    from ablate.launch.grid import expand

    expected = [t for t in expand(load_experiment(path)) if t.variant != "narrow" and t.seed in (0, 2)]
    rows = [line.split() for line in lines[3:7]]
    assert [(r[0], int(r[1]), r[2]) for r in rows] == [(t.variant, t.seed, t.key) for t in expected]
    assert rows[0][3:] == ["hidden_sizes=[8,", "8]"]
    assert lines[-1] == "NO RAY NO MLFLOW"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]  # no mlflow.db, no ray_results


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--only", "narow"], "--only: 'narow' is not a variant; valid: narrow, depth=2,width=8, wide"),
        (["--seeds", "0,5"], "--seeds: 5 is not a seed of this experiment; valid: 0, 1, 2"),
        (["--seeds", "a"], "argument --seeds: 'a' is not a comma-separated list of seeds, e.g. 0,1"),
    ],
)
def test_run_bad_only_or_seeds_is_exit_2(tmp_path, capsys, argv, message):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    with pytest.raises(SystemExit) as exit_info:
        raise SystemExit(main(["run", str(path), *argv, "--dry-run"]))
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "needs --variant (one of narrow, depth=2,width=8, wide) and --seed (one of 0, 1, 2)"),
        (["--variant", "wide"], "needs --variant"),
        (["--variant", "wid", "--seed", "0"], "--variant 'wid' is not a variant of"),
        (["--variant", "wide", "--seed", "7"], "--seed 7 is not a seed of"),
        (["--variant", "wide", "--seed", "0", "--dropout", "0.1"], "--dropout: not with --from"),
        (["--variant", "wide", "--seed", "0", "--preset", "course"], "--preset: not with --from"),
    ],
)
def test_train_from_bad_input_is_exit_2(tmp_path, capsys, argv, message):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    out = tmp_path / "out"
    assert main(["train", "--from", str(path), *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()
    assert main(["train", "--variant", "wide"]) == 2
    assert "--variant: only with --from" in capsys.readouterr().err


def test_train_from_runs_that_trial_with_its_key_and_config_and_no_sdl_noise(tmp_path):
    import csv

    from ablate.agent.trainer import run_trial
    from ablate.launch.grid import expand

    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    out = tmp_path / "out"
    env = {k: v for k, v in os.environ.items() if k not in ("XDG_RUNTIME_DIR", "SDL_VIDEODRIVER")}
    proc = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "train", "--from", str(path), "--variant", "depth=2,width=8"]
        + ["--seed", "2", "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    assert "XDG_RUNTIME_DIR" not in proc.stderr + proc.stdout and proc.stderr == ""  # the video was rendered quietly
    trial = next(t for t in expand(load_experiment(path)) if t.variant == "depth=2,width=8" and t.seed == 2)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["trial_key"] == trial.key and f"trial {trial.key}" in proc.stdout
    assert (out / "video.mp4").is_file()
    # The same config as the experiment's trial: the same episodes, return for return.
    reference = run_trial(trial.config)
    with open(out / "episodes.csv") as table:
        returns = [float(row["episode_return"]) for row in csv.DictReader(table)]
    assert returns == [m.episode_return for m in reference.episodes] and len(returns) == 16


def test_run_dry_run_takes_a_name_in_any_script_and_shows_its_storage_name(tmp_path, capsys, monkeypatch):
    from ablate.experiment import storage_name

    monkeypatch.chdir(tmp_path)
    path = tmp_path / "实验.toml"
    # NFD in the file (as some editors write it): the experiment is the NFC name.
    path.write_text('name = "实验e\u0301"\nseeds = 2\n[[variants]]\nname = "基线"\n', encoding="utf-8")
    assert main(["run", str(path), "--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    stored = storage_name("实验é")
    assert lines[1] == "实验é: 2 of 2 trials (dry run: nothing started or written)"
    assert lines[2].startswith(f"stored as {stored!r}: reports/{stored}/, the MLflow experiment")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["实验.toml"]  # nothing written


@pytest.mark.parametrize("name", ["", "a/b", "bell\u0007", "x" * 101])
def test_run_bad_name_is_one_line_exit_2(tmp_path, capsys, name):
    path = tmp_path / "bad.toml"
    path.write_text(f"name = {json.dumps(name)}\n[[variants]]\nname = 'a'\n", encoding="utf-8")
    assert main(["run", str(path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}: name = " in err and "is invalid (" in err


DESIGN = """
seeds = {seeds}
[base]
max_episodes = 10
[[variants]]
name = "a"
[[variants]]
name = "b"
hidden_sizes = [8]
"""


@pytest.mark.parametrize(("seeds", "warned"), [(3, True), (4, True), ("[0, 1, 2, 3, 4]", False), (1, True)])
def test_dry_run_warns_before_any_compute_when_the_design_cannot_reach_a_claim(tmp_path, capsys, seeds, warned):
    from ablate.cli import main

    path = tmp_path / "design.toml"
    path.write_text(DESIGN.format(seeds=seeds))
    assert main(["run", str(path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    if warned:
        first = out.splitlines()[-1]
        assert first.startswith(f"warning: design: with {seeds} seeds per variant no primary comparison can reach")
        assert "it takes at least 5 seeds per variant (seeds = 5)" in first  # 4 and 4: at best p = 4 / 70
    else:
        assert "warning" not in out


TUNED = """
seeds = 2
[base]
max_episodes = 10
[[variants]]
name = "a"
[[variants]]
name = "own"
learning_rate = 0.001
[tune]
learning_rate = [0.01, 0.1]
seeds = 2
"""


def test_dry_run_of_a_tuned_file_lists_stage_1_then_stage_2_after_tuning(tmp_path, capsys):
    from ablate.cli import main
    from ablate.launch.grid import tuning_trials

    path = tmp_path / "tuned.toml"
    path.write_text(TUNED)
    assert main(["run", str(path), "--dry-run", "--seeds", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert (
        lines[1] == "tuned: 4 tuning trials, then 2 at the base values and up to 1 at the chosen values (dry run: "
        "nothing started or written)"
    )
    rows = [line.split() for line in lines[3:-1]]
    experiment = load_experiment(path)
    tuning = tuning_trials(experiment)  # --seeds never narrows the tuning seeds
    assert [(r[0], r[2], r[3]) for r in rows[:4]] == [(t.variant, str(t.seed), t.key) for t in tuning]
    assert [r[:3] for r in rows[4:6]] == [["a", "[base]", "1"], ["own", "[base]", "1"]]
    assert rows[6][:5] == ["a", "[chosen]", "1", "after", "tuning"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tuned.toml"]


def test_dry_run_only_narrows_both_stages_to_the_variants_asked_for(tmp_path, capsys):
    path = tmp_path / "tuned.toml"
    path.write_text(TUNED.replace('name = "own"\nlearning_rate = 0.001', 'name = "b"\nhidden_sizes = [8]'))
    assert main(["run", str(path), "--dry-run", "--only", "b"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("tuned: 4 tuning trials, then 2 at the base values and up to 2 at the chosen values")
    assert {line.split()[0] for line in lines[3:-2]} == {"b"} and lines[0].startswith("time: ")


@pytest.mark.parametrize("seeds", [2, 1000])
def test_dry_run_into_a_pipe_its_reader_closed_exits_quietly(tmp_path, seeds):
    """``ablate run --dry-run | head -1``, with a real pipe: no ``BrokenPipeError`` traceback, and the status a shell
    gives a Unix tool ended by SIGPIPE. 2 seeds: the listing fits in one write, met by a pipe closed before the
    command starts (Python would otherwise fail at its exit's flush); 1000 seeds: ~120 kB, more than a pipe holds
    (64 kB), so the command is still writing when the reader leaves after the first line."""
    path = tmp_path / "listing.toml"
    smoke = Path(__file__).parents[1] / "experiments" / "smoke.toml"
    path.write_text(smoke.read_text().replace("seeds = 2\n", f"seeds = {seeds}\n"))
    read, write = os.pipe()
    if seeds == 2:
        os.close(read)
    argv = [sys.executable, "-m", "ablate.cli", "run", str(path), "--dry-run"]
    proc = subprocess.Popen(argv, stdout=write, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    os.close(write)
    if seeds != 2:
        with os.fdopen(read) as reader:
            assert reader.readline().startswith("time: ")  # the cost first, where `| head -1` keeps it
    _, err = proc.communicate(timeout=120)
    assert (proc.returncode, err) == (128 + 13, "")


def test_dry_run_prints_its_cost_first_with_the_start_and_the_report(tmp_path, capsys):
    # issue 46: the cost came last (`| head` lost it) and left out the start and the report (~0:44 said, 1:18 taken)
    from ablate.dry_run import START_S, report_guess

    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    assert main(["run", str(path), "--dry-run"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("time: ") and "a guess" in first, first
    assert f"~{clock(START_S)} to start" in first and f"~{clock(report_guess(9))} for the report" in first, first
    assert main(["run", str(path), "--dry-run", "--no-report"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "to start" in first and "report" not in first, first


def test_dry_run_gives_a_never_run_plan_a_time_from_its_budget_not_just_counts(tmp_path, capsys):
    """Issue 56: with no earlier run in the store it said "a guess in trials: round 1 runs 9 trials", no time.
    A never-run trial now costs its budget at its env's measured seconds per episode."""
    from ablate.dry_run import episode_seconds, guessed_s
    from ablate.launch.grid import expand

    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    assert main(["run", str(path), "--dry-run", "--no-report"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert re.match(r"time: ~\d+:\d\d in all: trials ~\d+:\d\d \(9 trials; no earlier run in the store: ", first), first
    rate = episode_seconds("CartPole-v1")  # the gym profile's measurement
    assert rate and f"a guess at {rate:g} s per CartPole-v1 episode of budget" in first, first
    trial = expand(load_experiment(path))[0]
    assert guessed_s(trial) == rate * trial.config.max_episodes
    # An env without a calibration is costed at CartPole-v1's rate, and says so.
    path.write_text(TINY.replace('"CartPole-v1"', '"Acrobot-v1"'))
    assert main(["run", str(path), "--dry-run", "--no-report"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "a guess at 0.021 s per Acrobot-v1 episode (CartPole-v1's: never measured) of budget" in first, first


def test_dry_run_costs_the_start_and_the_report_as_the_stores_last_launch_took_them(tmp_path, capsys):
    """It said "~0:31 to start and ~0:46 for the report: a guess" beside a store whose launches had taken 0:06-0:11
    and 0:02-0:11 (3e01923). A launch records both (``start_s``, ``report_s``); the dry run reads the newest."""
    from stores import fresh_store

    from ablate.launch.tracking import Tracker

    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    uri = fresh_store(tmp_path / "mlflow.db")
    tracker = Tracker(uri, "tiny")
    launch = tracker.start_launch("g", "tiny launch", {}, {})
    tracker.finish_launch(launch, "FINISHED", {"trials_finished": 4.0, "start_s": 7.0})
    tracker.record_report_time(launch, 12.0)
    assert main(["run", str(path), "--dry-run", "--tracking-uri", uri]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "~0:07 to start and ~0:12 for the report: as this store's last launch of it took them" in first, first


def test_dry_run_costs_only_what_the_run_would_run_not_the_trials_finished_in_the_newest_generation(tmp_path, capsys):
    """Its trials' time counted every trial, the 12 finished before among them, where a rerun ran 12 (a rerun at
    6 seeds said ~0:50 and took 1:52, and at 9 counted 36 trials). A run skips the newest generation's finished
    trials; so does the dry run, and ``--fresh`` skips none."""
    from stores import fresh_store

    from ablate.launch.grid import expand
    from ablate.launch.tracking import Tracker

    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    uri = fresh_store(tmp_path / "mlflow.db")
    tracker = Tracker(uri, "tiny")
    launch = tracker.start_launch("g", "tiny launch", {}, {})
    for trial in expand(load_experiment(path))[:3]:
        tracker.start_trial(launch, "g", trial.key, trial.variant, trial.seed, {}, "")
        tracker.finish_trial(trial.key, {"episodes_run": 16.0}, None)
    tracker.finish_launch(launch, "FINISHED", {"trials_finished": 3.0, "start_s": 7.0})
    assert main(["run", str(path), "--dry-run", "--no-report", "--tracking-uri", uri]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "(6 trials, 3 finished before; from the store's earlier runs" in first, first
    assert main(["run", str(path), "--dry-run", "--no-report", "--fresh", "--tracking-uri", uri]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "(9 trials; from the store's earlier runs" in first, first


def test_train_flags_for_a_users_env_module_refuse_one_that_registers_nothing_in_one_line(
    tmp_path, monkeypatch, capsys
):
    from ablate.cli import main

    (tmp_path / "emptyenvs.py").write_text("def register():\n    pass\n")
    monkeypatch.chdir(tmp_path)
    code = main(["train", "--env-module", "emptyenvs:register", "--env", "NowhereCartPole-v0", "--max-episodes", "2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0] == (
        "ablate train: env_module = 'emptyenvs:register' ran, but env_id = 'NowhereCartPole-v0' is still not a "
        "registered Gymnasium env; it registered none"
    )
    assert not (tmp_path / "outputs").exists()  # nothing written
