"""What the tests of the live view and of the time-left estimate share: trials of a tiny grid and their
episode rows (the ``clock`` fixture, a hand-moved ``time.monotonic``, is in ``conftest.py``)."""

from dataclasses import replace

from ablate.agent.records import EpisodeMetrics
from ablate.config import TrialConfig
from ablate.launch.grid import GridTrial


class Clock:
    """``time.monotonic`` as the test moves it."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def grid_trials(budget=100, variants=("fast", "slow"), seeds=(0, 1)):
    config = replace(TrialConfig(), max_episodes=budget)
    return [GridTrial(f"{v}-s{s}", v, s, replace(config, seed=s)) for v in variants for s in seeds]


def row(episode, rolling_mean):
    return EpisodeMetrics(episode, 10.0, 10, 0.0, 0.5, rolling_mean, episode * 10, 0.0, episode)
