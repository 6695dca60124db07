"""A population's CartPole policies (dense, or ``cnn``) as stacked tensors: one numpy forward to act for every
member, one backward to learn, one ``StackedAdam`` step; every member's episodes from one ``CartPoleBatch``.

Every member keeps its single trial's random streams (initial weights, actions, envs, dropout masks) and, on a
CPU, its single trial's own forward and backward kernels on its own batch: a member's whole run is the run of
its trial alone, bit for bit, whatever population it is in. (On a GPU, one padded batched forward: the same to
float tolerance, until float differences first flip a sampled action.)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ablate.agent.envs import env_info
from ablate.agent.optim import StackedAdam
from ablate.agent.policies import _NUMPY_ACTIVATIONS, Policy, conv1d, conv1d_weight, create_model
from ablate.agent.pong_acting import pong_population_group
from ablate.agent.reinforce import UpdateStats
from ablate.agent.stacked_episodes import Batch, StackedEpisodes
from ablate.agent.vector_cartpole import generator_at
from ablate.config import TrialConfig

_STACKABLE_ACTIVATIONS = ("relu", "tanh", "elu", "gelu")
"""Those acting has a numpy stand-in for (``policies._NUMPY_ACTIVATIONS``): a member acts in numpy exactly as
its single trial does."""

_STACKABLE_ARCHITECTURES = ("mlp", "cnn")
"""CartPole's dense MLP, and its ``cnn`` (1-D convolutions over a window of observations, then dense layers)."""


def stackable(config: TrialConfig) -> bool:
    """Whether ``config`` trains in a stacked population (CartPole's policies), not its own path."""
    return (
        config.env_id.startswith("CartPole")
        and config.model.architecture in _STACKABLE_ARCHITECTURES
        and config.model.activation in _STACKABLE_ACTIVATIONS
    )


def population_group(config: TrialConfig) -> tuple | None:
    """Configs with one group share a population: the same network and batch shape (everything else, the
    seed, learning rate, L2, discount, budget and stop rule, is per member). ``None``: a population of one.
    Pong's groups: ``pong_acting.pong_population_group``."""
    if not stackable(config):
        return pong_population_group(config)
    return (config.env_id, config.model, config.episodes_per_update)


SHARED_COST = {"mlp": 0.22, "cnn": 0.38, "pong": 0.89}
"""The part of a member's cost alone that it still pays in a large population, per kind of population: a
population of M members of equal cost c takes ``c * M * (share + (1 - share) / M)`` (``member_cost``). From
``make bench``: 16 default CartPole members run 3.7x the steps/s of one trial (mlp), 16 ``cnn`` members 2.4x
(docs/performance.md); 8 Pong members 1.10x (either arm, docs/pong.md)."""


def population_share(config: TrialConfig) -> float:
    """``SHARED_COST`` for ``config``'s kind of population (1.0: it trains alone, nothing is shared)."""
    if population_group(config) is None:
        return 1.0
    if not stackable(config):
        return SHARED_COST["pong"]
    return SHARED_COST["cnn" if config.model.architecture == "cnn" else "mlp"]


def member_cost(share: float, members: int) -> float:
    """A member's cost in a population of ``members``, in units of its cost alone (``SHARED_COST``)."""
    return share + (1.0 - share) / max(members, 1)


def crowd(config: TrialConfig, members: int) -> float:
    """How many times one member's cost alone a population of ``members`` of ``config``'s kind takes (each
    member's seconds are its population's clock): ``members * member_cost(share, members)``, 1 alone."""
    return members * member_cost(population_share(config), members)


