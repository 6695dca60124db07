"""ablate.agent.optim.Adam (each member's own Adam on the stacked parameters) against torch.optim.Adam, and the
import it exists to avoid."""

import subprocess
import sys

import pytest
import torch

from ablate.agent.optim import Adam
from ablate.agent.policies import create_cartpole_model
from ablate.agent.stacking import Members


def _loss(model: torch.nn.Module, batch: torch.Tensor) -> torch.Tensor:
    return model(batch).log_softmax(dim=1)[:, 0].mean() + 0.01 * model(batch).pow(2).sum()


def _members(count: int) -> tuple[list[torch.nn.Module], Members]:
    models = []
    for seed in range(count):
        torch.manual_seed(seed)
        models.append(create_cartpole_model(hidden_sizes=(16, 16)))
    return models, Members(models, torch.device("cpu"), range(count))


def test_each_member_steps_as_torch_adam_at_its_own_rate_and_only_when_served():
    """Three members at three learning rates; member 1 sits out every third step. Each member's weights follow
    torch.optim.Adam on its own module (to float tolerance), and a member not served is not touched at all."""
    rates = [1e-3, 3e-2, 1e-2]
    models, members = _members(3)
    references = [torch.optim.Adam(m.parameters(), lr=r) for m, r in zip(models, rates, strict=True)]
    ours = Adam(members.flat, lr=rates)
    for step in range(25):
        batch = torch.randn(32, 4, generator=torch.Generator().manual_seed(step))
        serving = [0, 2] if step % 3 == 0 else [0, 1, 2]
        before = members.state_dict(1)
        ours.zero_grad()
        index = torch.tensor(serving)
        logits = members(batch.expand(len(serving), *batch.shape), index)  # one forward for the members served
        (logits.log_softmax(dim=2)[..., 0].mean(1) + 0.01 * logits.pow(2).sum((1, 2))).sum().backward()
        ours.step(index)
        for m in serving:
            references[m].zero_grad()
            _loss(models[m], batch).backward()
            references[m].step()
        if 1 not in serving:
            after = members.state_dict(1)
            assert all(torch.equal(before[k], after[k]) for k in before)
    for m, model in enumerate(models):
        for name, expected in model.state_dict().items():
            torch.testing.assert_close(members.state_dict(m)[name], expected, rtol=1e-5, atol=1e-6, msg=name)
    assert ours.steps.tolist() == [25, 16, 25]


def test_adam_refuses_a_rate_that_is_not_positive_and_keeps_only_the_members_that_stay():
    models, members = _members(3)
    with pytest.raises(ValueError, match="learning rate"):
        Adam(members.flat, lr=[1e-3, 0.0, 1e-3])
    optimizer = Adam(members.flat, lr=[1e-3, 2e-3, 3e-3])
    members.keep([2, 0])
    optimizer.keep([2, 0], members.flat)
    assert optimizer.lr.tolist() == [3e-3, 1e-3]
    assert torch.equal(members.state_dict(0)["body.0.weight"], models[2].state_dict()["body.0.weight"])


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
