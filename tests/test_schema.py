"""The knob schema: a field is declared once, and the lists the package reads are derived from the declarations."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from ablate import config, schema
from ablate.config import DEFAULT, SCHEMA, TrialConfig, apply_knobs, population_group
from ablate.launch.grid import config_hash


@dataclass(frozen=True)
class _Inner:
    width: int = schema.knob(4, **schema.integer(1, 8), population=True)
    """Units."""


@dataclass(frozen=True)
class _Outer:
    rate: float = schema.knob(0.1, **schema.number(0, 1, open_low=True), tunable=True)
    """A rate."""
    inner: _Inner = field(default_factory=_Inner)
    late: bool = schema.knob(False, **schema.boolean(), key_since=2)
    """Added later."""
    note: str = schema.knob("", check=lambda v: isinstance(v, str), valid="text", key_since=None)


def test_fields_are_read_off_the_dataclass_with_their_declarations():
    found = schema.fields_of(_Outer)
    assert list(found) == ["rate", "inner.width", "late", "note"]
    width = found["inner.width"]
    assert (width.owner, width.attr, width.type, width.default, width.population) == ("inner", "width", "int", 4, True)
    assert found["rate"].valid == "a number in (0, 1]" and found["rate"].convert(1) == 1.0
    assert not found["rate"].check(0) and found["rate"].check(1)
    assert schema.field_docs(__import__(__name__), (_Outer, _Inner)) == {
        "rate": "A rate.",
        "width": "Units.",
        "late": "Added later.",
    }


def test_a_field_without_a_declaration_is_refused():
    @dataclass(frozen=True)
    class Bare:
        size: int = 3

    with pytest.raises(TypeError, match="Bare.size: declare it"):
        schema.fields_of(Bare)


def test_a_knob_joins_the_key_by_its_generation():
    found = schema.fields_of(_Outer)
    assert found["rate"].in_key(0.1) and found["rate"].in_key(0.2)  # generation 1: always
    assert not found["late"].in_key(False) and found["late"].in_key(True)  # later: only where set
    assert not found["note"].in_key("x")  # never


def test_the_package_lists_are_the_declarations():
    assert config.TUNABLE_KNOBS == ("learning_rate", "episodes_per_update")
    assert set(config.ENV_COLUMNS) <= set(config.POPULATION_COLUMNS)
    assert all(c in config.POPULATION_COLUMNS for c in SCHEMA if c.startswith("model."))
    assert "learning_rate" not in config.POPULATION_COLUMNS and "seed" not in config.POPULATION_COLUMNS
    assert {"hidden_sizes", "depth", "width", "architecture"} <= config.ARCHITECTURE_KNOBS
    assert "dropout" not in config.ARCHITECTURE_KNOBS and "model" not in config.BUILT_IN_MODEL_KNOBS
    assert "model.factory_source" not in config.flatten(DEFAULT)
    assert config.KNOBS["model"].column == "model.factory" and "factory_hash" not in config.KNOBS


def test_keys_and_populations_follow_the_declarations():
    wider = apply_knobs(DEFAULT, {"learning_rate": 0.1})
    assert population_group(wider) == population_group(DEFAULT)  # a per-member knob
    assert population_group(apply_knobs(DEFAULT, {"num_envs": 4})) != population_group(DEFAULT)
    assert config_hash(apply_knobs(DEFAULT, {"record_video": False})) == config_hash(DEFAULT)  # never keyed
    assert config_hash(wider) != config_hash(DEFAULT)


def test_every_config_field_is_declared():
    for cls in (TrialConfig, config.ModelConfig):
        schema.fields_of(cls)  # raises on a field without a Knob


def test_a_knob_of_one_built_in_network_is_tracked_only_where_that_network_runs():
    from dataclasses import replace

    from ablate.launch.records import tracked_params

    cnn_only = [column for column, knob in SCHEMA.items() if knob.only_for == "cnn"]
    assert "model.kernel_size" in cnn_only and "model.hidden_sizes" not in cnn_only
    mlp = tracked_params("v", config.DEFAULT)
    cnn = tracked_params("v", replace(config.DEFAULT, model=replace(config.DEFAULT.model, architecture="cnn")))
    assert not set(cnn_only) & set(mlp) and set(cnn_only) <= set(cnn)


def test_no_module_keeps_its_own_list_of_knob_names():
    """A tuple, list or set literal naming two or more knobs is a list kept by hand beside the schema: it drifts
    when a knob is added. Each such list is derived from the declarations instead (``config.SETTING_KNOBS``, ...)."""
    import ast
    from pathlib import Path

    names = set(config.KNOBS) | set(SCHEMA) | {knob.attr for knob in SCHEMA.values()}
    found = []
    for path in sorted((Path(config.__file__).parent).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Tuple | ast.List | ast.Set):
                named = [e.value for e in node.elts if isinstance(e, ast.Constant) and e.value in names]
                if len(named) >= 2:
                    found.append(f"{path.name}:{node.lineno} {named}")
    assert not found, found
