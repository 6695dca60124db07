"""An experiment's envs and user networks tried once before a launch: what cannot train is one line, exit 2, before
Ray starts and before anything is tracked.
"""

from __future__ import annotations

from collections.abc import Iterable

from ablate.config import BUILT_IN_ENVS, ConfigError, TrialConfig


def needs_check(config: TrialConfig) -> bool:
    """Built-in networks on the course's envs are known to work; a user's network or env is tried first."""
    return bool(config.model.factory or config.env_args or config.env_module or config.env_id not in BUILT_IN_ENVS)


def check_configs(named: Iterable[tuple[str, TrialConfig]], source: str) -> None:
    """Each distinct env described and each distinct network built and run on a sample observation; the first
    problem is a ``ConfigError`` naming the file, the variant and what is wrong."""
    # Here, not at the top: torch and Gymnasium (~1 s to import) only where there is a network or env to try.
    from ablate.agent.policies import ModelError
    from ablate.envs import EnvError, describe, env_facts

    seen: set = set()
    for variant, config in named:
        key = (env_facts(config), config.model)
        if key in seen or not needs_check(config):
            continue
        seen.add(key)
        try:
            check_model(config, describe(config))
        except (EnvError, ModelError) as error:
            where = [source] if source else []
            where += [f"variant {variant!r}"] if variant else []
            raise ConfigError(": ".join([*where, str(error)])) from None


def check_experiment(experiment) -> None:
    """An ``Experiment``'s own networks and envs tried once: a ``ConfigError`` before Ray starts. Nothing to try
    (and no torch imported) where every variant is built in."""
    if any(needs_check(v.config) for v in experiment.variants):
        check_configs(((v.name, v.config) for v in experiment.variants), experiment.path)


def check_model(config: TrialConfig, env) -> None:
    """Build ``config``'s network and run it on a sample observation: a ``ModelError`` unless it maps
    (batch, *observation) to (batch, n_actions)."""
    import torch

    from ablate.agent.policies import ModelError, build_model, history

    network = build_model(config, env)
    steps = history(config.model, env)
    shape = (2, steps, *env.observation_shape) if steps else (2, *env.observation_shape)
    try:
        with torch.no_grad():
            network.eval()
            logits = network(torch.zeros(shape))
    except Exception as error:
        raise ModelError(
            f"model = {config.model.factory!r}: its forward fails on a batch of shape {tuple(shape)} "
            f"({type(error).__name__}: {error})"
        ) from None
    if not isinstance(logits, torch.Tensor) or tuple(logits.shape) != (2, env.n_actions):
        got = tuple(logits.shape) if isinstance(logits, torch.Tensor) else type(logits).__name__
        raise ModelError(
            f"model = {config.model.factory!r}: its forward returns {got} for a batch of 2; valid: (batch, n_actions) "
            f"= (2, {env.n_actions}) logits"
        )
