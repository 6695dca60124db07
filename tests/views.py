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


class Watched:
    """A launch's state, its estimate and its view together, as the runner drives them: an event goes to the
    state, then the view is told (``update``); reading falls through to the state, the estimate, the view."""

    def __init__(self, *args, enabled=False, log_estimates=False, **kwargs):
        from ablate.launch.estimate import TimeLeft
        from ablate.launch.progress import ProgressView
        from ablate.launch.state import LaunchState

        self.state = LaunchState(*args, **kwargs)
        self.estimate = TimeLeft(self.state)
        self.view = ProgressView(self.state, enabled, log_estimates)

    def _event(self, name, *args, **kwargs):
        getattr(self.state, name)(*args, **kwargs)
        self.view.update()

    def started(self, *args, **kwargs):
        self._event("started", *args, **kwargs)

    def episodes(self, *args, **kwargs):
        self._event("episodes", *args, **kwargs)

    def finished(self, *args, **kwargs):
        self._event("finished", *args, **kwargs)

    def failed(self, *args, **kwargs):
        self._event("failed", *args, **kwargs)

    def add_trials(self, *args, **kwargs):
        self._event("add_trials", *args, **kwargs)

    def __getattr__(self, name):
        for part in (self.state, self.estimate, self.view):
            if hasattr(part, name):
                return getattr(part, name)
        raise AttributeError(name)
