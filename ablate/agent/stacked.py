"""A population's dense CartPole policies as stacked tensors: one numpy forward to act for every member, one
backward to learn, one ``StackedAdam`` step; every member's episodes from one ``CartPoleBatch``.

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
from ablate.agent.policies import _NUMPY_ACTIVATIONS, Policy, create_model
from ablate.agent.pong_acting import pong_population_group
from ablate.agent.reinforce import UpdateStats
from ablate.agent.stacked_episodes import Batch, StackedEpisodes
from ablate.agent.vector_cartpole import generator_at
from ablate.config import TrialConfig

_STACKABLE_ACTIVATIONS = ("relu", "tanh", "elu")
"""Those acting has a numpy stand-in for (``policies._NUMPY_ACTIVATIONS``): a member acts in numpy exactly as
its single trial does. GELU's single trial acts through torch, so a GELU variant keeps its own path."""


def stackable(config: TrialConfig) -> bool:
    """Whether ``config`` trains in a stacked population (CartPole's dense MLP), not its own path."""
    return (
        config.env_id.startswith("CartPole")
        and config.model.architecture == "mlp"
        and config.model.activation in _STACKABLE_ACTIVATIONS
    )


def population_group(config: TrialConfig) -> tuple | None:
    """Configs with one group share a population: the same network and batch shape (everything else, the
    seed, learning rate, L2, discount, budget and stop rule, is per member). ``None``: a population of one.
    Pong's groups: ``pong_acting.pong_population_group``."""
    if not stackable(config):
        return pong_population_group(config)
    return (config.env_id, config.model, config.episodes_per_update)


class StackedMLP:
    """M dense policies of one architecture, each layer's weights and biases stacked member-first, with the
    names, order and shapes of ``Policy`` parameters (a member's slice loads into a ``Policy`` as it is)."""

    def __init__(self, policies: Sequence[Policy], device: torch.device) -> None:
        body = policies[0].body
        self.template = policies[0]
        self.linear = [k for k, m in enumerate(body) if isinstance(m, nn.Linear)]
        self.activations = {k: body[k + 1] for k in self.linear[:-1]}
        self.dropout = next((m.p for m in body if isinstance(m, nn.Dropout)), 0.0)
        self.names = [name for name, _ in policies[0].named_parameters()]
        self.params = [
            torch.stack([dict(p.named_parameters())[name].detach() for p in policies]).to(device).requires_grad_()
            for name in self.names
        ]
        self._numpy: list | None = None

    @property
    def members(self) -> int:
        return self.params[0].shape[0]

    def layers(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return [(self.params[2 * i], self.params[2 * i + 1]) for i in range(len(self.linear))]

    def refresh(self) -> None:
        """Acting's numpy copies of the weights (as ``Policy.act_logits`` keeps them), after each update."""
        self._numpy = [
            (w.detach().cpu().numpy().transpose(0, 2, 1).copy(), b.detach().cpu().numpy()[:, None, :].copy())
            for w, b in self.layers()
        ]

    def act_logits(self, observations: np.ndarray) -> np.ndarray:
        """(M, N, obs) float32 -> (M, N, actions) logits, every member's ``Policy.act_logits`` in one pass."""
        if self._numpy is None:
            self.refresh()
        x = observations
        for (weight, bias), k in zip(self._numpy, self.linear, strict=True):
            x = np.matmul(x, weight)
            x += bias
            if k in self.activations:
                x = _NUMPY_ACTIVATIONS[type(self.activations[k])](x)
        return x

    def logits(self, x: torch.Tensor, masks: list[torch.Tensor], members: list[int]) -> torch.Tensor:
        """Training forward of ``members`` (slots, in order), (k, T, obs) -> (k, T, actions); ``masks``: each
        dropout layer's scaled mask."""
        layers = self.layers()
        if len(members) < self.members:
            index = torch.tensor(members, device=x.device)
            layers = [(w[index], b[index]) for w, b in layers]
        single = len(members) == 1
        for i, ((weight, bias), k) in enumerate(zip(layers, self.linear, strict=True)):
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
    """A population of CartPole dense-MLP members (``population_group`` equal): its episodes, updates and
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
        self.model = StackedMLP(policies, device)
        self.device = device
        self.optimizer = StackedAdam(self.model.params, [c.learning_rate for c in configs])
        self.episodes = StackedEpisodes(
            [c.seed for c in configs], [c.gamma for c in configs], self.num_envs, info.max_episode_steps
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
        layers = [(w.unbind(0), b.unbind(0)) for w, b in self.model.layers()]
        p = self.model.dropout
        total, losses, entropies = None, [], []
        for i, batch in zip(slots, batches, strict=True):
            config = self.configs[i]
            x = torch.from_numpy(batch.observations)  # the batch's own memory, as train_step reads it
            for (weights, biases), k in zip(layers, self.model.linear, strict=True):
                x = F.linear(x, weights[i], biases[i])
                if k in self.model.activations:
                    x = self.model.activations[k](x)
                    if p > 0:  # F.dropout's draw, from the member's own generator
                        x = x * torch.empty_like(x).bernoulli_(1 - p, generator=self.generators[i]).div_(1 - p)
            weights_t = torch.from_numpy(batch.weights)
            loss = (F.cross_entropy(x, torch.from_numpy(batch.actions), reduction="none") * weights_t).mean()
            losses.append(loss)
            if config.l2 > 0:
                penalty = sum((w[i].pow(2).sum() for w, _ in layers), torch.zeros(()))
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
            x = torch.zeros(m, longest, batches[0].observations.shape[1])
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
                weights = [w[slot] for w, _ in self.model.layers()]
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


__all__ = ["Batch", "StackedBackend", "StackedMLP", "generator_at", "population_group", "stackable"]
