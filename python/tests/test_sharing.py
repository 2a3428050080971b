"""One object from several threads, copies and pickles that go on as the original, and
evaluation that changes nothing."""

from __future__ import annotations

import copy
import pickle
import threading

import gymnasium
import numpy as np
import pytest
from scipy import sparse

import tes
from tes.evaluate import success_probability


def stream(rows: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = (rng.random((rows, 20)) < 0.2).astype(np.float64)
    y = (X[:, 0] + 2 * X[:, 3] + (rng.random(rows) < 0.1)).astype(np.int64) % 3
    return X, y


# ---- threads ------------------------------------------------------------------------------


def test_readers_during_learning_see_the_model_between_batches():
    """A learner feeds batches while readers predict a probe: every prediction a reader sees
    is, to the bit, the model's after some whole number of batches."""
    X, y = stream(12_000)
    batches = np.array_split(np.arange(len(y)), 40)
    probe = X[:50]
    reference = tes.Mdagl(lam=0.01, alpha=0.3)
    reference.partial_fit(X[:1], y[:1], classes=[0, 1, 2])
    snapshots = {reference.predict_proba(probe).tobytes()}
    for rows in batches:
        reference.partial_fit(X[rows], y[rows])
        snapshots.add(reference.predict_proba(probe).tobytes())

    model = tes.Mdagl(lam=0.01, alpha=0.3)
    model.partial_fit(X[:1], y[:1], classes=[0, 1, 2])
    seen: list[bytes] = []
    updates: list[int] = []
    errors: list[BaseException] = []
    done = threading.Event()

    def read():
        try:
            while not done.is_set():
                seen.append(model.predict_proba(probe).tobytes())
                updates.append(model.n_updates_)
                model.coef_, model.selected_
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    readers = [threading.Thread(target=read) for _ in range(3)]
    for r in readers:
        r.start()
    try:
        for rows in batches:
            model.partial_fit(X[rows], y[rows])
    finally:
        done.set()
        for r in readers:
            r.join()
    assert errors == []
    assert len(seen) > 10
    assert set(seen) <= snapshots
    sizes = {1 + sum(len(b) for b in batches[:k]) for k in range(len(batches) + 1)}
    assert set(updates) <= sizes
    assert model.predict_proba(probe).tobytes() == reference.predict_proba(probe).tobytes()


def test_two_learners_take_turns():
    """Two threads learning into one model: every row is learned once, no call fails, and
    the log-loss sum adds up both threads' batches."""
    X, y = stream(8_000, seed=1)
    model = tes.Mdagl(lam=0.01, alpha=0.3)
    model.partial_fit(X[:1], y[:1], classes=[0, 1, 2])
    halves = np.array_split(np.arange(1, len(y)), 2)
    errors: list[BaseException] = []

    def learn(rows):
        try:
            for chunk in np.array_split(rows, 20):
                model.partial_fit(X[chunk], y[chunk])
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=learn, args=(h,)) for h in halves]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert model.n_updates_ == len(y)
    assert np.isfinite(model.log_loss_sum_) and model.log_loss_sum_ > 0


def test_an_agent_used_from_several_threads_takes_turns():
    env = gymnasium.make("FrozenLake-v1", map_name="4x4", is_slippery=True)
    agent = tes.agents.LoreRL(tes.adapters.frozen_lake(env), seed=0)
    errors: list[BaseException] = []
    done = threading.Event()

    def evaluate():
        try:
            while not done.is_set():
                assert agent.greedy_policy().shape == (16,)
                agent.name
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    reader = threading.Thread(target=evaluate)
    reader.start()
    try:
        tes.run(env, agent, episodes=60, seed=0)
    finally:
        done.set()
        reader.join()
    assert errors == []


# ---- copies and pickles -------------------------------------------------------------------


def round_trips(obj):
    """pickle, copy.deepcopy and copy.copy of ``obj``."""
    return [pickle.loads(pickle.dumps(obj)), copy.deepcopy(obj), copy.copy(obj)]


@pytest.mark.parametrize("lam", ["auto", 0.01])
@pytest.mark.parametrize("rows_before", [300, 5_000])
def test_an_mdagl_copy_predicts_and_learns_on_as_the_original(lam, rows_before):
    """Fixed and racing (before the race's first cut and after it), on both paths."""
    X, y = stream(rows_before + 2_000, seed=2)
    model = tes.Mdagl(lam=lam)
    model.partial_fit(X[:rows_before], y[:rows_before], classes=[0, 1, 2])
    copies = round_trips(model)
    rest = slice(rows_before, None)
    model.partial_fit(X[rest], y[rest])
    for i, twin in enumerate(copies):
        before = twin.n_updates_
        twin.partial_fit(sparse.csr_matrix(X[rest]) if i == 0 else X[rest], y[rest])
        assert before == rows_before
        assert twin.predict_proba(X).tobytes() == model.predict_proba(X).tobytes()
        assert twin.log_loss_sum_ == model.log_loss_sum_
        assert (twin.lam_, twin.alpha_, twin.standings_) == (
            model.lam_,
            model.alpha_,
            model.standings_,
        )


