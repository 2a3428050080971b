"""The structure protocol: what an environment tells the agents about itself.

The paper's agents learn only *which effect* an action has in a state; what each effect
*does* is known to them (§3.1, the situation-calculus MDP). So to put ``LoreRL``, ``TES``,
``LWT`` or ``FEpsG`` on an environment, describe it with an object that has:

==========================================  ==================================================
``n_states``, ``n_actions``,                 sizes (ints)
``n_effects``, ``n_features``
``state(obs) -> int``                        the state an observation is in, ``0 .. n_states``
``features(state) -> Sequence[int]``         the indices of the binary features on in it
``next_state(state, effect) -> int``         where an effect leads from a state
``reward(state) -> float``                   the reward for *entering* a state
``terminal(state) -> bool``                  whether entering it ends the episode
``effect(state, action, next_state,          which effect a step had, from what was seen
reward) -> int``
==========================================  ==================================================

Optional: ``step_reward(state, action, next_state) -> float`` — the reward of taking
``action`` in ``state`` and landing in ``next_state``, for rewards that depend on the action
or the state left and not only on where the step ends (Taxi's −10 for a refused pick-up
beside −1 for a bump into a wall, both staying put; the planner then uses it instead of
``reward``, asking it once for each state, action and state an effect leads to);
``contexts(state) -> int`` (the factors ``FEpsG`` counts effects by; default:
every state its own), ``name`` (stored in a view library), ``action_names`` and
``feature_names`` (stored too, shown by ``tes library show``), and ``native()`` returning a
ready :class:`tes._tes.Structure` (our own worlds' adapters do, so nothing is rebuilt).

:func:`compile` reads such an object once into the native form the agents plan on, checking
it (a successor beyond the states, an unsorted or out-of-range feature, a non-finite reward
raise ``ValueError`` naming the state). :class:`GridStructure` is a ready base for worlds
laid out on a grid of cells, such as Gymnasium's toy texts (see :mod:`tes.adapters`).
"""

from __future__ import annotations

from typing import Any, Callable, Protocol, Sequence, runtime_checkable

import numpy as np

from tes import _tes


@runtime_checkable
class Structure(Protocol):
    """What the agents need to know about an environment (see the module docs)."""

    n_states: int
    n_actions: int
    n_effects: int
    n_features: int

    def state(self, obs: Any) -> int:
        """The state observation ``obs`` is in."""
        ...

    def features(self, state: int) -> Sequence[int]:
        """The indices of the binary features on in ``state``, sorted."""
        ...

    def next_state(self, state: int, effect: int) -> int:
        """Where ``effect`` leads from ``state``."""
        ...

    def reward(self, state: int) -> float:
        """The reward for entering ``state``."""
        ...

    def terminal(self, state: int) -> bool:
        """Whether entering ``state`` ends the episode."""
        ...

    def effect(self, state: int, action: int, next_state: int, reward: float) -> int:
        """Which effect taking ``action`` in ``state`` had, given where it led and its reward."""
        ...


def compile(structure: Structure) -> _tes.Structure:  # noqa: A001 - the protocol's verb
    """Reads ``structure`` into the checked native form the agents plan on."""
    native = getattr(structure, "native", None)
    if callable(native):
        return native()
    for name in ("n_states", "n_actions", "n_effects", "n_features"):
        if not hasattr(structure, name):
            raise TypeError(f"the structure has no {name}; see tes.structure.Structure")
    n_states, n_effects = int(structure.n_states), int(structure.n_effects)
    next_state = np.array(
        [[structure.next_state(s, e) for e in range(n_effects)] for s in range(n_states)],
        dtype=np.int64,
    ).reshape(n_states, n_effects)
    reward = np.array([structure.reward(s) for s in range(n_states)], dtype=np.float64)
    terminal = np.array([bool(structure.terminal(s)) for s in range(n_states)], dtype=bool)
    rows = [np.asarray(structure.features(s), dtype=np.int64) for s in range(n_states)]
    indptr = np.zeros(n_states + 1, dtype=np.int64)
    indptr[1:] = np.cumsum([len(r) for r in rows])
    for s, r in enumerate(rows):
        if r.size and (r.min() < 0 or r.max() >= 2**32):
            raise ValueError(f"state {s}: feature indices must be 0 to n_features - 1")
    indices = (np.concatenate(rows) if rows else np.zeros(0)).astype(np.uint32)
    contexts = None
    if callable(getattr(structure, "contexts", None)):
        contexts = np.array([structure.contexts(s) for s in range(n_states)], dtype=np.int64)
    step_reward = None
    if callable(getattr(structure, "step_reward", None)):
        step_reward = _step_rewards(structure.step_reward, next_state, int(structure.n_actions))
    return _tes.Structure(
        next_state,
        reward,
        terminal,
        indptr,
        indices,
        int(structure.n_features),
        int(structure.n_actions),
        contexts,
        None,
        step_reward,
    )


