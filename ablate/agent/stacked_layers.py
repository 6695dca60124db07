"""The stacked versions of torch's standard layers (``Linear``, ``LayerNorm``, ``Conv1d``/``Conv2d``,
``Dropout``), and ``swap``, which puts them in place of a user's module's own: each reads every member's
parameters at once from ``stacking``'s stack, the members folded into the batch dimension member-major (a
``Linear`` is one ``baddbmm``; a convolution one grouped convolution, a group per member), so the module's own
``forward`` runs as written.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import nn

from ablate.agent import sparse

if TYPE_CHECKING:
    from ablate.agent.stacking import _Stack


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
        one = self._stack.one
        if one is not None:  # one member's update: its own Linear
            return F.linear(x, one[self._weight], None if self._bias is None else one[self._bias])
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
    """A member's own ``F.layer_norm`` in its update; for several, the normalisation with a unit scale and zero
    shift (torch's kernel with an affine is ~1.6x its kernel without, 512 x 32 on one core: 13.6 us against 21.8),
    then each member's scale and shift."""

    def __init__(self, stack: _Stack, prefix: str, layer: nn.LayerNorm) -> None:
        super().__init__(stack, prefix, layer)
        self.normalized_shape, self.eps = tuple(layer.normalized_shape), layer.eps
        self.register_buffer("unit", torch.ones(self.normalized_shape), persistent=False)
        self.register_buffer("zero", torch.zeros(self.normalized_shape), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        one = self._stack.one
        if one is not None:
            weight, bias = (one[name] if name else None for name in (self._weight, self._bias))
            return F.layer_norm(x, self.normalized_shape, weight, bias, self.eps)
        out = F.layer_norm(x, self.normalized_shape, self.unit, self.zero, self.eps)
        weight, bias = self._params()
        if weight is None and bias is None:
            return out
        grouped = out.reshape(self._stack.count(), -1, *self.normalized_shape)
        if weight is not None and bias is not None:
            return torch.addcmul(bias.unsqueeze(1), grouped, weight.unsqueeze(1)).reshape(x.shape)
        grouped = grouped * weight.unsqueeze(1) if weight is not None else grouped + bias.unsqueeze(1)
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


def swappable(model: nn.Module) -> bool:
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


def swap(model: nn.Module, stack: _Stack, prefix: str = "") -> nn.Module:
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
        setattr(model, name, swap(child, stack, f"{prefix}{name}."))
    return model
