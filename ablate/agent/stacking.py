"""A population's networks as one: every member's parameters stacked member-first, one batched forward for all
members (or any subset), whatever the network; what acting and the update (``reinforce``) run on.

The user's module keeps its own ``forward``, its standard layers swapped for stacked ones (``stacked_layers``). A
module whose forward mixes batch rows, or that holds other parameters or buffers, goes through
``torch.func.vmap(functional_call)`` instead (``Members.check``); both read the same stacked parameters, so the
update is one either way.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence

import numpy as np
import torch
from torch import fx, nn

from ablate.agent import tracing
from ablate.agent.reinforce import penalised
from ablate.agent.stacked_layers import swap, swappable


def dropout_seed(seed: int) -> int:
    """A member's dropout stream's seed: its own, apart from the stream its initial weights came from."""
    return int(np.random.SeedSequence([seed, 1]).generate_state(1)[0])


class _Stack:
    """Every member's parameters as one (M, P) leaf tensor (a member's row: its parameters one after another), the
    rows a forward serves, and each member's dropout stream."""

    def __init__(self, models: Sequence[nn.Module], device: torch.device, generators: list[torch.Generator]) -> None:
        self.layout: dict[str, tuple[int, int, tuple[int, ...]]] = {}
        """name -> (start, end, shape) of the parameter in a row."""
        start = 0
        for name, p in models[0].named_parameters():
            self.layout[name] = (start, start + p.numel(), tuple(p.shape))
            start += p.numel()
        rows = [torch.cat([p.detach().reshape(-1) for p in m.parameters()]) for m in models] if start else []
        self.flat = (torch.stack(rows) if rows else torch.zeros(len(models), 0)).to(device).requires_grad_(True)
        self.generators = generators
        self._acting: tuple[torch.Tensor, dict] | None = None
        self.rows = self.flat
        self.index: torch.Tensor | None = None
        """The members a forward serves (rows of ``flat``); ``None``: all."""
        self.one: dict[str, torch.Tensor] | None = None
        """Serving one member: its parameters as leaves (``_leaves``)."""
        self._one: tuple[torch.Tensor, torch.Tensor, dict] | None = None
        """(``flat``, its gradient buffer, each member's leaves) for one-member updates."""
        self._zeroed: set[int] = set()
        self.tracer: fx.Tracer | None = None
        """Set while ``Members`` traces the acting forward: a parameter is then read as a graph node."""

    def serve(self, index: torch.Tensor | None) -> None:
        self.index = index
        self.one = None
        if index is not None and len(index) == 1:  # one member (a CPU's update): its own leaves, as its own module's
            self.one = self._leaves(int(index[0]))
            self.rows = self.flat.narrow(0, int(index[0]), 1)
        elif index is None or (len(index) == len(self.flat) and bool((index == self._order()).all())):
            self.rows = self.flat  # every member in order: no gather, no scatter
        else:
            self.rows = self.flat[index]

    def _leaves(self, member: int) -> dict[str, torch.Tensor]:
        """Member ``member``'s parameters as leaf tensors viewing its row of ``flat``, their gradients views of its
        row of ``flat.grad`` (zeroed here): an update of one member then runs, and backpropagates, as through its
        own module, with no slice of ``flat`` in its graph and no (M, P) gradient to scatter into."""
        if self._one is None or self._one[0] is not self.flat:
            self._one = (self.flat, torch.zeros_like(self.flat), {})
        _, grad, leaves = self._one
        if member not in leaves:
            row, grad_row = self.flat.detach()[member], grad[member]
            leaves[member] = {}
            for name, (start, end, shape) in self.layout.items():
                leaf = row[start:end].view(shape).requires_grad_(True)
                leaf.grad = grad_row[start:end].view(shape)  # backward accumulates into it in place
                leaves[member][name] = leaf
        if self.flat.grad is not grad:  # gradients were cleared (zero_grad) or are the (M, P) ones of another pass
            self.flat.grad, self._zeroed = grad, set()
        if member not in self._zeroed:  # once until they are cleared again: a chunked update's chunks sum into it
            grad[member].zero_()
            self._zeroed.add(member)
        return leaves[member]

    def _order(self) -> torch.Tensor:
        return torch.arange(len(self.flat), device=self.flat.device)

    def get(self, name: str) -> torch.Tensor:
        if self.tracer is not None:
            return self.tracer.create_proxy("get_attr", tracing.attribute(name), (), {})
        if self.one is not None:
            return self.one[name].unsqueeze(0)
        return self._acting_views()[name] if self._is_acting() else self._view(self.rows, name)

    def count(self) -> int:
        """How many members a forward serves."""
        return len(self.rows)

    def linear(self, weight: str, bias: str | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """A ``Linear``'s (A, in, out) transposed weight and (A, 1, out) bias, as ``baddbmm`` takes them."""
        if self._is_acting() and self.tracer is None:
            views = self._acting_views()
            key = ("linear", weight, bias)
            if key not in views:
                views[key] = (views[weight].transpose(1, 2), views[bias].unsqueeze(1) if bias else None)
            return views[key]
        return self.get(weight).transpose(1, 2), self.get(bias).unsqueeze(1) if bias else None

    def _is_acting(self) -> bool:
        return self.index is None and not torch.is_grad_enabled()

    def _acting_views(self) -> dict:
        """Acting: every member's views made once (Adam steps ``flat`` in place, so they stay current)."""
        if self._acting is None or self._acting[0] is not self.flat:
            with torch.no_grad():
                self._acting = (self.flat, {n: self._view(self.flat, n) for n in self.layout})
        return self._acting[1]

    def _view(self, rows: torch.Tensor, name: str) -> torch.Tensor:
        start, end, shape = self.layout[name]
        return rows[:, start:end].view(len(rows), *shape)

    def members(self) -> list[int]:
        return list(range(len(self.flat))) if self.index is None else self.index.tolist()

    def penalised(self) -> list[str]:
        """The parameters L2 penalises (``reinforce.penalised``)."""
        return [name for name in self.layout if penalised(name)]

    def weight_mask(self) -> torch.Tensor:
        """(P,): 1 at the entries of the ``penalised`` parameters, 0 elsewhere."""
        mask = torch.zeros(self.flat.shape[1], device=self.flat.device)
        for name in self.penalised():
            start, end, _ = self.layout[name]
            mask[start:end] = 1
        return mask


def _same(forward: Callable | None, x: torch.Tensor, expected: torch.Tensor) -> bool:
    """Whether ``forward`` gives ``expected`` on x bit for bit (a specialisation that no longer fits may raise)."""
    if forward is None:
        return False
    try:
        return torch.equal(forward(x), expected)
    except Exception:
        return False


class Members:
    """M members of one architecture as one network: ``members(x)`` maps (A, B, *obs) to (A, B, actions) logits for
    the A members of ``serving`` (all by default). ``flat``: every member's parameters, what Adam steps."""

    def __init__(self, models: Sequence[nn.Module], device: torch.device, seeds: Sequence[int]) -> None:
        self.device = device
        self.template = copy.deepcopy(models[0]).cpu()
        """Member 0's module as built (a member's own module is this with its ``state_dict`` loaded)."""
        self.buffers = {
            name: torch.stack([dict(m.named_buffers())[name] for m in models]).to(device)
            for name, _ in models[0].named_buffers()
        }
        generators = []
        for seed in seeds:
            generator = torch.Generator(device=device)
            generator.manual_seed(int(seed))
            generators.append(generator)
        self.stack = _Stack(models, device, generators)
        self.weight_mask = self.stack.weight_mask()
        self.network = swap(copy.deepcopy(self.template), self.stack).to(device) if swappable(models[0]) else None
        self._vmapped = None if self.network is not None else self._vmap_forward()
        self._acting: tuple[torch.Tensor, torch.Size, Callable | None] | None = None
        """(the ``flat`` and input shape it was traced for, the acting forward traced into one graph or ``None``)."""
        self.training = True
        self.eval()

    @property
    def flat(self) -> torch.Tensor:
        return self.stack.flat

    def _vmap_forward(self):
        from torch.func import functional_call

        base = copy.deepcopy(self.template).to("meta")

        def one(params, buffers, x):
            return functional_call(base, (params, buffers), (x,))

        return torch.vmap(one, randomness="different")

    def _acting_forward(self, x: torch.Tensor) -> torch.Tensor:
        """Acting (every member, eval mode, no gradients) on x (M, B, *observation) through the forward ``tracing``
        made for x's shape. When ``flat`` is replaced (``keep``) or the shape changes, the same function with the
        new views if it still gives the module's logits, else traced again; a forward that cannot be traced, or
        differs from the module's bit for bit, runs as a module."""
        traced = self._acting
        if traced is not None and traced[0] is self.flat and traced[1] == x.shape:
            return self._module_forward(x) if traced[2] is None else traced[2](x)
        expected = self._module_forward(x)
        forward = traced[2] if traced is not None else None
        if forward is not None:
            forward.rebind(self.stack)  # members left: the code traced for the population as it was
        if not _same(forward, x, expected):
            forward = tracing.trace(self.network, self.stack, x)
            forward = forward if _same(forward, x, expected) else None
        self._acting = (self.flat, x.shape, forward)
        return expected

    def _module_forward(self, x: torch.Tensor) -> torch.Tensor:
        members, batch = x.shape[:2]
        rows = x.reshape(members * batch, *x.shape[2:])
        if rows.dim() == 4 and torch.is_grad_enabled():
            # Images in an update: float32 channels-last (oneDNN's convolutions and their backward on the Pong CNN,
            # one core: 90 ms a 1,024 frames against 117), made here, as a reshape would lose the layout.
            rows = rows.to(torch.float32, memory_format=torch.channels_last)
        return self.network(rows.float()).reshape(members, batch, -1)

    def train(self, mode: bool = True) -> Members:
        if mode == self.training:  # acting calls eval() every step: walking the modules costs more than the forward
            return self
        self.training = mode
        if self.network is not None:
            self.network.train(mode)
        return self

    def eval(self) -> Members:
        return self.train(False)

    def __call__(self, x: torch.Tensor, serving: torch.Tensor | None = None) -> torch.Tensor:
        """Logits (A, B, actions) of the members ``serving`` (indices into the stack; ``None``: all) on x
        (A, B, *observation)."""
        x = x.to(self.device) if x.dim() == 5 and torch.is_grad_enabled() else x.to(self.device, torch.float32)
        if serving is None and self.network is not None and not self.training and not torch.is_grad_enabled():
            return self._acting_forward(x)  # acting: every member, the stack already serves them all
        if serving is None and self.network is not None:
            return self._module_forward(x)
        self.stack.serve(serving)
        try:
            if self.network is not None:
                return self._module_forward(x)
            params = {name: self.stack.get(name) for name in self.stack.layout}
            buffers = {k: (v if serving is None else v[serving]) for k, v in self.buffers.items()}
            return self._vmapped(params, buffers, x.float())
        finally:
            self.stack.serve(None)

    def l2_penalty(self, l2: torch.Tensor, serving: torch.Tensor | None = None) -> torch.Tensor:
        """Each member's ``l2 * sum(w**2)`` over its weight tensors (biases excluded), summed over the members."""
        if serving is not None and len(serving) == 1:  # one member: its leaves
            one = self.stack._leaves(int(serving[0]))
            return l2[0] * sum(one[name].pow(2).sum() for name in self.stack.penalised())
        rows = self.flat if serving is None else self.flat[serving]
        return (l2 * (rows.pow(2) * self.weight_mask).sum(1)).sum()

    def state_dict(self, member: int) -> dict[str, torch.Tensor]:
        row = self.flat[member].detach().cpu()
        state = {name: row[start:end].reshape(shape).clone() for name, (start, end, shape) in self.stack.layout.items()}
        state.update({name: b[member].cpu().clone() for name, b in self.buffers.items()})
        return self.template.state_dict() | state

    def load_state_dict(self, member: int, state: dict[str, torch.Tensor]) -> None:
        with torch.no_grad():
            for name, (start, end, _) in self.stack.layout.items():
                self.flat[member, start:end] = state[name].reshape(-1).to(self.device)
            for name, b in self.buffers.items():
                b[member].copy_(state[name])

    def keep(self, members: list[int]) -> None:
        """Only ``members`` (in this order) go on."""
        index = torch.tensor(members, device=self.device)
        self.stack.flat = self.flat.detach()[index].requires_grad_(True)
        self.stack.serve(None)
        self.buffers = {k: v[index] for k, v in self.buffers.items()}
        self.stack.generators[:] = [self.stack.generators[m] for m in members]

    def check(self, models: Sequence[nn.Module], observation_shape: Sequence[int]) -> None:
        """Falls back to ``vmap`` unless the swapped network gives each member its own module's logits on a sample
        (a forward that mixes batch rows, reshapes by the batch size it was given, or fails stacked)."""
        if self.network is None:
            return
        sample = torch.randn(len(models), 3, *observation_shape, generator=torch.Generator().manual_seed(0))
        try:
            with torch.no_grad():
                got = self._module_forward(sample.to(self.device)).cpu()
                expected = torch.stack([m.eval()(sample[i]).detach().cpu() for i, m in enumerate(models)])
            fits = got.shape == expected.shape and torch.allclose(got, expected, rtol=1e-4, atol=1e-5)
        except Exception:  # any failure of the swapped forward: the user's module is not written for it
            fits = False
        if not fits:
            self.network = None
            self._vmapped = self._vmap_forward()

    @property
    def swapped(self) -> bool:
        """Whether the members run through the user's module with stacked layers (else through ``vmap``)."""
        return self.network is not None


class Adam:
    """Adam (Kingma & Ba, 2015) with bias correction, no weight decay, no AMSGrad, one per member (its learning
    rate, its step count): a row of ``params`` (M, P), every member's parameters one after another
    (``Members.flat``), stepping only the members an update serves; the update ``torch.optim.Adam`` makes, member
    by member (tests/test_stacking.py). Not ``torch.optim.Adam``: it steps every row of a stacked tensor with one
    step count and one learning rate, and its import costs 1.3 s a process (docs/design.md)."""

    beta1, beta2, eps = 0.9, 0.999, 1e-8  # torch.optim.Adam's defaults

    def __init__(self, params: torch.Tensor, lr: Sequence[float]) -> None:
        if any(rate <= 0 for rate in lr):
            raise ValueError(f"learning rate must be positive, got {min(lr)}")
        self.params = params
        self.lr = torch.tensor(list(lr), dtype=torch.float64, device=params.device)
        self.steps = torch.zeros(len(self.lr), dtype=torch.int64, device=params.device)
        self.exp_avg = torch.zeros_like(params)
        self.exp_avg_sq = torch.zeros_like(params)

    def zero_grad(self) -> None:
        self.params.grad = None

    @torch.no_grad()
    def step(self, serving: torch.Tensor | None = None) -> None:
        """One step of the members ``serving`` (rows; ``None``: all), from their gradients."""
        grad = self.params.grad
        if grad is None:
            return
        if serving is not None and len(serving) == 1:  # one member (a CPU's update): torch's own arithmetic
            self._step_one(int(serving[0]), grad[int(serving[0])])
            return
        rows: slice | torch.Tensor = slice(None) if serving is None else serving
        self.steps[rows] += 1
        steps = self.steps[rows].double()
        step_size = (self.lr[rows] / (1 - self.beta1**steps)).float().unsqueeze(1)
        bias_correction2_sqrt = (1 - self.beta2**steps).sqrt().float().unsqueeze(1)
        exp_avg, exp_avg_sq, grad = self.exp_avg[rows], self.exp_avg_sq[rows], grad[rows]
        exp_avg.lerp_(grad, 1 - self.beta1)
        exp_avg_sq.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
        denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
        if isinstance(rows, slice):
            self.params[rows].sub_(step_size * exp_avg / denom)
            return
        self.exp_avg[rows], self.exp_avg_sq[rows] = exp_avg, exp_avg_sq
        self.params[rows] = self.params[rows] - step_size * exp_avg / denom

    def _step_one(self, member: int, grad: torch.Tensor) -> None:
        """Member ``member``'s step as ``torch.optim.Adam`` makes it for one tensor: the bias corrections in Python
        floats, its row's moments and parameters stepped in place (seven tensor operations)."""
        self.steps[member] += 1
        step = int(self.steps[member])
        step_size = float(self.lr[member]) / (1 - self.beta1**step)
        bias_correction2_sqrt = math.sqrt(1 - self.beta2**step)
        exp_avg, exp_avg_sq = self.exp_avg[member], self.exp_avg_sq[member]
        exp_avg.lerp_(grad, 1 - self.beta1)
        exp_avg_sq.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
        denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
        self.params.detach()[member].addcdiv_(exp_avg, denom, value=-step_size)

    def state_dict(self, member: int) -> dict:
        """Member ``member``'s step count and moment estimates (its checkpoint's)."""
        return {
            "steps": int(self.steps[member]),
            "exp_avg": self.exp_avg[member].cpu().clone(),
            "exp_avg_sq": self.exp_avg_sq[member].cpu().clone(),
        }

    def load_state_dict(self, member: int, state: dict) -> None:
        self.steps[member] = state["steps"]
        self.exp_avg[member] = state["exp_avg"]
        self.exp_avg_sq[member] = state["exp_avg_sq"]

    def keep(self, members: list[int], params: torch.Tensor) -> None:
        """Only ``members`` go on; ``params`` is the stack after the same ``keep``."""
        index = torch.tensor(members, device=self.lr.device)
        self.params = params
        self.lr, self.steps = self.lr[index], self.steps[index]
        self.exp_avg, self.exp_avg_sq = self.exp_avg[index], self.exp_avg_sq[index]
