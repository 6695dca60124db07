"""ablate.agent.tracing: the acting forward traced once, specialised to the acting batch's shape, rebound when
members leave; always the module's logits bit for bit."""

import torch

from ablate.agent.policies import create_cartpole_model
from ablate.agent.stacking import Members


def _members(count: int) -> Members:
    models = []
    for seed in range(count):
        torch.manual_seed(seed)
        models.append(create_cartpole_model(hidden_sizes=(16,)))
    return Members(models, torch.device("cpu"), range(count))


def test_the_default_networks_acting_forward_is_its_layers_products_with_no_reshape_and_no_shape_arithmetic():
    members = _members(4)
    x = torch.randn(4, 6, 4, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert torch.equal(members(x), members._module_forward(x))
    code = members._acting[2].module.code
    assert "baddbmm" in code and "bmm" in code
    for gone in ("reshape", "flatten", "shape", "getitem"):
        assert gone not in code, code


def test_members_leaving_rebind_the_traced_forward_to_the_new_stack_without_tracing_again():
    members = _members(4)
    x = torch.randn(4, 6, 4, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        members(x)
        traced = members._acting[2]
        members.keep([3, 1])
        got = members(x[:2])
        assert members._acting[2] is traced  # the same code, the new views
        assert torch.equal(got, members._module_forward(x[:2]))
        for position, member in enumerate([3, 1]):
            torch.manual_seed(member)
            own = create_cartpole_model(hidden_sizes=(16,))
            torch.testing.assert_close(got[position], own(x[position]))
        # another batch shape: the code has no shape in it, so it serves that too (checked, as after every change)
        assert torch.equal(members(x[:2, :3]), members._module_forward(x[:2, :3]))
