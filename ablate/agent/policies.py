"""The built-in policy networks: observation in, action logits out (no softmax inside).

``create_cartpole_model`` and ``create_pong_model`` are the course's names (``models.build_model`` picks one, or
the user's own factory); a population trains them as it trains a user's (``stacking``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ablate.config import ARCHITECTURES

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
