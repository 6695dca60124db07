"""A Pong population's acting: every member's frames through every member's own network in one pass, in numpy,
the members' weights stacked member-first (``StackedPongActor``); the sparse first convolutions kept.

The same function as each member's ``Policy.act_logits`` (to float rounding: stacked products sum in another
order), with a population's worth of frames per numpy call instead of one member's: acting at 4 frames a
member is per-call overhead, not arithmetic (docs/performance.md, Pong).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ablate.agent import sparse_cnn
from ablate.agent.envs import is_pong
from ablate.agent.policies import _NUMPY_ACTIVATIONS, Policy, _nonzero, _numpy_layer
from ablate.config import TrialConfig

_ACTING_LAYERS = (nn.Linear, nn.Dropout, nn.Flatten, nn.ReLU, nn.Tanh, nn.ELU)
"""Layers with a numpy stand-in for acting (``policies._NUMPY_ACTIVATIONS``; not GELU)."""


_ACTING_ACTIVATIONS = ("relu", "tanh", "elu")
"""Those the stacked forward has a numpy stand-in for (GELU's single trial acts through torch)."""


def pong_population_group(config: TrialConfig) -> tuple | None:
    """Pong configs with one group share a population: one network (the model and its actions) for the stacked
    forward, and one batch shape (emulators and episodes per update) so every member's step and update cost
    alike. ``None``: not a Pong config a population can act for."""
    if not is_pong(config.env_id) or config.model.activation not in _ACTING_ACTIVATIONS:
        return None
    return (config.env_id, config.model, config.action_set, config.vector_envs, config.episodes_per_update)


def stackable_policy(policy: Policy) -> bool:
    """Whether ``StackedPongActor`` can act for ``policy``: Pong's MLP, or its CNN on the sparse stem, with
    activations numpy has (GELU's acting runs through torch)."""
    body = policy.body
    dense = all(isinstance(m, _ACTING_LAYERS) for m in body)
    if policy._sparse_first:
        return dense
    if policy._sparse_stem is None or not isinstance(body[4], nn.Conv2d):
        return False
    return all(isinstance(m, _ACTING_LAYERS) for m in [body[1], body[3], *body[5:]])


def _versions(parameters: list[torch.Tensor]) -> tuple[int, ...]:
    return tuple(p._version for p in parameters)


def _grouped(x: np.ndarray, weights: torch.Tensor, bounds: np.ndarray) -> np.ndarray:
    """Rows ``bounds[m]:bounds[m + 1]`` of ``x`` times ``weights[m]``, one product per member: a member's
    logits never depend on which other members are playing (one ``torch.bmm`` over equal groups rounds
    differently from one member's product, so a resumed population could drift from the unbroken one)."""
    a = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
    parts = [a[b0:b1] @ weights[m] for m, (b0, b1) in enumerate(zip(bounds[:-1], bounds[1:], strict=True))]
    return torch.cat(parts).numpy() if parts else np.zeros((0, weights.shape[2]), np.float32)


class StackedPongActor:
    """Logits of M Pong policies of one architecture (``stackable_policy``), each on its own frames. A member's
    weights are copied into the stacks again whenever one of its parameters changes (after its update, or a
    restore), as ``Policy.act_logits`` refreshes its own copy."""

    def __init__(self, policies: Sequence[Policy]) -> None:
        self.policies = list(policies)
        body = self.policies[0].body
        self.cnn = not self.policies[0]._sparse_first
        self.linear = [k for k, m in enumerate(body) if isinstance(m, nn.Linear)]
        self.activations = {k: _NUMPY_ACTIVATIONS[type(body[k + 1])] for k in self.linear[:-1]}
        self.versions: list[tuple[int, ...] | None] = [None] * len(self.policies)
        # Cached: walking a module tree for its parameters costs ~70 us, a member's share of a forward.
        self.parameters = [list(p.parameters()) for p in self.policies]
        self.stacks: dict[str, np.ndarray | torch.Tensor] = {}

    def keep(self, slots: list[int]) -> None:
        """Only the members at ``slots`` go on (in that order)."""
        self.policies = [self.policies[s] for s in slots]
        self.versions = [self.versions[s] for s in slots]
        self.parameters = [self.parameters[s] for s in slots]
        self.stacks = {name: stack[slots] for name, stack in self.stacks.items()}

    def _member_arrays(self, policy: Policy) -> dict[str, np.ndarray]:
        """One member's acting weights, by stack name."""
        arrays: dict[str, np.ndarray] = {}
        layers = [_numpy_layer(policy.body[k]) for k in self.linear]
        if self.cnn:
            stem = sparse_cnn.NumpyStem(policy._sparse_stem, policy.body, _numpy_layer)
            arrays |= {
                "kernel1": stem.kernel1,
                "bias1": stem.bias1,
                "background1": stem.background1,
                "background2": stem.background2,
                "kernel2": stem.kernel2.numpy(),
                "kernel3": stem.kernel3.numpy(),
                "bias3": stem.bias3,
            }
        for i, (weight, bias) in enumerate(layers):
            arrays[f"dense_weight{i}"], arrays[f"dense_bias{i}"] = weight, bias
        return arrays

    def _refresh(self) -> None:
        for m, policy in enumerate(self.policies):
            versions = _versions(self.parameters[m])
            if versions == self.versions[m]:
                continue
            arrays = self._member_arrays(policy)
            if not self.stacks:
                shape = {name: (len(self.policies), *a.shape) for name, a in arrays.items()}
                self.stacks = {name: np.zeros(s, np.float32) for name, s in shape.items()}
                # Products read these as torch tensors sharing the numpy memory: refreshed in place.
                for name in ("kernel2", "kernel3", *(f"dense_weight{i}" for i in range(len(self.linear)))):
                    if name in self.stacks:
                        self.stacks[name] = torch.from_numpy(self.stacks[name])
            for name, a in arrays.items():
                self.stacks[name][m] = torch.from_numpy(a) if isinstance(self.stacks[name], torch.Tensor) else a
            self.versions[m] = versions

    def logits(self, frames: np.ndarray, counts: Sequence[int]) -> np.ndarray:
        """``frames``: int8 (F, 1, 80, 80), member 0's ``counts[0]`` frames first, then member 1's, ...;
        returns (F, actions) float32, each frame through its own member's network."""
        self._refresh()
        counts = np.asarray(counts, np.int64)
        bounds = np.concatenate([[0], np.cumsum(counts)])
        member = np.repeat(np.arange(len(counts)), counts)
        x = frames.reshape(len(frames), -1)
        rows, columns = _nonzero(x)
        if self.cnn:
            x, first = self._cnn_stem(x, rows, columns, member, bounds), 0
        else:
            x, first = self._sparse_first(x, rows, columns, member), 1
            if self.linear[0] in self.activations:
                x = self.activations[self.linear[0]](x)
        for i in range(first, len(self.linear)):
            x = _grouped(x, self.stacks[f"dense_weight{i}"], bounds) + self.stacks[f"dense_bias{i}"][member]
            if self.linear[i] in self.activations:
                x = self.activations[self.linear[i]](x)
        return x

    def _sparse_first(self, x: np.ndarray, rows: np.ndarray, columns: np.ndarray, member: np.ndarray) -> np.ndarray:
        """The MLP's first layer (and its bias) from the non-zero pixels: each one's weight row of its member,
        scaled by its value, summed per frame (one ``embedding_bag`` over every member's frames, as
        ``Policy._sparse_forward`` for one member's update)."""
        weight = self.stacks["dense_weight0"]  # (M, 6400, hidden)
        members, inputs, hidden = weight.shape
        table = weight.view(members * inputs, hidden)
        index = torch.from_numpy(member[rows] * inputs + columns)
        offsets = torch.from_numpy(np.searchsorted(rows, np.arange(len(x))))
        values = torch.from_numpy(x[rows, columns].astype(np.float32))
        summed = F.embedding_bag(index, table, offsets, mode="sum", per_sample_weights=values).numpy()
        return summed + self.stacks["dense_bias0"][member]

    def _cnn_stem(
        self, x: np.ndarray, rows: np.ndarray, columns: np.ndarray, member: np.ndarray, bounds: np.ndarray
    ) -> np.ndarray:
        """``sparse_cnn.NumpyStem`` over every member's frames at once: the two sparse convolutions and the third
        as a product over its patches, each frame with its member's kernels; returns the flattened features."""
        s = self.stacks
        stem = self.policies[0]._sparse_stem
        n = len(x)
        c1, c2 = s["bias1"].shape[1], s["background2"].shape[2]
        side1, side2 = stem.side1, stem.side2
        out1_pos, k1_pos = stem.out1_pos.numpy(), stem.k1_pos.numpy()
        values = x[rows, columns].astype(np.float32)
        out1 = out1_pos[columns]
        pixel, tap = np.nonzero(out1 >= 0)
        target1 = rows[pixel] * side1 * side1 + out1[pixel, tap]
        contributions = values[pixel, None] * s["kernel1"][member[rows[pixel]], k1_pos[columns[pixel], tap]]
        # The scatter-add over the touched positions only (a population's frames: n * 400 * 16 outputs, a few
        # hundred touched): each target's rank among them, then one bincount of that size.
        n1 = n * side1 * side1
        touched = np.flatnonzero(np.bincount(target1, minlength=n1))
        rank = np.zeros(n1, np.int64)
        rank[touched] = np.arange(len(touched))
        summed = np.bincount(
            (rank[target1][:, None] * c1 + np.arange(c1)).ravel(), contributions.ravel(), minlength=len(touched) * c1
        )
        touched_member = member[touched // (side1 * side1)]
        pre1 = summed.reshape(len(touched), c1).astype(np.float32) + s["bias1"][touched_member]
        act1 = _NUMPY_ACTIVATIONS[type(self.policies[0].body[1])]
        change1 = act1(pre1) - s["background1"][touched_member]

        # Second convolution: every kernel offset of each touched position through its member's kernel (touched
        # positions come frame by frame, so member by member), then the offsets that reach an output.
        offsets = self.policies[0].body[2].kernel_size[0] ** 2
        touched_bounds = np.searchsorted(touched_member, np.arange(len(bounds)))
        through = _grouped(change1, s["kernel2"], touched_bounds).reshape(len(touched) * offsets, c2)
        out2_pos, k2_pos = self._second_taps(stem)
        sample, position1 = touched // (side1 * side1), touched % (side1 * side1)
        out2 = out2_pos[position1]
        source, tap2 = np.nonzero(out2 >= 0)
        picked = through[source * offsets + k2_pos[position1[source], tap2]]
        target2 = sample[source] * side2 * side2 + out2[source, tap2]
        pre2 = np.bincount(
            (target2[:, None] * c2 + np.arange(c2)).ravel(), picked.ravel(), minlength=n * side2 * side2 * c2
        )
        pre2 = pre2.reshape(n, side2 * side2, c2).astype(np.float32) + s["background2"][member]
        hidden = _NUMPY_ACTIVATIONS[type(self.policies[0].body[3])](pre2)

        rows3 = np.concatenate([hidden, np.zeros((n, 1, c2), np.float32)], axis=1)
        patch3, side3 = self._third_patches(stem)
        patches = rows3[:, patch3].reshape(n * side3 * side3, -1)
        third = _grouped(patches, s["kernel3"], bounds * side3 * side3).reshape(n, side3 * side3, -1)
        third += s["bias3"][member][:, None, :]
        # NHWC -> the NCHW order nn.Flatten reads, as NumpyStem's transpose.
        features = third.reshape(n, side3, side3, -1).transpose(0, 3, 1, 2).reshape(n, -1)
        return _NUMPY_ACTIVATIONS[type(self.policies[0].body[5])](features)

    def _second_taps(self, stem: sparse_cnn.SparseStem) -> tuple[np.ndarray, np.ndarray]:
        if not hasattr(self, "_taps2"):
            kernel, stride, padding = stem.second.kernel_size[0], stem.second.stride[0], stem.second.padding[0]
            out2_pos, k2_pos, _ = sparse_cnn._taps(stem.side1, kernel, stride, padding)
            self._taps2 = out2_pos.numpy(), k2_pos.numpy()
        return self._taps2

    def _third_patches(self, stem: sparse_cnn.SparseStem) -> tuple[np.ndarray, int]:
        if not hasattr(self, "_patch3"):
            third = self.policies[0].body[4]
            k, s3, p3, side2 = third.kernel_size[0], third.stride[0], third.padding[0], stem.side2
            side3 = (side2 + 2 * p3 - k) // s3 + 1
            oy, ox, ky, kx = np.meshgrid(*[np.arange(side3)] * 2, *[np.arange(k)] * 2, indexing="ij")
            y, x = oy * s3 - p3 + ky, ox * s3 - p3 + kx
            inside = (y >= 0) & (y < side2) & (x >= 0) & (x < side2)
            self._patch3 = np.where(inside, y * side2 + x, side2 * side2).ravel(), side3
        return self._patch3
