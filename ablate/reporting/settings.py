"""What a variant runs at, knob by knob, read off the launch's ``grid.json``: its own value where it sets the
knob, else the base's; a knob counts as changed only when those values differ (``activation = "relu"`` written
in a file whose default is ``relu`` changes nothing)."""

from __future__ import annotations

from typing import Any

DERIVED = {"depth": lambda sizes: len(sizes), "width": lambda sizes: sizes[0] if sizes else None}
"""Shorthands a trial's config holds only as ``model.hidden_sizes``."""


def overrides(grid: dict[str, Any], variant: str) -> dict[str, Any]:
    """The knobs ``variant`` writes in the experiment file, as written."""
    return next((dict(v.get("overrides", {})) for v in grid["variants"] if v["name"] == variant), {})


def base_value(grid: dict[str, Any], knob: str) -> Any:
    """The base's value of ``knob`` (model knobs under their ``model.`` prefix); None where the grid lacks it."""
    base = grid.get("base", {})
    for key in (knob, f"model.{knob}"):
        if key in base:
            return base[key]
    sizes = base.get("model.hidden_sizes")
    return DERIVED[knob](list(sizes)) if knob in DERIVED and sizes is not None else None


def setting(grid: dict[str, Any], variant: str, knob: str) -> Any:
    """The value ``variant`` runs ``knob`` at: its own, else the base's."""
    own = overrides(grid, variant)
    if knob in own:
        return own[knob]
    if knob == "hidden_sizes" and ("depth" in own or "width" in own):  # config.apply_knobs' expansion
        sizes = base_value(grid, "hidden_sizes") or []
        return [own.get("width", sizes[0] if sizes else 32)] * own.get("depth", len(sizes))
    if knob in DERIVED:
        sizes = setting(grid, variant, "hidden_sizes")
        return DERIVED[knob](sizes) if isinstance(sizes, list) else None
    return base_value(grid, knob)


PART_OF = {"model_args": "model"}
"""Knobs that are part of another: a user's network and the arguments of its factory are one change."""


def changes(grid: dict[str, Any], variant: str, against: str) -> dict[str, Any]:
    """The knobs ``variant`` runs at another value than ``against`` does, with ``variant``'s values, in knob
    order. Only knobs one of them writes can differ: the others are the base's for both. A knob ``PART_OF``
    another that changes too is not a change of its own."""
    written = set(overrides(grid, variant)) | set(overrides(grid, against))
    changed = {
        knob: setting(grid, variant, knob)
        for knob in sorted(written)
        if setting(grid, variant, knob) != setting(grid, against, knob)
    }
    return {knob: value for knob, value in changed.items() if PART_OF.get(knob) not in changed}


def references(grid: dict[str, Any]) -> dict[str, str]:
    """Each variant -> the variant it is compared with: of the others, the one whose changes from the baseline are the
    largest part of its own (``mlp-dropout`` against ``mlp`` when ``mlp`` changes only the architecture), so that each
    comparison isolates what the variant adds; else the baseline. Between two as large, the one of the variant's own
    architecture family (``mlp-l2``: ``mlp``, not ``cnn-l2``), then the first in the experiment file."""
    baseline = grid["baseline"]
    changed = {v["name"]: list(changes(grid, v["name"], baseline).items()) for v in grid["variants"]}
    found = {}
    for variant, mine in changed.items():
        best, rank = baseline, (0, False)
        for other, theirs in changed.items():
            if other == variant or not len(theirs) < len(mine) or any(item not in mine for item in theirs):
                continue
            same_architecture = "architecture" not in changes(grid, variant, other)
            if (len(theirs), same_architecture) > rank:
                best, rank = other, (len(theirs), same_architecture)
        found[variant] = best
    return found


def own_changes(grid: dict[str, Any], variant: str) -> dict[str, Any]:
    """The knobs ``variant`` writes at a value other than the base's, as written (the variants table's
    "changes" column): a knob written at the base's own value is no change."""
    return {k: v for k, v in overrides(grid, variant).items() if base_value(grid, k) != v}
