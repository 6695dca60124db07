"""Kernels of ablate's own, for the one input where torch's dense layers waste most of their work: a frame
difference (Pong's), a few dozen non-zero pixels of 6,400. ``stacking`` runs them in place of a member's first
layers when its input is that sparse (``SPARSE``); each is the dense layers' function to float rounding, forward
and backward (``tests/test_sparse.py``), and ``make bench trainer`` measures what they save.

``linear``: a wide ``Linear`` as the sum of the columns its non-zero inputs select. ``Stem``: the first two
convolutions (conv, activation, conv) as changes to their background response: a frame difference makes the first
convolution's output its bias almost everywhere, and the second's the response to that constant almost everywhere,
so both are that background plus the contributions of the non-zero pixels only.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F

SPARSE = 1 / 16
"""An input this sparse or sparser (the share of non-zero entries) takes the sparse kernels."""


ROWS = 64
"""The stem pays from this many rows (an update's batch): for a step's few frames the dense convolutions cost
less than the stem's many small calls. ``linear`` pays for a step's frames too, with its weights transposed once
per update (``stacking.StackedLinear``)."""


def sparse(x: torch.Tensor) -> bool:
    return bool(torch.count_nonzero(x) <= SPARSE * x.numel())


def linear(x: torch.Tensor, weight_t: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``F.linear(x, weight_t.t(), bias)`` for a 2-D ``x`` that is mostly zeros: each row the sum of the rows of
    ``weight_t`` (in, out; contiguous) its non-zero inputs pick, times those inputs: one ``embedding_bag``,
    differentiable in ``weight_t`` and ``bias`` (1,000 Pong frames into 64 units, forward and backward: ~10 ms
    against ~18 dense, one core)."""
    rows, columns = x.nonzero(as_tuple=True)
    offsets = torch.searchsorted(rows, torch.arange(len(x), device=x.device))
    values = x[rows, columns].to(weight_t.dtype)
    out = F.embedding_bag(columns, weight_t, offsets, mode="sum", per_sample_weights=values)
    return out if bias is None else out + bias


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


class Stem:
    """Conv, activation, conv on a square one-channel image, from its non-zero pixels, for the weights given at
    each call (one member's): returns the second convolution's pre-activation output (batch, channels, side,
    side) in channels-last memory. Geometry: square kernels, strides and paddings, no dilation, no groups.

    First convolution: its bias everywhere, plus at the outputs a non-zero pixel feeds (up to 2x2 for Pong's
    7x7 stride 4) that pixel's value times the kernel. Its activation's change from the background, act(pre) -
    act(bias), is non-zero there only; the second convolution is its response to the constant background
    act(bias) (one dense convolution of a single constant image, zero padding included) plus each touched
    position's change times the kernel, at the outputs it feeds. Every step is a differentiable torch op."""

    def __init__(self, size: int, first: tuple[int, int, int], second: tuple[int, int, int], act: Callable) -> None:
        (k1, s1, p1), (k2, self.s2, self.p2) = first, second
        self.size, self.act = size, act
        self.out1_pos, self.k1_pos, self.side1 = _taps(size, k1, s1, p1)
        self.side2 = (self.side1 + 2 * self.p2 - k2) // self.s2 + 1
        # Per residue class (row, column) of an input position modulo the stride: its kernel offsets per axis.
        offsets = [torch.arange(r, k2, self.s2) for r in range(self.s2)]
        self.classes = [(offsets[ry], offsets[rx]) for ry in range(self.s2) for rx in range(self.s2)]

    def background(self, b1: torch.Tensor, w2: torch.Tensor, b2: torch.Tensor) -> torch.Tensor:
        """The second convolution's output (side2 * side2, channels) on the first's constant background."""
        channels = len(b1)
        constant = self.act(b1).view(1, channels, 1, 1).expand(1, channels, self.side1, self.side1)
        response = F.conv2d(constant.contiguous(memory_format=torch.channels_last), w2, b2, self.s2, self.p2)
        return response[0].permute(1, 2, 0).reshape(self.side2 * self.side2, -1)

    def __call__(self, frames: torch.Tensor, w1, b1, w2, b2, background: torch.Tensor | None = None) -> torch.Tensor:
        """``frames``: (batch, size * size), mostly zeros; ``background``: ``background(b1, w2, b2)`` if known."""
        n, device = len(frames), frames.device
        if self.out1_pos.device != device:
            with torch.inference_mode(False):
                self.out1_pos, self.k1_pos = self.out1_pos.to(device), self.k1_pos.to(device)
        rows, columns = frames.nonzero(as_tuple=True)
        channels1, channels2 = len(b1), len(b2)
        n_out1, n_out2 = self.side1 * self.side1, self.side2 * self.side2
        values = frames[rows, columns].to(w1.dtype)

        # First convolution at the outputs the non-zero pixels feed; -1 entries of the tables are no output.
        out1 = self.out1_pos[columns]
        pixel, tap = (out1 >= 0).nonzero(as_tuple=True)
        target1 = rows[pixel] * n_out1 + out1[pixel, tap]
        touched, where = torch.unique(target1, return_inverse=True)
        kernel1 = w1.reshape(channels1, -1).t()  # (k1*k1, channels1)
        contributions = values[pixel, None] * kernel1[self.k1_pos[columns[pixel], tap]]
        pre1 = w1.new_zeros(len(touched), channels1).index_add(0, where, contributions) + b1
        change1 = self.act(pre1) - self.act(b1)  # zero at every position no pixel feeds

        # Second convolution: background plus each touched position's change through the kernel offsets that
        # reach an output. Along an axis, input i meets offsets k = (i + padding) mod stride, + stride, ...:
        # the positions of one residue class share their offsets, one product for the class.
        sample, position1 = touched // n_out1, touched % n_out1
        row1, column1 = position1 // self.side1, position1 % self.side1
        stride, padding = self.s2, self.p2
        residue = ((row1 + padding) % stride) * stride + (column1 + padding) % stride
        targets, contributions2 = [], []
        for cls, (ky, kx) in enumerate(self.classes):
            members = (residue == cls).nonzero(as_tuple=True)[0]
            if not len(members):
                continue
            ky, kx = ky.to(device), kx.to(device)
            kernel = w2.index_select(2, ky).index_select(3, kx)  # (out, in, a, b)
            product = change1[members] @ kernel.permute(1, 2, 3, 0).reshape(channels1, -1)
            out_row = (row1[members, None] + padding - ky) // stride  # (members, a)
            out_column = (column1[members, None] + padding - kx) // stride  # (members, b)
            valid = ((out_row >= 0) & (out_row < self.side2))[:, :, None] & (
                (out_column >= 0) & (out_column < self.side2)
            )[:, None, :]
            target = sample[members, None, None] * n_out2 + out_row[:, :, None] * self.side2 + out_column[:, None, :]
            keep = valid.reshape(-1)
            targets.append(target.reshape(-1)[keep])
            contributions2.append(product.reshape(-1, channels2)[keep])
        target2 = torch.cat(targets) if targets else torch.zeros(0, dtype=torch.int64, device=device)
        picked = torch.cat(contributions2) if contributions2 else change1.new_zeros(0, channels2)
        if background is None:
            background = self.background(b1, w2, b2)
        pre2 = background.repeat(n, 1).index_add(0, target2, picked)
        # (batch * side * side, channels) is (batch, side, side, channels): NCHW shape in channels-last memory.
        return pre2.reshape(n, self.side2, self.side2, -1).permute(0, 3, 1, 2)
