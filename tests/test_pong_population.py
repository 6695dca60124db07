"""Pong populations: a member plays its single trial's episodes and takes its updates (the stacked forward is
its trial's to float rounding), a member that fails or ends early leaves the others untouched, a checkpointed
population resumes each member exactly."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from ablate.agent.envs import PongEnv
from ablate.agent.policies import create_pong_model
from ablate.agent.pong_acting import StackedPongActor
from ablate.agent.pong_population import PongPopulationBackend
from ablate.agent.population import SingleBackend, can_share, run_population
from ablate.agent.stacked import population_group
from ablate.agent.trial import TrialFailed, run_trial
from ablate.config import ModelConfig
from tests.test_trial import PONG

CNN = replace(PONG, model=ModelConfig(architecture="cnn", hidden_sizes=(8,)), max_episode_steps=30, max_episodes=6)


def _members(base, n=3):
    """Seeds and tuning candidates (learning rates) of one variant."""
    return [replace(base, seed=s, learning_rate=lr) for s, lr in zip(range(n), (1e-3, 3e-3, 2e-3), strict=False)]


def _frames(count: int) -> np.ndarray:
    env = PongEnv(action_set="move")
    frames = [env.reset(seed=3)]
    frames += [env.step(i % 2)[0] for i in range(count - 1)]
    return np.stack(frames)[:, None]


@pytest.mark.parametrize("architecture", ["mlp", "cnn"])
def test_the_stacked_forward_is_each_members_own_acting(architecture):
    torch.manual_seed(0)
    policies = [create_pong_model(2, (8,), architecture=architecture) for _ in range(3)]
    frames = _frames(30)  # the first is a whole screen: the single path's dense case
    counts = [4, 0, 3]  # member 1 idle (its emulators have stopped)
    logits = StackedPongActor(policies).logits(frames[:7], counts)
    expected = np.concatenate([policies[0].act_logits(frames[:4]), policies[2].act_logits(frames[4:7])])
    np.testing.assert_allclose(logits, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("base", [PONG, CNN], ids=["mlp+dropout", "cnn"])
def test_a_member_has_its_single_trials_first_episodes_loss_and_gradients(base):
    configs = _members(base)
    population = PongPopulationBackend(configs, torch.device("cpu"), [None] * 3)
    for member in population.members:
        member.optimizer.step = lambda: None  # the gradients stay to compare
    batches: dict = {}
    stats: dict = {}
    while len(batches) < 3:  # each member is returned as soon as its own batch is in
        ready = population.collect([2] * 3, [base.max_episodes] * 3)
        assert not set(ready) & set(batches)
        batches |= ready
        stats |= population.update(ready)
    for i, config in enumerate(configs):
        single = SingleBackend(config, torch.device("cpu"), None)
        single.optimizer.step = lambda: None
        [batch] = single.collect([2], [config.max_episodes]).values()
        [stat] = single.update({0: batch}).values()
        # The same episodes: no action flipped in these few steps (acting is the trial's to float rounding).
        for mine, theirs in zip(batches[i], batch, strict=True):
            np.testing.assert_array_equal(mine, theirs)
        assert stats[i].loss == pytest.approx(stat.loss, rel=1e-6)
        assert stats[i].entropy == pytest.approx(stat.entropy, rel=1e-6)
        for p, q in zip(population.policy(i).parameters(), single.model.parameters(), strict=True):
            torch.testing.assert_close(p.grad, q.grad)


def _same_run(outcome, single):
    assert outcome.returns == single.returns and outcome.env_steps == single.env_steps
    np.testing.assert_allclose([m.loss for m in outcome.episodes], [m.loss for m in single.episodes], rtol=1e-5)
    for name, tensor in single.state_dict.items():
        torch.testing.assert_close(outcome.state_dict[name], tensor)


def test_a_failing_member_fails_alone_and_one_that_ends_early_leaves_the_others_untouched():
    configs = _members(replace(PONG, checkpoint_every=0))
    configs[1] = replace(configs[1], fault="raise")
    configs[2] = replace(configs[2], max_episodes=4)
    outcomes = run_population(configs)
    assert isinstance(outcomes[1], TrialFailed) and "injected fault" in str(outcomes[1])
    for i in (0, 2):
        _same_run(outcomes[i], run_trial(configs[i]))
    assert len(outcomes[2].episodes) == 4 and len(outcomes[0].episodes) == 12


def test_a_checkpointed_population_resumes_each_member_exactly():
    configs = _members(PONG)
    blobs: dict[int, list[bytes]] = {}
    whole = run_population(configs, on_checkpoint=lambda i, blob: blobs.setdefault(i, []).append(blob))
    assert all(len(blobs[i]) == 2 for i in range(3))  # after episodes 4 and 8
    replayed: dict[int, list] = {}
    resumed = run_population(
        configs,
        on_episodes=lambda i, rows: replayed.setdefault(i, []).append(rows),
        resume_from=[blobs[0][0], blobs[1][1], blobs[2][0]],  # members checkpointed at different times
    )
    assert [m.episode for m in replayed[1][0]] == list(range(1, 9))  # the saved history first, in one call
    for done, again in zip(whole, resumed, strict=True):
        assert again.returns == done.returns and again.env_steps == done.env_steps
        assert [m.loss for m in again.episodes] == [m.loss for m in done.episodes]
        for name, tensor in done.state_dict.items():
            assert torch.equal(again.state_dict[name], tensor), name


def test_member_videos_go_to_their_own_folders(tmp_path):
    configs = [replace(c, max_episodes=2, video_every=1, video_max_frames=10) for c in _members(PONG, 2)]
    outcomes = run_population(configs, artifacts_dirs=[tmp_path / "a", tmp_path / "b"])
    for outcome, folder in zip(outcomes, ("a", "b"), strict=True):
        assert (tmp_path / folder / "videos" / "episode_00001.mp4").exists()
        assert outcome.artifacts["videos/episode_00001.mp4"].parent.parent == tmp_path / folder


def test_which_pong_configs_share_a_population():
    assert can_share(_members(PONG)) and can_share([PONG, replace(PONG, gamma=0.9, l2=0.01, max_episodes=3)])
    assert not can_share([PONG, CNN]) and not can_share([PONG, replace(PONG, num_envs=2)])
    assert not can_share([PONG, replace(PONG, action_set="all")])
    gelu = replace(PONG, model=replace(PONG.model, activation="gelu"))
    assert population_group(gelu) is None


def test_ablate_run_forms_pong_populations_per_arm_and_stage():
    from ablate.experiment import load_experiment
    from ablate.launch.grid import expand
    from ablate.launch.plan import plan_populations

    trials = expand(load_experiment("experiments/pong.toml"))
    plan = plan_populations(trials, cap=8, slots=2)
    assert sum(len(p.members) for p in plan) == len(trials)
    for population in plan:
        assert len({(t.variant, t.stage) for t in population.members}) == 1  # one arm, one stage
        assert can_share([t.config for t in population.members])
    assert max(len(p.members) for p in plan) > 1
