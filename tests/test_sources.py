"""A trial's own code: a factory's (or env module's) local imports are found, keyed and shipped; an unchanged
file without helpers keeps its hash; a node without the experiment's folder builds the same network."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ablate import sources
from ablate.config import ConfigError, config_from_document, flatten
from ablate.experiment import load_experiment
from ablate.launch.grid import expand

ROOT = Path(__file__).resolve().parents[1]

NET2 = """from torch import nn

from helpers import body


def create_model(observation_shape, n_actions):
    return nn.Sequential(nn.Flatten(), body(observation_shape[0]), nn.Linear(8, n_actions))
"""
HELPERS = """import math

from torch import nn


def body(inputs):
    return nn.Sequential(nn.Linear(inputs, 8), nn.Tanh())
"""
PLAIN = """from torch import nn


def create_model(n_actions):
    return nn.Sequential(nn.Flatten(), nn.Linear(4, n_actions))
"""
EXPERIMENT = """name = "helpers"
seeds = 2
[base]
env_id = "CartPole-v1"
max_episodes = 4
episodes_per_update = 2
[[variants]]
name = "net2"
model = "net2.py:create_model"
[[variants]]
name = "plain"
model = "plain.py:create_model"
"""


@pytest.fixture
def folder(tmp_path):
    experiment = tmp_path / "experiment"
    experiment.mkdir()
    (experiment / "net2.py").write_text(NET2)
    (experiment / "helpers.py").write_text(HELPERS)
    (experiment / "plain.py").write_text(PLAIN)
    (experiment / "helpers.toml").write_text(EXPERIMENT)
    return experiment


def _keys(path: Path) -> dict[str, set[str]]:
    keys: dict[str, set[str]] = {}
    for trial in expand(load_experiment(path)):
        keys.setdefault(trial.variant, set()).add(trial.key)
    return keys


def test_a_factory_file_without_local_imports_keeps_the_sha1_of_its_text(folder):
    # printf 'from torch import nn\n\n\ndef create_model(n_actions):\n ...' | sha1sum, by hand: the key of before
    assert hashlib.sha1(PLAIN.encode()).hexdigest()[:12] == "7730fbd2b522"
    config = next(v.config for v in load_experiment(folder / "helpers.toml").variants if v.name == "plain")
    assert config.model.factory_hash == "7730fbd2b522"
    assert config.model.factory_source == (("plain.py", PLAIN),)


def test_the_experiments_factories_keep_their_hashes():
    """experiments/your-model.toml's files import only torch: their hashes are their texts' as before."""
    for variant in load_experiment(ROOT / "experiments" / "your-model.toml").variants:
        model = variant.config.model
        if model.factory:
            text = (ROOT / "experiments" / model.factory.rsplit(":", 1)[0]).resolve().read_text()
            assert model.factory_hash == hashlib.sha1(text.encode()).hexdigest()[:12]


def test_a_helper_beside_the_factory_ships_and_keys_it(folder):
    config = next(v.config for v in load_experiment(folder / "helpers.toml").variants if v.name == "net2")
    assert config.model.factory_source == (("net2.py", NET2), ("helpers.py", HELPERS))  # not math, not torch
    assert config.model.factory_hash == sources.bundle_hash(config.model.factory_source)
    assert config.model.factory_hash != hashlib.sha1(NET2.encode()).hexdigest()[:12]


def test_editing_only_the_helper_reruns_its_variant_and_no_other(folder):
    before = _keys(folder / "helpers.toml")
    (folder / "helpers.py").write_text(HELPERS.replace("nn.Tanh()", "nn.ReLU()"))
    after = _keys(folder / "helpers.toml")
    assert before["plain"] == after["plain"]
    assert not before["net2"] & after["net2"] and len(after["net2"]) == 2


def test_a_model_with_a_helper_trains_through_train_from(folder, tmp_path):
    """The user's report: "net2.py raised ModuleNotFoundError: No module named 'helpers'"."""
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "ablate.cli", "train", "--from", str(folder / "helpers.toml"), "--variant", "net2"]
        + ["--seed", "1", "--out", str(out), "--no-video"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=os.environ | {"PYTHONPATH": str(ROOT)},
    )
    assert proc.returncode == 0, proc.stderr
    assert len((out / "episodes.csv").read_text().splitlines()) == 1 + 4


