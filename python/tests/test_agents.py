"""The agents on environments no one here wrote (Gymnasium's toy texts) and on our worlds."""

from __future__ import annotations

import pickle
import subprocess

import gymnasium
import numpy as np
import pytest
from gymnasium.envs.toy_text.frozen_lake import generate_random_map

import tes
from conftest import tes_binary
from tes.evaluate import optimal_success_probability, policy_value, success_probability

# loreRL's settings on the toy texts. The paper's λ = 0.05 is tuned for hundreds of features
# of which a few matter; here every feature is rare (a corner pattern is on in 1 of 64 cells),
# so its threshold switches everything off and loreRL plans on a uniform model (0.71 success
# on FrozenLake 8×8 against the optimum's 0.89). λ = 0.01 with an intercept keeps what matters.
TOY = {"lam": 0.01, "alpha": 0.3, "intercept": True, "gamma": 0.99}


class Corridor:
    """A hand-written structure: 5 cells in a row, the exit at the right end (+1)."""

    n_states, n_actions, n_effects, n_features = 5, 2, 3, 5

    def state(self, obs):
        return int(obs)

    def features(self, state):
        return [state]

    def next_state(self, state, effect):
        if state == 4 or effect == 2:
            return state
        return max(0, min(4, state + (1 if effect == 1 else -1)))

    def reward(self, state):
        return 1.0 if state == 4 else -0.1

    def terminal(self, state):
        return state == 4

    def effect(self, state, action, next_state, reward):
        return 2 if next_state == state else int(next_state > state)


class CorridorEnv:
    """The corridor as an environment: the action's move happens 80 % of the time."""

    def __init__(self):
        self.rng = np.random.default_rng(0)

    def reset(self, seed=None):
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.s = 0
        return self.s, {}

    def step(self, action):
        effect = action if self.rng.random() < 0.8 else 2
        self.s = Corridor().next_state(self.s, effect)
        return self.s, Corridor().reward(self.s), self.s == 4, False, {}


def test_a_hand_written_structure_is_learned_and_planned():
    assert isinstance(Corridor(), tes.structure.Structure)
    agent = tes.agents.LoreRL(Corridor(), seed=1)
    rewards = tes.run(CorridorEnv(), agent, episodes=60, seed=1)
    assert agent.greedy_policy()[:4].tolist() == [1, 1, 1, 1]
    assert rewards[-20:].mean() > rewards[:5].mean()


@pytest.mark.parametrize(
    "broken, words",
    [
        ("next_state", "next_state"),
        ("features", "state 2"),
        ("reward", "reward"),
    ],
)
def test_a_broken_structure_names_the_problem(broken, words):
    corridor = Corridor()
    if broken == "next_state":
        corridor.next_state = lambda s, e: 7
    elif broken == "features":
        corridor.features = lambda s: [3, 1] if s == 2 else [s]
    else:
        corridor.reward = lambda s: float("nan")
    with pytest.raises(ValueError, match=words):
        tes.agents.LoreRL(corridor)


def test_bad_steps_are_refused_and_change_nothing():
    agent = tes.agents.LoreRL(Corridor(), seed=1)
    before = agent.greedy_policy()
    with pytest.raises(ValueError, match="out of range"):
        agent.act(9)
    with pytest.raises(ValueError, match="action 5 is out of range"):
        agent.observe(0, 5, -0.1, 1, False, False)
    with pytest.raises(ValueError, match="epsilon"):
        tes.agents.LoreRL(Corridor(), epsilon=2.0)
    assert agent.greedy_policy().tolist() == before.tolist()


def test_a_seeded_run_repeats():
    env = gymnasium.make("FrozenLake-v1", map_name="4x4", is_slippery=True)
    runs = [
        tes.run(env, tes.agents.LoreRL(tes.adapters.frozen_lake(env), seed=3, **TOY), 100, seed=5)
        for _ in range(2)
    ]
    assert runs[0].tolist() == runs[1].tolist()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lore_rl_finds_a_near_optimal_policy_on_frozen_lake_8x8_slippery(seed):
    # FrozenLake-v1 on the 8×8 map, with the 200-step limit Gymnasium gives that map.
    env = gymnasium.make("FrozenLake8x8-v1", is_slippery=True)
    table, start = env.unwrapped.P, env.unwrapped.initial_state_distrib
    horizon = env.spec.max_episode_steps
    agent = tes.agents.LoreRL(tes.adapters.frozen_lake(env), seed=seed, **TOY)
    tes.run(env, agent, episodes=1000, seed=seed)
    learned = success_probability(table, agent.greedy_policy(), start, horizon)
    best = optimal_success_probability(table, start, horizon)
    print(f"seed {seed}: loreRL's greedy policy {learned:.4f}, optimal {best:.4f}")
    assert horizon == 200 and 0.88 < best < 1
    assert learned >= 0.9 * best


