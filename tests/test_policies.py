"""Policy networks: shapes, the ablation knobs, logits (no softmax)."""

import torch
from torch import nn

from ablate.agent.policies import create_cartpole_model, create_pong_model, parameter_count


def test_cartpole_mlp_depth_width_dropout():
    model = create_cartpole_model(hidden_sizes=(64, 32), activation="tanh", dropout=0.1)
    linears = [m for m in model.modules() if isinstance(m, nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(4, 64), (64, 32), (32, 2)]
    assert sum(isinstance(m, nn.Dropout) for m in model.modules()) == 2
    assert sum(isinstance(m, nn.Tanh) for m in model.modules()) == 2
    assert parameter_count(model) == 4 * 64 + 64 + 64 * 32 + 32 + 32 * 2 + 2
    assert model(torch.zeros(5, 4)).shape == (5, 2)


def test_cartpole_outputs_logits_not_probabilities():
    torch.manual_seed(0)
    out = create_cartpole_model()(torch.randn(100, 4) * 10)
    assert not torch.allclose(out.sum(dim=1), torch.ones(100))
    assert (out < 0).any()


def test_cartpole_cnn_reads_a_window_of_observations():
    model = create_cartpole_model(architecture="cnn", history=6, conv_channels=(8, 8), kernel_size=3)
    assert model.observation_shape == (6, 4)
    assert model(torch.zeros(3, 6, 4)).shape == (3, 2)
    assert any(isinstance(m, nn.Conv1d) for m in model.modules())


def test_pong_models():
    cnn = create_pong_model()
    assert cnn(torch.zeros(2, 1, 80, 80)).shape == (2, 6)
    assert sum(isinstance(m, nn.Conv2d) for m in cnn.modules()) == 3
    mlp = create_pong_model(architecture="mlp", hidden_sizes=(200,))
    assert mlp(torch.zeros(2, 1, 80, 80)).shape == (2, 6)
    assert parameter_count(mlp) == 6400 * 200 + 200 + 200 * 6 + 6


def test_pong_mlp_sparse_forward_matches_dense_in_value_and_gradient():
    import numpy as np

    torch.manual_seed(0)
    mlp = create_pong_model(n_actions=2, architecture="mlp", hidden_sizes=(16, 8))
    x = np.zeros((5, 1, 80, 80), np.int8)
    rng = np.random.default_rng(1)
    for i in (0, 1, 3, 4):  # observation 2 stays all zeros: an empty bag
        x[i].reshape(-1)[rng.integers(0, 6400, 40)] = rng.choice(np.array([-1, 1], np.int8), 40)
    weights = torch.linspace(-1, 1, 10).reshape(5, 2)
    grads = []
    for inputs in (torch.from_numpy(x), torch.from_numpy(x.astype(np.float32))):
        mlp.zero_grad()
        logits = mlp(inputs)
        (logits * weights).sum().backward()
        grads.append((logits.detach(), [p.grad.clone() for p in mlp.parameters()]))
    torch.testing.assert_close(grads[0][0], grads[1][0])
    for sparse, dense in zip(grads[0][1], grads[1][1], strict=True):
        torch.testing.assert_close(sparse, dense)


def test_word_scan_nonzero_equals_torch_nonzero_in_order():
    from ablate.agent.policies import _nonzero_rows_columns

    x = torch.zeros(4, 64, dtype=torch.int8)
    x[0, [0, 7, 8, 63]] = torch.tensor([1, -1, 1, -1], dtype=torch.int8)  # both ends of words and of the row
    x[2, 9:20] = 1  # several bytes of one word, spilling into the next; rows 1 and 3 stay empty
    for got, expected in zip(_nonzero_rows_columns(x), x.nonzero(as_tuple=True), strict=True):
        assert torch.equal(got, expected)


def test_numpy_conv1d_matches_torch_and_a_stack_is_each_member_alone_exactly():
    import numpy as np

    from ablate.agent.policies import conv1d, conv1d_weight

    rng = np.random.default_rng(0)
    x = rng.normal(size=(3, 7, 4, 5)).astype(np.float32)  # 3 members, 7 envs, 4 channels, 5 steps
    weight = rng.normal(size=(3, 6, 4, 2)).astype(np.float32)
    bias = rng.normal(size=(3, 6)).astype(np.float32)
    stacked = conv1d(x, conv1d_weight(weight), bias[:, None, :])
    assert stacked.shape == (3, 7, 6, 4) and stacked.flags.c_contiguous
    for i in range(3):
        alone = conv1d(x[i], conv1d_weight(weight[i]), bias[i])
        np.testing.assert_array_equal(stacked[i], alone)  # bit for bit: how a population acts as its trials
        expected = torch.nn.functional.conv1d(*(torch.from_numpy(a) for a in (x[i], weight[i], bias[i])))
        np.testing.assert_allclose(alone, expected.numpy(), rtol=1e-5, atol=1e-6)


def test_layer_norm_knob_builds_a_layer_norm_before_each_hidden_activation_and_acts_in_the_dense_stack():
    from dataclasses import replace

    import numpy as np

    from ablate.agent.acting import DenseStack
    from ablate.agent.envs import describe
    from ablate.agent.models import build_model
    from ablate.config import DEFAULT, apply_knobs
    from ablate.launch.grid import trial_key
    from ablate.reporting.sections import architecture

    config = apply_knobs(DEFAULT, {"hidden_sizes": [16, 8], "layer_norm": True})
    torch.manual_seed(0)
    model = build_model(config, describe(config))
    kinds = [type(m).__name__ for m in model.body]
    assert kinds == ["Linear", "LayerNorm", "ReLU", "Linear", "LayerNorm", "ReLU", "Linear"]
    pong = create_pong_model(architecture="mlp", hidden_sizes=(8,), layer_norm=True)
    assert sum(isinstance(m, nn.LayerNorm) for m in pong.modules()) == 1
    assert DenseStack.fits(model)  # acts with the built-in networks' fast path, not a fallback
    observations = torch.randn(2, 5, 4)
    with torch.no_grad():
        expected = model(observations.reshape(-1, 4)).reshape(2, 5, 2)
    stacked = DenseStack([model, model])(observations.numpy())
    np.testing.assert_allclose(stacked, expected.numpy(), rtol=1e-5, atol=1e-5)
    assert trial_key("v", replace(config, model=replace(config.model, layer_norm=False))) != trial_key("v", config)
    assert "LayerNorm" in architecture({"model.hidden_sizes": "(16, 8)", "model.layer_norm": "True"}, "CartPole-v1")
    assert "LayerNorm" not in architecture({"model.hidden_sizes": "(16,)", "model.layer_norm": "False"}, "CartPole-v1")
