"""Population trials: a member is its single trial, bit for bit (episodes, losses, gradients, weights), a member
that fails or solves early leaves the others untouched, a killed population resumes each member exactly."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from ablate.agent.population import SingleBackend, can_share, run_population
from ablate.agent.stacked import StackedBackend
from ablate.agent.trial import TrialFailed, TrialResult, run_trial
from ablate.config import DEFAULT, ModelConfig

SHORT = replace(DEFAULT, env_id="CartPole-v1", max_episodes=48, episodes_per_update=8, record_video=False)
DEEP = replace(SHORT, model=ModelConfig(hidden_sizes=(16, 16), dropout=0.2), l2=0.001)
CNN = replace(SHORT, model=ModelConfig(architecture="cnn", history=4, conv_channels=(16,), kernel_size=2))
"""experiments/cartpole.toml's ``cnn`` variant."""
DEEP_CNN = replace(
    SHORT,
    model=ModelConfig(
        architecture="cnn", history=5, conv_channels=(8, 6), kernel_size=2, hidden_sizes=(16,), dropout=0.2
    ),
    l2=0.001,
)
GELU = replace(SHORT, model=ModelConfig(hidden_sizes=(16, 16), activation="gelu"))
EXACT = [SHORT, DEEP, CNN, DEEP_CNN, GELU]
EXACT_IDS = ["dense", "dropout+l2", "cnn", "cnn-deep+dropout+l2", "gelu"]


def _members(base):
    """Seeds and tuning candidates (learning rates) of one variant: one population."""
    return [replace(base, seed=s, learning_rate=lr) for s, lr in ((0, 0.03), (1, 0.1), (2, 0.01), (3, 0.03))]


def _first_batches(backend):
    """Each member's first batch: collections end at different steps, a member's batch comes when its own
    episodes are in (its next collection, begun by the next call, is left unused)."""
    first = {}
    while len(first) < len(backend.configs):
        for slot, batch in backend.collect([8] * len(backend.configs), [48] * len(backend.configs)).items():
            first.setdefault(slot, batch)
    return first


def _first_update(backend):
    """The first batch of each member and its update's stats, the Adam step skipped (the gradients stay)."""
    backend.optimizer.step = lambda *members: None
    batches = _first_batches(backend)
    return batches, backend.update(batches)


@pytest.mark.parametrize("base", EXACT, ids=EXACT_IDS)
def test_a_member_has_its_single_trials_first_episodes_loss_and_gradients(base):
    configs = _members(base)
    population = StackedBackend(configs, torch.device("cpu"))
    batches, stats = _first_update(population)
    for i, config in enumerate(configs):
        single = SingleBackend(config, torch.device("cpu"), None)  # the pre-population path, nn.Linear and all
        single.optimizer.step = lambda: None
        [batch] = single.collect([8], [48]).values()
        [stat] = single.update({0: batch}).values()
        for mine, theirs in zip(batches[i], batch, strict=True):
            np.testing.assert_array_equal(mine, theirs)  # the same episodes, bit for bit
        assert stats[i] == stat  # the same loss and entropy
        for p, q in zip(population.model.params, single.model.parameters(), strict=True):
            assert torch.equal(p.grad[i], q.grad)


