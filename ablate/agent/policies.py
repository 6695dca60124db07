"""The built-in policy networks: observation in, action logits out (no softmax inside).

``create_cartpole_model`` and ``create_pong_model`` are the course's names (``models.build_model`` picks one, or
the user's own factory); the numpy forms of their layers serve ``acting.DenseStack``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ablate.agent import sparse_cnn

_ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU, "gelu": nn.GELU}


def _numpy_gelu(x: np.ndarray) -> np.ndarray:
    """``nn.GELU`` (the exact, erf form) for acting. SciPy's ``erf`` is scalar code per element, so an element's
    value does not depend on where it sits in the array: a stack of members acts exactly as each member alone."""
    from scipy.special import erf  # imported here: only a GELU policy pays for it

    return x * np.float32(0.5) * (np.float32(1.0) + erf(x * np.float32(np.sqrt(0.5))))


_NUMPY_ACTIVATIONS = {
    nn.ReLU: lambda x: np.maximum(x, 0),
    nn.Tanh: np.tanh,
    nn.ELU: lambda x: np.where(x > 0, x, np.expm1(np.minimum(x, 0))),
    nn.GELU: _numpy_gelu,
    nn.Dropout: lambda x: x,  # acting is in eval mode: dropout is the identity
    nn.Flatten: lambda x: x.reshape(len(x), -1),  # Pong's MLP: (batch, 1, 80, 80) -> (batch, 6400)
}


class Policy(nn.Module):
    """A built-in network mapping observations of ``observation_shape`` (plus a batch dimension) to logits."""

    def __init__(self, body: nn.Module, observation_shape: tuple[int, ...]) -> None:
        super().__init__()
        self.body = body
        self.observation_shape = tuple(observation_shape)
        self._sparse_first = (
            isinstance(body, nn.Sequential)
            and len(body) >= 2
            and isinstance(body[0], nn.Flatten)
            and isinstance(body[1], nn.Linear)
        )
        self._sparse_stem = (
            sparse_cnn.SparseStem(body, observation_shape[1]) if sparse_cnn.fits(body, self.observation_shape) else None
        )
        self.acts_in_numpy = (
            self._sparse_stem is not None
            and isinstance(body[4], nn.Conv2d)
            and all(isinstance(m, nn.Linear) or type(m) in _NUMPY_ACTIVATIONS for m in [body[1], body[3], *body[5:]])
        )
        """Whether the whole CNN acts in numpy (``numpy_stem``): Pong's, whose later layers all have numpy forms."""
        self._channels_last = any(isinstance(m, nn.Conv2d) for m in body.modules())
        if self._channels_last:
            # oneDNN's 2-D convolutions run ~20% faster forward and backward on NHWC than NCHW on one core
            # (Pong's CNN, a batch of 1,024: `make bench`, pong section); the weights are stored NHWC too.
            self.body.to(memory_format=torch.channels_last)

    def _input(self, observations: torch.Tensor) -> torch.Tensor:
        x = observations.float()
        return x.contiguous(memory_format=torch.channels_last) if self._channels_last else x

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        """Logits. int8 observations (Pong's frame differences) go through a dense body's first layer as a
        sparse product (``embedding_bag`` over the non-zero pixels: the same result, a few times faster for
        a batch in an update), and through a CNN's first two convolutions as their background response plus
        the non-zero pixels' contributions (``sparse_cnn``); any other body gets them as float32."""
        if observations.dtype == torch.int8 and self._sparse_first:
            return self._sparse_forward(observations)
        # CPU only: on a GPU the dense convolutions are a few large kernels, the sparse path dozens of small ones.
        if observations.dtype == torch.int8 and self._sparse_stem is not None and observations.device.type == "cpu":
            x = observations.reshape(len(observations), -1)
            rows, columns = _nonzero_rows_columns(x)
            # A frame with a quarter of its pixels set has no sparsity to exploit (the first frame of an episode
            # is the whole screen): the dense convolutions, the same function.
            if len(rows) * 4 < x.numel():
                return self.body[3:](self._sparse_stem(x, rows, columns))
        return self.body(self._input(observations))

    def numpy_stem(self) -> sparse_cnn.NumpyStem:
        """The CNN in numpy for acting, with copies of the current weights (``acts_in_numpy``)."""
        return sparse_cnn.NumpyStem(self._sparse_stem, self.body, numpy_layer)

    def dense_logits(self, observations: np.ndarray) -> np.ndarray:
        """Logits by the dense layers in torch (acting on frames with no sparsity to exploit)."""
        with torch.inference_mode():
            return self.body(self._input(torch.from_numpy(observations))).numpy()

    def _sparse_forward(self, observations: torch.Tensor) -> torch.Tensor:
        x = observations.reshape(len(observations), -1)
        rows, columns = _nonzero_rows_columns(x)  # row-major: rows ascending
        first = self.body[1]
        offsets = torch.searchsorted(rows, torch.arange(len(x), device=x.device))
        hidden = F.embedding_bag(
            columns, first.weight.t(), offsets, mode="sum", per_sample_weights=x[rows, columns].float()
        )
        return self.body[2:](hidden + first.bias)


