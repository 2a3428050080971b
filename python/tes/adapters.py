"""Ready structures (see :mod:`tes.structure`) for our worlds and Gymnasium's toy texts.

* :func:`grid_task` and :func:`arena` — ``tes/GridTask-v0`` and ``tes/Arena-v0``: the worlds'
  own structure (features, effects, rewards), built in Rust.
* :func:`frozen_lake` — Gymnasium's ``FrozenLake-v1``, any map, slippery or not, any
  ``success_rate`` and ``reward_schedule``.
* :func:`cliff_walking` — ``CliffWalking-v1`` and ``CliffWalkingSlippery-v1``.
* :func:`taxi` — ``Taxi-v4`` (dry, with a passenger who keeps to the destination: the
  defaults).

Each adapter checks it was given the environment it is for, and refuses another with
``TypeError`` naming both.

The toy texts' effects are the move made (in the order of the environment's actions) or
staying; the rewards and terminal cells are read from the environment's own transition table.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tes import _tes
from tes.structure import GridStructure

__all__ = ["WorldStructure", "TaxiStructure", "grid_task", "arena", "frozen_lake", "cliff_walking", "taxi"]


def _unwrap(env: Any, class_name: str, adapter: str) -> Any:
    """The environment under Gymnasium's wrappers, checked to be ``class_name``."""
    inner = getattr(env, "unwrapped", env)
    if type(inner).__name__ != class_name:
        raise TypeError(
            f"tes.adapters.{adapter} takes a {class_name} environment, "
            f"not {type(inner).__name__}"
        )
    return inner


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
    inner = _unwrap(env, "GridTaskEnv", "grid_task")
    return WorldStructure(
        inner.world,
        f"grid task {inner.task} (world seed {inner.world_seed})",
        ["north", "east", "south", "west"],
    )


def arena(env: Any) -> WorldStructure:
    """The structure of a ``tes/Arena-v0`` environment (all 312 camera features)."""
    inner = _unwrap(env, "ArenaEnv", "arena")
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
    inner = _unwrap(env, "FrozenLakeEnv", "frozen_lake")
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
    inner = _unwrap(env, "CliffWalkingEnv", "cliff_walking")
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


