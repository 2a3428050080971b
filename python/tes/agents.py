"""The paper's agents on any environment that declares its structure.

Every agent takes a structure (see :mod:`tes.structure`) and speaks the same protocol:

* ``act(obs) -> int`` — the action to take (ε-greedy on the current plan);
* ``observe(obs, action, reward, next_obs, terminated, truncated)`` — learn from the step;
* ``end_episode()`` — the episode ended (``observe`` also notices ``terminated`` or
  ``truncated``);
* ``greedy_policy() -> numpy.ndarray`` — for every state, in the structure's numbering, the
  action the agent's current plan takes (planned to convergence on a copy: asking changes
  nothing the agent does next).

An agent is safe to share between threads (its calls take turns), copies with ``copy.copy``
and ``copy.deepcopy`` into one that acts and learns on exactly as the original would, and
pickles as its structure, its settings and the steps it has learned from, which unpickling
replays (the same agent to the bit, at the cost of learning those steps again).

The learning and planning run in Rust with the GIL released: :class:`LoreRL` (the paper's
Algorithm 6), :class:`TES` and :class:`LWT` (Algorithms 2–3 and the single-view transfer
baseline) and :class:`FEpsG` (factored ε-greedy, counts per factor).

>>> import gymnasium, tes
>>> env = gymnasium.make("FrozenLake-v1", map_name="4x4", is_slippery=False)
>>> agent = tes.agents.LoreRL(tes.adapters.frozen_lake(env), seed=1)
>>> rewards = tes.run(env, agent, episodes=40, seed=1)
>>> float(rewards[-10:].mean())
1.0
"""

from __future__ import annotations

import copy
import numbers
import os
from typing import Any

import numpy as np

from tes import _tes
from tes.structure import Structure, compile

__all__ = ["Agent", "LoreRL", "TES", "LWT", "FEpsG"]


def _seed(seed: Any) -> int:
    """A seed as the native agents take it: a whole number from 0 to 2**64 - 1."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or not 0 <= int(seed) < 2**64:
        raise ValueError(f"seed must be a whole number from 0 to 2**64 - 1, not {seed!r}")
    return int(seed)


class Agent:
    """What the agents share: observations to states and effects, and the native agent."""

    def __init__(self, structure: Structure, native: _tes.Agent):
        self.structure = structure
        self._native = native
        self._starting = True

    @property
    def name(self) -> str:
        """The agent's short name ("loreRL", "TES", "LWT", "fEpsG")."""
        return self._native.name

    def act(self, obs: Any) -> int:
        """The action to take in the state ``obs`` is in."""
        state = self.structure.state(obs)
        if self._starting:
            self._native.begin_episode(state)
            self._starting = False
        return self._native.act(state)

    def observe(
        self,
        obs: Any,
        action: int,
        reward: float,
        next_obs: Any,
        terminated: bool,
        truncated: bool,
    ) -> None:
        """Learns which effect ``action`` had, from where it led (``next_obs``) and its reward."""
        state = self.structure.state(obs)
        next_state = self.structure.state(next_obs)
        effect = self.structure.effect(state, int(action), next_state, float(reward))
        self._native.observe(state, int(action), int(effect))
        if terminated or truncated:
            self._starting = True

    def end_episode(self) -> None:
        """Marks the end of an episode: the next ``act`` starts a new one."""
        self._starting = True

    def greedy_policy(self) -> np.ndarray:
        """For every state, the action the current plan takes (int64, ``n_states`` long)."""
        return self._native.greedy_policy()

    def __copy__(self) -> "Agent":
        """A copy that acts and learns on its own (the native agent is copied, not shared;
        the structure, which does not change, is)."""
        new = type(self).__new__(type(self))
        new.__dict__.update(self.__dict__)
        new._native = copy.copy(self._native)
        return new

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} on {self._native_structure_repr()}>"

    def _native_structure_repr(self) -> str:
        n = self.structure
        return f"{n.n_states} states, {n.n_actions} actions, {n.n_effects} effects"


