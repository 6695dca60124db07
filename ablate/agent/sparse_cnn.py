"""The first two convolutions of Pong's CNN on a sparse frame difference, as changes to their background response.

A frame difference has a few dozen non-zero pixels of 6,400, so the first convolution's output is its bias almost
everywhere, and the second's is the response to that constant almost everywhere: compute both as that background
plus the contributions of the non-zero pixels only. The same function as the dense convolutions (to float
rounding), forward and backward, a few times less arithmetic. ``NumpyStem``: the whole CNN in numpy for acting.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


def _taps(size: int, kernel: int, stride: int, padding: int) -> tuple[torch.Tensor, torch.Tensor, int]:
    """For each input position of a square ``size`` x ``size`` map under a square convolution: the output
    positions it feeds and the kernel offset it meets there, as (size*size, taps) tables of flat indices, and
    the output's side. Positions feeding fewer than ``taps`` outputs are padded with output index -1."""
    out = (size + 2 * padding - kernel) // stride + 1
    # 1-D first: input coordinate i feeds output o through kernel offset k = i + padding - stride * o.
    per_axis: list[list[tuple[int, int]]] = []
    for i in range(size):
        per_axis.append([(o, i + padding - stride * o) for o in range(out) if 0 <= i + padding - stride * o < kernel])
    width = max(len(p) for p in per_axis) ** 2
    outputs = np.full((size * size, width), -1, np.int64)
    offsets = np.zeros((size * size, width), np.int64)
    for y in range(size):
        for x in range(size):
            pairs = [(oy * out + ox, ky * kernel + kx) for oy, ky in per_axis[y] for ox, kx in per_axis[x]]
            for j, (o, k) in enumerate(pairs):
                outputs[y * size + x, j] = o
                offsets[y * size + x, j] = k
    return torch.from_numpy(outputs), torch.from_numpy(offsets), out


def fits(body: nn.Module, observation_shape: tuple[int, ...]) -> bool:
    """Whether ``body`` starts as ``SparseStem`` needs: a one-channel square image, two square convolutions
    with an elementwise activation after each, no dilation or groups."""
    if not isinstance(body, nn.Sequential) or len(body) < 5 or len(observation_shape) != 3:
        return False
    first, act1, second, act2 = body[0], body[1], body[2], body[3]
    convs_ok = all(
        isinstance(c, nn.Conv2d)
        and c.bias is not None
        and c.groups == 1
        and c.dilation == (1, 1)
        and c.padding_mode == "zeros"
        and isinstance(c.padding, tuple)
        and len(set(c.kernel_size)) == len(set(c.stride)) == len(set(c.padding)) == 1
        for c in (first, second)
    )
    elementwise = (nn.ReLU, nn.Tanh, nn.ELU, nn.GELU)
    return (
        convs_ok
        and isinstance(act1, elementwise)
        and isinstance(act2, elementwise)
        and observation_shape[0] == first.in_channels == 1
        and observation_shape[1] == observation_shape[2]
    )


