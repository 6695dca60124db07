"""`make bench` section `core`: the course-style loop against our trial, time to solve CartPole-v1."""

from __future__ import annotations

import statistics
from dataclasses import replace

import torch
from bench_results import RESULTS

from ablate.agent.trainer import run_trial
from ablate.config import COURSE, DEFAULT


def _course_loop(config, max_episodes: int) -> dict[str, float]:
    """The lab's loop as the assignment writes it (one env, a torch forward with autograd per step, a ``Memory``
    per episode, one Adam step per episode), built from the trainer's own pieces: the reference we measure against."""
    import time

    import gymnasium as gym
    import numpy as np

    from ablate.agent.policies import create_cartpole_model
    from ablate.agent.reinforce import Memory, discount_rewards, normalize, train_step

    torch.manual_seed(config.seed)
    env = gym.make(config.env_id)
    model = create_cartpole_model(hidden_sizes=config.model.hidden_sizes)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.learning_rate)  # the course's own optimizer
    memory, steps, started = Memory(), 0, time.perf_counter()
    for episode in range(max_episodes):
        observation, _ = env.reset(seed=config.seed if episode == 0 else None)
        memory.clear()
        done = False
        while not done:
            logits = model(torch.as_tensor(observation, dtype=torch.float32)[None])
            action = int(torch.distributions.Categorical(logits=logits).sample().item())
            next_observation, reward, terminated, truncated, _ = env.step(action)
            memory.add_to_memory(observation, action, reward)
            steps += 1
            done = terminated or truncated
            observation = next_observation
        returns = normalize(discount_rewards(memory.rewards, config.gamma))
        train_step(model, optimizer, np.vstack(memory.observations), np.array(memory.actions), returns)
    env.close()
    wall_s = time.perf_counter() - started
    return {"env_steps": steps, "wall_s": wall_s, "steps_per_s": steps / wall_s}


def bench_core(seeds: int = 5) -> None:
    """Env steps/s per core of the course-style loop and of our trial, same process, interleaved per seed;
    then time to solve CartPole-v1 (rolling mean >= 475 over 100 episodes) with the default config."""
    torch.set_num_threads(1)  # per core: both run on one thread
    course_sps, ours_sps, ratios = [], [], []
    for seed in range(seeds):
        course = _course_loop(replace(COURSE, env_id="CartPole-v1", seed=seed), max_episodes=150)
        ours = run_trial(replace(DEFAULT, env_id="CartPole-v1", seed=seed, max_episodes=1024, record_video=False))
        sps = ours.env_steps / ours.wall_s
        course_sps.append(course["steps_per_s"])
        ours_sps.append(sps)
        ratios.append(sps / course["steps_per_s"])
        print(
            f"  seed {seed}: course-style {course['steps_per_s']:8,.0f} steps/s | ours {sps:8,.0f} steps/s"
            f" | ratio {ratios[-1]:5.1f}x",
            flush=True,
        )
    print(
        f"core: course-style median {statistics.median(course_sps):,.0f} steps/s/core; ours median "
        f"{statistics.median(ours_sps):,.0f} steps/s/core; ratio median {statistics.median(ratios):.1f}x"
    )

    walls, episodes = [], []
    for seed in range(seeds):
        result = run_trial(replace(DEFAULT, env_id="CartPole-v1", seed=seed, record_video=False))
        status = f"solved at episode {result.episodes_to_solve}" if result.solved else "NOT solved"
        print(
            f"  CartPole-v1 seed {seed}: {status}, {result.wall_s:.2f} s, {result.env_steps:,} steps",
            flush=True,
        )
        if result.solved:
            walls.append(result.wall_s)
            episodes.append(result.episodes_to_solve)
    median_wall = statistics.median(walls) if walls else float("nan")
    print(
        f"core: CartPole-v1 solved by {len(walls)}/{seeds} seeds; median wall to solve {median_wall:.2f} s; "
        f"median episodes {statistics.median(episodes) if episodes else float('nan')}"
    )
    RESULTS["core"] = {
        "course_steps_per_s_median": statistics.median(course_sps),
        "ours_steps_per_s_median": statistics.median(ours_sps),
        "speedup_median": statistics.median(ratios),
        "solved_seeds": len(walls),
        "seeds": seeds,
        "median_wall_s_to_solve": median_wall,
    }
