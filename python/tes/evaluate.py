"""Exact evaluation on a Gymnasium toy text's own transition table (``env.unwrapped.P``).

A table maps ``state -> action -> [(probability, next_state, reward, terminated), ...]``, as
``FrozenLake-v1`` and ``CliffWalking-v1`` define it. These functions judge an agent's greedy
policy against the optimum without sampling:

>>> import gymnasium, tes
>>> env = gymnasium.make("FrozenLake-v1", map_name="4x4", is_slippery=False)
>>> P = env.unwrapped.P
>>> best = tes.evaluate.optimal_policy(P, gamma=0.95)
>>> start = env.unwrapped.initial_state_distrib
>>> round(tes.evaluate.success_probability(P, best, start, horizon=100), 6)
1.0
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import numpy.typing as npt

__all__ = [
    "optimal_policy",
    "optimal_success_probability",
    "success_probability",
    "policy_value",
]

Table = Mapping[int, Mapping[int, Sequence[tuple[float, int, float, bool]]]]


def _arrays(P: Table) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The table as dense arrays: T[s, a, s'], R[s, a] (expected reward), D[s, a, s'] (the
    probability of moving to s' *and* the episode ending there)."""
    n_states = len(P)
    n_actions = len(P[0])
    T = np.zeros((n_states, n_actions, n_states))
    R = np.zeros((n_states, n_actions))
    D = np.zeros((n_states, n_actions, n_states))
    for s, by_action in P.items():
        for a, outcomes in by_action.items():
            for p, s2, r, done in outcomes:
                T[s, a, s2] += p
                R[s, a] += p * r
                if done:
                    D[s, a, s2] += p
    return T, R, D


def optimal_policy(P: Table, gamma: float, tolerance: float = 1e-10) -> np.ndarray:
    """The optimal policy for discount ``gamma`` by value iteration on the table (an episode's
    end is absorbing: nothing is earned after it)."""
    T, R, D = _arrays(P)
    live = T - D
    values = np.zeros(len(P))
    while True:
        q = R + gamma * live @ values
        new = q.max(axis=1)
        if np.max(np.abs(new - values)) < tolerance:
            return q.argmax(axis=1)
        values = new


def optimal_success_probability(P: Table, start: npt.ArrayLike, horizon: int) -> float:
    """The highest probability any policy (free to change its action with the steps left)
    has of ending an episode with a positive reward within ``horizon`` steps: value
    iteration of ``horizon`` backups on the table, undiscounted, the goal's reward 1."""
    T, _, D = _arrays(P)
    win = np.zeros(T.shape[:2])
    for s, by_action in P.items():
        for a, outcomes in by_action.items():
            for p, _, r, done in outcomes:
                if done and r > 0:
                    win[s, a] += p
    live = T - D
    values = np.zeros(len(P))
    for _ in range(horizon):
        values = (win + live @ values).max(axis=1)
    return float(np.asarray(start, dtype=float) @ values)


def policy_value(
    P: Table, policy: npt.ArrayLike, start: npt.ArrayLike, horizon: int
) -> float:
    """The expected undiscounted return of ``policy`` from the ``start`` distribution within
    ``horizon`` steps."""
    T, R, D = _arrays(P)
    idx = np.arange(len(P))
    policy = np.asarray(policy)
    live = (T - D)[idx, policy]
    gain = R[idx, policy]
    mass, total = np.asarray(start, dtype=float), 0.0
    for _ in range(horizon):
        total += mass @ gain
        mass = mass @ live
    return float(total)


def success_probability(
    P: Table, policy: npt.ArrayLike, start: npt.ArrayLike, horizon: int
) -> float:
    """The probability that ``policy`` ends an episode with a positive reward (FrozenLake's
    goal) within ``horizon`` steps, from the ``start`` distribution."""
    T, _, D = _arrays(P)
    rewarded = np.zeros_like(D)
    for s, by_action in P.items():
        for a, outcomes in by_action.items():
            for p, s2, r, done in outcomes:
                if done and r > 0:
                    rewarded[s, a, s2] += p
    idx = np.arange(len(P))
    policy = np.asarray(policy)
    live = (T - D)[idx, policy]
    win = rewarded[idx, policy].sum(axis=1)
    mass, total = np.asarray(start, dtype=float), 0.0
    for _ in range(horizon):
        total += mass @ win
        mass = mass @ live
    return float(total)
