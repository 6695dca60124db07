"""The course's training loop, written the way the assignment describes it: the reference we measure against.

One env, one model forward (with autograd) per step, a ``Memory`` per episode, one Adam step per episode.
``make bench`` times it beside ``trial.run_trial``; it is not used to run ablations.
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np
import torch

from ablate.agent.policies import Policy, create_cartpole_model
from ablate.agent.reinforce import Memory, discount_rewards, normalize, train_step
from ablate.config import COURSE, TrialConfig


def course_choose_action(model: Policy, observation: np.ndarray) -> int:
    """As in the lab: logits for one observation, then sample from the categorical distribution."""
    logits = model(torch.as_tensor(observation, dtype=torch.float32)[None])
    return int(torch.distributions.Categorical(logits=logits).sample().item())


def course_loop(config: TrialConfig = COURSE, max_episodes: int | None = None) -> dict[str, float]:
    """Train as the course does and return env steps, seconds and the returns seen."""
    torch.manual_seed(config.seed)
    env = gym.make(config.env_id)
    model = create_cartpole_model(hidden_sizes=config.model.hidden_sizes, activation=config.model.activation)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    memory = Memory()
    returns: list[float] = []
    steps = 0
    started = time.perf_counter()
    for episode in range(max_episodes or config.max_episodes):
        observation, _ = env.reset(seed=config.seed if episode == 0 else None)
        memory.clear()
        while True:
            action = course_choose_action(model, observation)
            next_observation, reward, terminated, truncated, _ = env.step(action)
            memory.add_to_memory(observation, action, reward)
            steps += 1
            if terminated or truncated:
                returns.append(sum(memory.rewards))
                train_step(
                    model,
                    optimizer,
                    np.vstack(memory.observations),
                    np.array(memory.actions),
                    normalize(discount_rewards(memory.rewards, config.gamma)),
                )
                break
            observation = next_observation
    env.close()
    wall_s = time.perf_counter() - started
    return {"env_steps": steps, "wall_s": wall_s, "steps_per_s": steps / wall_s, "returns": returns}
