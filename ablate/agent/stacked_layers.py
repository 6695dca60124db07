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
        self.narrow = layer.out_features < layer.in_features
        """Fewer outputs than inputs (the logits): computed as W @ x^T, as batched GEMMs are ~2x slower with a
        handful of output columns than with a handful of rows (16 members' 32 -> 2 layer: 13 us against 30)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
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
        convolve = F.conv1d if self.dims == 1 else F.conv2d
        one = self._stack.one
        if one is not None:  # one member's update: its own convolution
            bias = one[self._bias] if self._bias else None
            return convolve(x, one[self._weight], bias, self.stride, self.padding, self.dilation)
        weight, bias = self._params()
        members = self._stack.count()
        # (members * batch, channels, ...) -> (batch, members * channels, ...): a group per member
        grouped = x.unflatten(0, (members, -1)).transpose(0, 1).flatten(1, 2)
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


def swap(model: nn.Module, stack: _Stack, prefix: str = "") -> nn.Module:
    """``model`` with its layers replaced (in place) by their stacked versions, reading ``stack`` by their names."""
    if isinstance(model, nn.Linear):
        return StackedLinear(stack, prefix, model)
    if isinstance(model, nn.LayerNorm):
        return StackedLayerNorm(stack, prefix, model)
    if isinstance(model, nn.Conv1d | nn.Conv2d):
        return StackedConv(stack, prefix, model)
    if type(model) is nn.Dropout:
        return StackedDropout(stack, model.p)
    for name, child in list(model.named_children()):
        setattr(model, name, swap(child, stack, f"{prefix}{name}."))
    return model