def test_lore_rl_walks_the_cliff_edge_and_fepsg_learns_too():
    env = gymnasium.make("CliffWalking-v1")
    table, start = env.unwrapped.P, env.unwrapped.initial_state_distrib
    structure = tes.adapters.cliff_walking(env)
    lore = tes.agents.LoreRL(structure, seed=0, **TOY)
    tes.run(env, lore, episodes=150, seed=0)
    # It reaches the goal without falling: along the edge (13 steps of −1) or, while its model
    # still allows a slip, one row up (15).
    assert policy_value(table, lore.greedy_policy(), start, horizon=100) in (-13.0, -15.0)
    fepsg = tes.agents.FEpsG(structure, seed=0)
    rewards = tes.run(env, fepsg, episodes=150, seed=0)
    assert fepsg.name == "fEpsG" and rewards[-20:].mean() > rewards[:5].mean()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lore_rl_solves_taxi_within_50_episodes(seed):
    """Taxi-v4 (Gymnasium's current name) with its structure declared by tes.adapters.taxi:
    each step's reward is Taxi's by state, action and next state (a refused pick-up −10, a
    bump into a wall −1, both staying put in one effect), with no mirror states. The greedy
    policy delivers from every start within 200 steps."""
    env = gymnasium.make("Taxi-v4")
    table, start = env.unwrapped.P, env.unwrapped.initial_state_distrib
    agent = tes.agents.LoreRL(tes.adapters.taxi(env), seed=seed, **TOY)
    for episode in range(1, 51):
        tes.run(env, agent, 1, seed=seed if episode == 1 else None)
        success = success_probability(table, agent.greedy_policy(), start, 200)
        if success == pytest.approx(1.0, abs=1e-12):
            break
    print(f"seed {seed}: greedy success 1.0 after {episode} episodes")
    assert success == pytest.approx(1.0, abs=1e-12)


def test_an_adapter_refuses_another_environment():
    with pytest.raises(TypeError, match="frozen_lake takes a FrozenLakeEnv environment, not TaxiEnv"):
        tes.adapters.frozen_lake(gymnasium.make("Taxi-v4"))
    with pytest.raises(TypeError, match="taxi takes a TaxiEnv"):
        tes.adapters.taxi(gymnasium.make("CliffWalking-v1"))
    with pytest.raises(ValueError, match="is_rainy"):
        tes.adapters.taxi(gymnasium.make("Taxi-v4", is_rainy=True))


def test_a_step_reward_is_what_the_plan_pays():
    """The Corridor with a toll on moving right from cell 2 that outweighs the exit: the plan
    then goes nowhere near it (with entering rewards alone it would walk right)."""

    class Tolled(Corridor):
        def step_reward(self, state, action, next_state):
            if (state, next_state) == (2, 3):
                return -50.0
            return self.reward(next_state)

    native = tes.structure.compile(Tolled())
    assert native.step_reward(2, 0, 1) == -50.0 and native.step_reward(2, 1, 1) == -50.0
    assert native.step_reward(1, 1, 1) == -0.1
    assert native.reward(3) == -0.1
    class CappedCorridorEnv(CorridorEnv):
        """Cut off after 20 steps: a plan that keeps away from the exit never ends."""

        def reset(self, seed=None):
            self.steps = 0
            return super().reset(seed)

        def step(self, action):
            self.steps += 1
            obs, reward, terminated, _, info = super().step(action)
            return obs, reward, terminated, self.steps >= 20, info

    agent = tes.agents.LoreRL(Tolled(), seed=1)
    tes.run(CappedCorridorEnv(), agent, episodes=30, seed=1)
    assert agent.greedy_policy()[2] == 0


