"""`ablate status`: ablations, launches, generations and trials by state, read from a real MLflow store."""

import re

from ablate.cli import main
from ablate.experiment import load_experiment
from ablate.launch.grid import expand, select

FAULTY = """
name = "faulty"
seeds = [0, 1]
[base]
env_id = "CartPole-v1"
max_episodes = 10
episodes_per_update = 10
record_video = false
[[variants]]
name = "ok"
[[variants]]
name = "boom"
fault = "raise"
"""


def test_status_of_a_real_store(run_quiet, tmp_path, tracking_uri, capsys):
    path = tmp_path / "faulty.toml"
    path.write_text(FAULTY)
    experiment = load_experiment(path)
    first = run_quiet(experiment, tmp_path, tracking_uri)
    assert len(first.finished) == 2 and len(first.failed) == 2
    second = run_quiet(experiment, tmp_path, tracking_uri, fresh=True, only=select(expand(experiment), ["ok"], [0]))
    assert second.finished == [t.key for t in expand(experiment) if t.variant == "ok" and t.seed == 0]

    assert main(["status", "--tracking-uri", tracking_uri]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^faulty\s+2\s+2\s+\S+ \S+\s+FINISHED\s+1 trial: 1 finished$", out, re.M), out

    assert main(["status", str(path), "--tracking-uri", tracking_uri]) == 0
    out = capsys.readouterr().out
    assert out.startswith("faulty: 2 launches in 2 generations")
    link = out.splitlines()[1]  # the variant comparison in MLflow's UI, as the launch prints it
    assert link.startswith("MLflow, the variants compared (the last report's): http://127.0.0.1:5000/#/experiments/")
    assert "searchFilter=tags.%60ablate.role%60+%3D+%22variant%22" in link and "compareRunsMode=CHART" in link
    newest, older = out.split("\ngeneration ")[1:]
    assert newest.startswith(f"{second.generation} (newest): 4 trials: 1 finished, 3 pending")
    assert re.search(r"^  ok\s+1\s+1$", newest, re.M) and re.search(r"^  boom\s+0\s+2$", newest, re.M), newest
    assert older.startswith(f"{first.generation}: 4 trials: 2 finished, 2 failed")
    assert re.search(r"launch \S+ \S+\s+FAILED", older), older  # a launch with failed trials ends FAILED
    assert "variant" not in older  # the per-variant table is the newest generation's

    assert main(["status", "faulty", "--tracking-uri", tracking_uri]) == 0
    assert "1 trial: 1 finished" in capsys.readouterr().out.split("\ngeneration ")[1]  # no file: no pending


def test_status_without_a_store_writes_nothing_and_unknown_names_are_exit_2(tmp_path, capsys):
    uri = f"sqlite:///{tmp_path / 'none.db'}"
    assert main(["status", "--tracking-uri", uri]) == 0
    assert capsys.readouterr().out.startswith(f"no ablations in the MLflow store {uri} yet")
    assert main(["status", "cartpole", "--tracking-uri", uri]) == 2
    err = capsys.readouterr().err
    assert (
        err
        == f"ablate status: 'cartpole' is not an ablation in the MLflow store {uri}; the store holds no ablation yet\n"
    )
    assert not list(tmp_path.iterdir())
