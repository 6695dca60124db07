"""A user's own policy network for ``ablate``, written as its own ``nn.Module`` class: the built-in default's shape
(one hidden layer of 32, ReLU), with ``F.relu`` in its ``forward`` instead of a layer.

Used by ``make bench``'s ``trainer`` section: a user's network must train about as fast as the built-in one.
"""

import torch
import torch.nn.functional as F
from torch import nn


class MLP(nn.Module):
    def __init__(self, inputs: int, n_actions: int, width: int) -> None:
        super().__init__()
        self.hidden = nn.Linear(inputs, width)
        self.out = nn.Linear(width, n_actions)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return self.out(F.relu(self.hidden(observations.flatten(1))))


def create_model(observation_shape, n_actions, width=32):
    """Observations (batch, *observation_shape) -> (batch, n_actions) logits."""
    inputs = 1
    for size in observation_shape:
        inputs *= size
    return MLP(inputs, n_actions, width)
