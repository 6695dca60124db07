"""Which trials can train together as one population.

Trials share a population when they share an env and a network (everything else, the seed, learning rate, L2,
discount, budget and stop rule, is per member); the launch groups them by this (``launch.plan``).
"""

from __future__ import annotations

from collections.abc import Sequence

from ablate.config import TrialConfig


def population_group(config: TrialConfig) -> tuple:
    """Configs with one group share a population: one env (and its settings), one network, one batch shape."""
    return (
        config.env_id,
        config.env_args,
        config.env_module,
        config.env_module_hash,
        config.model,
        config.episodes_per_update,
        config.num_envs,
        config.action_set,
        config.frameskip,
        config.repeat_action_probability,
        config.max_episode_steps,
    )


def can_share(configs: Sequence[TrialConfig]) -> bool:
    """Whether ``configs`` can train as one population (one is always a population)."""
    return len({population_group(c) for c in configs}) <= 1
