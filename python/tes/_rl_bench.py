"""``python -m tes.bench --rl``: loreRL and fEpsG beside tabular Q-learning on Gymnasium's toy
texts — FrozenLake 4×4 and 8×8 (slippery), CliffWalking-v1 and Taxi-v4.

What each method is given:

* **loreRL** and **fEpsG** get the environment's declared structure (``tes.adapters``): what
  each effect does in each state, the rewards and terminal states, and (loreRL) each state's
  binary features. They learn which effect each action has where.
* **Q-learning** gets nothing but the state and action counts: a table of ``Q(s, a)`` from 0,
  ε-greedy (ε = 0.1), step size 0.1, γ = 0.99.
* **DQN (SB3)**, when Stable-Baselines3 imports: its DQN on the state as a one-hot vector
  (``MlpPolicy``, two hidden layers of 64, Adam at 1e-3, replay of 50 000 steps from step
  500, a batch of 64 each step, the target network copied every 500 steps, ε from 1 to 0.05
  over the first 10 000 steps, γ = 0.99, on the CPU). Without it the bench says why and
  leaves the row out.

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


DQN = "DQN (SB3)"
METHODS = ("loreRL", "fEpsG", "Q-learning")


def dqn_absent() -> str | None:
    """Why Stable-Baselines3's DQN cannot run here, or None when it can."""
    try:
        import stable_baselines3  # type: ignore[import-not-found, unused-ignore]  # noqa: F401
    except ImportError as error:
        return (f"Stable-Baselines3 does not import ({error}): its DQN is not in this table "
                "(pip install stable-baselines3, which needs PyTorch)")
    return None


class OneHot(gymnasium.ObservationWrapper):
    """A discrete state as a one-hot float vector: what an MLP's input takes."""

    def __init__(self, env: gymnasium.Env):
        super().__init__(env)
        space = env.observation_space
        if not isinstance(space, gymnasium.spaces.Discrete):
            raise TypeError(f"OneHot takes a Discrete observation space, not {space}")
        self.n_states = int(space.n)
        self.observation_space = gymnasium.spaces.Box(0.0, 1.0, (self.n_states,), np.float32)
        self._rows = np.eye(self.n_states, dtype=np.float32)

    def observation(self, observation: Any) -> np.ndarray:
        return self._rows[int(observation)].copy()

    def all_states(self) -> np.ndarray:
        """Every state's observation, one a row."""
        return self._rows.copy()


def run_dqn(task: Task, seed: int, judge: Judge, best: float) -> tuple[int | None, float]:
    """Stable-Baselines3's DQN for ``task.episodes`` episodes, its greedy policy judged after
    each: the episode it first reached 90 % of ``best``, and its final success."""
    from stable_baselines3 import DQN as SB3DQN  # type: ignore[import-not-found, unused-ignore]
    from stable_baselines3.common.callbacks import (  # type: ignore[import-not-found, unused-ignore]
        BaseCallback,
    )

    env = OneHot(gymnasium.make(task.env_id, **task.kwargs))
    states = env.all_states()

    def greedy(model: Any) -> np.ndarray:
        return np.asarray(model.predict(states, deterministic=True)[0], dtype=np.int64)

    class JudgedEpisodes(BaseCallback):
        """Counts finished episodes, judges the greedy policy after each, stops at the
        budget."""

        def __init__(self) -> None:
            super().__init__()
            self.episodes = 0
            self.reached: int | None = None

        def _on_step(self) -> bool:
            for done in self.locals["dones"]:
                if done:
                    self.episodes += 1
                    if self.reached is None and judge.success(greedy(self.model)) >= 0.9 * best:
                        self.reached = self.episodes
            return self.episodes < task.episodes

    horizon = env.spec.max_episode_steps if env.spec and env.spec.max_episode_steps else 100
    # A cap the episode budget reaches first; ε decays over a fixed 10 000 steps of it.
    total = task.episodes * horizon
    model = SB3DQN(
        "MlpPolicy", env, learning_rate=1e-3, buffer_size=50_000, learning_starts=500,
        batch_size=64, gamma=0.99, train_freq=1, target_update_interval=500,
        exploration_fraction=min(1.0, 10_000 / total), exploration_final_eps=0.05,
        policy_kwargs={"net_arch": [64, 64]}, seed=seed, device="cpu", verbose=0,
    )
    callback = JudgedEpisodes()
    model.learn(total_timesteps=total, callback=callback)
    return callback.reached, judge.success(greedy(model))


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
    started = time.perf_counter()
    if method == DQN:
        reached, final = run_dqn(task, seed, judge, best)
    else:
        reached, final = run_agent(make_agent(method, env, task, seed), env, task, seed, judge,
                                   best)
    return {
        "task": task.name, "method": method, "seed": seed, "episodes_to_90": reached,
        "final_success": final, "optimum": best, "seconds": time.perf_counter() - started,
    }


def run_agent(agent: Any, env: Any, task: Task, seed: int, judge: Judge,
              best: float) -> tuple[int | None, float]:
    """An agent of ours (or Q-learning) for ``task.episodes`` episodes, judged after each."""
    reached = None
    for episode in range(1, task.episodes + 1):
        tes.run(env, agent, 1, seed=seed if episode == 1 else None)
        if reached is None and judge.success(agent.greedy_policy()) >= 0.9 * best:
            reached = episode
    return reached, judge.success(agent.greedy_policy())


def table(results: list[dict], budgets: dict[str, int]) -> str:
    """The markdown table docs/python.md shows (a column for each method that ran)."""
    methods = list(dict.fromkeys(r["method"] for r in results))
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
    absent = dqn_absent()
    methods = METHODS if absent else (*METHODS, DQN)
    if absent:
        print(absent, file=sys.stderr, flush=True)
    for task in TASKS:
        budget = max(1, int(task.episodes * scale))
        task = Task(task.name, task.env_id, task.kwargs, task.adapter, budget, task.goal)
        budgets[task.name] = budget
        for method in methods:
            for seed in range(seeds):
                r = run_one(task, method, seed)
                results.append(r)
                print(f"{task.name}, {method}, seed {seed}: 90 % after {r['episodes_to_90']}, "
                      f"final {r['final_success']:.3f} of {r['optimum']:.3f} "
                      f"({r['seconds']:.1f} s)", file=sys.stderr, flush=True)
    if as_json:
        absences = {DQN: absent} if absent else {}
        print(json.dumps({"results": results, "budgets": budgets, "absent": absences}, indent=1))
    else:
        print(table(results, budgets))
    return 0


if __name__ == "__main__":
    sys.exit(main(3, False))
