"""A user's own policy network for ``ablate`` that is not a plain stack of layers: an MLP with a residual block.

A population acts for it through its own ``forward`` with stacked layers (``ablate.agent.stacking``); used by the
trainer's tests.
"""

import torch
from torch import nn


class ResidualMLP(nn.Module):
    def __init__(self, inputs: int, n_actions: int, width: int) -> None:
        super().__init__()
        self.embed = nn.Linear(inputs, width)
        self.block = nn.Sequential(nn.LayerNorm(width), nn.Linear(width, width), nn.ReLU())
        self.head = nn.Linear(width, n_actions)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        hidden = torch.relu(self.embed(observations.flatten(1)))
        return self.head(hidden + self.block(hidden))


def create_model(observation_shape, n_actions, width=32):
    """Observations (batch, *observation_shape) -> (batch, n_actions) logits."""
    inputs = 1
    for size in observation_shape:
        inputs *= size
    return ResidualMLP(inputs, n_actions, width)
