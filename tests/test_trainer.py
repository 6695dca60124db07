"""The one trainer: a member is its single trial, bit for bit (episodes, losses, gradients, weights), a member
that fails or solves early leaves the others untouched, a killed population resumes each member exactly."""

import io
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from ablate.agent.population import PACK_SHARE, Population
from ablate.agent.records import TrialFailed, TrialResult
from ablate.agent.trainer import run_population, run_trial
from ablate.config import DEFAULT, ModelConfig, apply_knobs, can_share
from ablate.envs import describe

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


CUSTOM = Path(__file__).parent.parent / "examples" / "models" / "residual.py"


def _custom(**overrides):
    """A user's network (an MLP with a residual block, from a file, its own ``forward``)."""
    config = apply_knobs(SHORT, {"model": f"{CUSTOM}:create_model", "model_args": {"width": 16}})
    return replace(config, **overrides)


@pytest.mark.parametrize("base", EXACT, ids=EXACT_IDS)
def test_a_population_of_one_is_its_single_trial_bit_for_bit(base):
    """run_trial is run_population of one, bit for bit: episodes, losses, entropies, final weights."""
    config = replace(base, seed=5)
    [member] = run_population([config])
    alone = run_trial(config)
    assert [m[:7] for m in member.episodes] == [m[:7] for m in alone.episodes]
    for name, tensor in alone.state_dict.items():
        assert torch.equal(member.state_dict[name], tensor), name


