"""REINFORCE (vanilla policy gradient), pure: memory, action choice, discounted returns, loss, update.

No I/O, no Ray, no MLflow, no environment: arrays and a torch model in, arrays and numbers out.
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Protocol

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn


class Memory:
    """One episode's observations, actions and rewards, in the order they happened (one per env slot)."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self.observations: list[np.ndarray] = []
        self.actions: list[int] = []
        self.rewards: list[float] = []

    def add_to_memory(self, observation: np.ndarray, action: int, reward: float) -> None:
        self.observations.append(np.array(observation))  # a copy, in its own dtype (Pong's int8 frames stay int8)
        self.actions.append(int(action))
        self.rewards.append(float(reward))

    def __len__(self) -> int:
        return len(self.actions)


def choose_action(
    model: nn.Module,
    observation: np.ndarray,
    rng: np.random.Generator | None = None,
    *,
    greedy: bool = False,
    single: bool = True,
    uniforms: np.ndarray | None = None,
) -> int | np.ndarray:
    """Sample an action from the softmax of the model's logits (the argmax when ``greedy``).

    ``observation`` is one observation (``single``: returns an ``int``) or a batch (returns an array of ints).
    ``model`` is a torch module, or a population's members (``stacking.Members``: (members, envs, *obs) in,
    (members, envs, actions) logits out). The draws come from ``uniforms`` (one per row) or ``rng``. No autograd
    graph is built: the log-probabilities are recomputed in one batched forward at update time (``train_step``).
    """
    batch = np.asarray(observation)[None] if single else np.asarray(observation)
    model.eval()  # acting is deterministic apart from sampling: no dropout; train_step switches back
    device = getattr(model, "device", None) or next(model.parameters()).device
    with torch.inference_mode():
        logits = model(torch.from_numpy(np.require(batch, requirements="CW")).to(device, torch.float32)).cpu().numpy()
    if greedy:
        actions = logits.argmax(axis=-1)
    else:
        if uniforms is None:
            uniforms = (rng if rng is not None else np.random.default_rng()).random(logits.shape[:-1])
        actions = sample_actions(logits, uniforms)
    return int(actions[0]) if single else actions.astype(np.int64, copy=False)


