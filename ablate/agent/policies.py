"""A trial's network: observation in, action logits out (no softmax inside). The built-in ones,
``create_cartpole_model`` and ``create_pong_model`` (the course's names), or the user's own factory
(``model = "FILE.py:FUNCTION"`` or ``"package.module:FUNCTION"``); ``build_model`` picks one, and a population
trains a user's as it trains the built-in ones (``stacking``).

A factory is called with those of ``observation_shape``, ``n_actions`` and its ``model_args`` that its signature
accepts, and must return an ``nn.Module`` mapping a float32 batch of observations to (batch, n_actions) logits.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence

import torch
from torch import nn

from ablate import sources
from ablate.config import ARCHITECTURES, SCHEMA, ModelConfig, TrialConfig
from ablate.envs import Described

_ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU, "gelu": nn.GELU}


class Policy(nn.Module):
    """A built-in network: a batch of observations to logits."""

    def __init__(self, body: nn.Module) -> None:
        super().__init__()
        self.body = body

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        """Logits; int8 observations (Pong's frame differences) are taken as float32."""
        return self.body(observations.float())


def _dense_layers(
    in_features: int,
    hidden_sizes: Sequence[int],
    n_actions: int,
    activation: str,
    dropout: float,
    layer_norm: bool = False,
) -> list[nn.Module]:
    layers: list[nn.Module] = []
    for width in hidden_sizes:
        layers += [nn.Linear(in_features, width), *([nn.LayerNorm(width)] if layer_norm else [])]
        layers.append(_ACTIVATIONS[activation]())
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        in_features = width
    layers.append(nn.Linear(in_features, n_actions))
    return layers


def _convolutional(architecture: str) -> bool:
    """``cnn`` or ``mlp``; anything else is a ``ValueError`` (a trial's config is checked before: this is for a
    direct call of a factory)."""
    if architecture not in ARCHITECTURES:
        raise ValueError(f"architecture = {architecture!r} is invalid; valid: {', '.join(ARCHITECTURES)}")
    return architecture == "cnn"


def create_cartpole_model(
    observation_size: int = 4,
    n_actions: int = 2,
    hidden_sizes: Sequence[int] = (32,),
    activation: str = "relu",
    dropout: float = 0.0,
    architecture: str = "mlp",
    history: int = 4,
    conv_channels: Sequence[int] = (16,),
    kernel_size: int = 2,
    layer_norm: bool = False,
) -> Policy:
    """CartPole policy. ``mlp``: input (observation_size,). ``cnn``: input (history, observation_size), a
    window of recent observations, oldest first; 1-D convolutions run along time with the observation's
    components as channels, then the dense layers."""
    layers: list[nn.Module] = []
    inputs = observation_size
    if _convolutional(architecture):
        layers.append(_TimeAsLength())
        channels, length = observation_size, history
        for out_channels in conv_channels:
            layers += [nn.Conv1d(channels, out_channels, kernel_size), _ACTIVATIONS[activation]()]
            channels, length = out_channels, length - kernel_size + 1
            if length < 1:
                raise ValueError(
                    f"history {history} is too short for {len(conv_channels)} convolutions of {kernel_size}"
                )
        layers.append(nn.Flatten())
        inputs = channels * length
    dense = _dense_layers(inputs, hidden_sizes, n_actions, activation, dropout, layer_norm)
    return Policy(nn.Sequential(*layers, *dense))


class _TimeAsLength(nn.Module):
    """(batch, time, features) -> (batch, features, time): Conv1d wants channels before length."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.transpose(1, 2)


PONG_CONV = ((16, 7, 4, 3), (32, 5, 2, 2), (48, 3, 2, 1))
"""The course's Pong CNN: (filters, kernel, stride, padding) of each conv layer (the report describes it from here)."""


def create_pong_model(
    n_actions: int = 6,
    hidden_sizes: Sequence[int] = (64,),
    activation: str = "relu",
    dropout: float = 0.0,
    architecture: str = "cnn",
    observation_shape: Sequence[int] = (1, 80, 80),
    layer_norm: bool = False,
) -> Policy:
    """Pong policy over the (1, 80, 80) difference of pre-processed frames (any (channels, H, W) image for other
    Atari games). ``cnn`` is the course's convolutions (``PONG_CONV``), then dense layers; ``mlp`` flattens the
    pixels straight into the dense layers (Karpathy's)."""
    channels, height, width = observation_shape
    convs: list[nn.Module] = []
    for filters, kernel, stride, padding in PONG_CONV if _convolutional(architecture) else ():
        convs += [nn.Conv2d(channels, filters, kernel, stride=stride, padding=padding), _ACTIVATIONS[activation]()]
        channels = filters
        height, width = ((n + 2 * padding - kernel) // stride + 1 for n in (height, width))
    dense = _dense_layers(channels * height * width, hidden_sizes, n_actions, activation, dropout, layer_norm)
    return Policy(nn.Sequential(*convs, nn.Flatten(), *dense))


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
    taken = inspect.signature(factory).parameters
    knobs = {k.attr: getattr(model, k.attr) for k in SCHEMA.values() if k.built_in and k.attr in taken}
    return factory(n_actions=env.n_actions, **sizes, **knobs)


def history(model: ModelConfig, env: Described) -> int:
    """Observations a step's input holds (a built-in ``cnn`` over a vector observation reads a window); 0: one."""
    image = len(env.observation_shape) == 3
    return model.history if not model.factory and model.architecture == "cnn" and not image else 0
