"""A population's networks as one: every member's parameters stacked member-first, one batched forward for all
members (or any subset), whatever the network; what acting and the update (``reinforce``) run on.

The user's module keeps its own ``forward``: its standard layers (``Linear``, ``LayerNorm``, ``Conv1d``,
``Conv2d``, ``Dropout``) are swapped for versions that read every member's parameters at once, the members folded
into the batch dimension member-major (a ``Linear`` becomes one ``baddbmm``; a convolution one grouped
convolution, a group per member), so elementwise code and ``flatten(1)`` run as written. A module whose forward
mixes batch rows, or that holds other parameters or buffers, goes through ``torch.func.vmap(functional_call)``
instead; both read the same stacked parameters, so the update is one either way. Checked once per population
against each member's own forward (``Members.check``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import fx, nn

from ablate.agent import sparse, tracing


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
        self.tracer: fx.Tracer | None = None
        """Set while ``Members`` traces the acting forward: a parameter is then read as a graph node."""

    def serve(self, index: torch.Tensor | None) -> None:
        self.index = index
        if index is None or (len(index) == len(self.flat) and bool((index == self._order()).all())):
            self.rows = self.flat  # every member in order (a population of one): no gather, no scatter
        elif len(index) == 1:  # one member: a view of its row, its gradient written in place
            self.rows = self.flat.narrow(0, int(index[0]), 1)
        else:
            self.rows = self.flat[index]

    def _order(self) -> torch.Tensor:
        return torch.arange(len(self.flat), device=self.flat.device)

    def get(self, name: str) -> torch.Tensor:
        if self.tracer is not None:
            return self.tracer.create_proxy("get_attr", tracing.attribute(name), (), {})
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

    def weight_mask(self) -> torch.Tensor:
        """(P,): 1 at the entries of weight tensors (what L2 penalises), 0 at biases and norms' shifts."""
        mask = torch.zeros(self.flat.shape[1], device=self.flat.device)
        for name, (start, end, _) in self.layout.items():
            if name.endswith("weight"):
                mask[start:end] = 1
        return mask


class _StackedLayer(nn.Module):
    def __init__(self, stack: _Stack, prefix: str, layer: nn.Module) -> None:
        super().__init__()
        self._stack = stack  # plain attribute: not a submodule
        self._weight = prefix + "weight" if getattr(layer, "weight", None) is not None else None
        self._bias = prefix + "bias" if getattr(layer, "bias", None) is not None else None

    def _params(self) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        stack = self._stack
        weight = stack.get(self._weight) if self._weight else None
        return weight, stack.get(self._bias) if self._bias else None


