"""A trial's network: the user's own factory (``model = "FILE.py:FUNCTION"`` or ``"package.module:FUNCTION"``) or a
built-in one (``policies``: the course's CartPole MLP and 1-D CNN, its Pong CNN, an MLP over pixels).

A factory is called with those of ``observation_shape``, ``n_actions`` and its ``model_args`` that its signature
accepts, and must return an ``nn.Module`` mapping a float32 batch of observations to (batch, n_actions) logits.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable

from torch import nn

from ablate import sources
from ablate.agent.policies import create_cartpole_model, create_pong_model
from ablate.config import SCHEMA, ModelConfig, TrialConfig
from ablate.envs import Described


class ModelError(ValueError):
    """A user's factory that cannot build a policy; the message names the factory and what is wrong."""


def load_factory(model: ModelConfig) -> Callable[..., nn.Module]:
    """The factory function of ``model``, loaded from its shipped files (``sources.load_function``)."""
    try:
        return sources.load_function(model.factory, model.factory_source, model.factory_hash)
    except sources.SourceError as error:
        raise ModelError(f"model = {model.factory!r}: {error}") from None


def call_factory(model: ModelConfig, observation_shape: tuple[int, ...], n_actions: int) -> nn.Module:
    """The user's network: its factory called with the arguments its signature takes."""
    factory = load_factory(model)
    offered = {"observation_shape": tuple(observation_shape), "n_actions": n_actions, **dict(model.factory_args)}
    try:
        parameters = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        parameters = {}
    takes_all = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values())
    kwargs = offered if takes_all else {k: v for k, v in offered.items() if k in parameters}
    unknown = [k for k in dict(model.factory_args) if k not in kwargs]
    if unknown:
        raise ModelError(f"model_args.{unknown[0]}: {model.factory} takes no argument {unknown[0]!r}")
    try:
        network = factory(**kwargs)
    except Exception as error:
        raise ModelError(f"model = {model.factory!r} raised {type(error).__name__}: {error}") from None
    if not isinstance(network, nn.Module):
        raise ModelError(f"model = {model.factory!r} returned {type(network).__name__}; valid: a torch.nn.Module")
    return network


def build_model(config: TrialConfig, env: Described) -> nn.Module:
    """``config``'s network for ``env``, its initial weights drawn from torch's global RNG (the caller seeds it)."""
    model = config.model
    if model.factory:
        return call_factory(model, env.observation_shape, env.n_actions)
    if len(env.observation_shape) == 3:  # an image (Pong's frame difference, another Atari game's)
        channels, *_, last = env.observation_shape
        if model.architecture == "cnn" and last < channels:  # MinAtar's (10, 10, 4): its first axis is not channels
            raise ModelError(
                f"architecture = 'cnn' reads an image as (channels, height, width), but {config.env_id}'s "
                f"observation {tuple(env.observation_shape)} looks channels-last; valid: architecture = 'mlp', "
                "or your own model (model = 'FILE.py:FUNCTION') that permutes it"
            )
        factory, sizes = create_pong_model, {"observation_shape": env.observation_shape}
    else:
        factory, sizes = create_cartpole_model, {"observation_size": math.prod(env.observation_shape)}
    # The built-in knobs by name, as the schema declares them; each factory takes those its signature names.
    taken = inspect.signature(factory).parameters
    knobs = {k.attr: getattr(model, k.attr) for k in SCHEMA.values() if k.built_in and k.attr in taken}
    return factory(n_actions=env.n_actions, **sizes, **knobs)


def history(model: ModelConfig, env: Described) -> int:
    """Observations a step's input holds (a built-in ``cnn`` over a vector observation reads a window); 0: one."""
    image = len(env.observation_shape) == 3
    return model.history if not model.factory and model.architecture == "cnn" and not image else 0