def sample_actions(logits: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """One action per row of ``logits`` (..., actions), sampled from their softmax with the row's uniform in
    ``uniforms`` (...): a row's action depends on its logits and its uniform only, whoever shares the array."""
    # Inverse-CDF sampling on the unnormalised softmax (u scaled by the total instead of dividing every
    # probability by it); the clip guards against the last cumulative value rounding below u.
    if logits.shape[-1] == 2:
        # Two actions: the cumulative sums are [e0, e0 + e1] and u * (e0 + e1) < e0 + e1, so the action is whether
        # e0 falls below it; the same float operations as the general case, five array operations instead of its
        # reductions along a 2-wide axis.
        exps = np.exp(logits - np.maximum(logits[..., 0], logits[..., 1])[..., None])
        return (exps[..., 0] < uniforms * (exps[..., 0] + exps[..., 1])).astype(np.int64)
    cumulative = np.cumsum(np.exp(logits - logits.max(axis=-1, keepdims=True)), axis=-1)
    u = uniforms[..., None] * cumulative[..., -1:]
    return np.minimum((cumulative < u).sum(axis=-1), logits.shape[-1] - 1)


def discount_rewards(
    rewards: np.ndarray, gamma: float, reset_on_nonzero: bool = False, lengths: np.ndarray | None = None
) -> np.ndarray:
    """Discounted return G_t = r_t + gamma * G_{t+1} for one episode, not normalised; with ``lengths``, for
    several episodes back to back (each its own, as if discounted alone).

    With ``reset_on_nonzero`` (Pong), the running return restarts at zero at every point scored
    (reward != 0): each rally is its own game, and a point must not be credited to earlier rallies.
    """
    array = np.asarray(rewards, dtype=np.float64)
    lengths = np.asarray([len(array)] if lengths is None else lengths, np.int64)
    ends = np.cumsum(lengths)
    if len(array) and not reset_on_nonzero and (array == array[0]).all():
        # A constant reward (CartPole's 1.0 a step): every return is one entry of one recursion, computed once.
        steps_left = np.repeat(ends, lengths) - 1 - np.arange(len(array))
        table_length = 1 << (int(lengths.max()) - 1).bit_length()  # the next power of two: few tables
        return _constant_returns(float(array[0]), gamma, table_length)[steps_left]
    last = np.zeros(len(array), bool)
    last[ends[lengths > 0] - 1] = True  # an episode's last step: the running return starts again at zero
    # Python floats are IEEE doubles: the same values as float64 arrays, at a fifth of the cost of indexing one.
    values, lasts = array.tolist(), last.tolist()
    returns = [0.0] * len(values)
    running = 0.0
    for t in range(len(values) - 1, -1, -1):
        reward = values[t]
        if lasts[t] or (reset_on_nonzero and reward != 0):
            running = 0.0
        running = reward + gamma * running
        returns[t] = running
    return np.array(returns)


@functools.lru_cache(maxsize=32)
def _constant_returns(reward: float, gamma: float, length: int) -> np.ndarray:
    """``[d]``: the return of a step with ``d`` steps after it, every reward ``reward`` (the recursion's own
    operations, so ``discount_rewards``'s values bit for bit)."""
    table = np.zeros(length)
    running = 0.0
    for d in range(length):
        running = reward + gamma * running
        table[d] = running
    return table


def normalize(values: np.ndarray) -> np.ndarray:
    """Centre on the mean and scale by the standard deviation; a constant vector becomes all zeros."""
    values = np.asarray(values, dtype=np.float64)
    centred = values - values.mean()
    std = values.std()
    # A constant return vector (every episode identical) carries no signal: all-zero weights, not NaN.
    return (centred / std if std > 1e-8 else centred).astype(np.float32)


def compute_loss(logits: torch.Tensor, actions: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Softmax cross-entropy of the taken actions, weighted by the normalised returns, averaged over the steps
    (the last axis: one loss per member for a population's (members, steps) batch).

    Cross-entropy of the taken action is -log pi(a|s), so this is the policy-gradient loss
    ``-(log pi(a|s) * G).mean()``.
    """
    cross_entropy = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), actions.reshape(-1), reduction="none")
    return (cross_entropy.reshape(actions.shape) * weights).mean(-1)


def penalised(name: str) -> bool:
    """Whether L2 penalises the parameter ``name``: weight tensors, not biases or norms' shifts."""
    return name.endswith("weight")


def l2_penalty(model: nn.Module) -> torch.Tensor:
    """Sum of squared weights of every layer, biases excluded (Keras ``regularizers.l2`` semantics)."""
    weights = [p for name, p in model.named_parameters() if penalised(name)]
    return sum((p.pow(2).sum() for p in weights), torch.zeros((), device=weights[0].device if weights else None))


class Optimizer(Protocol):
    """What ``train_step`` needs of an optimizer: ``stacking.Adam`` and any ``torch.optim`` optimizer fit."""

    def zero_grad(self) -> None: ...
    def step(self) -> object: ...


class UpdateStats(NamedTuple):
    loss: float | np.ndarray
    """Policy-gradient loss of the batch, before the step (L2 term excluded); one per member for a population."""
    entropy: float | np.ndarray
    """Mean entropy (nats) of the policy over the batch's observations, before the step."""


def train_step(
    model: nn.Module,
    optimizer: Optimizer,
    observations: np.ndarray,
    actions: np.ndarray,
    discounted_rewards: np.ndarray,
    l2: float | np.ndarray = 0.0,
    chunk_size: int | None = None,
    lengths: np.ndarray | None = None,
    serving: torch.Tensor | None = None,
) -> UpdateStats:
    """One gradient step on a batch: a single forward in training mode (dropout active), backward, step.

    ``discounted_rewards`` are the normalised returns used as weights. L2 regularisation is a loss term,
    ``l2 * sum(w**2)`` over weight matrices (not biases), rather than Adam's ``weight_decay``: Adam's
    coupled decay would also shrink biases, and a loss term means the same thing as the course's Keras
    ``kernel_regularizer=l2(...)``, so a value read in the course transfers unchanged.

    A population (``model`` a ``stacking.Members``, ``optimizer`` its ``stacking.Adam``): the members ``serving``
    each take their own step in one forward and backward. Their batches come as (members, steps, ...), padded
    after each member's ``lengths[i]`` steps (padding weighs nothing); ``l2`` holds each member's.

    ``chunk_size``: forward and backward at most this many observations at a time, summing gradients (the
    same gradient as one pass, in bounded memory: a Pong batch of 8,000 frames is GBs of activations; ``_chunks``).
    Observations may be int8 (Pong's frame differences); they become float32 chunk by chunk, on the
    model's device.
    """
    model.train()
    stacked = lengths is not None
    device = getattr(model, "device", None) or next(model.parameters()).device
    steps = actions.shape[-1]
    members = len(actions) if stacked else 1
    lengths_t = torch.as_tensor(lengths if stacked else [steps], device=device)
    padded = stacked and int(np.min(lengths)) < steps
    optimizer.zero_grad()
    policy_losses = torch.zeros(members, device=device, dtype=torch.float64)
    entropies = torch.zeros(members, device=device, dtype=torch.float64)
    per_chunk = max(1, chunk_size // members) if chunk_size else None
    for start, end in _chunks(steps, per_chunk):
        chunk = torch.as_tensor(observations[:, start:end] if stacked else observations[start:end]).to(device)
        logits = model(chunk, serving) if stacked else model(chunk.float())
        actions_t = torch.as_tensor(actions[..., start:end], dtype=torch.int64, device=device)
        weights = torch.as_tensor(discounted_rewards[..., start:end], dtype=torch.float32, device=device)
        if padded:  # a member's mean is over its own steps: the padding after them weighs nothing
            weights = weights * (steps / lengths_t.clamp(min=1)).float().reshape(members, 1)
        # compute_loss is a mean over the chunk; scaled, the chunks' losses sum to the whole batch's mean.
        policy_loss = compute_loss(logits, actions_t, weights) * ((end - start) / steps)
        loss = policy_loss.sum()
        if start == 0 and np.any(np.asarray(l2) > 0):
            if stacked:
                loss = loss + model.l2_penalty(torch.as_tensor(l2, dtype=torch.float32, device=device), serving)
            else:
                loss = loss + l2 * l2_penalty(model)
        loss.backward()
        with torch.no_grad():
            policy_losses += policy_loss.detach().double().reshape(members)
            log_probs = F.log_softmax(logits.float(), dim=-1)
            entropy = -(log_probs.exp() * log_probs).sum(dim=-1).reshape(members, -1).double()
            seen = torch.arange(start, end, device=device) < lengths_t.reshape(members, 1)
            entropies += (entropy * seen).sum(dim=1)
    if stacked:
        optimizer.step(serving)
        return UpdateStats(policy_losses.cpu().numpy(), (entropies / lengths_t.clamp(min=1)).cpu().numpy())
    optimizer.step()
    return UpdateStats(loss=float(policy_losses[0]), entropy=float(entropies[0]) / max(steps, 1))


def _chunks(total: int, chunk_size: int | None, smallest: int = 64) -> list[tuple[int, int]]:
    """(start, end) of the chunks of ``train_step``: one for all without ``chunk_size``; else ``chunk_size``
    long, then the rest in decreasing powers of two down to ``smallest``, then what is left (under
    ``smallest``): 1,383 with 1,024 -> 1,024 + 256 + 64 + 39. So a trial meets at most ~70 batch shapes, not a
    new one at almost every update: oneDNN compiles and keeps kernels per convolution shape (~0.6 MB each),
    and a Pong CNN trial's memory grew ~0.7 MB an update with its rest in one chunk of its own size."""
    if not chunk_size or total <= 0:
        return [(0, total)]
    bounds, start = [], 0
    size = chunk_size
    while start < total:
        while size > smallest and total - start < size:
            size //= 2
        end = min(start + size, total)
        bounds.append((start, end))
        start = end
    return bounds
