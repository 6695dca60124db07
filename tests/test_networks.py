"""A user's network in the report is described from the module its run recorded: its layers, its model_args."""

from __future__ import annotations

import hashlib
from pathlib import Path

from ablate.reporting.networks import factory_args, layers
from ablate.reporting.sections import architecture

SOURCE = (Path(__file__).parent.parent / "examples" / "models" / "layernorm.py").read_text()


class _Store:
    """A run's recorded artifacts, as ``RunReader.load_text`` reads them."""

    def __init__(self, files: dict[str, str]) -> None:
        self.files = files

    def load_text(self, run_id: str, name: str) -> str:
        return self.files[name]


def _params(width: int, env_id: str = "CartPole-v1") -> dict[str, str]:
    return {
        "env_id": env_id,
        "model.factory": "../examples/models/layernorm.py:create_model",
        "model.factory_args": f'[["width", {width}]]',
        "model.factory_hash": hashlib.sha1(SOURCE.encode()).hexdigest()[:12],
    }


def test_a_users_network_is_summarised_from_its_recorded_source_with_its_args_and_env():
    store = _Store({"model.py": SOURCE})
    assert layers(store, "run", _params(16)) == "Flatten Linear(4→16) LayerNorm ReLU Linear(16→2)"
    assert layers(store, "run", _params(8, "Acrobot-v1")) == "Flatten Linear(6→8) LayerNorm ReLU Linear(8→3)"
    text = architecture({**_params(16), "model.layers": layers(store, "run", _params(16))}, "CartPole-v1")
    assert text.endswith(": Flatten Linear(4→16) LayerNorm ReLU Linear(16→2), width=16")


def test_no_recorded_source_or_a_source_that_is_not_the_tracked_one_leaves_the_factory_alone():
    assert layers(_Store({}), "run", _params(16)) is None  # an older run: no model.py among its artifacts
    assert layers(_Store({"model.py": SOURCE + "\n# edited\n"}), "run", _params(16)) is None  # not its hash
    assert layers(_Store({"model.py": SOURCE}), "run", {"env_id": "CartPole-v1"}) is None  # a built-in network
    assert factory_args('[["width", 32], ["depth", 2]]') == (("width", 32), ("depth", 2))
    assert factory_args("()") == ()