class SparseStem:
    """Conv, activation, conv of ``body[:3]`` on int8 frames, from their non-zero pixels: returns the second
    convolution's pre-activation output (batch, channels, side, side) in channels-last memory.

    First convolution: its bias everywhere, plus at the outputs a non-zero pixel feeds (up to 2x2 for Pong's
    7x7 stride 4) that pixel's value times the kernel. Its activation's change from the background, act(pre) -
    act(bias), is non-zero there only; the second convolution is its response to the constant background
    act(bias) (one dense convolution of a single constant image, zero padding included) plus each touched
    position's change times the kernel, at the outputs it feeds. Every step is a differentiable torch op:
    autograd gives the dense path's gradients."""

    def __init__(self, body: nn.Sequential, size: int) -> None:
        self.first, self.act1, self.second = body[0], body[1], body[2]
        k1, s1, p1 = self.first.kernel_size[0], self.first.stride[0], self.first.padding[0]
        k2, s2, p2 = self.second.kernel_size[0], self.second.stride[0], self.second.padding[0]
        self.size = size
        self.out1_pos, self.k1_pos, self.side1 = _taps(size, k1, s1, p1)
        self.side2 = (self.side1 + 2 * p2 - k2) // s2 + 1
        # Per residue class (row, column) of an input position modulo the stride: its kernel offsets per axis.
        offsets = [torch.arange(r, k2, s2) for r in range(s2)]
        self.classes = [(offsets[ry], offsets[rx]) for ry in range(s2) for rx in range(s2)]
        self._cache: tuple[tuple[int, ...], torch.Tensor] | None = None

    def _to(self, device: torch.device) -> None:
        if self.out1_pos.device != device:
            self.out1_pos, self.k1_pos = self.out1_pos.to(device), self.k1_pos.to(device)

    def background(self) -> torch.Tensor:
        """The second convolution's output (side2 * side2, channels) on the first's constant background.
        Outside autograd (acting) it is cached until a parameter of the two convolutions changes."""
        parameters = (self.first.bias, self.second.weight, self.second.bias)
        grad = torch.is_grad_enabled()
        versions = tuple(p._version for p in parameters)
        if not grad and self._cache is not None and self._cache[0] == versions:
            return self._cache[1]
        channels = self.first.out_channels
        constant = self.act1(self.first.bias).view(1, channels, 1, 1).expand(1, channels, self.side1, self.side1)
        response = self.second(constant.contiguous(memory_format=torch.channels_last))
        background = response[0].permute(1, 2, 0).reshape(self.side2 * self.side2, -1)
        if not grad:
            self._cache = (versions, background)
        return background

    def __call__(self, frames: torch.Tensor, rows: torch.Tensor, columns: torch.Tensor) -> torch.Tensor:
        """``frames``: int8 (batch, size * size); ``rows``, ``columns``: its non-zero entries."""
        n = len(frames)
        device = frames.device
        self._to(device)
        first, second = self.first, self.second
        n_out1, n_out2 = self.side1 * self.side1, self.side2 * self.side2
        values = frames[rows, columns].to(first.weight.dtype)

        # First convolution at the outputs the non-zero pixels feed; -1 entries of the tables are no output.
        out1 = self.out1_pos[columns]
        valid1 = out1 >= 0
        pixel, tap = valid1.nonzero(as_tuple=True)
        target1 = rows[pixel] * n_out1 + out1[pixel, tap]
        touched, where = torch.unique(target1, return_inverse=True)
        kernel1 = first.weight.reshape(first.out_channels, -1).t()  # (k1*k1, channels1)
        contributions = values[pixel, None] * kernel1[self.k1_pos[columns[pixel], tap]]
        pre1 = torch.zeros(len(touched), first.out_channels, dtype=kernel1.dtype, device=device)
        pre1 = pre1.index_add(0, where, contributions) + first.bias
        change1 = self.act1(pre1) - self.act1(first.bias)  # zero at every position no pixel feeds

        # Second convolution: background plus each touched position's change through the kernel offsets that
        # reach an output. Along an axis, input i meets offsets k = (i + padding) mod stride, + stride, ...:
        # the positions of one residue class share their offsets, one product for the class.
        sample, position1 = touched // n_out1, touched % n_out1
        row1, column1 = position1 // self.side1, position1 % self.side1
        stride, padding = second.stride[0], second.padding[0]
        residue = ((row1 + padding) % stride) * stride + (column1 + padding) % stride
        targets, contributions2 = [], []
        for cls, (ky, kx) in enumerate(self.classes):
            members = (residue == cls).nonzero(as_tuple=True)[0]
            if not len(members):
                continue
            ky, kx = ky.to(device), kx.to(device)
            kernel = second.weight.index_select(2, ky).index_select(3, kx)  # (out, in, a, b)
            product = change1[members] @ kernel.permute(1, 2, 3, 0).reshape(second.in_channels, -1)
            out_row = (row1[members, None] + padding - ky) // stride  # (members, a)
            out_column = (column1[members, None] + padding - kx) // stride  # (members, b)
            valid = ((out_row >= 0) & (out_row < self.side2))[:, :, None] & (
                (out_column >= 0) & (out_column < self.side2)
            )[:, None, :]
            target = sample[members, None, None] * n_out2 + out_row[:, :, None] * self.side2 + out_column[:, None, :]
            keep = valid.reshape(-1)
            targets.append(target.reshape(-1)[keep])
            contributions2.append(product.reshape(-1, second.out_channels)[keep])
        target2 = torch.cat(targets) if targets else torch.zeros(0, dtype=torch.int64, device=device)
        picked = torch.cat(contributions2) if contributions2 else change1.new_zeros(0, second.out_channels)
        pre2 = self.background().repeat(n, 1).index_add(0, target2, picked)
        # (batch * side * side, channels) is (batch, side, side, channels): NCHW shape in channels-last memory.
        return pre2.reshape(n, self.side2, self.side2, -1).permute(0, 3, 1, 2)


