"""Ready structures (see :mod:`tes.structure`) for our worlds and Gymnasium's toy texts.

* :func:`grid_task` and :func:`arena` — ``tes/GridTask-v0`` and ``tes/Arena-v0``: the worlds'
  own structure (features, effects, rewards), built in Rust.
* :func:`frozen_lake` — Gymnasium's ``FrozenLake-v1``, any map, slippery or not, any
  ``success_rate`` and ``reward_schedule``.
* :func:`cliff_walking` — ``CliffWalking-v1`` and ``CliffWalkingSlippery-v1``.

The toy texts' effects are the move made (in the order of the environment's actions) or
staying; the rewards and terminal cells are read from the environment's own transition table.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tes import _tes
from tes.structure import GridStructure

__all__ = ["WorldStructure", "grid_task", "arena", "frozen_lake", "cliff_walking"]


class WorldStructure:
    """The structure of one of our worlds: its native structure, states from the observation's
    ``"state"`` entry, effects by the world's own rule."""

    def __init__(self, world: Any, name: str, action_names: list[str]):
        self._world = world
        self._native = world.structure()
        self.name = name
        self.action_names = action_names
        self.n_states = self._native.n_states
        self.n_actions = self._native.n_actions
        self.n_effects = self._native.n_effects
        self.n_features = self._native.n_features
        self.feature_names = [world.feature_name(i) or f"f{i}" for i in range(self.n_features)]

    def native(self) -> _tes.Structure:
        return self._native

    def state(self, obs: Any) -> int:
        return int(obs["state"])

    def features(self, state: int) -> list[int]:
        return self._native.features(state)

    def next_state(self, state: int, effect: int) -> int:
        return self._native.next_state(state, effect)

    def reward(self, state: int) -> float:
        return self._native.reward(state)

    def terminal(self, state: int) -> bool:
        return self._native.terminal(state)

    def effect(self, state: int, action: int, next_state: int, reward: float) -> int:
        return self._world.effect_between(state, next_state)


def grid_task(env: Any) -> WorldStructure:
    """The structure of a ``tes/GridTask-v0`` environment."""
    inner = env.unwrapped
    return WorldStructure(
        inner.world,
        f"grid task {inner.task} (world seed {inner.world_seed})",
        ["north", "east", "south", "west"],
    )


def arena(env: Any) -> WorldStructure:
    """The structure of a ``tes/Arena-v0`` environment (all 312 camera features)."""
    inner = env.unwrapped
    return WorldStructure(inner.world, f"arena {inner.arena}", ["forward", "spin", "pivot"])


def _entry_rewards(P: dict, n_states: int) -> np.ndarray:
    """The reward for entering each state, as the transition table gives it (0 if never)."""
    rewards = np.zeros(n_states)
    for by_action in P.values():
        for outcomes in by_action.values():
            for _, next_state, reward, _ in outcomes:
                rewards[next_state] = reward
    return rewards


def frozen_lake(env: Any) -> GridStructure:
    """The structure of a ``FrozenLake-v1`` environment: 4 moves (left, down, right, up) and
    staying; holes and the goal are terminal."""
    inner = env.unwrapped
    desc = np.asarray(inner.desc)
    nrow, ncol = desc.shape
    n_states = nrow * ncol
    # A hole or the goal is absorbing in the table, so its own entry reward would be read
    # from its self-loop (0): take the rewards from the non-terminal cells' moves only.
    flat = desc.reshape(-1)
    terminal = [bytes(c) in (b"G", b"H") for c in flat]
    live = {s: a for s, a in inner.P.items() if not terminal[s]}
    rewards = _entry_rewards(live, n_states)
    return GridStructure(
        nrow,
        ncol,
        moves=[(0, -1), (1, 0), (0, 1), (-1, 0)],
        rewards=rewards,
        terminals=terminal,
        move_names=["left", "down", "right", "up"],
        name=f"FrozenLake {nrow}x{ncol}",
    )


def cliff_walking(env: Any) -> GridStructure:
    """The structure of ``CliffWalking-v1`` (or its slippery variant): 4 moves (up, right,
    down, left) and staying. Stepping into the cliff costs −100 and sends the agent back to
    the start; here the cliff cells are states whose every effect leads to the start, so the
    agent plans with the fall and its reward."""
    inner = env.unwrapped
    nrow, ncol = inner.shape
    cliff = np.asarray(inner._cliff).reshape(-1)
    start = int(inner.start_state_index)
    goal = nrow * ncol - 1
    rewards = np.full(nrow * ncol, -1.0)
    rewards[cliff] = -100.0
    terminal = [s == goal for s in range(nrow * ncol)]
    redirect = {int(s): start for s in np.flatnonzero(cliff)}
    return GridStructure(
        nrow,
        ncol,
        moves=[(-1, 0), (0, 1), (1, 0), (0, -1)],
        rewards=rewards,
        terminals=terminal,
        redirect=redirect,
        move_names=["up", "right", "down", "left"],
        name=f"CliffWalking {nrow}x{ncol}",
    )
