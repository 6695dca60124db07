"""Acting for a population: every member's logits on its own observations in one batched forward.

``DenseStack``: networks of dense layers (CartPole's 1-D convolutions, a user's LayerNorm, Pong's int8 frames as
sparse products): the members' weights stacked member-first, one numpy matrix product per layer for all of them;
each member's slice is the product it computes alone, so a member acts bit for bit as its population of one.
``StemStack``: Pong's built-in CNN, each member's whole network in numpy over the frame difference's non-zero
pixels. ``MembersStack``: any ``nn.Module``, its own forward over the members' stacked parameters
(``stacking.Members``; equal to float tolerance). ``LoopStack``: each member's own forward in turn (a built-in
network on a GPU, exactly; a population of one). No gradients: acting is eval mode.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from ablate.agent.policies import NUMPY_LAYERS, Policy, conv1d, conv1d_weight, nonzero, plain_conv1d, sparse_matmul
from ablate.agent.stacking import Members


class DenseStack:
    """M members of one dense architecture: (M, N, *obs) float32 -> (M, N, actions) logits in numpy."""

    def __init__(self, models: Sequence[nn.Module]) -> None:
        self.models = list(models)
        self.layers = list(_body(self.models[0]))
        self.weights: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for m in range(len(self.models)):
            self.refresh(m)

    @staticmethod
    def fits(model: nn.Module) -> bool:
        body = _body(model)
        return body is not None and all(
            isinstance(m, nn.Linear) or plain_conv1d(m) or _plain_layer_norm(m) or type(m) in NUMPY_LAYERS for m in body
        )

    def refresh(self, member: int) -> None:
        """Member ``member``'s weights copied into the stacks (after its update or a restore)."""
        body = _body(self.models[member])
        for k, module in enumerate(body):
            if isinstance(module, nn.LayerNorm):  # its affine scale and shift (ones and zeros without them)
                shape = module.normalized_shape
                weight = (
                    module.weight.detach().cpu().numpy()[None] if module.weight is not None else np.ones((1, *shape))
                )
                bias = module.bias.detach().cpu().numpy()[None] if module.bias is not None else np.zeros((1, *shape))
            elif isinstance(module, nn.Linear | nn.Conv1d):
                weight = module.weight.detach().cpu().numpy()
                weight = conv1d_weight(weight) if isinstance(module, nn.Conv1d) else weight.T
                bias = module.bias.detach().cpu().numpy()[None, :]
            else:
                continue
            if k not in self.weights:
                count = len(self.models)
                self.weights[k] = (
                    np.zeros((count, *weight.shape), np.float32),
                    np.zeros((count, *bias.shape), np.float32),
                )
            self.weights[k][0][member] = weight
            self.weights[k][1][member] = bias

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        x = observations if observations.dtype == np.int8 else observations.astype(np.float32, copy=False)
        for k, module in enumerate(self.layers):
            if k in self.weights:
                weight, bias = self.weights[k]
                if isinstance(module, nn.LayerNorm):
                    centred = x - x.mean(axis=-1, keepdims=True)
                    x = centred / np.sqrt((centred * centred).mean(axis=-1, keepdims=True) + module.eps)
                    x = x * weight + bias
                elif isinstance(module, nn.Conv1d):
                    x = conv1d(x, weight, bias)
                elif x.dtype == np.int8:  # Pong's frame differences: each member's few non-zero pixels' rows
                    x = np.stack([sparse_matmul(rows, w) for rows, w in zip(x, weight, strict=True)])
                    x += bias
                else:
                    x = np.matmul(x, weight)
                    x += bias
            elif isinstance(module, nn.Flatten):
                x = x.reshape(*x.shape[:2], -1)
            else:
                x = NUMPY_LAYERS[type(module)](x)
        return x

    def keep(self, members: list[int]) -> None:
        self.models = [self.models[m] for m in members]
        self.weights = {k: (w[members], b[members]) for k, (w, b) in self.weights.items()}


