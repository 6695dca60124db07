"""One trial end to end: determinism, solving, artifacts, metrics through the callback, faults."""

import os
import subprocess
import sys
from dataclasses import replace

import pytest
import torch

from ablate.agent.records import TrialFailed
from ablate.agent.trainer import run_trial
from ablate.config import DEFAULT, ModelConfig
from ablate.envs import PongFrameDifference

SHORT = replace(DEFAULT, env_id="CartPole-v1", max_episodes=64, episodes_per_update=8, record_video=False)


def test_same_config_and_seed_gives_identical_returns():
    first = run_trial(replace(SHORT, seed=3))
    second = run_trial(replace(SHORT, seed=3))
    assert first.returns == second.returns
    assert first.returns != run_trial(replace(SHORT, seed=4)).returns


def test_callback_sees_every_episode_once_in_order():
    seen = []
    result = run_trial(SHORT, on_episodes=seen.extend)
    assert [m.episode for m in seen] == list(range(1, 65))
    assert seen == result.episodes
    assert result.env_steps == sum(m.length for m in seen) == seen[-1].env_steps
    assert all(m.episode_return == m.length for m in seen)  # CartPole pays 1 per step


def test_budget_is_respected_when_not_a_multiple_of_the_batch():
    result = run_trial(replace(SHORT, max_episodes=13))
    assert len(result.episodes) == 13 and result.episodes_to_solve is None


def test_rolling_mean_and_solve_rule():
    # A threshold every episode meets: solved exactly when the window first fills.
    result = run_trial(replace(SHORT, solve_threshold=1.0, solve_window=20))
    assert result.episodes_to_solve == 20
    window = result.returns[:20]
    assert result.episodes[19].rolling_mean == pytest.approx(sum(window) / 20)


def test_cnn_variant_trains():
    config = replace(SHORT, model=ModelConfig(architecture="cnn", history=4, kernel_size=2, hidden_sizes=(16,)))
    result = run_trial(config)
    assert len(result.episodes) == 64 and result.parameter_count > 0


def test_nan_loss_fails_with_an_actionable_message():
    with pytest.raises(TrialFailed, match="injected fault"):
        run_trial(replace(SHORT, fault="raise"))


@pytest.mark.slow
def test_default_config_solves_cartpole_v0():
    result = run_trial(replace(DEFAULT, env_id="CartPole-v0", seed=0, record_video=False))
    assert result.solved, f"rolling mean only reached {result.episodes[-1].rolling_mean}"
    assert result.episodes[result.episodes_to_solve - 1].rolling_mean >= 195.0


PONG = replace(
    DEFAULT,
    env_id="ALE/Pong-v5",
    gamma=0.99,
    learning_rate=1e-3,
    model=ModelConfig(architecture="mlp", hidden_sizes=(8,), dropout=0.1),
    action_set="move",
    max_episode_steps=40,  # a few seconds per trial: episodes cut at 40 steps
    num_envs=3,
    episodes_per_update=2,
    max_episodes=12,
    checkpoint_every=4,
    record_video=False,
)


class _Stop(Exception):
    pass


def test_pong_trial_resumed_from_its_checkpoint_continues_exactly():
    blobs = []
    whole = run_trial(PONG, on_checkpoint=blobs.append)
    assert len(blobs) == 2  # after episodes 4 and 8; none at the end

    def stop(blob):  # the process "dies" right after its first checkpoint
        raise _Stop

    with pytest.raises(_Stop):
        run_trial(PONG, on_checkpoint=stop)
    calls = []
    resumed = run_trial(PONG, on_episodes=calls.append, resume_from=blobs[0])
    assert [m.episode for m in calls[0]] == [1, 2, 3, 4]  # the saved history first, in one call
    assert [m.episode for c in calls[1:] for m in c] == list(range(5, 13))
    assert resumed.returns == whole.returns and resumed.env_steps == whole.env_steps
    assert [m.loss for m in resumed.episodes] == [m.loss for m in whole.episodes]
    for name, tensor in whole.state_dict.items():
        assert torch.equal(resumed.state_dict[name], tensor), name


def test_cartpole_resume_continues_the_episode_count():
    blobs = []
    config = replace(SHORT, max_episodes=32, checkpoint_every=16)
    run_trial(config, on_checkpoint=blobs.append)
    assert len(blobs) == 1
    resumed = run_trial(config, resume_from=blobs[0])
    assert [m.episode for m in resumed.episodes] == list(range(1, 33))
    assert resumed.episodes[15].env_steps < resumed.episodes[16].env_steps


def test_pong_trial_spends_no_steps_on_episodes_past_its_budget(monkeypatch):
    """Sub-envs that finish once the trial's remaining episodes are finished or under way stop, instead of
    starting episodes nobody trains on: every emulator step taken belongs to an episode of the result."""
    taken = []
    step = PongFrameDifference.step
    monkeypatch.setattr(PongFrameDifference, "step", lambda self, action: (taken.append(1), step(self, action))[1])
    result = run_trial(replace(PONG, max_episodes=5, checkpoint_every=0))
    assert len(result.episodes) == 5
    assert len(taken) == result.env_steps == 5 * 40  # 3 sub-envs: without the budget, 6 episodes were played


@pytest.mark.parametrize(("given", "expected"), [(None, "1"), ("0", "0")])
def test_importing_ablate_puts_torch_tensors_on_huge_pages_unless_told_otherwise(given, expected):
    """torch reads THP_MEM_ALLOC_ENABLE once, at its first allocation: ``import ablate`` must set it before
    torch is imported (in a Ray worker, the trial's import of ablate comes first), and leave a user's value."""
    env = {k: v for k, v in os.environ.items() if k != "THP_MEM_ALLOC_ENABLE"}
    if given is not None:
        env["THP_MEM_ALLOC_ENABLE"] = given
    code = "import sys, os, ablate.agent.trainer; print(os.environ['THP_MEM_ALLOC_ENABLE'], 'torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == [expected, "True"]


def test_summary_auc_is_the_rolling_mean_over_the_whole_budget_a_solved_trial_holding_its_last_value():
    from ablate.agent.records import EpisodeMetrics, TrialResult

    def episode(i, rolling):
        return EpisodeMetrics(i, 0.0, 1, 0.0, 0.0, rolling, i, 0.0, i)

    config = replace(DEFAULT, max_episodes=5)
    result = TrialResult(config, [episode(1, 10.0), episode(2, 20.0), episode(3, 30.0)], 3, 20.0, 3, 1.0, 0)
    assert result.summary()["auc"] == (10 + 20 + 30 + 30 + 30) / 5  # stopped at 3 of 5: padded with 30
    full = TrialResult(config, [episode(i, float(i)) for i in range(1, 6)], None, 20.0, 5, 1.0, 0)
    assert full.summary()["auc"] == 3.0
