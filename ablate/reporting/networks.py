"""A trial's network in words for the variants table: a built-in one from its knobs and recorded observation shape, a
user's own from the module itself (built from the source its run recorded, ``model.py``), as one line of layers."""

from __future__ import annotations

import ast
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

from ablate.config import SCHEMA
from ablate.env_spec import profile_named
from ablate.reporting.reader import RunReader


def factory_args(text: str) -> tuple[tuple[str, Any], ...]:
    """A tracked ``model_args`` (pairs, as MLflow holds them) as pairs again; none where it cannot be read."""
    for parse in (json.loads, ast.literal_eval):
        try:
            return tuple((str(k), v) for k, v in parse(text))
        except (ValueError, SyntaxError, TypeError):
            continue
    return ()


def layers(tracker: RunReader, run_id: str, params: dict[str, str]) -> str | None:
    """The run's network as ``Linear(4→32) LayerNorm ReLU Linear(32→2)``, built as its trial built it (the
    recorded source, its ``model_args``, its env's shapes); None where the run recorded no source or the
    network cannot be built here."""
    from ablate.agent.policies import ModelError, build_model
    from ablate.config import DEFAULT, ModelConfig, config_from_document
    from ablate.envs import describe

    factory = params.get("model.factory", "")
    if not factory:
        return None
    target = factory.rsplit(":", 1)[0]
    try:  # the run's config.json ships the factory with its helpers; an older run left only model.py
        bundle = config_from_document(json.loads(tracker.load_text(run_id, "config.json"))).model.factory_source
    except Exception:  # noqa: BLE001 - no such artifact, or not one this version reads
        bundle = ()
    if not bundle and target.endswith(".py"):
        try:
            bundle = ((Path(target).name, tracker.load_text(run_id, "model.py")),)
        except Exception:  # noqa: BLE001 - no such artifact (an older run): described by its factory only
            return None
    model = ModelConfig(
        factory=factory,
        factory_hash=params.get("model.factory_hash", ""),
        factory_source=bundle,
        factory_args=factory_args(params.get("model.factory_args", "")),
    )
    config = replace(DEFAULT, env_id=params.get("env_id", DEFAULT.env_id), model=model)
    try:
        return summary(build_model(config, describe(config)))
    except (ModelError, ValueError, LookupError, ImportError):
        return None


def _sizes(params: dict[str, str], key: str = "model.hidden_sizes") -> list[int]:
    text = params.get(key, "[]").strip("[]() ")
    return [int(x) for x in text.replace(",", " ").split()]


def architecture(params: dict[str, str], env_id: str) -> str:
    """The policy in words, as ``policies.py`` builds it for ``env_id``; a user's own network by its factory and,
    where its run recorded the source, its layers (``networks.layers``)."""
    factory = params.get("model.factory", "")
    if factory:
        target, function = factory.rsplit(":", 1)
        text = f"the user's own network: {function} of {target.rsplit('/', 1)[-1]}"
        text += f" (source {params.get('model.factory_hash', '?')})"
        text += f": {params['model.layers']}" if params.get("model.layers") else ""
        text_args = params.get("model.factory_args", "")  # as ``width=32, depth=2``
        args = ", ".join(f"{k}={v}" for k, v in factory_args(text_args)) or text_args.strip("()[]")
        text += f", {args}" if args else ""
        return text + (f"; L2 {params['l2']}" if float(params.get("l2", 0) or 0) > 0 else "")
    arch = params.get("model.architecture", "mlp")
    activation = params.get("model.activation", "relu")
    hidden = _sizes(params)
    dense = f"dense {' → '.join(map(str, hidden))} ({activation})" if hidden else "no hidden layer"
    profile = profile_named(env_id, params.get("env_profile", ""))
    recorded = params.get("env.obs_shape", "")
    shape = tuple(int(n) for n in recorded.split("x")) if recorded else profile.observation_shape
    if len(shape) == 3:  # an image, as the trial recorded its observation (Pong's frame difference, another game's)
        channels, height, width = shape
        pixels = f"{height}×{width}" + ("" if channels == 1 else f"×{channels}") + f" {profile.observation}"
        if arch == "cnn":
            from ablate.agent.policies import PONG_CONV

            convs = ", ".join(f"{n}@{k}×{k} stride {s}" for n, k, s, _ in PONG_CONV)
            text = f"2-D CNN over the {pixels}: conv {convs} ({activation}), then {dense}"
        elif hidden:
            text = f"MLP over the {channels * height * width:,} pixels of the {pixels}: {dense}"
        else:
            text = f"linear policy over the {channels * height * width:,} pixels of the {pixels} (no hidden layer)"
        names = params.get("env.actions", "")
        text += f"; {params['env.n_actions']} actions" if params.get("env.n_actions") else ""
        text += f" ({names})" if names else ""
    elif arch == "cnn":
        conv = _sizes(params, "model.conv_channels")
        text = (
            f"1-D CNN over the last {params.get('model.history')} observations: conv "
            f"{', '.join(map(str, conv))} channels, kernel {params.get('model.kernel_size')} along time "
            f"({activation}), then {dense}"
        )
    else:
        text = f"MLP, {dense}" if hidden else "linear policy: observation → action logits, no hidden layer"
    for knob in SCHEMA.values():  # the built-in knobs the layers above do not show, as the schema names them
        value = params.get(knob.column)
        if knob.built_in and knob.words and value is not None and value != str(knob.default):
            text += "; " + knob.words.format(value)
    if float(params.get("l2", 0) or 0) > 0:
        text += f"; L2 {params['l2']}"
    return text


def summary(network) -> str:
    """One line: the network's layers by type, e.g. ``Linear(4→64) LayerNorm ReLU Linear(64→2)``."""
    from torch import nn

    parts = []
    for module in network.modules():
        if list(module.children()):
            continue
        if isinstance(module, nn.Linear):
            parts.append(f"Linear({module.in_features}→{module.out_features})")
        elif isinstance(module, nn.Conv1d | nn.Conv2d):
            parts.append(
                f"{type(module).__name__}({module.in_channels}→{module.out_channels}, k{module.kernel_size[0]})"
            )
        else:
            parts.append(type(module).__name__)
    return " ".join(parts)
