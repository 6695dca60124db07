"""Config knobs and experiment files: valid values load, bad ones give one actionable line."""

import json
import re
import unicodedata

import pytest

from ablate.config import COURSE, DEFAULT, ConfigError, apply_knobs, flatten
from ablate.experiment import load_experiment, storage_name


def test_course_preset_is_the_labs_setting():
    assert (COURSE.learning_rate, COURSE.episodes_per_update, COURSE.gamma) == (1e-3, 1, 0.95)
    assert COURSE.model.hidden_sizes == (32,)


def test_depth_and_width_expand_to_hidden_sizes():
    assert apply_knobs(DEFAULT, {"depth": 3, "width": 16}).model.hidden_sizes == (16, 16, 16)
    assert apply_knobs(DEFAULT, {"depth": 0}).model.hidden_sizes == ()
    assert apply_knobs(DEFAULT, {"hidden_sizes": [8, 4]}).model.hidden_sizes == (8, 4)


@pytest.mark.parametrize(
    ("knobs", "message"),
    [
        ({"env_id": "Mountain Car"}, "env_id = 'Mountain Car' is invalid; valid: a registered Gymnasium id"),
        ({"model": "net.py"}, "model = 'net.py' is invalid; valid: 'FILE.py:FUNCTION'"),
        ({"model": "missing.py:create"}, "model = 'missing.py:create' is invalid: no such file"),
        ({"model": "no_such_pkg_here.nets:create"}, "cannot import no_such_pkg_here.nets"),
        ({"model": "tests.test_config:f", "hidden_sizes": [4]}, "hidden_sizes: a built-in network knob beside model"),
        ({"model_args": 3}, "model_args = 3 is invalid; valid: a table"),
        ({"gamma": 0.0}, "gamma = 0.0 is invalid; valid: a number in (0, 1]"),
        ({"gamma": 1.5}, "gamma = 1.5 is invalid"),
        ({"dropout": 1.0}, "dropout = 1.0 is invalid; valid: a number in [0, 1)"),
        ({"max_episodes": -5}, "max_episodes = -5 is invalid; valid: an integer in [1, 1000000]"),
        ({"learning_rate": "fast"}, "learning_rate = 'fast' is invalid"),
        ({"widht": 3}, "widht: unknown key; valid keys:"),
        ({"hidden_sizes": [32], "depth": 2}, "either hidden_sizes or depth/width"),
        (
            {"action_set": "up"},
            "action_set = 'up' is invalid; valid: 'all' (the game's minimal action set) or 'move' (its RIGHT and LEFT)",
        ),
        ({"frameskip": 0}, "frameskip = 0 is invalid; valid: an integer in [1, 16]"),
        ({"repeat_action_probability": 1.5}, "repeat_action_probability = 1.5 is invalid"),
        ({"max_episode_steps": -1}, "max_episode_steps = -1 is invalid"),
        ({"checkpoint_every": 2.5}, "checkpoint_every = 2.5 is invalid"),
    ],
)
def test_bad_knobs_name_key_value_and_valid_range(knobs, message):
    with pytest.raises(ConfigError) as error:
        apply_knobs(DEFAULT, knobs)
    assert message in str(error.value)


def test_flatten_names_every_knob():
    flat = flatten(DEFAULT)
    assert flat["model.hidden_sizes"] == (32,) and flat["gamma"] == 0.95 and "model.dropout" in flat


def _write(tmp_path, text):
    path = tmp_path / "exp.toml"
    path.write_text(text)
    return path


def test_experiment_file_variants_grid_and_seeds(tmp_path):
    path = _write(
        tmp_path,
        """
name = "demo"
seeds = 3
baseline = "course"
[base]
env_id = "CartPole-v0"
max_episodes = 50
[[variants]]
name = "course"
learning_rate = 0.001
episodes_per_update = 1
[grid]
depth = [1, 2]
dropout = [0.0, 0.2]
""",
    )
    experiment = load_experiment(path)
    assert experiment.seeds == (0, 1, 2)
    names = [v.name for v in experiment.variants]
    assert names == [
        "course",
        "depth=1,dropout=0.0",
        "depth=1,dropout=0.2",
        "depth=2,dropout=0.0",
        "depth=2,dropout=0.2",
    ]
    deep = experiment.variants[4].config
    assert deep.model.hidden_sizes == (32, 32) and deep.model.dropout == 0.2 and deep.max_episodes == 50
    assert experiment.variants[0].config.learning_rate == 0.001


