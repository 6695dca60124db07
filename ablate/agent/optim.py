"""Adam for a population: each member's own Adam (its learning rate, its step count) on the stacked parameters,
stepping only the members an update serves; the update ``torch.optim.Adam`` makes, member by member.

Why not ``torch.optim.Adam``: it steps every row of a stacked tensor with one step count and one learning rate,
and constructing any ``torch.optim`` optimizer imports ``torch._dynamo`` (~1.3 s of CPU in every fresh process,
paid again by every Ray worker). Tested equal to ``torch.optim.Adam`` member by member.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch


class Adam:
    """Adam (Kingma & Ba, 2015) with bias correction, no weight decay, no AMSGrad, one per member: a row of
    ``params`` (M, P), every member's parameters one after another (``stacking.Members.flat``)."""

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
