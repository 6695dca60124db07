"""Policy networks: shapes, the ablation knobs, logits (no softmax)."""

import pytest
import torch
from torch import nn

from ablate.agent.policies import create_cartpole_model, create_pong_model


def test_cartpole_mlp_depth_width_dropout():
    model = create_cartpole_model(hidden_sizes=(64, 32), activation="tanh", dropout=0.1)
    linears = [m for m in model.modules() if isinstance(m, nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(4, 64), (64, 32), (32, 2)]
    assert sum(isinstance(m, nn.Dropout) for m in model.modules()) == 2
    assert sum(isinstance(m, nn.Tanh) for m in model.modules()) == 2
    assert sum(p.numel() for p in model.parameters()) == 4 * 64 + 64 + 64 * 32 + 32 + 32 * 2 + 2
    assert model(torch.zeros(5, 4)).shape == (5, 2)


def test_cartpole_outputs_logits_not_probabilities():
    torch.manual_seed(0)
    out = create_cartpole_model()(torch.randn(100, 4) * 10)
    assert not torch.allclose(out.sum(dim=1), torch.ones(100))
    assert (out < 0).any()


def test_cartpole_cnn_reads_a_window_of_observations():
    model = create_cartpole_model(architecture="cnn", history=6, conv_channels=(8, 8), kernel_size=3)
    assert model(torch.zeros(3, 6, 4)).shape == (3, 2)
    assert any(isinstance(m, nn.Conv1d) for m in model.modules())


def test_pong_models():
    cnn = create_pong_model()
    assert cnn(torch.zeros(2, 1, 80, 80)).shape == (2, 6)
    assert sum(isinstance(m, nn.Conv2d) for m in cnn.modules()) == 3
    mlp = create_pong_model(architecture="mlp", hidden_sizes=(200,))
    assert mlp(torch.zeros(2, 1, 80, 80)).shape == (2, 6)
    assert sum(p.numel() for p in mlp.parameters()) == 6400 * 200 + 200 + 200 * 6 + 6


def test_layer_norm_knob_builds_a_layer_norm_before_each_hidden_activation_and_acts_through_stacked_layers():
    from dataclasses import replace

    import numpy as np

    from ablate.agent.policies import build_model
    from ablate.agent.stacking import Members
    from ablate.config import DEFAULT, apply_knobs
    from ablate.envs import describe
    from ablate.launch.grid import trial_key
    from ablate.reporting.sections import architecture

    config = apply_knobs(DEFAULT, {"hidden_sizes": [16, 8], "layer_norm": True})
    torch.manual_seed(0)
    model = build_model(config, describe(config))
    kinds = [type(m).__name__ for m in model.body]
    assert kinds == ["Linear", "LayerNorm", "ReLU", "Linear", "LayerNorm", "ReLU", "Linear"]
    pong = create_pong_model(architecture="mlp", hidden_sizes=(8,), layer_norm=True)
    assert sum(isinstance(m, nn.LayerNorm) for m in pong.modules()) == 1
    members = Members([model, model], torch.device("cpu"), [0, 1])
    members.check([model, model], (4,))
    assert members.swapped  # its LayerNorm is stacked like its Linear layers, not a fallback
    observations = torch.randn(2, 5, 4)
    with torch.no_grad():
        expected = model(observations.reshape(-1, 4)).reshape(2, 5, 2)
        stacked = members(observations)
    np.testing.assert_allclose(stacked.numpy(), expected.numpy(), rtol=1e-5, atol=1e-5)
    assert trial_key("v", replace(config, model=replace(config.model, layer_norm=False))) != trial_key("v", config)
    assert "LayerNorm" in architecture({"model.hidden_sizes": "(16, 8)", "model.layer_norm": "True"}, "CartPole-v1")
    assert "LayerNorm" not in architecture({"model.hidden_sizes": "(16,)", "model.layer_norm": "False"}, "CartPole-v1")


def test_a_factory_refuses_an_architecture_it_does_not_build():
    for factory in (create_cartpole_model, create_pong_model):
        with pytest.raises(ValueError, match="architecture = 'CNN' is invalid; valid: mlp, cnn"):
            factory(architecture="CNN")