NODE = """
import json, sys
from ablate.envs import describe
from ablate.agent.policies import build_model
from ablate.reporting.networks import summary
from ablate.config import config_from_document
config = config_from_document(json.load(open(sys.argv[1])))
print(summary(build_model(config, describe(config))))
print(sys.modules["helpers"].__file__)
"""


def test_a_node_without_the_experiments_folder_builds_the_network_from_what_ships(folder, tmp_path):
    config = next(v.config for v in load_experiment(folder / "helpers.toml").variants if v.name == "net2")
    node = tmp_path / "node"
    node.mkdir()
    (node / "config.json").write_text(json.dumps(dataclasses.asdict(config)))
    shutil.rmtree(folder)  # the driver's files are gone: only the document travels
    proc = subprocess.run(
        [sys.executable, "-c", NODE, "config.json"],
        capture_output=True,
        text=True,
        cwd=node,
        env=os.environ | {"PYTHONPATH": str(ROOT)},
    )
    assert proc.returncode == 0, proc.stderr
    layers, helper = proc.stdout.splitlines()
    assert layers == "Flatten Linear(4→8) Tanh Linear(8→2)"
    assert "ablate-code-" in helper and helper.endswith("helpers.py")


def test_shipped_files_that_do_not_match_the_hash_are_refused(folder):
    from ablate.agent.policies import ModelError, load_factory

    config = next(v.config for v in load_experiment(folder / "helpers.toml").variants if v.name == "net2")
    document = json.loads(json.dumps(dataclasses.asdict(config)))  # as config.json holds it
    document["model"]["factory_source"][1][1] += "\n# edited on the node\n"
    with pytest.raises(ModelError, match="its shipped files do not match the trial's hash"):
        load_factory(config_from_document(document).model)


def test_an_older_document_with_the_factorys_text_alone_still_reads(folder):
    config = next(v.config for v in load_experiment(folder / "helpers.toml").variants if v.name == "plain")
    document = dataclasses.asdict(config)
    document["model"]["factory_source"] = PLAIN  # as config.json held it before helpers shipped
    assert config_from_document(document) == config
    document["model"] |= {"factory": "", "factory_source": "", "factory_hash": ""}  # a built-in network's
    assert config_from_document(document).model.factory_source == ()


def test_a_package_in_the_experiments_folder_ships_with_its_relative_imports(tmp_path):
    package = tmp_path / "nets"
    (package / "parts").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "parts" / "__init__.py").write_text("")
    (package / "parts" / "layers.py").write_text("from torch import nn\nWIDTH = 8\n")
    (package / "common.py").write_text("import os\nSCALE = 1\n")
    (package / "mlp.py").write_text(
        "from . import common\nfrom .parts.layers import WIDTH\nfrom .. import nothing_above\n"
        "def create_model(n_actions):\n    import torch\n    return torch.nn.Linear(4 * common.SCALE, n_actions)\n"
    )
    bundle, digest = sources.resolve_model("nets.mlp", tmp_path)
    assert [path for path, _ in bundle] == [
        "nets/mlp.py",
        "nets/__init__.py",
        "nets/common.py",
        "nets/parts/__init__.py",
        "nets/parts/layers.py",
    ]
    assert digest == sources.bundle_hash(bundle) != sources.bundle_hash(bundle[:1])
    alone = "def create_model(n_actions):\n    import torch\n    return torch.nn.Linear(4, n_actions)\n"
    (package / "mlp.py").write_text(alone)  # imports nothing local: its package's bare __init__.py does not count
    bundle, digest = sources.resolve_model("nets.mlp", tmp_path)
    assert [path for path, _ in bundle] == ["nets/mlp.py", "nets/__init__.py"]
    assert digest == hashlib.sha1(alone.encode()).hexdigest()[:12]  # the hash this module had before


def test_imports_of_the_standard_library_and_installed_packages_are_not_local(tmp_path):
    (tmp_path / "json.py").write_text("")  # a local file named like a standard module is not what imports
    assert sources.local_path(tmp_path, "json") is None
    assert sources.local_path(tmp_path, "torch") is None
    assert sources.imported_names("import a.b.c\nfrom d import e\nfrom g import *\nfrom . import f\n", "") == {
        "a",
        "a.b",
        "a.b.c",
        "d",
        "d.e",
        "g",
    }


