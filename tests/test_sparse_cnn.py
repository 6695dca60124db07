"""The sparse first two convolutions of Pong's CNN are the dense network's function: forward and gradients."""

import pytest
import torch

from ablate.agent import sparse_cnn
from ablate.agent.policies import _nonzero_rows_columns, create_pong_model


def _frames(n: int, density: float, seed: int) -> torch.Tensor:
    """int8 frame differences (n, 1, 80, 80): each pixel -1 or +1 with probability ``density``, else 0."""
    generator = torch.Generator().manual_seed(seed)
    changed = torch.rand(n, 1, 80, 80, generator=generator) < density
    signs = torch.randint(0, 2, (n, 1, 80, 80), generator=generator) * 2 - 1
    return (changed * signs).to(torch.int8)


def _model(activation: str = "relu", hidden_sizes=(64,), seed: int = 0):
    torch.manual_seed(seed)
    model = create_pong_model(6, hidden_sizes, activation, architecture="cnn")
    # Biases of both signs and away from zero: a zero bias would hide a missing background term.
    with torch.no_grad():
        for parameter in model.parameters():
            if parameter.dim() == 1:
                parameter.uniform_(-0.5, 0.5)
    return model


def _dense(model, frames: torch.Tensor) -> torch.Tensor:
    return model.body(model._input(frames))


def _gradients(model, logits: torch.Tensor) -> list[torch.Tensor]:
    model.zero_grad(set_to_none=True)
    # A weighted sum, so every logit's gradient differs (a plain sum would test less).
    (logits * torch.linspace(-1, 1, logits.shape[1])).sum().backward()
    return [p.grad.clone() for p in model.parameters()]


@pytest.mark.parametrize(("activation", "hidden_sizes"), [("relu", (64,)), ("tanh", (32, 16)), ("elu", (64,))])
@pytest.mark.parametrize("density", [0.002, 0.01, 0.05])
def test_sparse_path_equals_the_dense_convolutions_forward_and_gradients(activation, hidden_sizes, density):
    model = _model(activation, hidden_sizes)
    assert model._sparse_stem is not None
    frames = _frames(32, density, seed=int(density * 1000))
    dense = _dense(model, frames)
    sparse = model(frames)
    torch.testing.assert_close(sparse, dense, rtol=1e-5, atol=1e-5)
    for got, expected in zip(_gradients(model, model(frames)), _gradients(model, _dense(model, frames)), strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-5)


def test_sparse_stem_on_an_all_zero_and_a_dense_frame():
    """The stem itself (below the policy's fall-back to the dense body for dense frames): a frame with no change
    is the background everywhere; a frame of all non-zero pixels still gives the dense result."""
    model = _model()
    frames = torch.cat([torch.zeros(1, 1, 80, 80, dtype=torch.int8), _frames(1, 1.0, seed=3)])
    x = frames.reshape(2, -1)
    rows, columns = _nonzero_rows_columns(x)
    stem = model._sparse_stem(x, rows, columns)
    expected = model.body[:3](model._input(frames))
    torch.testing.assert_close(stem, expected, rtol=1e-4, atol=1e-4)
    model.zero_grad(set_to_none=True)
    model.body[3:](stem).sum().backward()
    got = [p.grad.clone() for p in model.parameters()]
    model.zero_grad(set_to_none=True)
    _dense(model, frames).sum().backward()
    for g, e in zip(got, [p.grad for p in model.parameters()], strict=True):
        torch.testing.assert_close(g, e, rtol=1e-4, atol=1e-4)


def test_policy_falls_back_to_the_dense_body_for_a_dense_frame_and_takes_an_all_zero_one():
    model = _model()
    frames = torch.cat([_frames(1, 0.9, seed=4), torch.zeros(1, 1, 80, 80, dtype=torch.int8)])
    torch.testing.assert_close(model(frames), _dense(model, frames), rtol=1e-5, atol=1e-5)


def test_taps_tables_match_the_convolution_arithmetic():
    """Input position p of a 20 x 20 map under 5 x 5 stride 2 padding 2 feeds output o through offset k exactly
    when p = stride * o - padding + k along each axis."""
    outputs, offsets, side = sparse_cnn._taps(20, 5, 2, 2)
    assert side == 10
    for position in (0, 21, 210, 399):
        y, x = divmod(position, 20)
        expected = {
            (oy * 10 + ox, (y - 2 * oy + 2) * 5 + (x - 2 * ox + 2))
            for oy in range(10)
            for ox in range(10)
            if 0 <= y - 2 * oy + 2 < 5 and 0 <= x - 2 * ox + 2 < 5
        }
        got = {(int(o), int(k)) for o, k in zip(outputs[position], offsets[position], strict=True) if o >= 0}
        assert got == expected


def test_only_the_courses_kind_of_body_takes_the_sparse_path():
    assert create_pong_model(architecture="cnn")._sparse_stem is not None
    assert create_pong_model(architecture="mlp")._sparse_stem is None