class TaxiStructure:
    """Taxi's structure (Dietterich's taxi, Gymnasium's ``Taxi-v4``): 500 states (taxi row and
    column, passenger at one of the 4 stands or in the taxi, destination), 6 actions (south,
    north, east, west, pick up, drop off).

    Effects: 0–3 the taxi moved south, north, east, west; 4 the passenger got in; 5 the
    passenger got out at the destination (the end); 6 the passenger got out at another
    stand; 7 the taxi stayed put. The rewards are Taxi's own, by state, action and next state
    (``step_reward``): +20 for the delivery, −10 for a pick-up or drop-off that stays put (it
    was refused), −1 for every other step — a bump into a wall stays put too, at −1, with no
    effect or state of its own.

    Features, per state: the taxi's cell (25), which sides of it are walled (4), the
    passenger in the taxi, the taxi at the passenger's stand, at the destination, at any
    stand, and the three combinations pick-up and drop-off turn on (passenger waiting at the
    taxi's cell; in the taxi at the destination; in the taxi at another stand).
    """

    MOVES = ((1, 0), (-1, 0), (0, 1), (0, -1))
    PICKED_UP, DELIVERED, DROPPED, STAYED = 4, 5, 6, 7
    PICKUP, DROPOFF = 4, 5

    def __init__(self, env: Any):
        inner = _unwrap(env, "TaxiEnv", "taxi")
        if any(len(outcomes) != 1 for by_action in inner.P.values() for outcomes in by_action.values()):
            raise ValueError("tes.adapters.taxi takes the dry taxi (is_rainy=False)")
        if getattr(inner, "fickle_passenger", False):
            raise ValueError(
                "tes.adapters.taxi takes a passenger who keeps to the destination "
                "(fickle_passenger=False)"
            )
        self._env = inner
        self.locs = [tuple(loc) for loc in inner.locs]
        self.nrow, self.ncol = inner.max_row + 1, inner.max_col + 1
        self.n_states = int(inner.observation_space.n)
        self.n_actions = int(inner.action_space.n)
        self.n_effects = 8
        self.n_features = self.nrow * self.ncol + 4 + 4 + 3
        self.name = "Taxi"
        self.action_names = ["south", "north", "east", "west", "pickup", "dropoff"]
        self.feature_names = (
            [f"cell=({r},{c})" for r in range(self.nrow) for c in range(self.ncol)]
            + [f"wall={n}" for n in ("south", "north", "east", "west")]
            + ["in_taxi", "at_passenger", "at_destination", "at_stand"]
            + ["waiting_here", "deliverable", "droppable_elsewhere"]
        )
        # Walls from the table itself: a move that stays put in the dry taxi hit one.
        self._walled = np.zeros((self.nrow, self.ncol, 4), dtype=bool)
        for s in range(self.n_states):
            row, col, _, _ = inner.decode(s)
            for a in range(4):
                self._walled[row, col, a] = inner.P[s][a][0][1] == s

    def state(self, obs: Any) -> int:
        return int(obs)

    def _decode(self, state: int) -> tuple[int, int, int, int]:
        row, col, passenger, destination = self._env.decode(state)
        return int(row), int(col), int(passenger), int(destination)

    def _encode(self, row: int, col: int, passenger: int, destination: int) -> int:
        return int(self._env.encode(row, col, passenger, destination))

    def features(self, state: int) -> list[int]:
        row, col, passenger, destination = self._decode(state)
        cells = self.nrow * self.ncol
        on = [row * self.ncol + col]
        on += [cells + a for a in range(4) if self._walled[row, col, a]]
        here = (row, col)
        in_taxi = passenger == 4
        at_passenger = not in_taxi and self.locs[passenger] == here
        at_destination = self.locs[destination] == here
        at_stand = here in self.locs
        flags = [in_taxi, at_passenger, at_destination, at_stand]
        combos = [at_passenger, in_taxi and at_destination, in_taxi and at_stand and not at_destination]
        on += [cells + 4 + i for i, f in enumerate(flags + combos) if f]
        return sorted(on)

    def next_state(self, state: int, effect: int) -> int:
        row, col, passenger, destination = self._decode(state)
        if self.terminal(state) or effect == self.STAYED:
            return state
        if effect < 4:
            dr, dc = self.MOVES[effect]
            r, c = row + dr, col + dc
            if 0 <= r < self.nrow and 0 <= c < self.ncol and not self._walled[row, col, effect]:
                return self._encode(r, c, passenger, destination)
            return state
        here = (row, col)
        if effect == self.PICKED_UP:
            ok = passenger < 4 and self.locs[passenger] == here
            return self._encode(row, col, 4, destination) if ok else state
        if effect == self.DELIVERED:
            ok = passenger == 4 and self.locs[destination] == here
            return self._encode(row, col, destination, destination) if ok else state
        ok = passenger == 4 and here in self.locs and self.locs[destination] != here
        return self._encode(row, col, self.locs.index(here), destination) if ok else state

    def step_reward(self, state: int, action: int, next_state: int) -> float:
        if next_state != state and self.terminal(next_state):
            return 20.0
        if next_state == state and action in (self.PICKUP, self.DROPOFF):
            return -10.0
        return -1.0

    def reward(self, state: int) -> float:
        """The reward for entering ``state`` (+20 for the delivered states; the planner reads
        ``step_reward``, which also knows the action)."""
        return 20.0 if self.terminal(state) else -1.0

    def terminal(self, state: int) -> bool:
        _, _, passenger, destination = self._decode(state)
        return passenger == destination

    def effect(self, state: int, action: int, next_state: int, reward: float) -> int:
        if next_state == state:
            return self.STAYED
        row, col, passenger, _ = self._decode(state)
        row2, col2, passenger2, destination = self._decode(next_state)
        if passenger2 != passenger:
            if passenger2 == 4:
                return self.PICKED_UP
            return self.DELIVERED if passenger2 == destination else self.DROPPED
        for e, (dr, dc) in enumerate(self.MOVES):
            if (row + dr, col + dc) == (row2, col2):
                return e
        raise ValueError(f"no effect leads from state {state} to state {next_state}")


def taxi(env: Any) -> TaxiStructure:
    """The structure of a ``Taxi-v4`` environment (see :class:`TaxiStructure`)."""
    return TaxiStructure(env)