def frozen_lake(map_seed: int, success_rate: float = 0.8):
    desc = generate_random_map(size=8, p=0.8, seed=map_seed)
    return gymnasium.make(
        "FrozenLake-v1", desc=desc, is_slippery=True, success_rate=success_rate
    )


@pytest.fixture(scope="module")
def frozen_lake_library(tmp_path_factory):
    """A TES library trained on three random 8×8 maps with success rate 0.8."""
    path = tmp_path_factory.mktemp("library") / "frozen-lake.tesl"
    for task in range(3):
        env = frozen_lake(100 + task)
        agent = tes.agents.TES(tes.adapters.frozen_lake(env), library=path, seed=task, **TOY)
        tes.run(env, agent, episodes=300, seed=task)
        report = agent.end_task()
        assert report["task"] == task
    return path


def test_tes_transfers_to_new_maps_with_a_jumpstart(frozen_lake_library):
    # Ten new maps, the same slip: TES on the library against loreRL from scratch, the mean
    # reward of their first 50 episodes, paired by map and seed.
    gains = []
    for run in range(10):
        env = frozen_lake(200 + run)
        structure = tes.adapters.frozen_lake(env)
        transfer = tes.agents.TES(structure, library=frozen_lake_library, seed=run, **TOY)
        scratch = tes.agents.LoreRL(structure, seed=run, **TOY)
        gains.append(
            tes.run(env, transfer, 50, seed=run).mean() - tes.run(env, scratch, 50, seed=run).mean()
        )
    gains = np.array(gains)
    half_width = 2.262 * gains.std(ddof=1) / np.sqrt(len(gains))  # t(0.975, 9 dof)
    print(f"jumpstart {gains.mean():.3f} ± {half_width:.3f} (95 %)")
    assert gains.mean() - half_width > 0


