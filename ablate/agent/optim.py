"""Adam, the update ``torch.optim.Adam`` makes on CPU (single-tensor path, default betas and eps), in a few lines.

Why not ``torch.optim.Adam``: constructing any ``torch.optim`` optimizer imports ``torch._dynamo`` (its
``add_param_group`` is wrapped by ``torch._disable_dynamo``), which costs ~1.3 s of CPU in every fresh
process, more than a third of a typical CartPole trial, paid again by every Ray worker. The update below
is tested equal to ``torch.optim.Adam``'s, step for step.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import torch


class Adam:
    """Adam (Kingma & Ba, 2015) with bias correction, no weight decay, no AMSGrad."""

    def __init__(
        self, params: Iterable[torch.Tensor], lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8
    ) -> None:
        if lr <= 0:
            raise ValueError(f"learning rate must be positive, got {lr}")
        self.params = [p for p in params if p.requires_grad]
        self.lr = lr
        self.beta1, self.beta2 = betas
        self.eps = eps
        self.steps = 0
        self.exp_avg = [torch.zeros_like(p) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p) for p in self.params]

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.params:
            if set_to_none:
                p.grad = None
            elif p.grad is not None:
                p.grad.zero_()

    @torch.no_grad()
    def step(self) -> None:
        self.steps += 1
        bias_correction1 = 1 - self.beta1**self.steps
        bias_correction2_sqrt = (1 - self.beta2**self.steps) ** 0.5
        step_size = self.lr / bias_correction1
        for p, exp_avg, exp_avg_sq in zip(self.params, self.exp_avg, self.exp_avg_sq, strict=True):
            if p.grad is None:
                continue
            grad = p.grad
            exp_avg.lerp_(grad, 1 - self.beta1)
            exp_avg_sq.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
            denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
            p.addcdiv_(exp_avg, denom, value=-step_size)

    def state_dict(self) -> dict:
        """Step count and moment estimates (for a trial's checkpoint)."""
        return {
            "steps": self.steps,
            "exp_avg": [t.clone() for t in self.exp_avg],
            "exp_avg_sq": [t.clone() for t in self.exp_avg_sq],
        }

    def load_state_dict(self, state: dict) -> None:
        self.steps = state["steps"]
        for mine, saved in zip(self.exp_avg + self.exp_avg_sq, state["exp_avg"] + state["exp_avg_sq"], strict=True):
            mine.copy_(saved)


class StackedAdam:
    """``Adam`` for a population: each parameter is a stack of M members' tensors (member first), each member
    with its own learning rate and step count. Adam is elementwise, so every member's slice is updated exactly
    as its own ``Adam`` would update it (tested bit for bit): the same operations on the same values, only the
    two per-member scalars (step size and bias correction) come from a tensor instead of a Python float."""

    def __init__(
        self,
        params: Iterable[torch.Tensor],
        lrs: Iterable[float],
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        self.params = [p for p in params if p.requires_grad]
        self.lrs = [float(lr) for lr in lrs]
        if any(lr <= 0 for lr in self.lrs):
            raise ValueError(f"learning rates must be positive, got {self.lrs}")
        self.beta1, self.beta2 = betas
        self.eps = eps
        self.steps = [0] * len(self.lrs)
        self.exp_avg = [torch.zeros_like(p) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p) for p in self.params]

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self, members: Sequence[int] | None = None) -> None:
        """One Adam step of ``members`` (slots; default all): every other member's parameters, moments and step
        count stay as they are, whatever gradient they hold."""
        everyone = members is None or list(members) == list(range(len(self.lrs)))
        members = list(range(len(self.lrs))) if members is None else list(members)
        for m in members:
            self.steps[m] += 1
        # Adam's Python floats, per member: rounded to float32 as the scalar arguments of its kernels are.
        step_sizes = [-self.lrs[m] / (1 - self.beta1 ** self.steps[m]) for m in members]
        corrections = [(1 - self.beta2 ** self.steps[m]) ** 0.5 for m in members]
        device = self.params[0].device if self.params else None
        neg_step = torch.tensor(step_sizes, dtype=torch.float32, device=device)
        correction = torch.tensor(corrections, dtype=torch.float32, device=device)
        index = None if everyone else torch.tensor(members, device=device)
        for p, exp_avg, exp_avg_sq in zip(self.params, self.exp_avg, self.exp_avg_sq, strict=True):
            if p.grad is None:
                continue
            shape = (-1,) + (1,) * (p.dim() - 1)
            if index is None:
                self._update(p, p.grad, exp_avg, exp_avg_sq, neg_step.view(shape), correction.view(shape))
                continue
            if p.device.type == "cpu":  # a few members at a time: each in place on its own slices
                for j, m in enumerate(members):
                    self._update(p[m], p.grad[m], exp_avg[m], exp_avg_sq[m], neg_step[j], correction[j])
                continue
            # Many members (a GPU): their slices gathered, updated as above (elementwise: the same values), put back.
            mine, avg, avg_sq = p[index], exp_avg[index], exp_avg_sq[index]
            self._update(mine, p.grad[index], avg, avg_sq, neg_step.view(shape), correction.view(shape))
            p[index], exp_avg[index], exp_avg_sq[index] = mine, avg, avg_sq

    def _update(self, p, grad, exp_avg, exp_avg_sq, neg_step, correction) -> None:
        exp_avg.lerp_(grad, 1 - self.beta1)
        exp_avg_sq.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
        denom = (exp_avg_sq.sqrt() / correction).add_(self.eps)
        # addcdiv_'s kernel computes p + (value * exp_avg) / denom, in that order.
        p.add_(neg_step * exp_avg / denom)

    def member_state(self, member: int) -> dict:
        """Member ``member``'s state in ``Adam.state_dict``'s form (a trial's checkpoint)."""
        return {
            "steps": self.steps[member],
            "exp_avg": [t[member].clone() for t in self.exp_avg],
            "exp_avg_sq": [t[member].clone() for t in self.exp_avg_sq],
        }

    def load_member_state(self, member: int, state: dict) -> None:
        self.steps[member] = state["steps"]
        for mine, saved in zip(self.exp_avg + self.exp_avg_sq, state["exp_avg"] + state["exp_avg_sq"], strict=True):
            mine[member].copy_(saved)

    def keep(self, members: list[int], params: list[torch.Tensor]) -> None:
        """Only ``members`` go on, their parameters now ``params`` (new stacks of the kept members' slices)."""
        self.params = [p for p in params if p.requires_grad]
        self.lrs = [self.lrs[m] for m in members]
        self.steps = [self.steps[m] for m in members]
        self.exp_avg = [t[members].clone() for t in self.exp_avg]
        self.exp_avg_sq = [t[members].clone() for t in self.exp_avg_sq]
