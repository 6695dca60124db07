"""What Gymnasium's registry says of a config's env, without building it: registering it (a user's module,
ale-py's games), its spec's reward threshold, the solve threshold a trial stops at, Pong's return rule.

Below the agent (stdlib; Gymnasium and ale-py imported lazily), so the experiment, the launch's driver and the
report ask the same functions the trainer does.
"""

from __future__ import annotations

import functools
from typing import Any, Protocol

from ablate import sources


class EnvError(ValueError):
    """An env the trainer cannot run (not registered, continuous actions, a non-Box observation, bad env_args)."""


class EnvConfig(Protocol):
    """What these functions read of a config (a ``TrialConfig``, or the report's record of one)."""

    env_id: str
    env_module: str
    solve_threshold: float | None


def is_pong(env_id: str) -> bool:
    """The course's Pong (``ALE/Pong-*``): its frame-difference env, its sampling-policy videos, its return rule."""
    return env_id.startswith("ALE/Pong")


def resets_on_score(env_id: str) -> bool:
    """Does the discounted return restart at every point scored? The course's rule for Pong."""
    return is_pong(env_id)


def register(config: EnvConfig) -> None:
    """Make ``config.env_id`` known to Gymnasium: the user's ``env_module`` imported (from its shipped files where
    it is local) and its function called where it names one, ale-py's games registered."""
    import gymnasium as gym

    if config.env_module:
        before = set(gym.registry)
        source, digest = getattr(config, "env_module_source", ()), getattr(config, "env_module_hash", "")
        try:
            sources.run_env_module(config.env_module, source, digest)
        except sources.SourceError as error:
            raise EnvError(f"env_module = {config.env_module!r}: {error}") from None
        added = _REGISTERED_BY.setdefault(config.env_module, sorted(set(gym.registry) - before))
    if config.env_id.startswith("ALE/") and "ALE/Pong-v5" not in gym.registry:  # again costs ~0.1 s (100 envs)
        import ale_py  # imported lazily: CartPole-only users never pay for the emulator

        gym.register_envs(ale_py)
    if config.env_module and config.env_id not in gym.registry:
        named = ", ".join(added[:5]) + (", ..." if len(added) > 5 else "") or "none"
        raise EnvError(
            f"env_module = {config.env_module!r} ran, but env_id = {config.env_id!r} is still not a registered "
            f"Gymnasium env; it registered {named}"
        )


_REGISTERED_BY: dict[str, list[str]] = {}
"""The env ids each ``env_module`` registered the first time it ran in this process, for the message above."""


def reward_threshold(config: EnvConfig) -> float | None:
    """The env spec's ``reward_threshold`` (``None``: it has none, as Pong); an unknown env is an ``EnvError``."""
    import gymnasium as gym

    register(config)
    if config.env_id not in gym.registry:
        raise EnvError(f"env_id = {config.env_id!r} is not a registered Gymnasium env (e.g. CartPole-v1, Acrobot-v1)")
    threshold = gym.spec(config.env_id).reward_threshold
    return None if threshold is None else float(threshold)


def solve_threshold(config: EnvConfig) -> float | None:
    """The rolling mean over ``solve_window`` episodes at which a trial counts as solved and stops: its own
    ``solve_threshold``, else its env spec's ``reward_threshold`` (``None``: Pong has none). The one rule: the
    trainer stops at it, the launch estimates with it, the experiment's default primary metric and the report's
    fallback for trials that did not record theirs ask it."""
    if config.solve_threshold is not None:
        return float(config.solve_threshold)
    return reward_threshold(config)


def solve_threshold_or_none(config: EnvConfig) -> float | None:
    """``solve_threshold``, or ``None`` where the env cannot be looked up here (an unknown id, a module that does
    not import: ``checks`` says so in words before a launch)."""
    try:
        return solve_threshold(config)
    except (EnvError, ImportError):
        return None


@functools.cache
def versions() -> dict[str, str]:
    """The versions of the env libraries a trial ran against (``not installed`` where absent)."""
    from importlib.metadata import PackageNotFoundError, version

    found: dict[str, Any] = {}
    for name in ("gymnasium", "ale-py"):
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = "not installed"
    return found