class LoreRL(Agent):
    """loreRL: one mDAGL view per action predicting its effect from the state's features,
    value iteration on the learned model, ε-greedy.

    ``lam`` and ``alpha`` are mDAGL's λ and α (the paper's §5.1: 0.05 and 1.5), ``intercept``
    adds an always-on unregularised column, ``gamma`` is the planner's discount.
    """

    def __init__(
        self,
        structure: Structure,
        *,
        lam: float = 0.05,
        alpha: float = 1.5,
        intercept: bool = False,
        epsilon: float = 0.05,
        gamma: float = 0.95,
        seed: int = 0,
    ):
        native = _tes.Agent.lore_rl(
            compile(structure), lam, alpha, intercept, epsilon, gamma, _seed(seed)
        )
        super().__init__(structure, native)


class FEpsG(Agent):
    """Factored ε-greedy (the paper's fEpsG baseline): effect counts per (factor, action) on
    the maximum-likelihood model. The factors are the structure's ``contexts(state)`` if it
    has them (an oracle's knowledge), else every state is its own (tabular)."""

    def __init__(
        self,
        structure: Structure,
        *,
        epsilon: float = 0.1,
        gamma: float = 0.95,
        seed: int = 0,
    ):
        native = _tes.Agent.fepsg(compile(structure), epsilon, gamma, _seed(seed))
        super().__init__(structure, native)


class _Transfer(Agent):
    _policy = "tes"

    def __init__(
        self,
        structure: Structure,
        library: str | os.PathLike[str] | None = None,
        *,
        lam: float = 0.05,
        alpha: float = 1.5,
        intercept: bool = False,
        epsilon: float = 0.05,
        gamma: float = 0.95,
        max_views: int = 20,
        seed: int = 0,
    ):
        self.library = None if library is None else os.fspath(library)
        native = _tes.Agent.transfer(
            compile(structure),
            self.library,
            self._policy,
            lam,
            alpha,
            intercept,
            epsilon,
            gamma,
            max_views,
            _seed(seed),
            str(getattr(structure, "name", "") or type(structure).__name__),
            [str(n) for n in getattr(structure, "action_names", None) or []],
            [str(n) for n in getattr(structure, "feature_names", None) or []],
        )
        super().__init__(structure, native)

    def save(self, path: str | os.PathLike[str] | None = None) -> None:
        """Writes the library (as it stood when this task began) to ``path``, or to the
        agent's library file, atomically, in the format ``tes library show`` reads."""
        self._native.save(None if path is None else os.fspath(path))

    def end_task(self) -> dict[str, Any]:
        """Ends the task: TES grows the library with the views that explained this task
        better than any it had, prunes it to ``max_views``, and writes it to the library file;
        the agent then starts a new task (same structure) on the grown library. Returns
        ``{"task", "added", "updated", "removed"}`` (view ids)."""
        return self._native.end_task()

    @property
    def library_size(self) -> tuple[int, int]:
        """``(views, tasks seen)`` of the library."""
        return self._native.library_size()


class TES(_Transfer):
    """TES: a library of mDAGL views carried from task to task. Every view of the taken action
    is scored online by its log-likelihood and learns; the best-scoring one is planned on; at
    ``end_task()`` the library grows (an adjusted view that beats its original by the
    likelihood ratio 300, or a fresh view that won) and is pruned.

    ``library`` is a ``.tesl`` file: loaded if it exists (a corrupt file, or one for another
    shape of environment, raises :class:`tes.LibraryFileError` and is left as it is), written by
    ``save()`` and ``end_task()``.
    """

    _policy = "tes"


class LWT(_Transfer):
    """LWT: for each action the library view with the best track record, frozen (the paper's
    transfer baseline). Needs an existing library file."""

    _policy = "lwt"

    def __init__(self, structure: Structure, library: str | os.PathLike[str], **kwargs: Any):
        if library is None or not os.path.exists(library):
            raise FileNotFoundError(f"LWT needs a view library, and {library!r} does not exist")
        super().__init__(structure, library, **kwargs)