def test_the_library_file_is_the_one_tes_library_show_reads(frozen_lake_library):
    shown = subprocess.run(
        [tes_binary(), "library", "show", str(frozen_lake_library)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "world: FrozenLake 8x8; 4 actions, 5 effects, 84 features" in shown
    assert "3 tasks seen" in shown
    assert "blocked=" in shown


def test_lwt_follows_the_library_without_learning(frozen_lake_library, tmp_path):
    env = frozen_lake(300)
    agent = tes.agents.LWT(tes.adapters.frozen_lake(env), frozen_lake_library, seed=0, **TOY)
    assert agent.name == "LWT"
    before = agent.greedy_policy()
    tes.run(env, agent, 30, seed=0)
    assert agent.greedy_policy().tolist() == before.tolist()
    with pytest.raises(FileNotFoundError, match="LWT needs a view library"):
        tes.agents.LWT(tes.adapters.frozen_lake(env), tmp_path / "none.tesl")


def test_a_corrupt_or_foreign_library_is_refused_and_kept(frozen_lake_library, tmp_path):
    structure = tes.adapters.frozen_lake(frozen_lake(1))
    corrupt = tmp_path / "corrupt.tesl"
    data = bytearray(frozen_lake_library.read_bytes())
    data[-3] ^= 0xFF
    corrupt.write_bytes(bytes(data))
    with pytest.raises(tes.LibraryFileError, match="corrupt"):
        tes.agents.TES(structure, library=corrupt)
    assert corrupt.read_bytes() == bytes(data)
    small = tes.adapters.frozen_lake(gymnasium.make("FrozenLake-v1", map_name="4x4"))
    with pytest.raises(tes.LibraryFileError, match="this world has"):
        tes.agents.TES(small, library=frozen_lake_library)
    (tmp_path / "not.tesl").write_text("hello")
    with pytest.raises(tes.LibraryFileError, match="not a TES view library"):
        tes.agents.TES(structure, library=tmp_path / "not.tesl")


def test_save_writes_the_library_where_asked(tmp_path):
    env = frozen_lake(7)
    agent = tes.agents.TES(tes.adapters.frozen_lake(env), seed=0, **TOY)
    with pytest.raises(ValueError, match="no library path"):
        agent.save()
    tes.run(env, agent, 20, seed=0)
    agent.end_task()
    agent.save(tmp_path / "saved.tesl")
    again = tes.agents.TES(tes.adapters.frozen_lake(env), library=tmp_path / "saved.tesl")
    assert again.library_size == agent.library_size and agent.library_size[1] == 1


@pytest.mark.parametrize("make_agent", ["LoreRL", "TES"])
def test_agents_learn_our_grid_task(make_agent):
    env = gymnasium.make("tes/GridTask-v0", task=1, irrelevant=20)
    structure = tes.adapters.grid_task(env)
    agent = getattr(tes.agents, make_agent)(structure, seed=1)
    rewards = tes.run(env, agent, episodes=120, seed=1)
    assert rewards[-30:].mean() > rewards[:10].mean()


def test_lore_rl_steps_the_arena():
    env = gymnasium.make("tes/Arena-v0", arena=3)
    agent = tes.agents.LoreRL(tes.adapters.arena(env), seed=0)
    rewards = tes.run(env, agent, episodes=30, seed=0)
    assert len(rewards) == 30 and agent.greedy_policy().shape == (env.unwrapped.world.n_states,)


@pytest.mark.parametrize("module", ["tes.agents", "tes.envs", "tes.evaluate"])
def test_the_module_examples_run(module):
    import doctest
    import importlib

    failures, tried = doctest.testmod(importlib.import_module(module))
    assert tried > 0 and failures == 0


def test_a_bad_step_reward_table_is_refused():
    class Bad(Corridor):
        def __init__(self, value):
            self.value = value

        def step_reward(self, state, action, next_state):
            return self.value if (state, action, next_state) == (1, 1, 1) else -0.1

    with pytest.raises(ValueError, match="reward of action 1 with effect 2 in state 1 is not finite"):
        tes.structure.compile(Bad(float("nan")))
    good = tes.structure.compile(Bad(-1.0))
    args = list(good.__reduce__()[1])
    args[-1] = np.zeros((5, 3, 3))
    with pytest.raises(
        ValueError,
        match=r"step_reward is \(5, 3, 3\) but the structure has 5 states, 2 actions and 3 effects",
    ):
        tes._tes.Structure(*args)
    copied = pickle.loads(pickle.dumps(good))
    assert copied.step_reward(1, 1, 2) == -1.0 and copied.step_reward(1, 0, 2) == -0.1
    with pytest.raises(ValueError, match="action 2 is out of range"):
        copied.step_reward(1, 2, 2)


def test_a_reward_that_depends_on_the_action_alone_is_planned_on():
    """Two actions that do the same thing — each moves right or stays with the same chances,
    from the same cell to the same next cell — but action 0 costs 1.0 a step and action 1
    0.1: the plan takes the cheaper one everywhere, though nothing in where the steps lead
    tells the actions apart, and the agent learns nothing about the costs (they are
    declared)."""

    class Tolls(Corridor):
        def step_reward(self, state, action, next_state):
            cost = -1.0 if action == 0 else -0.1
            return cost + (1.0 if next_state == 4 and state != 4 else 0.0)

    class SameMovesEnv(CorridorEnv):
        """Either action moves right 80 % of the time and stays otherwise."""

        def step(self, action):
            moved = self.rng.random() < 0.8
            self.s = min(4, self.s + 1) if moved else self.s
            cost = -1.0 if action == 0 else -0.1
            reward = cost + (1.0 if moved and self.s == 4 else 0.0)
            return self.s, reward, self.s == 4, False, {}

    structure = Tolls()
    native = tes.structure.compile(structure)
    assert native.step_reward(1, 0, 1) == -1.0 and native.step_reward(1, 1, 1) == -0.1
    assert native.step_reward(1, 0, 2) == native.step_reward(1, 0, 0) == -1.0
    agent = tes.agents.LoreRL(structure, seed=0, **TOY)
    tes.run(SameMovesEnv(), agent, episodes=30, seed=0)
    assert list(agent.greedy_policy()[:4]) == [1, 1, 1, 1]


def test_the_taxi_adapter_pays_what_taxi_pays():
    """Every state and action of Taxi-v4's own table: the declared reward of the step, and
    the effect the adapter reads from it leads where the table says."""
    env = gymnasium.make("Taxi-v4")
    structure = tes.adapters.taxi(env)
    native = tes.structure.compile(structure)
    for s, by_action in env.unwrapped.P.items():
        if structure.terminal(s):
            continue
        for a, [(_, next_state, reward, _)] in by_action.items():
            effect = structure.effect(s, a, next_state, reward)
            assert native.next_state(s, effect) == next_state
            assert native.step_reward(s, a, effect) == reward, (s, a)
