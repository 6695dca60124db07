"""The REINFORCE core, checked against values computed by hand."""

import numpy as np
import pytest
import torch

from ablate.agent.policies import create_cartpole_model
from ablate.agent.reinforce import (
    Memory,
    choose_action,
    compute_loss,
    discount_rewards,
    l2_penalty,
    normalize,
    train_step,
)


def test_memory_adds_in_order_and_clears():
    memory = Memory()
    memory.add_to_memory(np.array([1.0, 2.0]), 1, 1.0)
    memory.add_to_memory(np.array([3.0, 4.0]), 0, 0.5)
    assert len(memory) == 2
    assert memory.actions == [1, 0]
    assert memory.rewards == [1.0, 0.5]
    np.testing.assert_array_equal(memory.observations[1], [3.0, 4.0])
    memory.clear()
    assert len(memory) == 0 and memory.observations == [] and memory.rewards == []


def test_discount_rewards_by_hand():
    # G2 = 1; G1 = 1 + 0.5 * 1 = 1.5; G0 = 1 + 0.5 * 1.5 = 1.75
    np.testing.assert_allclose(discount_rewards([1, 1, 1], gamma=0.5), [1.75, 1.5, 1.0])
    # gamma = 0.95 over four steps of reward 1
    g3 = 1.0
    g2 = 1 + 0.95 * g3
    g1 = 1 + 0.95 * g2
    g0 = 1 + 0.95 * g1
    np.testing.assert_allclose(discount_rewards([1, 1, 1, 1], gamma=0.95), [g0, g1, g2, g3])


def test_discount_rewards_resets_at_every_point_scored():
    rewards = [0, 0, 1, 0, -1]
    # plain: the -1 of the second rally leaks into the first
    # G4 = -1; G3 = 0 + 0.5 * -1 = -0.5; G2 = 1 + 0.5 * -0.5 = 0.75; G1 = 0.375; G0 = 0.1875
    np.testing.assert_allclose(discount_rewards(rewards, gamma=0.5), [0.1875, 0.375, 0.75, -0.5, -1])
    # Pong: the running return restarts at each non-zero reward, scanning backwards
    np.testing.assert_allclose(discount_rewards(rewards, gamma=0.5, reset_on_nonzero=True), [0.25, 0.5, 1, -0.5, -1])


def test_normalize_has_zero_mean_unit_std():
    x = normalize(np.array([1.0, 2.0, 3.0, 4.0]))
    assert abs(x.mean()) < 1e-6 and abs(x.std() - 1) < 1e-6


def test_normalize_constant_returns_is_finite_zero():
    x = normalize(np.full(7, 3.0))
    assert np.all(np.isfinite(x)) and np.all(x == 0)


def test_compute_loss_is_weighted_cross_entropy_by_hand():
    logits = torch.tensor([[1.0, 2.0], [0.5, -0.5]])
    actions = torch.tensor([1, 0])
    weights = torch.tensor([2.0, -1.0])
    # -log softmax(taken): row 0 takes logit 2 of (1, 2); row 1 takes 0.5 of (0.5, -0.5)
    ce0 = -(2.0 - np.log(np.exp(1.0) + np.exp(2.0)))
    ce1 = -(0.5 - np.log(np.exp(0.5) + np.exp(-0.5)))
    expected = (ce0 * 2.0 + ce1 * -1.0) / 2
    assert compute_loss(logits, actions, weights).item() == pytest.approx(expected, rel=1e-6)


def _fixed_batch():
    rng = np.random.default_rng(0)
    observations = rng.normal(size=(64, 4)).astype(np.float32)
    actions = (observations[:, 0] > 0).astype(np.int64)
    weights = np.ones(64, dtype=np.float32)
    return observations, actions, weights


def test_train_step_changes_weights_and_lowers_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    model = create_cartpole_model(hidden_sizes=(16,))
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)
    observations, actions, weights = _fixed_batch()
    before = [p.detach().clone() for p in model.parameters()]
    first = train_step(model, optimizer, observations, actions, weights)
    assert any(not torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))
    for _ in range(30):
        last = train_step(model, optimizer, observations, actions, weights)
    assert last.loss < first.loss * 0.8
    assert 0 < last.entropy < np.log(2) + 1e-6


def test_l2_is_a_loss_term_over_weights_only():
    model = create_cartpole_model(hidden_sizes=(3,))
    with torch.no_grad():
        for name, p in model.named_parameters():
            p.fill_(2.0 if name.endswith("weight") else 100.0)
    # weights: 4x3 + 3x2 = 18 entries of 2.0 -> 18 * 4 = 72; biases are not counted
    assert l2_penalty(model).item() == pytest.approx(72.0)
    optimizer = torch.optim.SGD(model.parameters(), lr=0.0)
    observations, actions, weights = _fixed_batch()
    plain = train_step(model, optimizer, observations, actions, weights, l2=0.0)
    penalised = train_step(model, optimizer, observations, actions, weights, l2=0.1)
    assert penalised.loss == pytest.approx(plain.loss)  # the reported loss is the policy loss alone


