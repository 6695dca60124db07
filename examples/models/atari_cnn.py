"""A user's own CNN for an Atari game's frame differences (``ablate``'s (1, 84, 84) images): Nature-DQN's three
convolutions, narrower, then one hidden layer. Used by ``make bench``'s ``trainer`` section against the built-in
``cnn`` on Breakout.
"""

from torch import nn


def create_model(observation_shape, n_actions, width=64):
    """Observations (batch, channels, height, width) -> (batch, n_actions) logits."""
    channels, height, _ = observation_shape
    convolutions = nn.Sequential(
        nn.Conv2d(channels, 16, 8, stride=4),
        nn.ReLU(),
        nn.Conv2d(16, 32, 4, stride=2),
        nn.ReLU(),
        nn.Conv2d(32, 32, 3, stride=1),
        nn.ReLU(),
        nn.Flatten(),
    )
    side = ((height - 8) // 4 + 1 - 4) // 2 + 1 - 3 + 1
    return nn.Sequential(convolutions, nn.Linear(32 * side * side, width), nn.ReLU(), nn.Linear(width, n_actions))
