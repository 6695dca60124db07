"""Stacked members: each member's logits and gradients are its own module's, whatever the network (stacked layers,
or ``vmap`` for a module they cannot serve), and a member's dropout never depends on who shares the stack; each
member's own Adam against torch.optim.Adam, and the import it exists to avoid."""

from __future__ import annotations

import copy
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torch import nn

from ablate.agent.policies import create_cartpole_model, create_pong_model
from ablate.agent.stacking import Adam, Members

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "models"


def _example(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.create_model


class _MixesRows(nn.Module):
    """A forward that normalises over the batch: stacked members would share statistics, so it must go to vmap."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(4, 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.linear(x - x.mean(0))


class _OwnParameter(nn.Module):
    """A parameter outside the layers the stack knows (a learnt temperature)."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(4, 2)
        self.temperature = nn.Parameter(torch.ones(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.linear(x) / self.temperature


NETWORKS = {
    "mlp": (lambda: create_cartpole_model(hidden_sizes=(16, 8), activation="tanh"), (4,), True),
    "cnn-1d": (lambda: create_cartpole_model(architecture="cnn", history=4, conv_channels=(6, 5)), (4, 4), True),
    "layernorm": (lambda: _example("layernorm")((4,), 2, width=16), (4,), True),
    "residual": (lambda: _example("residual")((4,), 2, width=16), (4,), True),
    "pong-cnn": (lambda: create_pong_model(n_actions=3), (1, 80, 80), True),
    "mixes-rows": (_MixesRows, (4,), False),
    "own-parameter": (_OwnParameter, (4,), False),
}


def _module(members: Members, member: int) -> nn.Module:
    """Member ``member``'s own module: the template with its row loaded."""
    model = copy.deepcopy(members.template)
    model.load_state_dict(members.state_dict(member))
    return model


def _models(name: str, count: int = 3) -> tuple[list[nn.Module], tuple[int, ...], bool]:
    build, shape, swapped = NETWORKS[name]
    models = []
    for seed in range(count):
        torch.manual_seed(seed)
        models.append(build())
    return models, shape, swapped


@pytest.mark.parametrize("name", list(NETWORKS))
def test_each_member_gets_its_own_modules_logits_and_gradients(name):
    models, shape, swapped = _models(name)
    members = Members(models, torch.device("cpu"), range(len(models)))
    members.check(models, shape)
    assert members.swapped == swapped  # stacked layers where they serve, vmap where they cannot
    x = torch.randn(len(models), 5, *shape, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        logits = members(x)
    for m, model in enumerate(models):
        torch.testing.assert_close(logits[m], model.eval()(x[m]), rtol=1e-4, atol=1e-5)
    # The members served (2 and 0, in that order) get their own module's gradients, the one not served none.
    serving = torch.tensor([2, 0])
    members.train()
    members(x[[2, 0]], serving).pow(2).sum().backward()
    grads = members.flat.grad
    assert torch.count_nonzero(grads[1]) == 0
    for m in (2, 0):
        models[m].zero_grad()
        models[m].train()(x[m]).pow(2).sum().backward()
        expected = torch.cat([p.grad.reshape(-1) for p in models[m].parameters()])
        torch.testing.assert_close(grads[m], expected, rtol=1e-4, atol=1e-5)


def test_a_members_dropout_is_its_own_stream_whoever_shares_the_stack():
    build = lambda: create_cartpole_model(hidden_sizes=(32,), dropout=0.5)  # noqa: E731
    torch.manual_seed(0)
    models = [build() for _ in range(3)]
    together = Members(models, torch.device("cpu"), [10, 11, 12]).train()
    alone = Members([models[1]], torch.device("cpu"), [11]).train()
    x = torch.randn(1, 64, 4).expand(3, 64, 4)
    for _ in range(3):  # draw after draw, the streams stay in step
        torch.testing.assert_close(together(x)[1], alone(x[1:2])[0])
    masks = together(x)
    assert not torch.equal(masks[0], masks[2])  # members draw different masks


def test_a_member_leaves_and_the_others_keep_their_weights_and_streams():
    models, shape, _ = _models("mlp", 4)
    members = Members(models, torch.device("cpu"), range(4))
    state = members.state_dict(3)
    members.keep([3, 1])
    assert all(torch.equal(state[k], v) for k, v in members.state_dict(0).items())
    assert isinstance(_module(members, 1), type(models[1]))
    torch.testing.assert_close(_module(members, 1)(torch.ones(2, 4)), models[1](torch.ones(2, 4)))


class _BranchesOnValues(nn.Module):
    """A forward fx cannot trace (Python control flow on a tensor's value): acting runs it as a module."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(4, 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.linear(x)
        return out if bool(out.sum() > -1e9) else -out


USERS_NETWORKS = {
    "mlp-class": (lambda: _example("mlp_class")((4,), 2, width=16), (4,)),
    "layernorm": (lambda: _example("layernorm")((4,), 2, width=16), (4,)),
    "residual": (lambda: _example("residual")((4,), 2, width=16), (4,)),
    "atari-cnn": (lambda: _example("atari_cnn")((2, 44, 44), 3, width=8), (2, 44, 44)),
    "branches": (_BranchesOnValues, (4,)),
}


@pytest.mark.parametrize("name", list(USERS_NETWORKS))
def test_acting_is_the_modules_forward_bit_for_bit_after_steps_in_place_and_a_member_leaving(name):
    build, shape = USERS_NETWORKS[name]
    models = []
    for seed in range(3):
        torch.manual_seed(seed)
        models.append(build())
    members = Members(models, torch.device("cpu"), range(len(models)))
    x = torch.randn(len(models), 5, *shape, generator=torch.Generator().manual_seed(2))

    def module_forward(count: int) -> torch.Tensor:
        return members.network(x[:count].reshape(-1, *shape)).reshape(count, 5, -1)

    with torch.no_grad():
        assert torch.equal(members(x), module_forward(3))  # the first call traces and checks
        assert (members._acting[2] is not None) == (name != "branches")  # traced where fx can follow the forward
        members.flat.mul_(1.5)  # Adam steps ``flat`` in place: the traced forward reads the new weights
        assert torch.equal(members(x), module_forward(3))
        members.keep([2, 0])  # a new ``flat``: traced again for the two members left
        assert torch.equal(members(x[:2]), module_forward(2))
        for position in range(2):
            torch.testing.assert_close(members(x[:2])[position], _module(members, position)(x[position]))


@pytest.mark.parametrize("name", ["mlp-class", "layernorm", "atari-cnn"])
def test_one_members_update_is_its_own_modules_in_chunks_or_whole_and_touches_no_other_member(name):
    """A CPU's update serves one member: its parameters as leaf views of its row. Its step equals train_step on its
    own module with torch's Adam (to float tolerance), a chunked update sums its chunks' gradients (a later chunk
    must not clear the earlier ones'), and the other members' rows do not move."""
    from ablate.agent.reinforce import train_step

    build, shape = USERS_NETWORKS[name]
    models = []
    for seed in range(3):
        torch.manual_seed(seed)
        models.append(build())
    rng = torch.Generator().manual_seed(5)
    observations = torch.randn(1, 40, *shape, generator=rng).numpy()
    actions = torch.randint(0, 2, (1, 40), generator=rng).numpy()
    weights = torch.randn(1, 40, generator=rng).numpy()
    results = []
    for chunk in (None, 8):
        members = Members(models, torch.device("cpu"), range(3))
        optimizer = Adam(members.flat, lr=[1e-2] * 3)
        before = members.flat.detach().clone()
        for _ in range(3):
            train_step(members, optimizer, observations, actions, weights, l2=torch.tensor([0.0]).numpy(),
                       chunk_size=chunk, lengths=torch.tensor([40]).numpy(), serving=torch.tensor([1]))  # fmt: skip
        after = members.flat.detach()
        assert torch.equal(after[[0, 2]], before[[0, 2]])
        results.append(members.state_dict(1))
    own = models[1]
    reference = torch.optim.Adam(own.parameters(), lr=1e-2)
    for _ in range(3):
        train_step(own, reference, observations[0], actions[0], weights[0])
    for name_, expected in own.state_dict().items():
        for got in results:
            torch.testing.assert_close(got[name_], expected, rtol=1e-4, atol=1e-5, msg=name_)


def _loss(model: torch.nn.Module, batch: torch.Tensor) -> torch.Tensor:
    return model(batch).log_softmax(dim=1)[:, 0].mean() + 0.01 * model(batch).pow(2).sum()


def _cartpole_members(count: int) -> tuple[list[torch.nn.Module], Members]:
    models = []
    for seed in range(count):
        torch.manual_seed(seed)
        models.append(create_cartpole_model(hidden_sizes=(16, 16)))
    return models, Members(models, torch.device("cpu"), range(count))


def test_each_member_steps_as_torch_adam_at_its_own_rate_and_only_when_served():
    """Three members at three learning rates; member 1 sits out every third step. Each member's weights follow
    torch.optim.Adam on its own module (to float tolerance), and a member not served is not touched at all."""
    rates = [1e-3, 3e-2, 1e-2]
    models, members = _cartpole_members(3)
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
    models, members = _cartpole_members(3)
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
