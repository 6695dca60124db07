"""Acting: each stack gives every member the logits its own network gives, and a member's logits never depend on
who shares the stack."""

from __future__ import annotations

import numpy as np
import torch

from ablate.agent.acting import DenseStack, StemStack, stack
from ablate.agent.policies import create_pong_model


def _frames(n: int, density: float, seed: int) -> np.ndarray:
    """int8 frame differences (n, 1, 80, 80): each pixel -1 or +1 with probability ``density``, else 0."""
    rng = np.random.default_rng(seed)
    changed = rng.random((n, 1, 80, 80)) < density
    return (changed * rng.choice([-1, 1], (n, 1, 80, 80))).astype(np.int8)


def _pong(architecture: str, seed: int):
    torch.manual_seed(seed)
    model = create_pong_model(2, architecture=architecture)
    with torch.no_grad():  # biases of both signs: a zero bias would hide a missing background term
        for parameter in model.parameters():
            if parameter.dim() == 1:
                parameter.uniform_(-0.5, 0.5)
    return model.eval()


def _torch_logits(model, frames: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return model.body(model._input(torch.from_numpy(frames.astype(np.float32)))).numpy()


def test_pongs_cnn_acts_in_numpy_as_its_network_and_follows_an_update():
    models = [_pong("cnn", seed) for seed in range(3)]
    acting = stack(models, torch.device("cpu"), built_in=True, shape=models[0].observation_shape)
    assert isinstance(acting, StemStack)
    # Sparse frames (the numpy path), a dense one (the dense layers) and an empty one, for each member.
    frames = np.stack([np.concatenate([_frames(3, 0.01, m), _frames(1, 0.9, 9), np.zeros((1, 1, 80, 80), np.int8)])
                       for m in range(3)])  # fmt: skip
    logits = acting(frames)
    for m, model in enumerate(models):
        np.testing.assert_allclose(logits[m], _torch_logits(model, frames[m]), rtol=1e-5, atol=1e-5)
        alone = stack([model], torch.device("cpu"), built_in=True, shape=model.observation_shape)
        np.testing.assert_array_equal(alone(frames[m : m + 1])[0], logits[m])  # whoever shares the stack
    with torch.no_grad():
        models[1].body[0].bias.add_(0.25)  # the background changes: the member's numpy copy must follow
        models[1].body[2].weight.mul_(1.5)
    acting.refresh(1)
    np.testing.assert_allclose(acting(frames)[1], _torch_logits(models[1], frames[1]), rtol=1e-5, atol=1e-5)


def test_pongs_mlp_acts_on_int8_frames_as_sparse_products_equal_to_its_network():
    models = [_pong("mlp", seed) for seed in range(2)]
    acting = stack(models, torch.device("cpu"), built_in=True, shape=models[0].observation_shape)
    assert isinstance(acting, DenseStack)
    frames = np.stack([np.concatenate([_frames(3, 0.01, m), _frames(1, 0.9, 5)]) for m in range(2)])
    logits = acting(frames)
    for m, model in enumerate(models):
        np.testing.assert_allclose(logits[m], _torch_logits(model, frames[m]), rtol=1e-5, atol=1e-5)
        np.testing.assert_array_equal(DenseStack([model])(frames[m : m + 1])[0], logits[m])


def test_a_users_layernorm_mlp_acts_in_numpy_to_float_tolerance_and_a_member_as_alone():
    from pathlib import Path

    from ablate.agent.acting import MembersStack

    source = Path(__file__).parent.parent / "examples" / "models"
    namespace: dict = {}
    exec((source / "layernorm.py").read_text(), namespace)
    models = []
    for seed in range(3):
        torch.manual_seed(seed)
        model = namespace["create_model"]((4,), 2, width=16).eval()
        with torch.no_grad():  # a scale and shift of its own: the affine part must be each member's
            model[2].weight.uniform_(0.5, 1.5)
            model[2].bias.uniform_(-0.5, 0.5)
        models.append(model)
    acting = stack(models, torch.device("cpu"), built_in=False, shape=(4,))
    assert isinstance(acting, DenseStack)
    observations = np.random.default_rng(0).normal(size=(3, 5, 4)).astype(np.float32)
    logits = acting(observations)
    for m, model in enumerate(models):
        with torch.no_grad():
            expected = model(torch.from_numpy(observations[m])).numpy()
        np.testing.assert_allclose(logits[m], expected, rtol=1e-5, atol=1e-5)
        np.testing.assert_array_equal(DenseStack([model])(observations[m : m + 1])[0], logits[m])
    namespace = {}
    exec((source / "residual.py").read_text(), namespace)
    residual = [namespace["create_model"]((4,), 2) for _ in range(2)]
    acting = stack(residual, torch.device("cpu"), built_in=False, shape=(4,))
    assert isinstance(acting, MembersStack) and acting.members.swapped  # its own forward, stacked layers
    logits = acting(observations[:2])
    for m, model in enumerate(residual):
        with torch.no_grad():
            expected = model.eval()(torch.from_numpy(observations[m])).numpy()
        np.testing.assert_allclose(logits[m], expected, rtol=1e-5, atol=1e-5)
    with torch.no_grad():
        residual[1].head.bias.add_(0.5)  # an update: the member's stacked row must follow
    acting.refresh(1)
    np.testing.assert_allclose(acting(observations[:2])[1], logits[1] + 0.5, rtol=1e-5, atol=1e-5)


def test_another_atari_games_frames_act_through_the_cnns_own_forward():
    """An 84 x 84 frame difference that is not int8 (Gymnasium's AtariPreprocessing): the numpy stem reads only
    Pong's int8 frames, any other image goes through the network's forward (it failed with an IndexError)."""
    from ablate.agent.policies import nonzero

    torch.manual_seed(0)
    models = [create_pong_model(4, observation_shape=(1, 84, 84)).eval() for _ in range(2)]
    acting = stack(models, torch.device("cpu"), built_in=True, shape=models[0].observation_shape)
    frames = np.random.default_rng(0).normal(size=(2, 3, 1, 84, 84)).astype(np.float32)
    logits = acting(frames)
    for m, model in enumerate(models):
        np.testing.assert_allclose(logits[m], _torch_logits(model, frames[m]), rtol=1e-5, atol=1e-5)
    wide = np.zeros((2, 16), np.int16)
    wide[1, 3] = 300
    assert [list(a) for a in nonzero(wide)] == [[1], [3]]