def _step_rewards(
    step_reward: Callable[[int, int, int], float], next_state: np.ndarray, n_actions: int
) -> np.ndarray:
    """``step_reward(s, a, next_state[s, e])`` as an ``(n_states, n_actions, n_effects)``
    table: what the planner reads per effect, asked once per distinct next state (effects
    that land in the same state share the reward, as a reward of the next state must)."""
    n_states, n_effects = next_state.shape
    table = np.empty((n_states, n_actions, n_effects), dtype=np.float64)
    for s in range(n_states):
        targets, where = np.unique(next_state[s], return_inverse=True)
        for a in range(n_actions):
            paid = np.array([float(step_reward(s, a, int(t))) for t in targets], dtype=np.float64)
            table[s, a] = paid[where]
    return table


class GridStructure:
    """A world on a grid of cells whose effects are moves to a neighbouring cell or staying.

    States are ``row * ncol + col``; effect ``i < len(moves)`` moves by ``moves[i]`` (a
    ``(drow, dcol)`` pair), the last effect stays. A move off the grid stays, and the agent
    learns that it never happens there. The observed effect is the move that was made, so
    it follows from the two states alone; ``redirect`` maps a cell that is never occupied (a
    cliff) to the state the agent is sent to instead, and a step with that cell's reward is
    the move into it.

    Features, for each cell: which of its sides are blocked (one bit per move), which
    combination of them is (one bit per combination: the dynamics of a grid world with the
    same rule everywhere depend on nothing else), and the cell itself (one bit per cell, so
    anything that holds in one cell only can still be learned).
    """

    def __init__(
        self,
        nrow: int,
        ncol: int,
        moves: Sequence[tuple[int, int]],
        rewards: Sequence[float] | np.ndarray,
        terminals: Sequence[bool] | np.ndarray,
        redirect: dict[int, int] | None = None,
        move_names: Sequence[str] | None = None,
        name: str = "grid",
    ):
        self.nrow, self.ncol = int(nrow), int(ncol)
        self.moves = [tuple(m) for m in moves]
        self.n_states = self.nrow * self.ncol
        self.n_effects = len(self.moves) + 1
        self.stay = len(self.moves)
        self.n_actions = len(self.moves)
        self._rewards = [float(r) for r in rewards]
        self._terminals = [bool(t) for t in terminals]
        self.redirect = dict(redirect or {})
        self.name = name
        n_moves = len(self.moves)
        self.n_features = n_moves + 2**n_moves + self.n_states
        names = list(move_names or [f"move{i}" for i in range(n_moves)])
        self.action_names = names
        self.feature_names = (
            [f"blocked={n}" for n in names]
            + [
                "blocked={" + ",".join(n for i, n in enumerate(names) if mask >> i & 1) + "}"
                for mask in range(2**n_moves)
            ]
            + [f"cell=({s // self.ncol},{s % self.ncol})" for s in range(self.n_states)]
        )

    def state(self, obs: Any) -> int:
        return int(obs)

    def _neighbour(self, state: int, move: int) -> int | None:
        row, col = divmod(state, self.ncol)
        dr, dc = self.moves[move]
        r, c = row + dr, col + dc
        if 0 <= r < self.nrow and 0 <= c < self.ncol:
            return r * self.ncol + c
        return None

    def blocked(self, state: int) -> list[int]:
        """The moves that would leave the grid from ``state``."""
        return [m for m in range(len(self.moves)) if self._neighbour(state, m) is None]

    def features(self, state: int) -> list[int]:
        blocked = self.blocked(state)
        mask = sum(1 << m for m in blocked)
        n_moves = len(self.moves)
        return sorted(blocked + [n_moves + mask, n_moves + 2**n_moves + state])

    def next_state(self, state: int, effect: int) -> int:
        if state in self.redirect:
            return self.redirect[state]
        if self._terminals[state] or effect == self.stay:
            return state
        target = self._neighbour(state, effect)
        return state if target is None else target

    def reward(self, state: int) -> float:
        return self._rewards[state]

    def terminal(self, state: int) -> bool:
        return self._terminals[state]

    def effect(self, state: int, action: int, next_state: int, reward: float) -> int:
        for move in range(len(self.moves)):
            target = self._neighbour(state, move)
            if target is None:
                continue
            if target == next_state or (
                target in self.redirect
                and self.redirect[target] == next_state
                and reward == self._rewards[target]
            ):
                return move
        if next_state == state:
            return self.stay
        raise ValueError(f"no move leads from state {state} to state {next_state}")
