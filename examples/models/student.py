"""The course's CartPole network as a student completes it in the lab: ``create_cartpole_model()``, no arguments.

``ablate`` calls it as written (``model = "student.py:create_cartpole_model"``) and ablates it against its own
built-in baseline: see docs/your-model.md.
"""

from torch import nn


def create_cartpole_model():
    return nn.Sequential(
        nn.Linear(4, 32),  # CartPole's 4 observations
        nn.ReLU(),
        nn.Linear(32, 2),  # logits of its 2 actions: ablate samples from their softmax
    )
