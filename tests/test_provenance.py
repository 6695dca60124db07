"""The reproducibility record against a real git clone."""

import subprocess

from ablate.reporting.provenance import earlier_note, experiment_file_state


def _git(folder, *argv):
    command = ["git", "-c", "user.email=t@t", "-c", "user.name=t", *argv]
    return subprocess.run(command, cwd=folder, capture_output=True, text=True, check=True).stdout.strip()


def test_the_record_says_whether_the_experiment_file_is_the_committed_one(tmp_path):
    # issue 18 item 7: the record named the commit but not that the experiment file was not in it
    _git(tmp_path, "init", "-q")
    (tmp_path / "experiments").mkdir()
    (tmp_path / "experiments" / "mine.toml").write_text('name = "mine"\n')
    _git(tmp_path, "add", "experiments/mine.toml")
    _git(tmp_path, "commit", "-qm", "an experiment")
    commit = _git(tmp_path, "rev-parse", "HEAD")
    path = "experiments/mine.toml"
    same = experiment_file_state(commit, path, 'name = "mine"\n', cwd=tmp_path)
    assert "is the one committed at" in same and "uncommitted" not in same
    edited = experiment_file_state(commit + "-dirty", path, 'name = "mine"\nseeds = 9\n', cwd=tmp_path)
    assert "had uncommitted changes" in edited and "experiment.toml" in edited
    never = experiment_file_state(commit, "experiments/other.toml", 'name = "other"\n', cwd=tmp_path)
    assert "was not committed at" in never and commit[:12] in never
    absolute = experiment_file_state(commit, str(tmp_path / path), 'name = "mine"\n', cwd=tmp_path)
    assert "is the one committed at" in absolute
    assert "lacks it" in experiment_file_state("0" * 40, path, "", cwd=tmp_path)
    assert experiment_file_state("unknown", path, "", cwd=tmp_path) == ""


def test_earlier_trials_are_said_in_one_line_with_their_number():
    assert earlier_note({"lab": 1}).startswith(
        "1 earlier trial of `lab` (an earlier version of its settings or code) is in the store and not counted"
    )
    assert earlier_note({"a": 2, "b": 3}).startswith("2 earlier trials of `a` and 3 earlier trials of `b` (an")
    assert earlier_note({}) == ""
