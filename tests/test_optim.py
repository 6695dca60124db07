"""ablate.agent.optim.Adam against torch.optim.Adam, and the import it exists to avoid."""

import subprocess
import sys

import pytest
import torch

from ablate.agent.optim import Adam
from ablate.agent.policies import create_cartpole_model


def _loss(model: torch.nn.Module, batch: torch.Tensor) -> torch.Tensor:
    return model(batch).log_softmax(dim=1)[:, 0].mean() + 0.01 * model(batch).pow(2).sum()


@pytest.mark.parametrize("lr", [1e-3, 3e-2])
def test_adam_matches_torch_step_for_step(lr):
    torch.manual_seed(0)
    ours_model = create_cartpole_model(hidden_sizes=(16, 16))
    torch_model = create_cartpole_model(hidden_sizes=(16, 16))
    torch_model.load_state_dict(ours_model.state_dict())
    ours, reference = Adam(ours_model.parameters(), lr=lr), torch.optim.Adam(torch_model.parameters(), lr=lr)
    for step in range(25):
        batch = torch.randn(32, 4, generator=torch.Generator().manual_seed(step))
        for model, optimizer in ((ours_model, ours), (torch_model, reference)):
            optimizer.zero_grad(set_to_none=True)
            _loss(model, batch).backward()
            optimizer.step()
    for (name, a), b in zip(ours_model.state_dict().items(), torch_model.state_dict().values(), strict=True):
        assert torch.equal(a, b), name  # the same float operations in the same order: bit for bit
    assert ours.steps == 25


def test_adam_skips_parameters_without_gradients_and_zero_grad_modes():
    used, unused = torch.nn.Parameter(torch.ones(3)), torch.nn.Parameter(torch.ones(2))
    optimizer = Adam([used, unused], lr=0.1)
    (used * torch.tensor([1.0, -1.0, 0.0])).sum().backward()
    optimizer.step()
    assert torch.allclose(used.detach(), torch.tensor([0.9, 1.1, 1.0]))  # first Adam step: lr * sign(grad)
    assert torch.equal(unused.detach(), torch.ones(2))
    optimizer.zero_grad(set_to_none=False)
    assert torch.equal(used.grad, torch.zeros(3))
    optimizer.zero_grad()
    assert used.grad is None
    with pytest.raises(ValueError, match="learning rate"):
        Adam([used], lr=0.0)


def test_a_trial_never_imports_torch_dynamo():
    """torch.optim's optimizers import torch._dynamo (~1.3 s per process); a trial must not pay it."""
    code = (
        "import sys\n"
        "from ablate.config import DEFAULT, apply_knobs\n"
        "from ablate.agent.trainer import run_trial\n"
        "run_trial(apply_knobs(DEFAULT, {'max_episodes': 64, 'seed': 1}))\n"
        "print('torch._dynamo' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "False"
