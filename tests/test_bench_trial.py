"""`benchmarks/bench_trial.py`'s course-style loop, what `make bench core` measures the trainer against, runs."""

import importlib.util
from dataclasses import replace
from pathlib import Path

from ablate.config import COURSE

BENCH_TRIAL = Path(__file__).parent.parent / "benchmarks" / "bench_trial.py"


def test_the_course_style_reference_loop_trains_and_counts_its_steps(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCH_TRIAL.parent))  # its sibling modules, as bench.py runs it
    spec = importlib.util.spec_from_file_location("bench_trial_under_test", BENCH_TRIAL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    measured = module._course_loop(replace(COURSE, env_id="CartPole-v1", seed=0), max_episodes=3)
    assert measured["env_steps"] >= 3 * 8  # CartPole's shortest episode is 8 steps
    assert measured["steps_per_s"] > 0
