"""`tes.run`: an agent's episodes on a Gymnasium environment."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np


def run(
    env: Any,
    agent: Any,
    episodes: int,
    seed: int | None = None,
    on_episode: Callable[[int, float], None] | None = None,
) -> np.ndarray:
    """Runs ``episodes`` episodes of ``agent`` (``act`` / ``observe`` / ``end_episode``, as
    :mod:`tes.agents`) on ``env`` and returns each episode's total reward.

    ``seed`` seeds the environment's first ``reset`` (the later ones continue its random
    source, Gymnasium's convention), so a run with a seed and a seeded agent is reproducible.
    ``on_episode(index, total_reward)`` is called after each episode (for progress).
    """
    if episodes < 0:
        raise ValueError(f"episodes must be at least 0, not {episodes}")
    totals = np.zeros(episodes)
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed if episode == 0 else None)
        done, total = False, 0.0
        while not done:
            action = agent.act(obs)
            next_obs, reward, terminated, truncated, _ = env.step(action)
            agent.observe(obs, action, reward, next_obs, terminated, truncated)
            total += float(reward)
            obs, done = next_obs, terminated or truncated
        agent.end_episode()
        totals[episode] = total
        if on_episode is not None:
            on_episode(episode, total)
    return totals