def test_an_installed_package_is_recorded_by_its_version_not_keyed():
    import gymnasium

    from ablate.config import DEFAULT, TrialConfig, apply_knobs
    from ablate.launch.grid import config_hash
    from ablate.launch.records import tracked_params

    config = apply_knobs(DEFAULT, {"env_module": "gymnasium.envs.classic_control"})
    assert config.env_module_hash == "" and config.env_module_source == ()
    params = tracked_params("v", config)
    assert params["env_module.package_version"] == f"gymnasium=={gymnasium.__version__}"
    assert "env_module_source" not in params
    assert config_hash(config) == config_hash(TrialConfig(env_module="gymnasium.envs.classic_control"))
    import torch

    installed = apply_knobs(DEFAULT, {"model": "torch.nn:Linear"})
    assert installed.model.factory_source == () and "model.package_version" not in flatten(installed)
    assert tracked_params("v", installed)["model.package_version"] == f"torch=={torch.__version__}"
    assert "model.package_version" not in tracked_params("v", DEFAULT)  # a built-in network: no package


REGISTER = """import gymnasium as gym

CALLS = []


def register(env_id="Mine-v0"):
    CALLS.append(env_id)
    gym.register(env_id, entry_point="gymnasium.envs.classic_control.cartpole:CartPoleEnv", max_episode_steps=50)


def nothing():
    pass
"""


def _env_experiment(folder: Path, env_module: str, env_id: str = "Mine-v0") -> Path:
    (folder / "myenvs").mkdir(exist_ok=True)
    (folder / "myenvs" / "__init__.py").write_text("")
    (folder / "myenvs" / "reg.py").write_text(REGISTER)
    path = folder / "env.toml"
    path.write_text(
        f'name = "env"\nseeds = 1\n[base]\nenv_id = "{env_id}"\nenv_module = "{env_module}"\n'
        "max_episodes = 2\nsolve_threshold = 40\n[[variants]]\nname = 'a'\n"
    )
    return path


def test_env_module_naming_a_function_calls_it_and_a_local_one_ships_and_is_keyed(tmp_path):
    from ablate.checks import check_experiment
    from ablate.envs import describe

    experiment = load_experiment(_env_experiment(tmp_path, "myenvs.reg:register"))
    config = experiment.variants[0].config
    assert [p for p, _ in config.env_module_source] == ["myenvs/reg.py", "myenvs/__init__.py"]
    assert config.env_module_hash == sources.bundle_hash(config.env_module_source)
    check_experiment(experiment)  # the pre-flight: imported, register() called, Mine-v0 known
    assert sys.modules["myenvs.reg"].CALLS == ["Mine-v0"]
    assert describe(config).max_episode_steps == 50
    before = {t.key for t in expand(experiment)}
    (tmp_path / "myenvs" / "reg.py").write_text(REGISTER.replace("max_episode_steps=50", "max_episode_steps=60"))
    assert not before & {t.key for t in expand(load_experiment(tmp_path / "env.toml"))}  # an edited env reruns