class StackedLinear(_StackedLayer):
    def __init__(self, stack: _Stack, prefix: str, layer: nn.Linear) -> None:
        super().__init__(stack, prefix, layer)
        self.in_features, self.out_features = layer.in_features, layer.out_features
        self._cached: tuple[torch.Tensor, int, torch.Tensor] | None = None
        """(``flat``, its version, the weights transposed) for acting."""
        self.wide = layer.in_features >= 1024
        """Wide enough that a sparse input (``sparse.SPARSE``) takes ``sparse.linear``."""
        self.narrow = layer.out_features < layer.in_features
        """Fewer outputs than inputs (the logits): computed as W @ x^T, as batched GEMMs are ~2x slower with a
        handful of output columns than with a handful of rows (16 members' 32 -> 2 layer: 13 us against 30)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.wide and x.dim() == 2 and sparse.sparse(x):  # frame differences: the rows their pixels pick
            weight, bias = self._params()
            parts = x.reshape(self._stack.count(), -1, self.in_features)
            return torch.cat(
                [sparse.linear(part, w, None if bias is None else bias[a]) for a, (part, w) in
                 enumerate(zip(parts, self._transposed(weight), strict=True))]
            )  # fmt: skip
        if self._stack.index is not None and self._stack.count() == 1:  # one member's update: its own Linear
            weight, bias = self._params()
            return F.linear(x, weight[0], None if bias is None else bias[0])
        weight_t, bias = self._stack.linear(self._weight, self._bias)
        rows = x.reshape(self._stack.count(), -1, self.in_features)
        if self.narrow:
            out = torch.bmm(weight_t.transpose(1, 2), rows.transpose(1, 2)).transpose(1, 2)
            out = out if bias is None else out + bias
        else:
            out = torch.bmm(rows, weight_t) if bias is None else torch.baddbmm(bias, rows, weight_t)
        return out.reshape(x.shape[:-1] + (self.out_features,))

    def _transposed(self, weight: torch.Tensor) -> torch.Tensor:
        """(A, in, out) contiguous: in an update, part of its graph; acting, made once per change of the weights."""
        if torch.is_grad_enabled():
            return weight.transpose(1, 2).contiguous()
        flat = self._stack.flat
        cached = self._cached
        if cached is None or cached[0] is not flat or cached[1] != flat._version:
            cached = self._cached = (flat, flat._version, weight.transpose(1, 2).contiguous())
        return cached[2]


class StackedLayerNorm(_StackedLayer):
    def __init__(self, stack: _Stack, prefix: str, layer: nn.LayerNorm) -> None:
        super().__init__(stack, prefix, layer)
        self.normalized_shape, self.eps = tuple(layer.normalized_shape), layer.eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = F.layer_norm(x, self.normalized_shape, eps=self.eps)
        weight, bias = self._params()
        if weight is None and bias is None:
            return out
        grouped = out.reshape(self._stack.count(), -1, *self.normalized_shape)
        if weight is not None:
            grouped = grouped * weight.unsqueeze(1)
        if bias is not None:
            grouped = grouped + bias.unsqueeze(1)
        return grouped.reshape(x.shape)


class StackedConv(_StackedLayer):
    """``Conv1d``/``Conv2d`` for every member as one grouped convolution (a group per member)."""

    def __init__(self, stack: _Stack, prefix: str, layer: nn.Conv1d | nn.Conv2d) -> None:
        super().__init__(stack, prefix, layer)
        self.dims = 1 if isinstance(layer, nn.Conv1d) else 2
        self.out_channels = layer.out_channels
        self.stride, self.padding, self.dilation = layer.stride, layer.padding, layer.dilation

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        weight, bias = self._params()
        members = self._stack.count()
        # (members * batch, channels, ...) -> (batch, members * channels, ...): a group per member
        grouped = x.unflatten(0, (members, -1)).transpose(0, 1).flatten(1, 2)
        convolve = F.conv1d if self.dims == 1 else F.conv2d
        out = convolve(
            grouped,
            weight.flatten(0, 1),
            None if bias is None else bias.flatten(),
            self.stride,
            self.padding,
            self.dilation,
            members,
        )
        return out.unflatten(1, (members, self.out_channels)).transpose(0, 1).flatten(0, 1)


class StackedSparseStem(nn.Module):
    """Conv, activation, conv of a module (a one-channel image in, square geometry), through ``sparse.Stem``
    member by member when the input is that sparse (a frame difference), else the three stacked layers."""

    def __init__(self, stack: _Stack, prefix1: str, prefix2: str, conv1: nn.Conv2d, act: nn.Module, conv2: nn.Conv2d):
        super().__init__()
        self._stack = stack
        self.conv1, self.act, self.conv2 = StackedConv(stack, prefix1, conv1), act, StackedConv(stack, prefix2, conv2)
        self.names = [prefix1 + "weight", prefix1 + "bias", prefix2 + "weight", prefix2 + "bias"]
        self.geometry = [(c.kernel_size[0], c.stride[0], c.padding[0]) for c in (conv1, conv2)]
        self._stems: dict[int, sparse.Stem] = {}
        self._backgrounds: dict[int, tuple[torch.Tensor, int, torch.Tensor]] = {}

    @staticmethod
    def fits(conv1: nn.Module, act: nn.Module, conv2: nn.Module) -> bool:
        square = all(
            isinstance(c, nn.Conv2d)
            and c.bias is not None
            and c.groups == 1
            and c.dilation == (1, 1)
            and c.padding_mode == "zeros"
            and isinstance(c.padding, tuple)
            and len(set(c.kernel_size)) == len(set(c.stride)) == len(set(c.padding)) == 1
            for c in (conv1, conv2)
        )
        return square and conv1.in_channels == 1 and isinstance(act, nn.ReLU | nn.Tanh | nn.ELU | nn.GELU)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = x.shape[-1]
        if x.dim() != 4 or x.shape[1] != 1 or x.shape[2] != size or len(x) < sparse.ROWS or not sparse.sparse(x):
            return self.conv2(self.act(self.conv1(x)))
        if size not in self._stems:
            with torch.inference_mode(False):  # its tables serve acting (inference mode) and updates alike
                self._stems[size] = sparse.Stem(size, *self.geometry, self.act)
        stem, stack = self._stems[size], self._stack
        w1, b1, w2, b2 = (stack.get(name) for name in self.names)
        frames = x.reshape(stack.count(), -1, size * size)
        out = []
        for a, member in enumerate(stack.members()):
            background = None
            if not torch.is_grad_enabled():  # acting: the background changes only when the weights do
                cached = self._backgrounds.get(member)
                if cached is None or cached[0] is not stack.flat or cached[1] != stack.flat._version:
                    cached = (stack.flat, stack.flat._version, stem.background(b1[a], w2[a], b2[a]))
                    self._backgrounds[member] = cached
                background = cached[2]
            out.append(stem(frames[a], w1[a], b1[a], w2[a], b2[a], background))
        return torch.cat(out)


class StackedDropout(nn.Module):
    """Dropout whose mask each member draws from its own stream (``_Stack.generators``)."""

    def __init__(self, stack: _Stack, p: float) -> None:
        super().__init__()
        self._stack, self.p = stack, p

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training or self.p == 0:
            return x
        members = self._stack.members()
        grouped = x.unflatten(0, (len(members), -1))
        keep = torch.stack(
            [
                torch.rand(grouped.shape[1:], generator=self._stack.generators[m], device=x.device) >= self.p
                for m in members
            ]
        )
        return (grouped * keep / (1 - self.p)).reshape(x.shape)


_PARAMETRIC = (nn.Linear, nn.LayerNorm, nn.Conv1d, nn.Conv2d)


def _swappable(model: nn.Module) -> bool:
    """Whether every parameter sits in a layer ``_swap`` knows and nothing holds a buffer."""
    if any(True for _ in model.buffers()):
        return False
    for module in model.modules():
        own = list(module.parameters(recurse=False))
        if not own:
            continue
        if not isinstance(module, _PARAMETRIC):
            return False
        if isinstance(module, nn.Conv1d | nn.Conv2d) and (module.groups != 1 or module.padding_mode != "zeros"):
            return False
        if isinstance(module, nn.Conv1d | nn.Conv2d) and isinstance(module.padding, str):
            return False
    return True


def _replacement(layer: nn.Module, stack: _Stack, path: str) -> nn.Module | None:
    """``layer``'s stacked version, reading ``stack`` under ``path``; ``None`` for a layer kept as it is."""
    if isinstance(layer, nn.Linear):
        return StackedLinear(stack, path, layer)
    if isinstance(layer, nn.LayerNorm):
        return StackedLayerNorm(stack, path, layer)
    if isinstance(layer, nn.Conv1d | nn.Conv2d):
        return StackedConv(stack, path, layer)
    if type(layer) is nn.Dropout:
        return StackedDropout(stack, layer.p)
    return None