class NumpyStem:
    """The whole CNN for acting (a few frames, no autograd), in numpy: ``SparseStem``'s two sparse convolutions,
    then the rest of the body (a convolution as one product over its patches, the dense layers). torch's
    per-op overhead (~10 us) is most of a forward through this network at 4 frames; numpy's is ~1 us.
    ``numpy_layer`` maps a module of the body to its numpy function ((weight.T, bias) for a Linear)."""

    def __init__(self, stem: SparseStem, body: nn.Sequential, numpy_layer) -> None:
        self.stem = stem
        self.act1, self.act2 = numpy_layer(body[1]), numpy_layer(body[3])
        third = body[4]
        self.layers = [
            (torch.from_numpy(layer[0]), layer[1]) if isinstance(layer, tuple) else layer
            for layer in (numpy_layer(m) for m in body[5:])
        ]
        first, second = stem.first, stem.second
        self.kernel1 = first.weight.detach().reshape(first.out_channels, -1).t().numpy().copy()
        self.bias1 = first.bias.detach().numpy().copy()
        with torch.inference_mode():
            self.background2 = stem.background().numpy().copy()  # (side2 * side2, channels2)
        self.background1 = self.act1(self.bias1)
        self.channels1 = np.arange(first.out_channels)
        self.channels2 = np.arange(second.out_channels)
        self.out1_pos, self.k1_pos = stem.out1_pos.numpy(), stem.k1_pos.numpy()
        out2_pos, k2_pos, _ = _taps(stem.side1, second.kernel_size[0], second.stride[0], second.padding[0])
        self.out2_pos, self.k2_pos = out2_pos.numpy(), k2_pos.numpy()
        self.out2_offsets = second.kernel_size[0] ** 2
        # (in, offsets * out): row i, column k * out + o is weight[o, i, ky, kx] with k = ky * kernel + kx.
        self.kernel2 = second.weight.detach().permute(1, 2, 3, 0).reshape(second.in_channels, -1).contiguous()
        self.kernel3 = third.weight.detach().permute(2, 3, 1, 0).reshape(-1, third.out_channels).contiguous()
        self.bias3 = third.bias.detach().numpy().copy()
        # For each output of the third convolution and kernel offset (ky, kx): the input position it reads, or
        # side2 * side2 (a zero row) where that falls in the padding.
        k, s3, p3, side2 = third.kernel_size[0], third.stride[0], third.padding[0], stem.side2
        self.side3 = (side2 + 2 * p3 - k) // s3 + 1
        oy, ox, ky, kx = np.meshgrid(*[np.arange(self.side3)] * 2, *[np.arange(k)] * 2, indexing="ij")
        y, x = oy * s3 - p3 + ky, ox * s3 - p3 + kx
        inside = (y >= 0) & (y < side2) & (x >= 0) & (x < side2)
        self.patch3 = np.where(inside, y * side2 + x, side2 * side2).ravel()

    def __call__(self, frames: np.ndarray, rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """Logits of int8 ``frames`` (batch, size * size) with non-zero entries at ``rows``, ``columns``."""
        stem = self.stem
        n, c1, c2 = len(frames), len(self.bias1), self.background2.shape[1]
        side1, side2 = stem.side1, stem.side2
        values = frames[rows, columns].astype(np.float32)
        out1 = self.out1_pos[columns]
        pixel, tap = np.nonzero(out1 >= 0)
        target1 = rows[pixel] * side1 * side1 + out1[pixel, tap]
        contributions = values[pixel, None] * self.kernel1[self.k1_pos[columns[pixel], tap]]
        # Few ops rather than little arithmetic (at 4 frames numpy's per-call cost dominates): bincount as the
        # scatter-add over every (position, channel) of the batch, then the touched positions picked out.
        n1 = n * side1 * side1
        summed = np.bincount((target1[:, None] * c1 + self.channels1).ravel(), contributions.ravel(), minlength=n1 * c1)
        touched = np.flatnonzero(np.bincount(target1, minlength=n1))
        pre1 = summed.reshape(n1, c1)[touched].astype(np.float32) + self.bias1
        change1 = self.act1(pre1) - self.background1

        # Every kernel offset of the second convolution in one product; the tables pick the offsets that
        # reach an output (up to 3 x 3 of 5 x 5 for Pong's stride 2).
        offsets = self.out2_offsets
        through = _matmul(change1, self.kernel2).reshape(len(touched) * offsets, c2)
        sample, position1 = touched // (side1 * side1), touched % (side1 * side1)
        out2 = self.out2_pos[position1]
        source, tap2 = np.nonzero(out2 >= 0)
        picked = through[source * offsets + self.k2_pos[position1[source], tap2]]
        target2 = sample[source] * side2 * side2 + out2[source, tap2]
        pre2 = np.bincount(
            (target2[:, None] * c2 + self.channels2).ravel(), picked.ravel(), minlength=n * side2 * side2 * c2
        )
        pre2 = pre2.reshape(n, side2 * side2, c2).astype(np.float32) + self.background2
        hidden = self.act2(pre2.reshape(n, side2, side2, c2))

        # Third convolution: every output's patch (k x k x channels, the kernel's layout) gathered in one index
        # (padding reads an appended zero row), one product.
        rows3 = np.concatenate([hidden.reshape(n, side2 * side2, c2), np.zeros((n, 1, c2), np.float32)], axis=1)
        patches = rows3[:, self.patch3].reshape(n * self.side3 * self.side3, -1)
        x = (_matmul(patches, self.kernel3) + self.bias3).reshape(n, self.side3, self.side3, -1).transpose(0, 3, 1, 2)
        for layer in self.layers:
            if isinstance(layer, tuple):
                x = _matmul(x, layer[0])
                x += layer[1]
            else:
                x = layer(x)
        return x


def _matmul(a: np.ndarray, b: torch.Tensor) -> np.ndarray:
    """``a @ b`` through torch's oneDNN/MKL product: numpy's bundled OpenBLAS took ~10x as long for the third
    convolution's (100 x 288) @ (288 x 48) on one thread."""
    return (torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)) @ b).numpy()
