"""What an env family needs, declared once as its profile (the wrappers that make a trial's env, the knobs it
honours, its return rule, its videos, its words in the report), and what Gymnasium's registry says of a config's
env without building it.

Below the agent (stdlib; Gymnasium and ale-py imported lazily), so the experiment, the launch's driver and the
report ask the same functions the trainer does. The one place that reads an env's name: ``profile_of`` picks a
profile by ``Profile.matches`` where the experiment names none.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from ablate import sources


class EnvError(ValueError):
    """An env the trainer cannot run (not registered, continuous actions, a non-Box observation, bad env_args)."""


class EnvConfig(Protocol):
    """What these functions read of a config (a ``TrialConfig``, or the report's record of one)."""

    env_id: str
    env_module: str
    solve_threshold: float | None


@dataclass(frozen=True)
class Profile:
    """An env family: how a trial's env is made and what follows from it, each fact once (the knobs it honours
    are declared with them: ``schema.Knob.profiles``)."""

    name: str
    summary: str
    """One line for the docs and the knob's message."""
    make: str
    """``module:function`` building one env of a trial, called as ``function(config, render)`` (Gymnasium's own
    entry-point form)."""
    matches: str = ""
    """The env ids it is the default profile for: those starting with this ("": any)."""
    needs: str = ""
    """The env ids it can make: those starting with this ("": any)."""
    resets_on_score: bool = False
    """The discounted return restarts at every nonzero reward (the course's rule for Pong: a point scored)."""
    sampling_video: bool = False
    """The end-of-trial video plays the sampling policy, not the greedy one (a greedy agent that has not learnt
    much holds one button for a whole Atari game)."""
    episode_limit_from_spec: bool = True
    """An episode is cut at the spec's ``max_episode_steps`` where ``max_episode_steps`` is 0 (else: never)."""
    observation: str = "image"
    """What a 3-D observation is, in the report's words."""
    observation_shape: tuple[int, ...] = (0,)
    """The observation's shape where a trial did not record it (a run from before trials recorded it)."""
    observation_figure: bool = False
    """A trial draws ``observation.png`` (a raw frame, pre-processed, as a difference)."""
    large_frames: bool = False
    """Per-update arrays of megabytes: glibc maps them, and gives them back when freed (``trainer._set_malloc``)."""
    checkpoint_every: int = 0
    """Episodes between checkpoints where ``checkpoint_every`` is unset (trials of hours need them)."""
    atari: bool = False
    """An Atari game: the report cites the Arcade Learning Environment."""
    return_levels: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    """Return levels the report counts episodes to, by game (no solve threshold there)."""
    episode_seconds: Mapping[str, float] = field(default_factory=dict)
    """Seconds a trial no launch has run yet costs per episode of its budget, by env id, as the store would record
    it (its run's start to end, in a population on 2 shared cores): ``ablate run --dry-run``'s guess."""

    def maker(self):
        module, function = self.make.split(":")
        return getattr(importlib.import_module(module), function)


PROFILES = {
    profile.name: profile
    for profile in (
        Profile(
            "pong",
            "the course's Pong pipeline for any Atari game: 80x80 foreground frames (rows 35:195, every 2nd pixel, "
            "backgrounds 144 and 109 erased) differenced, the return reset at every point, action_set",
            "ablate.envs:make_pong",
            matches="ALE/Pong",
            needs="ALE/",
            resets_on_score=True,
            sampling_video=True,
            episode_limit_from_spec=False,
            observation="frame difference",
            observation_shape=(1, 80, 80),
            observation_figure=True,
            large_frames=True,
            checkpoint_every=50,
            atari=True,
            return_levels={"ALE/Pong-v5": (-15.0, -10.0)},
            episode_seconds={"ALE/Pong-v5": 0.8},  # pong.toml's launch: 48:30 of trials (docs/pong.md)
        ),
        Profile(
            "atari",
            "Gymnasium's AtariPreprocessing (grayscale 84x84, frameskip, sticky actions), frames differenced",
            "ablate.envs:make_atari_trial_env",
            matches="ALE/",
            needs="ALE/",
            observation="frame difference",
            atari=True,
        ),
        Profile(
            "gym",
            "gym.make(env_id, **env_args), observations as the env gives them",
            "ablate.envs:make_gym_trial_env",
            # A fresh launch of 4 variants x 3 seeds x 300 episodes: 12 trials of 5.6-7.9 s (2026-12-06).
            episode_seconds={"CartPole-v0": 0.021, "CartPole-v1": 0.021},
        ),
    )
}
"""The env families, by the name an experiment's ``env_profile`` gives; most specific first."""


def profile_of(config: Any) -> Profile:
    """``config``'s profile (a config, or anything with its ``env_id`` and ``env_profile``)."""
    return profile_named(config.env_id, getattr(config, "env_profile", ""))


def profile_named(env_id: str, env_profile: str = "") -> Profile:
    """The profile ``env_profile`` names, else the first whose ``matches`` starts ``env_id``."""
    if env_profile:
        return PROFILES[env_profile]
    return next(p for p in PROFILES.values() if env_id.startswith(p.matches))


def register(config: EnvConfig) -> None:
    """Make ``config.env_id`` known to Gymnasium: the user's ``env_module`` imported (from its shipped files where
    it is local) and its function called where it names one, ale-py's games registered; an id that is still not
    known is an ``EnvError``."""
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
    if config.env_id in gym.registry:
        return
    if config.env_module:
        named = ", ".join(added[:5]) + (", ..." if len(added) > 5 else "") or "none"
        raise EnvError(
            f"env_module = {config.env_module!r} ran, but env_id = {config.env_id!r} is still not a registered "
            f"Gymnasium env; it registered {named}"
        )
    raise EnvError(f"env_id = {config.env_id!r} is not a registered Gymnasium env (e.g. CartPole-v1, Acrobot-v1)")


_REGISTERED_BY: dict[str, list[str]] = {}
"""The env ids each ``env_module`` registered the first time it ran in this process, for the message above."""


def solve_threshold(config: EnvConfig) -> float | None:
    """The rolling mean over ``solve_window`` episodes at which a trial counts as solved and stops: its own
    ``solve_threshold``, else its env spec's ``reward_threshold`` (``None``: Pong has none; an unknown env is an
    ``EnvError``)."""
    import gymnasium as gym

    if config.solve_threshold is not None:
        return float(config.solve_threshold)
    register(config)
    threshold = gym.spec(config.env_id).reward_threshold
    return None if threshold is None else float(threshold)


def solve_threshold_or_none(config: EnvConfig) -> float | None:
    """``solve_threshold``, or ``None`` where the env cannot be looked up here (an unknown id, a module that does
    not import: ``checks`` says so in words before a launch)."""
    try:
        return solve_threshold(config)
    except (EnvError, ImportError):
        return None


@functools.cache
def versions(names: tuple[str, ...] = ("gymnasium", "ale-py")) -> dict[str, str]:
    """The installed versions of ``names`` (``not installed`` where absent): by default, the env libraries a trial
    ran against."""
    from importlib.metadata import PackageNotFoundError, version

    found: dict[str, Any] = {}
    for name in names:
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = "not installed"
    return found