def _swap(model: nn.Module, stack: _Stack, prefix: str = "") -> nn.Module:
    """``model`` with its layers replaced (in place) by their stacked versions, reading ``stack`` by their names."""
    replacement = _replacement(model, stack, prefix)
    if replacement is not None:
        return replacement
    if isinstance(model, nn.Sequential):  # conv, activation, conv on a one-channel image: the sparse stem
        names = list(model._modules)
        for i in range(len(names) - 2):
            conv1, act, conv2 = (model._modules[n] for n in names[i : i + 3])
            if StackedSparseStem.fits(conv1, act, conv2):
                first, second = f"{prefix}{names[i]}.", f"{prefix}{names[i + 2]}."
                model._modules[names[i]] = StackedSparseStem(stack, first, second, conv1, act, conv2)
                model._modules[names[i + 1]] = model._modules[names[i + 2]] = nn.Identity()
                break
    for name, child in list(model.named_children()):
        setattr(model, name, _swap(child, stack, f"{prefix}{name}."))
    return model


class Members:
    """M members of one architecture as one network: ``members(x)`` maps (A, B, *obs) to (A, B, actions) logits for
    the A members of ``serving`` (all by default). ``flat``: every member's parameters, what Adam steps."""

    def __init__(self, models: Sequence[nn.Module], device: torch.device, seeds: Sequence[int]) -> None:
        self.device = device
        self.template = copy.deepcopy(models[0]).cpu()
        """Member 0's module as built (a member's own module is this with its row loaded: ``module``)."""
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
        self.network = _swap(copy.deepcopy(self.template), self.stack).to(device) if _swappable(models[0]) else None
        self._vmapped = None if self.network is not None else self._vmap_forward()
        self._acting: tuple[torch.Tensor, Callable | None] | None = None
        """(the ``flat`` it was traced for, the acting forward traced into one graph or ``None`` where it cannot)."""
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
        """Acting (every member, eval mode, no gradients): the swapped network's forward traced once
        (``torch.fx``) into one function of torch calls, each layer's weight views and their reshapes read once
        at the trace (they stay views of ``flat``, which Adam steps in place), no module call per layer: the same
        operations in the same order (16 members of the default MLP: ~17 us a step against ~26, one core).
        Traced again when ``flat`` is replaced (``keep``); the first call after a trace checks it against the
        module bit for bit, and a forward that cannot be traced, or differs, runs as a module."""
        traced = self._acting
        if traced is not None and traced[0] is self.flat:
            return self.network(x) if traced[1] is None else traced[1](x)
        forward = tracing.trace(self.network, self.stack)
        expected = self.network(x)
        fits = forward is not None and torch.equal(forward(x), expected)
        self._acting = (self.flat, forward if fits else None)
        return expected

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
        x = x.to(self.device, torch.float32)
        if serving is None and self.network is not None and not self.training and not torch.is_grad_enabled():
            members, batch = x.shape[:2]  # acting: every member, the stack already serves them all
            return self._acting_forward(x.reshape(members * batch, *x.shape[2:])).reshape(members, batch, -1)
        if serving is None and self.network is not None:
            members, batch = x.shape[:2]
            return self.network(x.reshape(members * batch, *x.shape[2:])).reshape(members, batch, -1)
        self.stack.serve(serving)
        try:
            if self.network is not None:
                members, batch = x.shape[:2]
                return self.network(x.reshape(members * batch, *x.shape[2:])).reshape(members, batch, -1)
            params = {name: self.stack.get(name) for name in self.stack.layout}
            buffers = {k: (v if serving is None else v[serving]) for k, v in self.buffers.items()}
            return self._vmapped(params, buffers, x)
        finally:
            self.stack.serve(None)

    def l2_penalty(self, l2: torch.Tensor, serving: torch.Tensor | None = None) -> torch.Tensor:
        """Each member's ``l2 * sum(w**2)`` over its weight tensors (biases excluded), summed over the members."""
        rows = self.flat if serving is None else self.flat[serving]
        return (l2 * (rows.pow(2) * self.weight_mask).sum(1)).sum()

    def module(self, member: int) -> nn.Module:
        """Member ``member``'s own ``nn.Module`` (on the CPU), its current weights loaded."""
        model = copy.deepcopy(self.template)
        model.load_state_dict(self.state_dict(member))
        return model

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

    def generator_state(self, member: int) -> torch.Tensor:
        return self.stack.generators[member].get_state()

    def set_generator_state(self, member: int, state: torch.Tensor) -> None:
        self.stack.generators[member].set_state(state)

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
                got = self(sample).cpu()
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
