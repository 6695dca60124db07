"""Sparse kernels: each is the dense layers' function to float rounding, forward and backward, and a population
of Pong networks on frame differences gets each member's own module's logits and gradients through them."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from ablate.agent import sparse
from ablate.agent.policies import create_pong_model
from ablate.agent.stacking import Members


def _frames(count: int, size: int = 80, seed: int = 0) -> torch.Tensor:
    """Frame differences: a few dozen pixels of -1 or 1, the rest 0 (float32, as a network receives them)."""
    generator = torch.Generator().manual_seed(seed)
    frames = torch.zeros(count, size * size)
    for row in frames:
        where = torch.randperm(size * size, generator=generator)[:40]
        row[where] = torch.randint(0, 2, (40,), generator=generator).float() * 2 - 1
    return frames.reshape(count, 1, size, size)


def test_a_wide_linear_takes_the_sparse_kernel_for_an_updates_rows(monkeypatch):
    calls = []
    linear = sparse.linear
    monkeypatch.setattr(sparse, "linear", lambda *a: calls.append(1) or linear(*a))
    torch.manual_seed(0)
    model = create_pong_model(n_actions=3, architecture="mlp")
    members = Members([model], torch.device("cpu"), [0]).train()
    x = _frames(sparse.ROWS, seed=2)
    logits = members(x[None], torch.tensor([0]))
    torch.testing.assert_close(logits[0], model(x), rtol=1e-4, atol=1e-5)
    assert calls == [1]


def test_a_sparse_linear_is_the_dense_one_forward_and_backward():
    x = _frames(5).reshape(5, -1)
    assert sparse.sparse(x) and not sparse.sparse(torch.ones(3, 4))
    torch.manual_seed(0)
    layer = nn.Linear(x.shape[1], 7)
    dense = layer(x)
    dense.square().sum().backward()
    expected = [p.grad.clone() for p in layer.parameters()]
    layer.zero_grad()
    out = sparse.linear(x, layer.weight.t().contiguous(), layer.bias)
    out.square().sum().backward()
    torch.testing.assert_close(out, dense, rtol=1e-5, atol=1e-6)
    for got, want in zip([p.grad for p in layer.parameters()], expected, strict=True):
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)


def test_the_sparse_stem_is_conv_act_conv_forward_and_backward():
    torch.manual_seed(0)
    conv1, conv2 = nn.Conv2d(1, 16, 7, stride=4, padding=3), nn.Conv2d(16, 32, 5, stride=2, padding=2)
    x = _frames(3)
    dense = conv2(F.relu(conv1(x)))
    dense.square().sum().backward()
    expected = [p.grad.clone() for p in (*conv1.parameters(), *conv2.parameters())]
    for p in (*conv1.parameters(), *conv2.parameters()):
        p.grad = None
    stem = sparse.Stem(80, (7, 4, 3), (5, 2, 2), F.relu)
    out = stem(x.reshape(3, -1), conv1.weight, conv1.bias, conv2.weight, conv2.bias)
    out.square().sum().backward()
    torch.testing.assert_close(out, dense, rtol=1e-4, atol=1e-5)
    for p, want in zip((*conv1.parameters(), *conv2.parameters()), expected, strict=True):
        torch.testing.assert_close(p.grad, want, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("architecture", ["cnn", "mlp"])
def test_pong_members_on_frame_differences_get_their_own_modules_logits_and_gradients(architecture, monkeypatch):
    calls = []
    linear, stem = sparse.linear, sparse.Stem.__call__
    monkeypatch.setattr(sparse, "linear", lambda *a: calls.append("linear") or linear(*a))
    monkeypatch.setattr(sparse.Stem, "__call__", lambda *a, **k: calls.append("stem") or stem(*a, **k))
    models = []
    for seed in range(2):
        torch.manual_seed(seed)
        models.append(create_pong_model(n_actions=3, architecture=architecture))
    members = Members(models, torch.device("cpu"), range(2))
    x = _frames(2 * sparse.ROWS, seed=1).reshape(2, sparse.ROWS, 1, 80, 80)
    with torch.no_grad():
        logits = members(x)  # acting: every member
    for m, model in enumerate(models):
        torch.testing.assert_close(logits[m], model.eval()(x[m]), rtol=1e-4, atol=1e-5)
    members.train()
    members(x[1:], torch.tensor([1])).square().sum().backward()  # one member's update
    models[1].zero_grad()
    models[1].train()(x[1]).square().sum().backward()
    expected = torch.cat([p.grad.reshape(-1) for p in models[1].parameters()])
    torch.testing.assert_close(members.flat.grad[1], expected, rtol=1e-4, atol=1e-5)
    assert torch.count_nonzero(members.flat.grad[0]) == 0
    # an update's many rows (and as many acting): the stem for both members acting and the one updating, the
    # linear for each member's rows
    assert calls.count("stem" if architecture == "cnn" else "linear") == 3
