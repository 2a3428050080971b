"""``python -m tes.bench --rl``: loreRL and fEpsG beside tabular Q-learning on Gymnasium's toy
texts — FrozenLake 4×4 and 8×8 (slippery), CliffWalking-v1 and Taxi-v4.

What each method is given:

* **loreRL** and **fEpsG** get the environment's declared structure (``tes.adapters``): what
  each effect does in each state, the rewards and terminal states, and (loreRL) each state's
  binary features. They learn which effect each action has where.
* **Q-learning** gets nothing but the state and action counts: a table of ``Q(s, a)`` from 0,
  ε-greedy (ε = 0.1), step size 0.1, γ = 0.99.

After every episode each method's greedy policy is judged exactly on the environment's own
transition table (no sampling): the probability that it reaches the goal within the
environment's step limit (FrozenLake: the goal's +1; Taxi: the delivery's +20; CliffWalking:
the goal, the only end) within the environment's step limit (CliffWalking, which has none:
100 steps). The table reports, over the seeds, the median number of episodes
until that first reaches 90 % of the best any policy achieves (``>N`` when a seed never did
within the budget of ``N``), and the greedy success after the last episode.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable

import gymnasium
import numpy as np

import tes

# loreRL on the toy texts: their features are rare (one cell each, a corner pattern in a few),
# so the paper's λ = 0.05 keeps none (see docs/python.md).
TOY = {"lam": 0.01, "alpha": 0.3, "intercept": True, "gamma": 0.99}


@dataclass(frozen=True)
class Task:
    name: str
    env_id: str
    kwargs: dict
    adapter: Callable[[Any], Any]
    episodes: int
    # Whether an ending transition with this reward is the goal.
    goal: Callable[[float], bool]


TASKS = [
    Task("FrozenLake 4x4", "FrozenLake-v1", {"map_name": "4x4"}, tes.adapters.frozen_lake,
         2000, lambda r: r > 0),
    Task("FrozenLake 8x8", "FrozenLake8x8-v1", {}, tes.adapters.frozen_lake, 4000,
         lambda r: r > 0),
    Task("CliffWalking", "CliffWalking-v1", {}, tes.adapters.cliff_walking, 500,
         lambda r: True),
    Task("Taxi", "Taxi-v4", {}, tes.adapters.taxi, 4000, lambda r: r > 0),
]


class Judge:
    """A greedy policy's exact probability of reaching the goal within ``horizon`` steps, from
    the start distribution, on a toy text's table (kept as padded arrays: cheap per call)."""

    def __init__(self, P: dict, start: np.ndarray, horizon: int, goal: Callable[[float], bool]):
        n_states, n_actions = len(P), len(P[0])
        width = max(len(o) for by_action in P.values() for o in by_action.values())
        self.next = np.zeros((n_states, n_actions, width), dtype=np.int64)
        self.live = np.zeros((n_states, n_actions, width))
        self.win = np.zeros((n_states, n_actions))
        for s, by_action in P.items():
            for a, outcomes in by_action.items():
                for k, (p, s2, r, done) in enumerate(outcomes):
                    self.next[s, a, k] = s2
                    if done:
                        self.win[s, a] += p if goal(r) else 0.0
                    else:
                        self.live[s, a, k] = p
        self.start, self.horizon, self.n_states = np.asarray(start, float), horizon, n_states

    def optimum(self) -> float:
        """The best any policy (free to change its action with the steps left) achieves:
        ``horizon`` backups of the chance of reaching the goal."""
        values = np.zeros(self.n_states)
        for _ in range(self.horizon):
            values = (self.win + (self.live * values[self.next]).sum(axis=2)).max(axis=1)
        return float(self.start @ values)

    def success(self, policy: np.ndarray) -> float:
        idx = np.arange(self.n_states)
        nxt, live, win = self.next[idx, policy], self.live[idx, policy], self.win[idx, policy]
        mass, total = self.start, 0.0
        for _ in range(self.horizon):
            total += mass @ win
            mass = np.bincount(nxt.ravel(), (mass[:, None] * live).ravel(), self.n_states)
        return float(total)


