"""Expand an experiment into trials (variants x seeds), each with a stable key.

The key is a hash of everything that changes a trial's result, so a re-run recognises finished trials.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, replace

from ablate.config import Experiment, TrialConfig, flatten

# Knobs that change what is recorded, not what is learned: they stay out of the key.
_NOT_IN_KEY = ("record_video", "video_max_frames", "fault", "fault_marker")


@dataclass(frozen=True)
class GridTrial:
    key: str
    """``<variant>-s<seed>-<hash>``: stable across runs of the same experiment file."""
    variant: str
    seed: int
    config: TrialConfig


def config_hash(config: TrialConfig) -> str:
    flat = {k: v for k, v in flatten(config).items() if k not in _NOT_IN_KEY}
    return hashlib.sha1(json.dumps(flat, sort_keys=True, default=list).encode()).hexdigest()[:10]


def trial_key(variant: str, config: TrialConfig) -> str:
    slug = re.sub(r"[^A-Za-z0-9._=-]+", "_", variant).strip("_") or "variant"
    return f"{slug}-s{config.seed}-{config_hash(config)}"


def expand(experiment: Experiment) -> list[GridTrial]:
    """Every (variant, seed) pair, variant-major: the order trials are scheduled in."""
    trials = []
    for variant in experiment.variants:
        for seed in experiment.seeds:
            config = replace(variant.config, seed=seed)
            trials.append(GridTrial(trial_key(variant.name, config), variant.name, seed, config))
    return trials
