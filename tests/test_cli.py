"""`ablate train` from the command line: bad input is one line and exit 2; good input writes its outputs."""

import subprocess
import sys

import pytest

from ablate.cli import main


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--env", "Pong-v0"],
            "env_id = 'Pong-v0' is invalid; valid: one of CartPole-v0, CartPole-v1, ALE/Pong-v5",
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
    assert names == {"weights.pt", "learning_curve.png", "video.mp4", "episodes.csv", "summary.json"}
    lines = (out / "episodes.csv").read_text().splitlines()
    assert len(lines) == 41 and lines[0].startswith("episode,episode_return,length")
    assert "not solved in 40 episodes" in capsys.readouterr().out


BAD_EXPERIMENTS = [
    ("name = 'x'\n[base\n", "not valid TOML"),
    ("[[variants]]\nname='a'\nwidht = 3\n", "variants[0].widht: unknown key"),
    ("[[variants]]\nname='a'\nlearning_rate = 'high'\n", "variants[0].learning_rate = 'high' is invalid"),
    ("[base]\nenv_id = 'Breakout'\n[[variants]]\nname='a'\n", "base.env_id = 'Breakout' is invalid"),
    ("seeds = 2\n", "the grid is empty"),
    ("[[variants]]\nname='a'\ngamma = 1.2\n", "variants[0].gamma = 1.2 is invalid; valid: a number in (0, 1]"),
    ("[grid]\ndropout = [0.0, 1.5]\n", "grid.dropout = 1.5 is invalid; valid: a number in [0, 1)"),
    ("[[variants]]\nname='a'\n[[variants]]\nname='a'\n", "duplicate variant name 'a'"),
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