def test_a_custom_member_equals_its_population_of_one_to_float_tolerance_in_its_first_update():
    """A user's network in a population of four and alone: the same episodes (their actions differ only if a float
    difference flips a sampled action) and the same first update, to float tolerance."""
    configs = [_custom(seed=s, max_episodes=8) for s in range(4)]
    together = run_population(configs)
    for config, member in zip(configs, together, strict=True):
        alone = run_trial(config)
        first, theirs = member.episodes[0], alone.episodes[0]
        assert first.episode_return == theirs.episode_return
        assert first.loss == pytest.approx(theirs.loss, rel=1e-5, abs=1e-7)
        for name, tensor in alone.state_dict.items():
            torch.testing.assert_close(member.state_dict[name], tensor, rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_a_custom_network_learns_alike_in_a_population_of_30_and_alone():
    """30 seeds of a user's network, once as one population and once each alone: the same distribution of AUC
    and of episodes to solve (two-sample Mann-Whitney tests at 1%)."""
    from scipy.stats import mannwhitneyu

    configs = [_custom(seed=s, max_episodes=160) for s in range(30)]
    together = run_population(configs)
    alone = [run_trial(c) for c in configs]
    for key in ("auc", "episodes_run"):
        a = [r.summary()[key] for r in together]
        b = [r.summary()[key] for r in alone]
        assert mannwhitneyu(a, b).pvalue > 0.01, key
    assert len({r.summary()["auc"] for r in together}) > 20  # 30 different runs, not one repeated


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
    step = Population.step

    def recorded(self):
        ready = step(self)
        if ready:
            handed.append(ready)
        return ready

    monkeypatch.setattr(Population, "step", recorded)
    outcomes = run_population(configs)
    monkeypatch.undo()
    assert any(0 < len(slots) < 4 for slots in handed)  # members updated apart
    for config, outcome in zip(configs, outcomes, strict=True):
        alone = run_trial(config)
        assert len(outcome.episodes) == config.max_episodes
        assert [m[:7] for m in outcome.episodes] == [m[:7] for m in alone.episodes]
        for name, tensor in alone.state_dict.items():
            assert torch.equal(outcome.state_dict[name], tensor), name


@pytest.mark.parametrize("base", [SHORT, CNN, replace(SHORT, num_envs=4)], ids=["dense", "cnn", "continuous"])
def test_members_that_left_idle_in_their_rows_until_packed_and_the_others_run_as_alone(monkeypatch, base):
    """Nine members leave one after another (one fails at its first update, the others at their own budgets):
    those that left keep their rows (slots resting, weights zeroed) until they hold ``PACK_SHARE`` of the rows,
    then the others are packed into new arrays; every member is still its single trial, bit for bit."""
    configs = [replace(base, seed=s, max_episodes=8 * s + 10) for s in range(9)]  # the last update: 2 episodes
    configs[4] = replace(configs[4], fault="raise")
    for s in (7, 8):  # solved mid-budget: continuous slots still play as they leave
        configs[s] = replace(configs[s], solve_threshold=25.0, solve_window=4)
    packs: list[tuple[int, int, int]] = []
    pack, leave = Population._pack, Population.leave

    def idle(self):
        for position in self.left:  # until packed: no slot steps, no parameter acts
            assert not self.stepping[self.slots_of(position)].any()
            assert not self.network.flat[position].any()

    def recorded(self, positions):
        idle(self)
        packs.append((len(self.members), len(self.left), len(positions)))
        pack(self, positions)

    def resting(self, positions):
        leave(self, positions)
        idle(self)

    monkeypatch.setattr(Population, "_pack", recorded)
    monkeypatch.setattr(Population, "leave", resting)
    outcomes = run_population(configs)
    monkeypatch.undo()
    assert packs[0] == (9, 3, 6)  # the first two to leave idled in their rows; the third packed the six left
    assert all(rows - left == kept and left >= PACK_SHARE * rows for rows, left, kept in packs)
    assert isinstance(outcomes[4], TrialFailed)
    for config, outcome in zip(configs, outcomes, strict=True):
        if config.fault:
            continue
        alone = run_trial(config)
        assert outcome.episodes_to_solve == alone.episodes_to_solve
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
    update = Population.update

    def poisoned(self, batches):
        stats = update(self, batches)
        for position in batches:
            if len(self.members) == 3 and self.members[position].index == 1:  # NaN weights after its first update
                with torch.no_grad():
                    self.network.flat[position, :3] = float("nan")
        return stats

    monkeypatch.setattr(Population, "update", poisoned)
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


def test_a_cartpole_trial_resumes_exactly_and_an_earlier_trainers_checkpoint_starts_afresh():
    config = replace(SHORT, checkpoint_every=16, episodes_per_update=2)
    blobs = []
    whole = run_trial(config, on_checkpoint=blobs.append)
    resumed = run_trial(config, resume_from=blobs[0])
    assert resumed.returns == whole.returns
    assert [m.loss for m in resumed.episodes] == [m.loss for m in whole.episodes]
    saved = torch.load(io.BytesIO(blobs[0]), weights_only=False)
    saved["version"] = 1  # the stacked trainer's checkpoints: no slots to restore from
    buffer = io.BytesIO()
    torch.save(saved, buffer)
    assert [m[:7] for m in run_trial(config, resume_from=buffer.getvalue()).episodes] == [m[:7] for m in whole.episodes]


def test_which_configs_share_a_population():
    assert can_share(_members(SHORT)) and can_share([replace(SHORT, gamma=0.9), replace(SHORT, l2=0.01)])
    assert not can_share([SHORT, replace(SHORT, episodes_per_update=4)])
    assert not can_share([SHORT, DEEP])
    assert can_share(_members(CNN)) and can_share(_members(GELU))
    assert not can_share([CNN, SHORT]) and not can_share([CNN, replace(CNN, model=replace(CNN.model, history=3))])
    with pytest.raises(ValueError, match="cannot share"):
        run_population([CNN, SHORT])


def test_continuous_slots_draw_one_uniform_per_playing_slot_and_a_resting_one_draws_none():
    """Pong's rule (``num_envs`` set): each step a member draws a uniform for each slot still playing, in slot
    order; a slot that rests near the end of the budget draws none (as a loop over the playing emulators)."""
    import numpy as np

    config = replace(SHORT, num_envs=4, seed=5)
    population = Population([config, replace(config, seed=6)], describe(config), torch.device("cpu"), [None, None])
    for position in range(2):
        population.start(position)
    population.set_counting(0, population.slots_of(0)[[1, 3]])  # member 0: two slots rest
    first, second = (np.random.default_rng(s) for s in (5, 6))
    uniforms = population._uniforms()
    np.testing.assert_array_equal(uniforms[0, [1, 3]], first.random(2))
    assert uniforms[0, 0] == uniforms[0, 2] == 0
    np.testing.assert_array_equal(uniforms[1], second.random(4))
    # The streams moved by exactly what was drawn: the next draws continue them.
    assert population.members[0].actions_rng.random() == first.random()
    assert population.members[1].actions_rng.random() == second.random()
    population.close()


@pytest.mark.parametrize("base", [SHORT, CNN], ids=["dense", "cnn"])
def test_the_batched_update_a_gpu_takes_is_each_members_own_update_to_float_tolerance(base):
    """On a GPU the members ready at one step update in one pass (``update_groups``: their batches padded to the
    longest); on a CPU each in its own. Run here on the CPU, the batched pass moves each member as its own pass
    does: its weights, Adam's state after the step, its loss and entropy, to float tolerance."""
    configs = [
        replace(base, seed=s, learning_rate=lr, l2=l2) for s, lr, l2 in ((0, 0.03, 0.0), (1, 0.1, 1e-3), (2, 0.01, 0.0))
    ]
    populations = [Population(configs, describe(configs[0]), torch.device("cpu"), [None] * 3) for _ in range(2)]
    batches = []
    for population in populations:  # the same seeds, the same collections: each member's first batch
        for position in range(3):
            population.start(position)
        ready: set[int] = set()
        while len(ready) < 3:
            ready.update(population.step())
        batches.append({p: population.batch(population.members[p]) for p in range(3)})
    assert len({len(b.actions) for b in batches[0].values()}) > 1  # batches of different lengths: padding is used
    before = populations[0].network.flat.detach().clone()
    together = populations[0].update(batches[0])
    alone = {}
    for position in range(3):
        alone |= populations[1].update({position: batches[1][position]})
    for position in range(3):
        assert together[position] == pytest.approx(alone[position], rel=1e-5, abs=1e-7)
    torch.testing.assert_close(populations[0].network.flat, populations[1].network.flat, rtol=1e-5, atol=1e-6)
    assert all(bool((populations[0].network.flat[m] != before[m]).any()) for m in range(3))  # every member stepped
    for position in range(3):
        first, second = (p.optimizer.state_dict(position) for p in populations)
        for key, value in first.items():
            if isinstance(value, torch.Tensor):
                torch.testing.assert_close(value, second[key], rtol=1e-5, atol=1e-6)
    for population in populations:
        population.close()
