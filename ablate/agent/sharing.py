"""Which trials can train together as one population.

Trials share a population when they share an env and a network (everything else, the seed, learning rate, L2,
discount, budget and stop rule, is per member); the launch groups them by this (``launch.plan``).
"""

from __future__ import annotations

from collections.abc import Sequence

from ablate.config import POPULATION_COLUMNS, TrialConfig
from ablate.schema import value_of


def population_group(config: TrialConfig) -> tuple:
    """Configs with one group share a population: one env (and its settings), one network, one batch shape (the
    fields the schema marks ``population``)."""
    return tuple(value_of(config, column) for column in POPULATION_COLUMNS)


def can_share(configs: Sequence[TrialConfig]) -> bool:
    """Whether ``configs`` can train as one population (one is always a population)."""
    return len({population_group(c) for c in configs}) <= 1
