"""Which trials can train together as one population, and what a population of M costs against its members alone.

Trials share a population when they share an env and a network (everything else, the seed, learning rate, L2,
discount, budget and stop rule, is per member); the launch groups them (``launch.plan``) and the time-left estimate
costs them (``launch.estimate``) with these.
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


SHARED_COST = {"mlp": 0.22, "cnn": 0.38, "pong": 0.89}
"""The part of a member's cost alone that it still pays in a large population, per kind of population: a
population of M members of equal cost c takes ``c * M * (share + (1 - share) / M)`` (``member_cost``); from
``make bench`` (docs/performance.md): ``mlp`` dense networks (CartPole's), ``cnn`` any other network over a vector
observation, ``pong`` image envs (the emulators are most of the cost, and each member steps its own)."""


def population_share(config: TrialConfig) -> float:
    """``SHARED_COST`` for ``config``'s kind of population."""
    if config.env_id.startswith("ALE/"):
        return SHARED_COST["pong"]
    dense = not config.model.factory and config.model.architecture == "mlp"
    return SHARED_COST["mlp" if dense else "cnn"]


def member_cost(share: float, members: int) -> float:
    """A member's cost in a population of ``members``, in units of its cost alone (``SHARED_COST``)."""
    return share + (1.0 - share) / max(members, 1)


def crowd(config: TrialConfig, members: int) -> float:
    """How many times one member's cost alone a population of ``members`` of ``config``'s kind takes (each
    member's seconds are its population's clock): ``members * member_cost(share, members)``, 1 alone."""
    return members * member_cost(population_share(config), members)
