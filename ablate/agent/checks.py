"""An experiment's envs and user networks tried once before a launch: what cannot train is one line, exit 2, before
Ray starts and before anything is tracked.
"""

from __future__ import annotations

from collections.abc import Iterable

from ablate.config import ConfigError, TrialConfig


def needs_check(config: TrialConfig) -> bool:
    """Built-in networks on the course's envs are known to work; a user's network or env is tried first."""
    from ablate.config import BUILT_IN_ENVS

    return bool(config.model.factory or config.env_args or config.env_module or config.env_id not in BUILT_IN_ENVS)


def check_configs(named: Iterable[tuple[str, TrialConfig]], source: str) -> None:
    """Each distinct env described and each distinct network built and run on a sample observation; the first
    problem is a ``ConfigError`` naming the file, the variant and what is wrong."""
    # Here, not at the top: torch and Gymnasium (~1 s to import) only where there is a network or env to try.
    from ablate.agent.envs import EnvError, describe
    from ablate.agent.models import ModelError, check_model

    seen: set = set()
    for variant, config in named:
        key = (
            config.env_id,
            config.env_args,
            config.env_module,
            config.env_module_hash,
            config.action_set,
            config.model,
        )
        if key in seen or not needs_check(config):
            continue
        seen.add(key)
        try:
            check_model(config, describe(config))
        except (EnvError, ModelError) as error:
            raise ConfigError(f"{source}: variant {variant!r}: {error}") from None


def check_experiment(experiment) -> None:
    """An ``Experiment``'s own networks and envs tried once: a ``ConfigError`` before Ray starts. Nothing to try
    (and no torch imported) where every variant is built in."""
    if any(needs_check(v.config) for v in experiment.variants):
        check_configs(((v.name, v.config) for v in experiment.variants), experiment.path)