BAD_FILES = [
    ("name = 'x'\n[base\n", "not valid TOML"),
    ("colour = 'blue'\n[[variants]]\nname='a'\n", "colour: unknown key; valid top-level keys"),
    ("[[variants]]\nname='a'\nwidht = 3\n", "variants[0].widht: unknown key"),
    ("[[variants]]\nname='a'\nlearning_rate = 'high'\n", "variants[0].learning_rate = 'high' is invalid"),
    (
        "[base]\nenv_id = 'Break out'\n[[variants]]\nname='a'\n",
        "base.env_id = 'Break out' is invalid; valid: a registered Gymnasium id",
    ),
    ("seeds = 2\n", "the grid is empty"),
    (  # Breakout's env acts on its own actions: the knob was silently ignored (3e01923)
        "[base]\nenv_id = 'ALE/Breakout-v5'\n[[variants]]\nname='a'\naction_set = 'move'\n",
        "variants[0].action_set = 'move' is invalid for env_id = 'ALE/Breakout-v5' (profile 'atari', which ignores "
        "it); valid: only with env_profile 'pong'",
    ),
    ("[grid]\ndropout = []\n", "grid.dropout = [] is invalid; valid: a non-empty list"),
    (
        "[[variants]]\nname='a'\ngamma = 1.2\n",
        "variants[0].gamma = 1.2 is invalid; valid: a number in (0, 1]",
    ),
    (
        "[[variants]]\nname='a'\ndropout = 1.0\n",
        "variants[0].dropout = 1.0 is invalid; valid: a number in [0, 1)",
    ),
    ("[[variants]]\nname='a'\n[[variants]]\nname='a'\n", "duplicate variant name 'a'"),
    ("seeds = 0\n[[variants]]\nname='a'\n", "seeds = 0 is invalid"),
    (
        "baseline = 'b'\n[[variants]]\nname='a'\n",
        "baseline = 'b' is invalid; valid: one of the variant names",
    ),
    ("[[variants]]\nname='a'\nseed = 1\n", "variants[0].seed: set seeds at the top level"),
    ("[[variants]]\ndepth = 2\n", "variants[0].name: missing or empty"),
    ("gpus_per_trial = -1\n[[variants]]\nname='a'\n", "gpus_per_trial = -1 is invalid; valid: a number in [0, 16]"),
    ("primary = 3\n[[variants]]\nname='a'\n", "primary = 3 is invalid; valid: one of episodes_to_solve, auc, return"),
    ("smallest_effect = 0\n[[variants]]\nname='a'\n", "smallest_effect = 0 is invalid; valid: a fraction in (0, 1)"),
]


def test_pong_knobs_gpus_and_checkpoint_defaults(tmp_path):
    path = _write(
        tmp_path,
        "gpus_per_trial = 0.25\n[base]\nenv_id = 'ALE/Pong-v5'\naction_set = 'move'\nmax_episode_steps = 50\n"
        "repeat_action_probability = 0\n[[variants]]\nname = 'a'\n",
    )
    experiment = load_experiment(path)
    assert experiment.gpus_per_trial == 0.25
    config = experiment.variants[0].config
    assert (config.action_set, config.max_episode_steps, config.repeat_action_probability) == ("move", 50, 0.0)
    assert config.checkpoint_interval == 50 and DEFAULT.checkpoint_interval == 0  # Pong on, CartPole off