def test_copy_copy_does_not_share_the_native_model():
    X, y = stream(100)
    model = tes.Mdagl(lam=0.01, alpha=0.3).partial_fit(X, y, classes=[0, 1, 2])
    shallow = copy.copy(model)
    shallow.partial_fit(X, y)
    assert model.n_updates_ == 100 and shallow.n_updates_ == 200
    agent = tes.agents.FEpsG(tes.adapters.frozen_lake(gymnasium.make("FrozenLake-v1")))
    other = copy.copy(agent)
    other.act(0)
    assert agent._native.steps_logged == 0 and other._native.steps_logged == 2


def toy_agents(structure, library):
    yield tes.agents.LoreRL(structure, lam=0.01, alpha=0.3, intercept=True, seed=4)
    yield tes.agents.FEpsG(structure, seed=4)
    yield tes.agents.TES(structure, library, lam=0.01, alpha=0.3, intercept=True, seed=4)
    yield tes.agents.LWT(structure, library, seed=4)


def test_every_agent_copies_and_pickles_into_one_that_goes_on_alike(tmp_path):
    env = gymnasium.make("FrozenLake-v1", map_name="4x4", is_slippery=True)
    structure = tes.adapters.frozen_lake(env)
    # A library with views in it, for TES and LWT to start on.
    teacher = tes.agents.TES(structure, tmp_path / "views.tesl", lam=0.01, alpha=0.3, seed=1)
    tes.run(env, teacher, episodes=40, seed=1)
    teacher.end_task()
    for agent in toy_agents(structure, tmp_path / "views.tesl"):
        tes.run(env, agent, episodes=15, seed=2)
        if isinstance(agent, tes.agents.TES):
            agent.end_task()  # replayed from the log, without writing the file again
            tes.run(env, agent, episodes=5, seed=5)
        copies = round_trips(agent)
        later = tes.run(gymnasium.make("FrozenLake-v1", is_slippery=True), agent, 20, seed=3)
        for twin in copies:
            assert type(twin) is type(agent)
            twin_later = tes.run(gymnasium.make("FrozenLake-v1", is_slippery=True), twin, 20, seed=3)
            assert twin_later.tolist() == later.tolist(), agent.name
            assert twin.greedy_policy().tolist() == agent.greedy_policy().tolist(), agent.name


@pytest.mark.parametrize(
    "env_id, kwargs",
    [("tes/GridTask-v0", {"task": 2, "irrelevant": 20}), ("tes/Arena-v0", {"arena": 2})],
)
def test_both_worlds_copy_and_pickle_mid_episode(env_id, kwargs):
    env = gymnasium.make(env_id, **kwargs)
    env.reset(seed=11)
    rng = np.random.default_rng(0)
    for _ in range(3):
        _, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        if terminated or truncated:
            env.reset()
    copies = round_trips(env.unwrapped)[:2]  # a shallow copy of an env shares its world

    def trace(e):
        out = []
        for a in [0, 1, 2, 0, 1, 2, 2, 1, 0, 0] * 3:
            obs, reward, terminated, truncated, info = e.step(a)
            out.append((int(obs["state"]), float(reward), terminated, truncated, info["effect"]))
            if terminated or truncated:
                e.reset()
        return out

    original = trace(env.unwrapped)
    for twin in copies:
        assert trace(twin) == original


# ---- evaluation is pure -------------------------------------------------------------------


@pytest.mark.parametrize("make", [tes.agents.LoreRL, tes.agents.FEpsG])
def test_evaluating_every_episode_leaves_training_as_it_was(make):
    """Two agents of one seed on environments of one seed: one's greedy policy is judged
    after every episode, the other's never; their rewards agree bit for bit."""
    P = gymnasium.make("FrozenLake-v1", is_slippery=True).unwrapped.P

    def train(evaluate: bool) -> list[float]:
        env = gymnasium.make("FrozenLake-v1", map_name="4x4", is_slippery=True)
        agent = make(tes.adapters.frozen_lake(env), seed=9)
        rewards = []
        start = env.unwrapped.initial_state_distrib
        for episode in range(80):
            rewards += tes.run(env, agent, 1, seed=9 if episode == 0 else None).tolist()
            if evaluate:
                success_probability(P, agent.greedy_policy(), start, 100)
        return rewards

    assert train(True) == train(False)
