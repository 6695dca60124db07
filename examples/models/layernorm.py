"""A user's own policy network for ``ablate``: an MLP with LayerNorm, the kind of change a student tries.

Used by ``experiments/your-model.toml``, ``docs/your-model.md`` and the trainer's tests.
"""

from torch import nn


def create_model(observation_shape, n_actions, width=32):
    """Observations (batch, *observation_shape) -> (batch, n_actions) logits."""
    inputs = 1
    for size in observation_shape:
        inputs *= size
    return nn.Sequential(
        nn.Flatten(),
        nn.Linear(inputs, width),
        nn.LayerNorm(width),
        nn.ReLU(),
        nn.Linear(width, n_actions),
    )