class StemStack:
    """Pong's built-in CNN: each member acts through its whole network in numpy (``sparse_cnn.NumpyStem``, built
    from its weights after each update); a frame with no sparsity to exploit goes through its dense layers."""

    def __init__(self, models: Sequence[nn.Module]) -> None:
        self.models = list(models)
        self.stems: list = [None] * len(self.models)

    @staticmethod
    def fits(model: nn.Module) -> bool:
        return isinstance(model, Policy) and model.acts_in_numpy

    def refresh(self, member: int) -> None:
        self.stems[member] = None

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        return np.stack([self._logits(m, x) for m, x in enumerate(observations)])

    def _logits(self, member: int, observations: np.ndarray) -> np.ndarray:
        model = self.models[member]
        frames = observations.reshape(len(observations), -1)
        if observations.dtype != np.int8:  # not Pong's frame differences (another Atari game's): the dense network
            return model.dense_logits(observations)
        rows, columns = nonzero(frames)
        if len(rows) * 4 >= frames.size:  # no sparsity to exploit: the dense network
            return model.dense_logits(observations)
        if self.stems[member] is None:
            self.stems[member] = model.numpy_stem()
        return self.stems[member](frames, rows, columns)

    def keep(self, members: list[int]) -> None:
        self.models = [self.models[m] for m in members]
        self.stems = [self.stems[m] for m in members]


class LoopStack:
    """Each member's own ``forward`` on its own rows, in turn (a built-in CNN acts exactly as alone)."""

    def __init__(self, models: Sequence[nn.Module], device: torch.device) -> None:
        self.models = list(models)
        self.device = device

    def refresh(self, member: int) -> None:
        pass

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return np.stack(
                [
                    model(torch.from_numpy(np.ascontiguousarray(x)).to(self.device)).float().cpu().numpy()
                    for model, x in zip(self.models, observations, strict=True)
                ]
            )

    def keep(self, members: list[int]) -> None:
        self.models = [self.models[m] for m in members]


class MembersStack:
    """Any module (a user's): the members' parameters stacked as one (``stacking.Members``), acting through the
    module's own ``forward`` with stacked layers (``vmap`` where those cannot serve); a member's row is refreshed
    after its update (equal to each member's own forward to float tolerance)."""

    def __init__(self, models: Sequence[nn.Module], device: torch.device, shape: Sequence[int]) -> None:
        self.models = list(models)
        self.members = Members(self.models, device, range(len(self.models)))
        self.members.check(self.models, shape)

    def refresh(self, member: int) -> None:
        self.members.load_state_dict(member, self.models[member].state_dict())

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(np.require(observations, requirements="CW"))
        with torch.inference_mode():
            return self.members(x).cpu().numpy()

    def keep(self, members: list[int]) -> None:
        self.models = [self.models[m] for m in members]
        self.members.keep(members)


def stack(models: Sequence[nn.Module], device: torch.device, built_in: bool, shape: Sequence[int]):
    """The fastest exact stack for ``models`` (one architecture) whose observations have ``shape``: dense in numpy
    on a CPU, each member's own forward for a built-in CNN or a single member, else stacked members."""
    for model in models:
        model.eval()
    if device.type == "cpu" and DenseStack.fits(models[0]):
        return DenseStack(models)
    if device.type == "cpu" and StemStack.fits(models[0]):
        return StemStack(models)
    if built_in or len(models) == 1:
        return LoopStack(models, device)
    return MembersStack(models, device, shape)


def _plain_layer_norm(module: nn.Module) -> bool:
    """A ``LayerNorm`` over the last axis (a user's LayerNorm MLP), which numpy computes to float tolerance."""
    return isinstance(module, nn.LayerNorm) and len(module.normalized_shape) == 1


def _body(model: nn.Module) -> nn.Sequential | None:
    """The ``nn.Sequential`` that maps observations to logits: the module itself, or a built-in ``Policy``'s body."""
    body = getattr(model, "body", model)
    return body if isinstance(body, nn.Sequential) and model.forward.__func__ in _PLAIN_FORWARDS else None


_PLAIN_FORWARDS = {nn.Sequential.forward, Policy.forward}
"""Forwards that run their ``Sequential`` body on float observations (``Policy``'s int8 paths are the same function)."""
