"""The knob schema: how one field of a trial's config is declared once, and every list the rest of the package
needs (keys, populations, env facts, flags, docs, columns) derived from those declarations. Standard library only.

A field's type and default are the dataclass field's own, its one-line doc is the docstring under it, and the rest
(its check, what is valid, whether it is in the trial key and since when, whether it separates populations, ...)
is the ``Knob`` in its ``metadata``. ``ablate.config`` declares the fields; nothing else lists them again.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import itertools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

KEY_VERSION = 4
"""The newest key generation: 1, the knobs keyed from the start; 2, a user's own network and env (issue 40);
3, ``layer_norm``; 4, ``env_profile``. A knob that joins the key in a later generation is in it only where set away
from its default, so every key an earlier version made (users' resume state) stays as it was."""


RESULTS_VERSION = 2
"""What the trainer computes, in every key from 2 on: 1, every trainer up to the numpy acting paths (each bit for
bit the one before); 2, the stacked members (issue 45), whose results equal 1's only to float rounding. A store's
trials of an earlier version are never counted as this code's: their keys differ."""


def _same(value: Any) -> Any:
    return value


@dataclass(frozen=True)
class Knob:
    """One field's declaration beyond its type and default. The first three say what a user may write; the rest
    what the field is to the key, the launch, the CLI and the report."""

    check: Callable[[Any], bool]
    valid: str
    """What is valid, in words, for the one-line error."""
    convert: Callable[[Any], Any] = _same
    """A checked TOML value to the field's type (lists to tuples, ints to floats where a float is meant)."""
    name: str = ""
    """The experiment file's key and the flag's name, where it is not the field's (``model`` sets ``factory``)."""
    key_since: int | None = 1
    """The key generation in which the field joined the trial key (``KEY_VERSION``); ``None``: never in the key
    (it changes what a trial records, not what it learns)."""
    population: bool = False
    """Trials that differ in it cannot share a population (one env, one network, one batch shape)."""
    env: bool = False
    """It changes the env a trial is built against (what ``envs.describe`` reads)."""
    built_in: bool = False
    """A knob of the built-in networks, which a user's own ``model`` does not read."""
    architecture: bool = False
    """With the other architecture knobs, it makes one architecture: a variant changing several changes one thing."""
    tunable: bool = False
    """``[tune]`` may search it: an optimisation knob, not what an ablation compares."""
    only_for: str = ""
    """The one built-in architecture that reads it (``cnn``): other networks' runs leave its param out."""
    profiles: tuple[str, ...] = ()
    """The env profiles (``env_spec.PROFILES``) that honour it; set away from its default under another, it is
    refused (``config.apply_knobs``). Empty: every profile."""
    setting: bool = False
    """A training setting every network reads: every trial's row in the tables and the report's table of base
    values carry it, whether or not a variant changes it."""
    user: bool = True
    """A user sets it (``False``: derived, such as the factory's hash)."""
    tracked: bool = True
    """A column of ``flatten``: an MLflow param and a table column (``False``: a factory file's text)."""
    test_only: bool = False
    """For the test suite: no flag, and the docs say so."""
    aliases: tuple[str, ...] = ()
    """Extra flags (``--env`` for ``--env-id``)."""
    words: str = ""
    """How the report's description of a built-in network names the knob where a trial sets it away from its
    default (``{}``: the value); "" where the description is built from it otherwise (the layers' sizes)."""
    # Filled in from the dataclass field (``fields_of``):
    column: str = ""
    """Its name in ``flatten``, MLflow's params and the tables: ``learning_rate``, ``model.hidden_sizes``."""
    owner: str = ""
    """``trial`` or ``model``: the dataclass that holds it."""
    attr: str = ""
    """The dataclass field's name."""
    type: str = ""
    """The field's annotation, as written."""
    default: Any = None

    @property
    def key_name(self) -> str:
        """The name an experiment file writes."""
        return self.name or self.attr

    @property
    def flag(self) -> str:
        return "--" + self.key_name.replace("_", "-")

    def in_key(self, value: Any) -> bool:
        """Whether ``value`` of this field is part of the trial key."""
        if self.key_since is None:
            return False
        return self.key_since == 1 or value != self.default


def knob(default: Any, *, repr: bool = True, **declared: Any) -> Any:  # noqa: A002 - dataclasses.field's name
    """A dataclass field declared with its ``Knob`` (``check``, ``valid``, ... as keywords)."""
    return field(default=default, repr=repr, metadata={"knob": Knob(**declared)})


def derived(default: Any, **declared: Any) -> Any:
    """A field no user writes (a factory's hash or text), with what it is to the key and the launch."""
    return knob(default, check=lambda _: False, valid="derived", user=False, **declared)


def fields_of(root: type, prefix: str = "", owner: str = "trial") -> dict[str, Knob]:
    """Every declared field under ``root`` (nested config dataclasses by their ``name.`` prefix), by column, in
    declaration order."""
    found: dict[str, Knob] = {}
    defaults = root()
    for f in dataclasses.fields(root):
        value = getattr(defaults, f.name)
        if dataclasses.is_dataclass(value):
            found |= fields_of(type(value), f"{prefix}{f.name}.", f.name)
            continue
        declared = f.metadata.get("knob")
        if declared is None:
            raise TypeError(f"{root.__name__}.{f.name}: declare it with schema.knob or schema.derived")
        column = prefix + f.name
        found[column] = dataclasses.replace(
            declared, column=column, owner=owner, attr=f.name, type=str(f.type), default=value
        )
    return found


def flatten(config: Any, schema: Mapping[str, Knob]) -> dict[str, Any]:
    """Every tracked field of ``config`` as ``{column: value}``."""
    return {column: value_of(config, column) for column, k in schema.items() if k.tracked}


def value_of(config: Any, column: str) -> Any:
    for part in column.split("."):
        config = getattr(config, part)
    return config


def field_docs(module: Any, classes: tuple[type, ...], code_mark: str = "") -> dict[str, str]:
    """The docstring under each field of ``classes`` (defined in ``module``), one line each, by field name; the
    docstrings' ````code```` marks become ``code_mark`` (```` ` ```` for Markdown)."""
    names = {cls.__name__ for cls in classes}
    docs: dict[str, str] = {}
    for node in ast.parse(inspect.getsource(module)).body:
        if not (isinstance(node, ast.ClassDef) and node.name in names):
            continue
        for field_node, doc in itertools.pairwise(node.body):
            if (
                isinstance(field_node, ast.AnnAssign)
                and isinstance(field_node.target, ast.Name)
                and isinstance(doc, ast.Expr)
                and isinstance(doc.value, ast.Constant)
                and isinstance(doc.value.value, str)
            ):
                docs[field_node.target.id] = " ".join(doc.value.value.replace("``", code_mark).split())
    return docs


# Checks that many knobs share, each returning (check, valid) for ``knob(...)``.


def is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v: Any) -> bool:
    return (isinstance(v, int | float)) and not isinstance(v, bool)


def integer(low: int, high: int, note: str = "") -> dict[str, Any]:
    """An integer in [low, high]."""
    return {"check": lambda v: is_int(v) and low <= v <= high, "valid": f"an integer in [{low}, {high}]{note}"}


def number(low: float, high: float, open_low: bool = False, open_high: bool = False) -> dict[str, Any]:
    """A number between low and high, either end open; converted to float."""
    return {
        "check": lambda v: (
            is_number(v) and (low < v if open_low else low <= v) and (v < high if open_high else v <= high)
        ),
        "valid": f"a number in {'(' if open_low else '['}{low}, {high}{')' if open_high else ']'}",
        "convert": float,
    }


def one_of(options: tuple[str, ...], valid: str = "") -> dict[str, Any]:
    return {"check": lambda v: v in options, "valid": valid or f"one of {', '.join(options)}"}


def boolean() -> dict[str, Any]:
    return {"check": lambda v: isinstance(v, bool), "valid": "true or false"}