class QLearning:
    """Tabular Q-learning, ε-greedy: what a learner given no structure does."""

    name = "Q-learning"

    def __init__(self, n_states: int, n_actions: int, seed: int, epsilon: float = 0.1,
                 step: float = 0.1, gamma: float = 0.99):
        self.q = np.zeros((n_states, n_actions))
        self.rng = np.random.default_rng(seed)
        self.epsilon, self.step, self.gamma = epsilon, step, gamma

    def act(self, obs: Any) -> int:
        s = int(obs)
        if self.rng.random() < self.epsilon:
            return int(self.rng.integers(self.q.shape[1]))
        row = self.q[s]
        return int(self.rng.choice(np.flatnonzero(row == row.max())))

    def observe(self, obs, action, reward, next_obs, terminated, truncated) -> None:
        s, s2 = int(obs), int(next_obs)
        target = reward + (0.0 if terminated else self.gamma * self.q[s2].max())
        self.q[s, action] += self.step * (target - self.q[s, action])

    def end_episode(self) -> None:
        pass

    def greedy_policy(self) -> np.ndarray:
        return self.q.argmax(axis=1)


def make_agent(method: str, env: Any, task: Task, seed: int) -> Any:
    if method == "loreRL":
        return tes.agents.LoreRL(task.adapter(env), seed=seed, **TOY)
    if method == "fEpsG":
        return tes.agents.FEpsG(task.adapter(env), gamma=0.99, seed=seed)
    return QLearning(env.observation_space.n, env.action_space.n, seed)


def run_one(task: Task, method: str, seed: int) -> dict:
    """One method on one task and seed: episodes to 90 % of the optimum, final success."""
    env = gymnasium.make(task.env_id, **task.kwargs)
    inner = env.unwrapped
    # CliffWalking has no step limit: judge it within 100 steps (its shortest path is 13).
    horizon = env.spec.max_episode_steps or 100
    judge = Judge(inner.P, inner.initial_state_distrib, horizon, task.goal)
    best = judge.optimum()
    agent = make_agent(method, env, task, seed)
    reached = None
    started = time.perf_counter()
    for episode in range(1, task.episodes + 1):
        tes.run(env, agent, 1, seed=seed if episode == 1 else None)
        if reached is None and judge.success(agent.greedy_policy()) >= 0.9 * best:
            reached = episode
    final = judge.success(agent.greedy_policy())
    return {
        "task": task.name, "method": method, "seed": seed, "episodes_to_90": reached,
        "final_success": final, "optimum": best, "seconds": time.perf_counter() - started,
    }


def table(results: list[dict], budgets: dict[str, int]) -> str:
    """The markdown table docs/python.md shows."""
    methods = ["loreRL", "fEpsG", "Q-learning"]
    lines = ["| environment (episodes) | optimum | " + " | ".join(
        f"{m}: to 90 % / final" for m in methods) + " |",
        "|---|---|" + "---|" * len(methods)]
    for task in dict.fromkeys(r["task"] for r in results):
        rows = [r for r in results if r["task"] == task]
        cells = []
        for m in methods:
            mine = [r for r in rows if r["method"] == m]
            reached = [r["episodes_to_90"] for r in mine]
            budget = budgets[task]
            done = sorted(x if x is not None else budget + 1 for x in reached)
            median = statistics.median(done)
            to90 = f">{budget}" if median > budget else f"{median:g}"
            finals = ", ".join(f"{r['final_success']:.2f}" for r in mine)
            cells.append(f"{to90} / {finals}")
        lines.append(f"| {task} ({budgets[task]}) | {rows[0]['optimum']:.3f} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(seeds: int, as_json: bool, scale: float = 1.0) -> int:
    results = []
    budgets = {}
    for task in TASKS:
        budget = max(1, int(task.episodes * scale))
        task = Task(task.name, task.env_id, task.kwargs, task.adapter, budget, task.goal)
        budgets[task.name] = budget
        for method in ("loreRL", "fEpsG", "Q-learning"):
            for seed in range(seeds):
                r = run_one(task, method, seed)
                results.append(r)
                print(f"{task.name}, {method}, seed {seed}: 90 % after {r['episodes_to_90']}, "
                      f"final {r['final_success']:.3f} of {r['optimum']:.3f} "
                      f"({r['seconds']:.1f} s)", file=sys.stderr, flush=True)
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        print("Stable-Baselines3 is not installed: its DQN and PPO are not in this table",
              file=sys.stderr)
    if as_json:
        print(json.dumps({"results": results, "budgets": budgets}, indent=1))
    else:
        print(table(results, budgets))
    return 0


if __name__ == "__main__":
    sys.exit(main(3, False))