class StackedPolicy:
    """M CartPole policies of one architecture (dense, or ``cnn``'s 1-D convolutions then dense), each layer's
    weights and biases stacked member-first, with the names, order and shapes of ``Policy`` parameters (a
    member's slice loads into a ``Policy`` as it is)."""

    def __init__(self, policies: Sequence[Policy], device: torch.device) -> None:
        body = policies[0].body
        self.template = policies[0]
        self.names = [name for name, _ in policies[0].named_parameters()]
        index = {name: i for i, name in enumerate(self.names)}
        self.weighted = {
            k: (index[f"body.{k}.weight"], index[f"body.{k}.bias"])
            for k, m in enumerate(body)
            if isinstance(m, nn.Linear | nn.Conv1d)
        }
        """Body position of each Linear and Conv1d -> the positions of its weight and bias in ``params``."""
        self.linear = [k for k, m in enumerate(body) if isinstance(m, nn.Linear)]
        self.convs = [k for k, m in enumerate(body) if isinstance(m, nn.Conv1d)]
        self.activations = {k: body[k + 1] for k in self.linear[:-1] + self.convs}
        self.dropout = next((m.p for m in body if isinstance(m, nn.Dropout)), 0.0)
        self.weights = [i for i, name in enumerate(self.names) if name.endswith("weight")]
        """Positions of the weights L2 penalises (``reinforce.l2_penalty``'s, in its order)."""
        self.params = [
            torch.stack([dict(p.named_parameters())[name].detach() for p in policies]).to(device).requires_grad_()
            for name in self.names
        ]
        self._numpy: dict[int, tuple[np.ndarray, np.ndarray]] | None = None

    @property
    def members(self) -> int:
        return self.params[0].shape[0]

    def layers(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The dense layers' stacked (weight, bias), in order."""
        return [(self.params[self.weighted[k][0]], self.params[self.weighted[k][1]]) for k in self.linear]

    def refresh(self) -> None:
        """Acting's numpy copies of the weights (as ``Policy.act_logits`` keeps them), after each update."""
        self._numpy = {}
        for k, (w, b) in self.weighted.items():
            weight = self.params[w].detach().cpu().numpy()
            weight = conv1d_weight(weight) if k in self.convs else weight.transpose(0, 2, 1).copy()
            self._numpy[k] = (weight, self.params[b].detach().cpu().numpy()[:, None, :].copy())

    def act_logits(self, observations: np.ndarray) -> np.ndarray:
        """(M, N, *observation) float32 -> (M, N, actions) logits: every member's ``Policy.act_logits`` in one
        pass, layer by layer the same numpy operations on each member's rows (``policies.conv1d`` included)."""
        if self._numpy is None:
            self.refresh()
        x = observations
        for k, module in enumerate(self.template.body):
            if k in self.convs:
                x = conv1d(x, *self._numpy[k])
            elif k in self._numpy:
                weight, bias = self._numpy[k]
                x = np.matmul(x, weight)
                x += bias
            elif isinstance(module, nn.Flatten):
                x = x.reshape(*x.shape[:-2], -1)  # (M, N, channels, length): each row's channels, then time
            else:
                x = _NUMPY_ACTIVATIONS[type(module)](x)
        return x

    def member_logits(self, member: int, x: torch.Tensor, slices: list, generator: torch.Generator) -> torch.Tensor:
        """Training forward of one member on its own batch: its single trial's ``Policy.forward``, module by
        module with the same kernels and shapes, its parameters ``slices[j][member]`` (``unbind`` slices of the
        stacks) and its dropout drawn from its own ``generator`` (as ``F.dropout`` draws in its trial)."""
        p = self.dropout
        for k, module in enumerate(self.template.body):
            if k in self.weighted:
                w, b = self.weighted[k]
                weight, bias = slices[w][member], slices[b][member]
                x = F.linear(x, weight, bias) if k in self.linear else module._conv_forward(x, weight, bias)
            elif isinstance(module, nn.Dropout):
                if p > 0:
                    x = x * torch.empty_like(x).bernoulli_(1 - p, generator=generator).div_(1 - p)
            else:
                x = module(x)
        return x

    def logits(self, x: torch.Tensor, masks: list[torch.Tensor], members: list[int]) -> torch.Tensor:
        """Training forward of ``members`` (slots, in order), (k, T, *observation) -> (k, T, actions) in batched
        products (the GPU's padded path); ``masks``: each dropout layer's scaled mask."""
        index = torch.tensor(members, device=x.device) if len(members) < self.members else None

        def take(k: int) -> tuple[torch.Tensor, torch.Tensor]:
            w, b = (self.params[j] for j in self.weighted[k])
            return (w, b) if index is None else (w[index], b[index])

        single = len(members) == 1
        if self.convs:
            x = x.transpose(-1, -2)  # (k, T, features, time), as _TimeAsLength
        for k in self.convs:
            weight, bias = take(k)
            m, steps, channels, length = x.shape
            kernel = weight.shape[-1]
            patches = x.unfold(-1, kernel, 1).transpose(2, 3).reshape(m, -1, channels * kernel)
            x = torch.baddbmm(bias[:, None], patches, weight.reshape(m, weight.shape[1], -1).transpose(1, 2))
            x = self.activations[k](x.reshape(m, steps, length - kernel + 1, -1).transpose(-1, -2))
        if self.convs:
            x = x.flatten(2)
        for i, k in enumerate(self.linear):
            weight, bias = take(k)
            # One member: the same kernel as nn.Linear, so a population of one is its single trial exactly.
            x = (
                F.linear(x[0], weight[0], bias[0])[None]
                if single
                else torch.baddbmm(bias[:, None], x, weight.transpose(1, 2))
            )
            if k in self.activations:
                x = self.activations[k](x)
                if masks:
                    x = x * masks[i]
        return x

    def member_state(self, member: int) -> dict[str, torch.Tensor]:
        return {name: p[member].detach().cpu().clone() for name, p in zip(self.names, self.params, strict=True)}

    def load_member_state(self, member: int, state: dict[str, torch.Tensor]) -> None:
        with torch.no_grad():
            for name, p in zip(self.names, self.params, strict=True):
                p[member].copy_(state[name])
        self._numpy = None

    def keep(self, members: list[int]) -> None:
        self.params = [p.detach()[members].clone().requires_grad_() for p in self.params]
        self._numpy = None


class StackedBackend:
    """A population of CartPole members (``population_group`` equal): its episodes, updates and
    per-member state. Slots are members' positions in the current stacks; ``keep`` drops those that left."""

    def __init__(self, configs: Sequence[TrialConfig], device: torch.device) -> None:
        self.configs = list(configs)
        info = env_info(configs[0].env_id)
        self.num_envs = configs[0].episodes_per_update
        policies, self.generators = [], []
        for config in configs:
            torch.manual_seed(config.seed)  # initial weights as run_trial draws them, then dropout's stream
            policies.append(create_model(config.env_id, config.model, info.observation_size, info.n_actions))
            generator = torch.Generator()
            generator.set_state(torch.get_rng_state())
            self.generators.append(generator)
        self.model = StackedPolicy(policies, device)
        self.device = device
        self.optimizer = StackedAdam(self.model.params, [c.learning_rate for c in configs])
        history = configs[0].model.history if configs[0].model.architecture == "cnn" else 0
        self.episodes = StackedEpisodes(
            [c.seed for c in configs], [c.gamma for c in configs], self.num_envs, info.max_episode_steps, history
        )

    # --- episodes ---
    def collect(self, counts: Sequence[int], budgets: Sequence[int]) -> dict[int, Batch]:
        """The members whose next ``counts[i]`` episodes have all ended (at least one), by slot: every member
        steps together, each sampling and drawing exactly as ``collectors.collect_episodes`` does alone; a
        member whose batch is not complete yet keeps its collection in flight to the next call."""
        return self.episodes.collect(self.model.act_logits, counts)

    # --- updates ---
    def update(self, ready: dict[int, Batch]) -> dict[int, UpdateStats]:
        """The ``ready`` members' losses and gradients in one backward, then one ``StackedAdam`` step for them
        alone (every other member's weights and Adam state untouched). On a CPU each member's forward is its
        single trial's own (``_member_losses``); on a GPU, one padded batched forward (``_padded_losses``):
        there a kernel per member and layer would cost more than the math."""
        slots = sorted(ready)
        batches = [ready[slot] for slot in slots]
        self.optimizer.zero_grad()
        if self.device.type == "cpu":
            total, losses, entropies = self._member_losses(slots, batches)
        else:
            total, losses, entropies = self._padded_losses(slots, batches)
        total.backward()
        values = torch.stack([torch.stack(losses).detach(), torch.stack(entropies)]).cpu().tolist()
        self.optimizer.step(slots)
        self.model.refresh()
        sizes = [len(b.actions) for b in batches]
        return {
            slot: UpdateStats(loss, entropy / max(size, 1))
            for slot, loss, entropy, size in zip(slots, *values, sizes, strict=True)
        }

    def _member_losses(self, slots: list[int], batches: Sequence[Batch]) -> tuple[torch.Tensor, list, list]:
        """Each member's ``reinforce.train_step`` graph on its own batch, with its slices of the stacked
        parameters (``unbind``: one node hands every member's gradient back into the stacks). The same kernels
        on the same shapes as its single trial, and no padding: a member's update is its single trial's."""
        slices = [p.unbind(0) for p in self.model.params]
        total, losses, entropies = None, [], []
        for i, batch in zip(slots, batches, strict=True):
            config = self.configs[i]
            x = torch.from_numpy(batch.observations)  # the batch's own memory, as train_step reads it
            x = self.model.member_logits(i, x, slices, self.generators[i])
            weights_t = torch.from_numpy(batch.weights)
            loss = (F.cross_entropy(x, torch.from_numpy(batch.actions), reduction="none") * weights_t).mean()
            losses.append(loss)
            if config.l2 > 0:
                penalty = sum((slices[j][i].pow(2).sum() for j in self.model.weights), torch.zeros(()))
                loss = loss + config.l2 * penalty
            total = loss if total is None else total + loss
            with torch.no_grad():
                log_probs = F.log_softmax(x, dim=1)
                entropies.append(-(log_probs.exp() * log_probs).sum(dim=1).sum())
        return total, losses, entropies

    def _padded_losses(self, slots: list[int], batches: Sequence[Batch]) -> tuple[torch.Tensor, list, list]:
        """The members ``slots`` in one padded (k, T, obs) batch through batched products (the GPU's path)."""
        sizes = [len(b.actions) for b in batches]
        longest = max(sizes)
        m = len(batches)
        if m == 1:  # the batch's own memory, as train_step reads it: gemm's result can depend on alignment
            x, actions = torch.from_numpy(batches[0].observations)[None], torch.from_numpy(batches[0].actions)[None]
        else:
            x = torch.zeros(m, longest, *batches[0].observations.shape[1:])
            actions = torch.zeros(m, longest, dtype=torch.int64)
            for i, b in enumerate(batches):
                x[i, : sizes[i]] = torch.from_numpy(b.observations)
                actions[i, : sizes[i]] = torch.from_numpy(b.actions)
        masks = self._dropout_masks(slots, sizes, longest)
        x, actions = x.to(self.device), actions.to(self.device)
        logits = self.model.logits(x, masks, slots)
        # F.cross_entropy is nll_loss of log_softmax: computed apart, the log-probabilities serve the entropy too.
        log_probs = F.log_softmax(logits, dim=2)
        cross_entropy = F.nll_loss(log_probs.reshape(m * longest, -1), actions.reshape(-1), reduction="none")
        cross_entropy = cross_entropy.reshape(m, longest)
        # reinforce.compute_loss per member, over its own observations only.
        losses = [
            (cross_entropy[i, : sizes[i]] * torch.from_numpy(b.weights).to(self.device)).mean()
            for i, b in enumerate(batches)
        ]
        total = sum(losses)
        for slot in slots:
            l2 = self.configs[slot].l2
            if l2 > 0:
                weights = [self.model.params[j][slot] for j in self.model.weights]
                penalty = sum((w.pow(2).sum() for w in weights), torch.zeros((), device=self.device))
                total = total + l2 * penalty
        with torch.no_grad():
            log_probs = log_probs.detach()
            entropy = -(log_probs.exp() * log_probs).sum(dim=2)
            entropies = [entropy[i, : sizes[i]].sum() for i in range(m)]
        return total, losses, entropies

    def _dropout_masks(self, slots: list[int], sizes: list[int], longest: int) -> list[torch.Tensor]:
        """Each dropout layer's mask (scaled by 1/(1-p)), per member from its own generator, drawn as
        ``F.dropout`` draws them in its single trial (a bernoulli over that layer's (T, width) output)."""
        p = self.model.dropout
        if p <= 0:
            return []
        masks = []
        for w, _ in self.model.layers()[:-1]:
            width = w.shape[1]
            mask = torch.zeros(len(sizes), longest, width)
            for i, (slot, size) in enumerate(zip(slots, sizes, strict=True)):
                generator = self.generators[slot]
                mask[i, :size] = torch.empty(size, width).bernoulli_(1 - p, generator=generator).div_(1 - p)
            masks.append(mask.to(self.device))
        return masks

    # --- members ---
    def policy(self, slot: int) -> Policy:
        """Member ``slot`` as a ``Policy`` (its video, its weights)."""
        config = self.configs[slot]
        info = env_info(config.env_id)
        policy = create_model(config.env_id, config.model, info.observation_size, info.n_actions)
        policy.load_state_dict(self.model.member_state(slot))
        return policy

    def state(self, slot: int) -> dict:
        """Member ``slot``'s part of a checkpoint, in run_trial's format."""
        return {
            "model": self.model.member_state(slot),
            "optimizer": self.optimizer.member_state(slot),
            "torch_rng": self.generators[slot].get_state(),
            "numpy_rng": self.episodes.action_state(slot),
            "collector": {"env_streams": self.episodes.env.stream_states(slot)},
        }

    def restore(self, slot: int, saved: dict, episodes_done: int) -> None:
        config = self.configs[slot]
        self.model.load_member_state(slot, saved["model"])
        self.optimizer.load_member_state(slot, saved["optimizer"])
        self.generators[slot].set_state(saved["torch_rng"])
        self.episodes.set_action_state(slot, saved["numpy_rng"])
        streams = saved["collector"].get("env_streams")
        if streams is None:
            # A checkpoint of the Gymnasium-env collector, which could not save its envs' streams: re-seeded from
            # the episode count, as it resumed (deterministic, though not the unbroken run).
            seed = config.seed + 7919 * episodes_done
            count = 1 if self.episodes.env.shared else self.num_envs
            streams = [np.random.default_rng(seed + j).bit_generator.state for j in range(count)]
        self.episodes.env.set_stream_states(slot, streams)

    def keep(self, slots: list[int]) -> None:
        """Only ``slots`` go on (the others left the population), in this order, with their collections in
        flight."""
        self.model.keep(slots)
        self.optimizer.keep(slots, self.model.params)
        self.episodes.keep(slots)
        self.configs = [self.configs[s] for s in slots]
        self.generators = [self.generators[s] for s in slots]

    def video_paths(self, slot: int) -> list:
        return []

    def close(self) -> None:
        pass


__all__ = ["Batch", "StackedBackend", "StackedPolicy", "generator_at", "population_group", "stackable"]