@pytest.mark.parametrize(("text", "message"), BAD_FILES)
def test_bad_experiment_files_name_file_key_and_valid_values(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as error:
        load_experiment(path)
    assert str(path) in str(error.value)
    assert message in str(error.value)
    assert "\n" not in str(error.value)


def test_missing_experiment_file(tmp_path):
    with pytest.raises(ConfigError, match="no such experiment file"):
        load_experiment(tmp_path / "nope.toml")


def test_a_file_starting_with_a_utf8_byte_order_mark_loads(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_bytes('\ufeffname = "bom"\n[[variants]]\nname = "a"\n'.encode())
    assert load_experiment(path).name == "bom"


# --- experiment names in any script (issue 18, item 6) ----------------------------------------------------


def _named(tmp_path, name: str, file: str = "exp.toml"):
    path = tmp_path / file
    path.write_text(f"name = {json.dumps(name)}\n[[variants]]\nname = 'a'\n", encoding="utf-8")
    return load_experiment(path)


@pytest.mark.parametrize("name", ["cartpole", "pong", "smoke", "pong-smoke", "A_b-9", "x" * 100])
def test_every_name_valid_before_is_its_own_storage_name(tmp_path, name):
    assert storage_name(name) == name
    assert _named(tmp_path, name).storage_name == name


def test_a_name_in_any_script_loads_nfc_normalised_with_a_safe_stable_storage_name(tmp_path):
    nfc, nfd = "实验é", unicodedata.normalize("NFD", "实验é")
    assert nfc != nfd
    first, second = _named(tmp_path, nfc, "a.toml"), _named(tmp_path, nfd, "b.toml")
    assert first.name == second.name == nfc  # one experiment, whichever form the editor wrote
    assert first.storage_name == second.storage_name == storage_name(nfd)
    assert re.fullmatch(r"e-[0-9a-f]{8}", first.storage_name)  # é keeps its letter; the hash tells names apart
    assert storage_name(first.storage_name) == first.storage_name  # a report asked for by it finds the same
    assert storage_name("实验") != storage_name("实验二")
    assert storage_name("Größe über alles") == f"Groe-uber-alles-{storage_name('Größe über alles')[-8:]}"


def test_a_100_character_cjk_name_stores_within_one_folder_names_255_bytes(tmp_path):
    name = "实" * 100
    assert len(name.encode()) == 300  # the name itself would not fit in a folder name
    stored = _named(tmp_path, name).storage_name
    assert stored.isascii() and len(stored.encode()) <= 57
    (tmp_path / stored).mkdir()  # the file system takes it
    from ablate.reporting.document import report_folder

    assert report_folder(name, tmp_path) == tmp_path / stored


@pytest.mark.parametrize(
    ("name", "problem"),
    [
        ("", "empty"),
        ("   ", "empty"),
        ("a\nb", "a control or unassigned character"),
        ("tab\there", "a control or unassigned character"),
        ("a/b", "a path separator"),
        ("a\\b", "a path separator"),
        ("..", "only dots"),
        ("实" * 101, "101 characters"),
        (5, "not a string"),
    ],
)
def test_bad_names_are_one_line_naming_the_problem(tmp_path, name, problem):
    path = tmp_path / "bad.toml"
    path.write_text(f"name = {json.dumps(name)}\n[[variants]]\nname = 'a'\n", encoding="utf-8")
    with pytest.raises(ConfigError) as error:
        load_experiment(path)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{path}: name = ")
    assert f"is invalid ({problem}); valid: 1 to 100 characters in any script" in message


@pytest.mark.parametrize("value", ["0", "1", "-0.1", "'ten'", "true", "1.5"])
def test_a_bad_smallest_effect_is_one_line_exit_2_and_nothing_tracked(tmp_path, capsys, value):
    from ablate.cli import main

    path = _write(tmp_path, f"smallest_effect = {value}\n[[variants]]\nname = 'a'\n")
    assert main(["run", str(path), "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert "smallest_effect" in err and "a fraction in (0, 1)" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "mlflow.db").exists()


def test_smallest_effect_defaults_to_a_tenth(tmp_path):
    assert load_experiment(_write(tmp_path, "[[variants]]\nname = 'a'\n")).smallest_effect == 0.1
    path = _write(tmp_path, "smallest_effect = 0.25\n[[variants]]\nname = 'a'\n")
    assert load_experiment(path).smallest_effect == 0.25


# --- [tune] (issue 19) ---

TUNED = """
name = "tuned"
seeds = 3
[base]
learning_rate = 0.03
[[variants]]
name = "baseline"
[[variants]]
name = "course"
learning_rate = 0.001
[tune]
learning_rate = [0.01, 0.1, 1]
seeds = 2
metric = "episodes_to_solve"
max_episodes = 200
"""


def test_tune_parses_to_a_tune_spec_and_a_variant_setting_the_knob_keeps_it(tmp_path):
    from ablate.config import TUNE_SEED_START

    experiment = load_experiment(_write(tmp_path, TUNED))
    spec = experiment.tune
    assert spec.knobs == (("learning_rate", (0.01, 0.1, 1.0)),)
    assert spec.seeds == (TUNE_SEED_START, TUNE_SEED_START + 1) == (10_000, 10_001)
    assert (spec.metric, spec.direction, spec.max_episodes) == ("episodes_to_solve", "min", 200)
    baseline, course = experiment.variants
    assert spec.tuned_knobs(baseline) == ("learning_rate",) and spec.tuned_knobs(course) == ()
    assert spec.candidates(baseline) == [{"learning_rate": v} for v in (0.01, 0.1, 1.0)]
    assert spec.candidates(course) == [{}]
    defaults = load_experiment(_write(tmp_path, "[[variants]]\nname='a'\n[tune]\nepisodes_per_update = [8, 16]\n"))
    assert (defaults.tune.seeds, defaults.tune.metric, defaults.tune.max_episodes) == (
        (10_000, 10_001, 10_002),
        "auc",
        None,
    )
    assert load_experiment(_write(tmp_path, "[[variants]]\nname='a'\n")).tune is None


_V = "[[variants]]\nname = 'a'\n"
BAD_TUNE = [
    (_V + "[tune]\nwidht = [1]\n", "tune.widht: unknown key; valid: learning_rate, episodes_per_update"),
    (_V + "[tune]\ndropout = [0.0, 0.2]\n", "tune.dropout: not tunable (architecture, regularisation"),
    (_V + "[tune]\nhidden_sizes = [[8], [16]]\n", "tune.hidden_sizes: not tunable"),
    (_V + "[tune]\nl2 = [0.0]\n", "tune.l2: not tunable"),
    (
        _V + "[grid]\nlearning_rate = [0.01, 0.1]\n[tune]\nlearning_rate = [0.01]\n",
        "tune.learning_rate: also a [grid] axis",
    ),
    (_V + "[tune]\nlearning_rate = []\n", "tune.learning_rate = [] is invalid; valid: a non-empty list"),
    (_V + "[tune]\nlearning_rate = 0.1\n", "tune.learning_rate = 0.1 is invalid; valid: a non-empty list"),
    (
        _V + "[tune]\nlearning_rate = [0.1, 2.0]\n",
        "tune.learning_rate: candidate 2.0 is invalid; valid: a number in (0, 1]",
    ),
    (_V + "[tune]\nlearning_rate = [0.1, 'x']\n", "tune.learning_rate: candidate 'x' is invalid"),
    (
        _V + "[tune]\nepisodes_per_update = [8, 0]\n",
        "tune.episodes_per_update: candidate 0 is invalid; valid: an integer",
    ),
    (_V + "[tune]\nlearning_rate = [0.1, 0.1]\n", "valid: distinct candidate values"),
    (_V + "[tune]\nseeds = 3\n", "tune: no knob to tune"),
    (_V + "[tune]\nlearning_rate = [0.1]\nseeds = 0\n", "tune.seeds = 0 is invalid; valid: a count of tuning seeds"),
    (
        _V + "[tune]\nlearning_rate = [0.1]\nmetric = 'iqm'\n",
        "tune.metric = 'iqm' is invalid; valid: one of episodes_to_solve, auc, final_return",
    ),
    (_V + "[tune]\nlearning_rate = [0.1]\nmax_episodes = 0\n", "tune.max_episodes = 0 is invalid"),
    ("seeds = [0, 10000]\n" + _V + "[tune]\nlearning_rate = [0.1]\n", "seeds: 10000 is invalid with [tune]"),
    (
        "seeds = 1000\n[grid]\nwidth = [1, 2, 3, 4, 5]\n[tune]\nlearning_rate = [0.1, 0.2]\n",
        "is more than 10,000 trials",
    ),
    ("tune = 3\n" + _V, "tune must be a table"),
]


@pytest.mark.parametrize(("text", "message"), BAD_TUNE)
def test_bad_tune_input_is_one_line_naming_file_and_key(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as error:
        load_experiment(path)
    assert str(path) in str(error.value)
    assert message in str(error.value)
    assert "\n" not in str(error.value)