@pytest.mark.parametrize(
    ("env_module", "words"),
    [
        ("myenvs.reg:nothing", "env_module = 'myenvs.reg:nothing' ran, but env_id = 'Mine2-v0' is still not a "),
        ("myenvs.reg:absent", "env_module = 'myenvs.reg:absent': myenvs.reg has no function absent"),
        ("myenvs.nope", "env_module = 'myenvs.nope': cannot import it (ModuleNotFoundError: "),
    ],
)
def test_an_env_module_that_does_not_make_the_env_is_one_line_exit_2(tmp_path, capsys, env_module, words):
    from ablate.cli import main

    path = _env_experiment(tmp_path, env_module, "Mine2-v0")
    assert main(["run", str(path), "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "mlflow.db").exists()


def test_a_bad_env_module_spec_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="or 'module:function' to call"):
        load_experiment(_env_experiment(tmp_path, "myenvs.reg:"))


MINATAR = """name = "minatar"
seeds = 1
[base]
env_id = "MinAtar/Breakout-v1"
env_module = "{env_module}"
max_episodes = 2
[[variants]]
name = "{architecture}"
architecture = "{architecture}"
"""


@pytest.mark.parametrize(
    ("env_module", "architecture", "words"),
    [
        ("minatar", "mlp", "env_module = 'minatar' ran, but env_id = 'MinAtar/Breakout-v1' is still not a registered"),
        ("minatar.gym:register_envs", "cnn", "observation (10, 10, 4) looks channels-last; valid: "),
    ],
)
def test_minatar_registers_its_envs_only_in_its_function_and_its_image_is_channels_last(
    tmp_path, capsys, env_module, architecture, words
):
    from ablate.cli import main

    pytest.importorskip("minatar")
    path = tmp_path / "minatar.toml"
    path.write_text(MINATAR.format(env_module=env_module, architecture=architecture))
    assert main(["run", str(path), "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err


def test_minatar_through_its_register_function_builds_an_mlp(tmp_path):
    from ablate.checks import check_experiment

    pytest.importorskip("minatar")
    path = tmp_path / "minatar.toml"
    path.write_text(MINATAR.format(env_module="minatar.gym:register_envs", architecture="mlp"))
    check_experiment(load_experiment(path))


LOCAL_ENV = """import gymnasium as gym

gym.register("Beside-v0", entry_point="gymnasium.envs.classic_control.cartpole:CartPoleEnv", max_episode_steps=30)
"""
NODE_ENV = """
import json, sys
from ablate.envs import describe
from ablate.config import config_from_document
print(describe(config_from_document(json.load(open(sys.argv[1])))).max_episode_steps)
"""


def test_a_local_env_module_beside_the_experiment_ships_to_a_node_without_it(tmp_path):
    experiment = tmp_path / "experiment"
    experiment.mkdir()
    (experiment / "besideenvs.py").write_text(LOCAL_ENV)
    (experiment / "env.toml").write_text(
        'name = "env"\nseeds = 1\n[base]\nenv_id = "Beside-v0"\nenv_module = "besideenvs"\n'
        "max_episodes = 2\nsolve_threshold = 20\n[[variants]]\nname = 'a'\n"
    )
    config = load_experiment(experiment / "env.toml").variants[0].config
    assert config.env_module_source == (("besideenvs.py", LOCAL_ENV),)
    assert config.env_module_hash == hashlib.sha1(LOCAL_ENV.encode()).hexdigest()[:12]
    (tmp_path / "config.json").write_text(json.dumps(dataclasses.asdict(config)))
    shutil.rmtree(experiment)
    proc = subprocess.run(
        [sys.executable, "-c", NODE_ENV, "config.json"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=os.environ | {"PYTHONPATH": str(ROOT)},
    )
    assert proc.returncode == 0 and proc.stdout.strip() == "30", proc.stderr


def test_on_a_node_whose_env_module_differs_the_trial_fails_before_training_with_the_pre_flights_line():
    from dataclasses import replace

    from ablate.agent.trainer import run_trial
    from ablate.config import DEFAULT
    from ablate.envs import EnvError

    config = replace(DEFAULT, env_module="no_such_env_package.envs:register", max_episodes=2, record_video=False)
    with pytest.raises(EnvError) as error:
        run_trial(config)
    assert str(error.value).startswith("env_module = 'no_such_env_package.envs:register': cannot import it (")
    assert "\n" not in str(error.value)


@pytest.mark.parametrize(
    ("text", "factory", "words"),
    [
        ("from torch import nn\n", "net.py:create", "model = 'net.py:create': net.py has no function create"),
        ("raise RuntimeError('half written')\n", "net.py:create", "net.py raised RuntimeError: half written"),
    ],
)
def test_a_model_file_that_gives_no_factory_is_one_line_exit_2(tmp_path, capsys, text, factory, words):
    """``sources.load_function``'s errors, as a user meets them: one line naming the model, exit 2, nothing tracked."""
    from ablate.cli import main

    (tmp_path / "net.py").write_text(text)
    path = tmp_path / "net.toml"
    path.write_text(
        f'name = "net"\nseeds = 1\n[base]\nmodel = "{factory}"\nmax_episodes = 2\n[[variants]]\nname = "a"\n'
    )
    assert main(["run", str(path), "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "mlflow.db").exists()