NUMPY_LAYERS = _NUMPY_ACTIVATIONS
"""Layers without weights, as numpy functions (acting: ``acting.DenseStack``)."""


def numpy_layer(module: nn.Module):
    """A numpy stand-in for ``module`` when acting: (weight.T, bias) copies for a Linear, else a function."""
    if isinstance(module, nn.Linear):
        return module.weight.detach().numpy().T.copy(), module.bias.detach().numpy().copy()
    return _NUMPY_ACTIVATIONS[type(module)]


def nonzero(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.nonzero`` of a 2-D int8 array, ~10x faster when it is mostly zeros: scan it 8 bytes at a time,
    then look inside the non-zero words only."""
    width = x.shape[1]
    if x.dtype != np.int8 or width % 8 or not x.flags.c_contiguous:
        return np.nonzero(x)
    words = np.flatnonzero(x.view(np.int64))
    in_word_rows, in_word_columns = np.nonzero(x.reshape(-1, 8)[words])
    positions = words[in_word_rows] * 8 + in_word_columns
    return np.divmod(positions, width)


def sparse_matmul(x: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``x @ weight`` for an int8 batch that is mostly zeros (Pong's frame differences: a few dozen of 6,400
    pixels change between frames): the sum of the weight rows of the non-zero pixels, ~10x faster than a
    dense product for a batch of 8. Dense when a quarter or more of ``x`` is non-zero."""
    rows, columns = nonzero(x)
    if len(rows) * 4 >= x.size:
        return x.astype(np.float32) @ weight
    # Row i of the product sums the weight rows of row i's non-zero pixels, scaled by their values (+-1):
    # a (batch x non-zeros) mixing matrix times those weight rows.
    mixing = np.zeros((len(x), len(rows)), np.float32)
    mixing[rows, np.arange(len(rows))] = x[rows, columns]
    return mixing @ weight[columns]


def _plain_conv1d(module: nn.Module) -> bool:
    """A ``Conv1d`` that ``conv1d`` computes: stride 1, no padding or dilation, one group (CartPole's)."""
    return (
        isinstance(module, nn.Conv1d)
        and module.stride == (1,)
        and module.padding == (0,)
        and module.dilation == (1,)
        and module.groups == 1
        and module.bias is not None
    )


plain_conv1d = _plain_conv1d


def conv1d_weight(weight: np.ndarray) -> np.ndarray:
    """A ``Conv1d`` weight (..., out, in, kernel) as the matrix ``conv1d`` multiplies patches by: (..., kernel *
    in, out), contiguous (a patch holds its steps one after another, each step's channels together)."""
    *lead, out, channels, kernel = weight.shape
    moved = np.moveaxis(weight, (-1, -2, -3), (-3, -2, -1))  # (..., kernel, in, out)
    return np.ascontiguousarray(moved).reshape(*lead, kernel * channels, out)


def conv1d(x: np.ndarray, weight: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """A stride-1, unpadded ``Conv1d`` in numpy: (..., N, in, T) -> (..., N, out, T - kernel + 1), contiguous;
    ``weight`` from ``conv1d_weight`` (with the same leading axes as ``x``, or none), ``bias`` broadcasting
    against (..., N * length, out). Each (N * length, kernel * in) block of patches is one matrix product: a
    stack of members (a leading axis) multiplies each member's block exactly as that member alone does."""
    *lead, n, channels, steps = x.shape
    kernel = weight.shape[-2] // channels
    length = steps - kernel + 1
    by_step = np.swapaxes(x, -1, -2)  # (..., N, T, in): a patch is `kernel` consecutive rows
    patches = np.concatenate([by_step[..., j : j + length, :] for j in range(kernel)], axis=-1)
    out = np.matmul(patches.reshape(*lead, n * length, kernel * channels), weight)
    out += bias
    return np.ascontiguousarray(np.swapaxes(out.reshape(*lead, n, length, -1), -1, -2))


def _nonzero_rows_columns(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``x.nonzero(as_tuple=True)`` of a 2-D int8 tensor, row-major, ~4x faster when it is mostly zeros (a
    Pong update's frames): the same 8-bytes-at-a-time scan as ``_nonzero``."""
    n, width = x.shape
    if width % 8 or not x.is_contiguous():
        return x.nonzero(as_tuple=True)
    word_rows, word_columns = x.view(torch.int64).nonzero(as_tuple=True)
    in_word, byte = x.view(n, width // 8, 8)[word_rows, word_columns].nonzero(as_tuple=True)
    return word_rows[in_word], word_columns[in_word] * 8 + byte


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def _dense_layers(
    in_features: int,
    hidden_sizes: Sequence[int],
    n_actions: int,
    activation: str,
    dropout: float,
    layer_norm: bool = False,
) -> list[nn.Module]:
    layers: list[nn.Module] = []
    for width in hidden_sizes:
        layers += [nn.Linear(in_features, width), *([nn.LayerNorm(width)] if layer_norm else [])]
        layers.append(_ACTIVATIONS[activation]())
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        in_features = width
    layers.append(nn.Linear(in_features, n_actions))
    return layers


def create_cartpole_model(
    observation_size: int = 4,
    n_actions: int = 2,
    hidden_sizes: Sequence[int] = (32,),
    activation: str = "relu",
    dropout: float = 0.0,
    architecture: str = "mlp",
    history: int = 4,
    conv_channels: Sequence[int] = (16,),
    kernel_size: int = 2,
    layer_norm: bool = False,
) -> Policy:
    """CartPole policy. ``mlp``: input (observation_size,). ``cnn``: input (history, observation_size), a
    window of recent observations, oldest first; 1-D convolutions run along time with the observation's
    components as channels, then the dense layers."""
    if architecture == "mlp":
        body = nn.Sequential(*_dense_layers(observation_size, hidden_sizes, n_actions, activation, dropout, layer_norm))
        return Policy(body, (observation_size,))
    conv: list[nn.Module] = [_TimeAsLength()]
    channels, length = observation_size, history
    for out_channels in conv_channels:
        conv += [nn.Conv1d(channels, out_channels, kernel_size), _ACTIVATIONS[activation]()]
        channels, length = out_channels, length - kernel_size + 1
        if length < 1:
            raise ValueError(f"history {history} is too short for {len(conv_channels)} convolutions of {kernel_size}")
    conv.append(nn.Flatten())
    dense = _dense_layers(channels * length, hidden_sizes, n_actions, activation, dropout, layer_norm)
    body = nn.Sequential(*conv, *dense)
    return Policy(body, (history, observation_size))


class _TimeAsLength(nn.Module):
    """(batch, time, features) -> (batch, features, time): Conv1d wants channels before length."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.transpose(1, 2)


_NUMPY_ACTIVATIONS[_TimeAsLength] = lambda x: np.swapaxes(x, -1, -2)  # CartPole's cnn acts in numpy too


PONG_CONV = ((16, 7, 4, 3), (32, 5, 2, 2), (48, 3, 2, 1))
"""The course's Pong CNN: (filters, kernel, stride, padding) of each conv layer (the report describes it from here)."""


def create_pong_model(
    n_actions: int = 6,
    hidden_sizes: Sequence[int] = (64,),
    activation: str = "relu",
    dropout: float = 0.0,
    architecture: str = "cnn",
    observation_shape: Sequence[int] = (1, 80, 80),
    layer_norm: bool = False,
) -> Policy:
    """Pong policy over the (1, 80, 80) difference of pre-processed frames (any (channels, H, W) image for other
    Atari games). ``cnn`` is the course's (``PONG_CONV``): 16 filters 7x7 stride 4, 32 filters 5x5 stride 2,
    48 filters 3x3 stride 2, then dense layers. ``mlp`` flattens the pixels straight into the dense layers
    (Karpathy's)."""
    act = _ACTIVATIONS[activation]
    channels, height, width = observation_shape
    if architecture == "mlp":
        body = nn.Sequential(
            nn.Flatten(),
            *_dense_layers(channels * height * width, hidden_sizes, n_actions, activation, dropout, layer_norm),
        )
        return Policy(body, tuple(observation_shape))
    convs = []
    for filters, kernel, stride, padding in PONG_CONV:
        convs += [nn.Conv2d(channels, filters, kernel, stride=stride, padding=padding), act()]
        channels = filters
        height, width = ((n + 2 * padding - kernel) // stride + 1 for n in (height, width))
    body = nn.Sequential(
        *convs,
        nn.Flatten(),
        *_dense_layers(channels * height * width, hidden_sizes, n_actions, activation, dropout, layer_norm),
    )
    return Policy(body, tuple(observation_shape))