def test_choose_action_samples_with_softmax_frequencies():
    model = create_cartpole_model(hidden_sizes=())
    with torch.no_grad():
        model.body[0].weight.zero_()
        model.body[0].bias.copy_(torch.tensor([0.0, np.log(3.0)]))  # softmax -> (0.25, 0.75)
    rng = np.random.default_rng(123)
    actions = choose_action(model, np.zeros((20_000, 4), np.float32), rng, single=False)
    assert actions.shape == (20_000,)
    assert abs(actions.mean() - 0.75) < 0.01
    single = [choose_action(model, np.zeros(4, np.float32), rng) for _ in range(2000)]
    assert all(isinstance(a, int) for a in single)
    assert abs(np.mean(single) - 0.75) < 0.03
    assert choose_action(model, np.zeros(4, np.float32), greedy=True) == 1


def test_choose_action_is_reproducible_with_a_seeded_generator():
    torch.manual_seed(1)
    model = create_cartpole_model()
    obs = np.random.default_rng(0).normal(size=(50, 4)).astype(np.float32)
    a = choose_action(model, obs, np.random.default_rng(7), single=False)
    b = choose_action(model, obs, np.random.default_rng(7), single=False)
    np.testing.assert_array_equal(a, b)


def test_chunks_cover_the_batch_in_a_bounded_set_of_shapes():
    from ablate.agent.reinforce import _chunks

    shapes = set()
    for total in range(1, 5000):
        chunks = _chunks(total, 1024)
        assert chunks[0][0] == 0 and chunks[-1][1] == total
        assert all(a[1] == b[0] for a, b in zip(chunks, chunks[1:], strict=False))  # contiguous, in order
        shapes |= {end - start for start, end in chunks}
    # 1024, 512, 256, 128, 64 and the rests under 64: a trial's updates meet these shapes and no others.
    assert shapes == {1024, 512, 256, 128, 64} | set(range(1, 64))
    assert _chunks(1383, 1024) == [(0, 1024), (1024, 1280), (1280, 1344), (1344, 1383)]
    assert _chunks(10, None) == [(0, 10)]


def test_train_step_in_chunks_sums_the_same_gradient_as_one_pass():
    from ablate.agent.policies import create_pong_model

    rng = np.random.default_rng(0)
    observations = rng.choice(np.array([-1, 0, 0, 0, 1], np.int8), (150, 1, 80, 80))
    actions = rng.integers(0, 2, 150)
    returns = rng.standard_normal(150).astype(np.float32)
    results = []
    for chunk_size in (None, 64):  # 64 + 64 + 22
        torch.manual_seed(0)
        model = create_pong_model(2, (16,), architecture="cnn")
        optimizer = torch.optim.SGD(model.parameters(), lr=0.0)  # the step leaves the gradients to compare
        stats = train_step(model, optimizer, observations, actions, returns, chunk_size=chunk_size)
        results.append((stats, [p.grad.clone() for p in model.parameters()]))
    assert results[0][0].loss == pytest.approx(results[1][0].loss, rel=1e-5)
    assert results[0][0].entropy == pytest.approx(results[1][0].entropy, rel=1e-5)
    for one, chunked in zip(results[0][1], results[1][1], strict=True):
        torch.testing.assert_close(one, chunked, rtol=1e-4, atol=1e-7)


def test_discount_rewards_equals_the_float64_recursion_bit_for_bit():
    rng = np.random.default_rng(0)
    for gamma in (0.9, 0.95, 0.99):
        for rewards in (rng.normal(size=300).astype(np.float32), np.ones(500, np.float32), np.ones(1)):
            expected, running = np.zeros(len(rewards)), 0.0
            for t in range(len(rewards) - 1, -1, -1):
                running = float(rewards[t]) + gamma * running
                expected[t] = running
            np.testing.assert_array_equal(discount_rewards(rewards, gamma), expected)


def test_two_action_sampling_is_the_general_rule_exactly():
    from ablate.agent.reinforce import sample_actions

    rng = np.random.default_rng(1)
    logits = rng.normal(size=(4, 64, 2)).astype(np.float32) * 3
    uniforms = rng.random((4, 64))
    padded = np.concatenate([logits, np.full((4, 64, 1), -np.inf, np.float32)], axis=-1)  # a third, never taken
    np.testing.assert_array_equal(sample_actions(logits, uniforms), sample_actions(padded, uniforms))


@pytest.mark.parametrize("reset_on_nonzero", [False, True])
def test_discount_rewards_of_episodes_back_to_back_is_each_discounted_alone(reset_on_nonzero):
    rng = np.random.default_rng(1)
    cases = [
        [np.ones(5), np.ones(1), np.ones(40)],  # CartPole's constant reward: the table's path
        [rng.choice([-1.0, 0.0, 1.0], size=n) for n in (30, 3, 17)],  # Pong's points
        [rng.normal(size=n) for n in (4, 9)],
    ]
    for episodes in cases:
        lengths = np.array([len(e) for e in episodes])
        together = discount_rewards(np.concatenate(episodes), 0.95, reset_on_nonzero, lengths=lengths)
        alone = np.concatenate([discount_rewards(e, 0.95, reset_on_nonzero) for e in episodes])
        np.testing.assert_array_equal(together, alone)