@pytest.mark.parametrize("base", [SHORT, DEEP, DEEP_CNN], ids=["dense", "dropout+l2", "cnn-deep+dropout+l2"])
def test_the_padded_batched_update_a_gpu_takes_gives_the_same_loss_and_gradients(base):
    """The GPU's path (one padded batch through batched products), run here on the CPU: the members' losses
    and gradients to float tolerance (the dropout masks are each member's own draws in both)."""
    configs = _members(base)
    exact, padded = StackedBackend(configs, torch.device("cpu")), StackedBackend(configs, torch.device("cpu"))
    first, again = _first_batches(exact), _first_batches(padded)
    batches = [first[slot] for slot in range(4)]
    assert all((a == b).all() for slot in range(4) for a, b in zip(first[slot], again[slot], strict=True))
    results = []
    for backend, losses in ((exact, exact._member_losses), (padded, padded._padded_losses)):
        total, member_losses, entropies = losses(list(range(4)), batches)
        total.backward()
        results.append(
            ([float(x.detach()) for x in member_losses], [float(e) for e in entropies], backend.model.params)
        )
    (loss_a, entropy_a, params_a), (loss_b, entropy_b, params_b) = results
    assert loss_a == pytest.approx(loss_b, rel=1e-5, abs=1e-7) and entropy_a == pytest.approx(entropy_b, rel=1e-5)
    for p, q in zip(params_a, params_b, strict=True):
        torch.testing.assert_close(p.grad, q.grad, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("base", [DEEP, DEEP_CNN], ids=["dropout+l2", "cnn-deep+dropout+l2"])
def test_a_population_of_one_is_its_single_trial_bit_for_bit(base):
    """run_trial is a population of one, and that is the pre-population path exactly (nn.Linear's kernels;
    the cnn's Gymnasium envs, ``ObservationWindow`` and ``Policy.act_logits``)."""
    config = replace(base, seed=5)
    single = SingleBackend(config, torch.device("cpu"), None)
    stacked = StackedBackend([config], torch.device("cpu"))
    for _ in range(3):
        [a], [b] = single.collect([8], [48]).values(), stacked.collect([8], [48]).values()
        for mine, theirs in zip(a, b, strict=True):
            np.testing.assert_array_equal(mine, theirs)
        assert single.update({0: a}) == stacked.update({0: b})
    for name, tensor in stacked.policy(0).state_dict().items():
        assert torch.equal(tensor, single.model.state_dict()[name]), name


@pytest.mark.parametrize("base", [DEEP, CNN], ids=["dropout+l2", "cnn"])
def test_members_follow_their_single_trials(base):
    """Not only the first update: each member's whole run is its single trial's, bit for bit (on a CPU)."""
    configs = _members(base)
    outcomes = run_population(configs)
    for config, outcome in zip(configs, outcomes, strict=True):
        alone = run_trial(config)
        assert [m[:7] for m in outcome.episodes] == [m[:7] for m in alone.episodes]
        for name, tensor in alone.state_dict.items():
            assert torch.equal(outcome.state_dict[name], tensor), name


@pytest.mark.parametrize("base", [DEEP, CNN], ids=["dropout+l2", "cnn"])
def test_members_with_their_own_budgets_update_when_their_own_episodes_are_in(monkeypatch, base):
    """No lockstep: seeds, learning rates and budgets differ, so collections end at different steps; a collect
    hands over only the members whose episodes are all in, and each member is still its single trial."""
    configs = [replace(c, max_episodes=b) for c, b in zip(_members(base), (48, 20, 36, 44), strict=True)]
    handed: list[list[int]] = []
    collect = StackedBackend.collect

    def recorded(self, counts, budgets):
        batches = collect(self, counts, budgets)
        handed.append(sorted(batches))
        return batches

    monkeypatch.setattr(StackedBackend, "collect", recorded)
    outcomes = run_population(configs)
    monkeypatch.undo()
    assert any(0 < len(slots) < 4 for slots in handed)  # members updated apart
    for config, outcome in zip(configs, outcomes, strict=True):
        alone = run_trial(config)
        assert len(outcome.episodes) == config.max_episodes
        assert [m[:7] for m in outcome.episodes] == [m[:7] for m in alone.episodes]
        for name, tensor in alone.state_dict.items():
            assert torch.equal(outcome.state_dict[name], tensor), name


def test_callbacks_are_per_member_and_in_order():
    seen: dict[int, list] = {}
    finished = []
    outcomes = run_population(
        _members(SHORT),
        on_episodes=lambda i, rows: seen.setdefault(i, []).extend(rows),
        on_outcome=lambda i, outcome: finished.append(i),
    )
    assert sorted(finished) == [0, 1, 2, 3]
    for i, outcome in enumerate(outcomes):
        assert [m.episode for m in seen[i]] == list(range(1, 49))
        assert seen[i] == outcome.episodes


def test_a_failing_member_fails_alone_and_one_that_solves_leaves_early():
    configs = _members(SHORT)
    configs[1] = replace(configs[1], fault="raise")
    configs[2] = replace(configs[2], solve_threshold=1.0, solve_window=8)  # solved when its window first fills
    order = []
    outcomes = run_population(configs, on_outcome=lambda i, outcome: order.append(i))
    assert isinstance(outcomes[1], TrialFailed) and "injected fault" in str(outcomes[1])
    assert isinstance(outcomes[2], TrialResult) and outcomes[2].episodes_to_solve == 8
    assert len(outcomes[2].episodes) == 8
    assert order[:2] == [1, 2]  # each left as it ended, not when the population did
    others = run_population([configs[0], configs[3]])
    for mine, theirs in zip((outcomes[0], outcomes[3]), others, strict=True):
        assert len(mine.episodes) == 48 and [m[:7] for m in mine.episodes] == [m[:7] for m in theirs.episodes]


def test_a_member_whose_weights_turn_nan_fails_alone(monkeypatch):
    update = StackedBackend.update

    def poisoned(self, batches):
        stats = update(self, batches)
        if len(self.configs) == 3 and 1 in batches:  # member 1's weights become NaN after its first update
            with torch.no_grad():
                self.model.params[0][1].fill_(float("nan"))
            self.model.refresh()
        return stats

    monkeypatch.setattr(StackedBackend, "update", poisoned)
    configs = _members(SHORT)[:3]
    outcomes = run_population(configs)
    assert isinstance(outcomes[1], TrialFailed) and "loss became nan at episode 16" in str(outcomes[1])
    assert "learning_rate (now 0.1)" in str(outcomes[1])
    others = run_population([configs[0], configs[2]])
    for mine, theirs in zip((outcomes[0], outcomes[2]), others, strict=True):
        assert len(mine.episodes) == 48 and [m[:7] for m in mine.episodes] == [m[:7] for m in theirs.episodes]


def test_a_killed_population_resumes_every_member_exactly():
    configs = [replace(c, checkpoint_every=16) for c in _members(DEEP)]
    blobs: dict[int, list[bytes]] = {}
    whole = run_population(configs, on_checkpoint=lambda i, blob: blobs.setdefault(i, []).append(blob))
    assert all(len(blobs[i]) == 2 for i in range(4))  # at 16 and 32 of 48 episodes
    replayed: dict[int, list] = {}
    resumed = run_population(
        configs,
        on_episodes=lambda i, rows: replayed.setdefault(i, []).append(rows),
        resume_from=[blobs[i][0] for i in range(4)],
    )
    for i, (a, b) in enumerate(zip(whole, resumed, strict=True)):
        assert [m[:7] for m in a.episodes] == [m[:7] for m in b.episodes]
        for name, tensor in a.state_dict.items():
            assert torch.equal(b.state_dict[name], tensor), (i, name)
        assert len(replayed[i][0]) == 16  # the saved history first, in one call


@pytest.mark.parametrize("base", [DEEP, CNN], ids=["dropout+l2", "cnn"])
def test_members_resume_from_different_points_beside_fresh_ones(base):
    """One member resumes from its first checkpoint, one from its second, two start afresh, all in one
    population: each collection in flight around them (the cnn's windows too), each member ends as its
    unbroken run."""
    configs = [replace(c, checkpoint_every=16) for c in _members(base)]
    blobs: dict[int, list[bytes]] = {}
    whole = run_population(configs, on_checkpoint=lambda i, blob: blobs.setdefault(i, []).append(blob))
    resumed = run_population(configs, resume_from=[blobs[0][0], None, blobs[2][1], None])
    for i, (a, b) in enumerate(zip(whole, resumed, strict=True)):
        assert [m[:7] for m in a.episodes] == [m[:7] for m in b.episodes], i
        for name, tensor in a.state_dict.items():
            assert torch.equal(b.state_dict[name], tensor), (i, name)
    alone = run_trial(configs[2], resume_from=blobs[2][0])  # a member's checkpoint resumes as a trial of its own
    assert [m[:7] for m in alone.episodes] == [m[:7] for m in whole[2].episodes]


def test_a_cartpole_trial_resumes_exactly_and_reads_the_old_collectors_checkpoints():
    config = replace(SHORT, checkpoint_every=16, episodes_per_update=2)
    blobs = []
    whole = run_trial(config, on_checkpoint=blobs.append)
    resumed = run_trial(config, resume_from=blobs[0])
    assert resumed.returns == whole.returns
    assert [m.loss for m in resumed.episodes] == [m.loss for m in whole.episodes]
    # A blob of the Gymnasium-env collector (no env streams): re-seeded from the episode count, as it resumed.
    saved = torch.load(__import__("io").BytesIO(blobs[0]), weights_only=False)
    saved["collector"] = {"reset_seed": None}
    buffer = __import__("io").BytesIO()
    torch.save(saved, buffer)
    legacy = run_trial(config, resume_from=buffer.getvalue())
    assert legacy.returns[:16] == whole.returns[:16] and len(legacy.episodes) == 48


def test_which_configs_share_a_population():
    assert can_share(_members(SHORT)) and can_share([replace(SHORT, gamma=0.9), replace(SHORT, l2=0.01)])
    assert not can_share([SHORT, replace(SHORT, episodes_per_update=4)])
    assert not can_share([SHORT, DEEP])
    assert can_share(_members(CNN)) and can_share(_members(GELU))
    assert not can_share([CNN, SHORT]) and not can_share([CNN, replace(CNN, model=replace(CNN.model, history=3))])
    with pytest.raises(ValueError, match="cannot share"):
        run_population([CNN, SHORT])
