"""A user's own network described from the module itself: built from the source its run recorded (``model.py``)
and summarised as one line of layers for the variants table."""

from __future__ import annotations

import ast
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

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
    from ablate.agent.envs import describe
    from ablate.agent.models import ModelError, build_model, summary
    from ablate.config import DEFAULT, ModelConfig, config_from_document

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
