"""tes/GridTask-v0 and tes/Arena-v0 as Gymnasium environments."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import tes

WORLDS = [
    ("tes/GridTask-v0", {"task": 1, "irrelevant": 20}),
    ("tes/GridTask-v0", {"task": 14, "irrelevant": 200, "world_seed": 5}),
    ("tes/Arena-v0", {"arena": 1}),
    ("tes/Arena-v0", {"arena": 2}),
    ("tes/Arena-v0", {"arena": 3}),
]


@pytest.mark.parametrize("env_id, kwargs", WORLDS)
def test_passes_gymnasiums_checks(env_id, kwargs):
    env = gymnasium.make(env_id, render_mode="rgb_array", **kwargs)
    check_env(env.unwrapped, skip_render_check=False)
    # gymnasium.make's own wrappers (the passive checker, order enforcing) accept it too.
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert env.observation_space.contains(obs)
    assert isinstance(info["effect"], int) and info["effect_name"]


def rollout(env, seed: int, actions: int) -> list:
    obs, _ = env.reset(seed=seed)
    seen = [int(obs["state"])]
    rng = np.random.default_rng(seed)
    for _ in range(actions):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
        seen.append((int(obs["state"]), info["effect"], reward))
        if terminated or truncated:
            obs, _ = env.reset()
            seen.append(int(obs["state"]))
    return seen


@pytest.mark.parametrize("env_id, kwargs", WORLDS)
def test_a_seed_reproduces_every_step(env_id, kwargs):
    env = gymnasium.make(env_id, **kwargs)
    first = rollout(env, seed=11, actions=300)
    assert rollout(env, seed=11, actions=300) == first
    assert rollout(gymnasium.make(env_id, **kwargs), seed=11, actions=300) == first
    assert rollout(env, seed=12, actions=300) != first


@pytest.mark.parametrize("env_id, kwargs", WORLDS)
def test_observation_holds_the_states_features_and_attributes(env_id, kwargs):
    env = gymnasium.make(env_id, **kwargs)
    world = env.unwrapped.world
    obs, _ = env.reset(seed=3)
    for _ in range(50):
        state = int(obs["state"])
        assert np.flatnonzero(obs["features"]).tolist() == world.features(state).tolist()
        if "position" in obs:
            assert obs["position"].tolist() == [state % world.width, state // world.width]
        else:
            assert tuple(obs["attributes"]) == world.attributes(state)
        obs, _, terminated, truncated, info = env.step(env.action_space.sample())
        # The effect in info is the one that leads from the last state to this one.
        assert world.effect_between(state, int(obs["state"])) == info["effect"]
        if terminated or truncated:
            obs, _ = env.reset()


def test_the_grid_task_is_the_suites():
    # Task 0 is the 30×30 task of the paper's Fig. 3; its features are 10 relevant + irrelevant.
    env = gymnasium.make("tes/GridTask-v0", task=0, irrelevant=200)
    world = env.unwrapped.world
    assert (world.width, world.height, world.n_features) == (30, 30, 210)
    assert world.feature_name(0) == "bias" and world.feature_name(9) == "wall=W"


def test_the_arena_ends_an_episode_when_stuck():
    # The paper's rule: 4 actions in a row that leave the state unchanged end the episode.
    env = gymnasium.make("tes/Arena-v0", arena=1)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=1)
    states, stuck = [int(obs["state"])], 0
    for _ in range(5000):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(3)))
        states.append(int(obs["state"]))
        assert info["stuck"] == (len(set(states[-5:])) == 1 and len(states) >= 5)
        if terminated:
            assert reward in (-1.0, 2.0)
        if terminated or truncated:
            stuck += info["stuck"]
            obs, _ = env.reset()
            states = [int(obs["state"])]
    assert stuck > 0


@pytest.mark.parametrize("env_id, kwargs", WORLDS[:1] + WORLDS[2:3])
def test_renders_the_world_with_the_agent(env_id, kwargs):
    env = gymnasium.make(env_id, render_mode="rgb_array", **kwargs)
    env.reset(seed=4)
    before = env.render()
    assert before.dtype == np.uint8 and before.ndim == 3 and before.shape[2] == 3
    for _ in range(20):
        _, _, terminated, truncated, _ = env.step(0)
        if terminated or truncated:
            break
        after = env.render()
        if not np.array_equal(after, before):
            return
    pytest.fail("the picture never changed as the agent moved")


def test_bad_settings_and_actions_are_refused():
    with pytest.raises(ValueError, match="task must be 0 to 14"):
        gymnasium.make("tes/GridTask-v0", task=15)
    with pytest.raises(ValueError, match="arena"):
        gymnasium.make("tes/Arena-v0", arena=4)
    env = gymnasium.make("tes/GridTask-v0", task=1, irrelevant=0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.unwrapped.step(4)
    with pytest.raises(ValueError, match="out of range"):
        env.unwrapped.world.features(10**6)


@pytest.mark.parametrize(
    "env_id, kwargs",
    [("tes/GridTask-v0", {"task": 1, "irrelevant": 5}), ("tes/Arena-v0", {"arena": 1})],
)
def test_a_step_after_the_end_is_an_error_in_both_worlds(env_id, kwargs):
    env = gymnasium.make(env_id, **kwargs).unwrapped  # beneath Gymnasium's own wrappers
    env.reset(seed=4)
    rng = np.random.default_rng(4)
    for _ in range(10_000):
        _, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        if terminated or truncated:
            break
    else:
        pytest.fail("no episode ended")
    with pytest.raises(gymnasium.error.ResetNeeded, match="reset"):
        env.step(0)
    env.reset()
    env.step(0)


@pytest.mark.parametrize("env_id", ["tes/GridTask-v0", "tes/Arena-v0"])
def test_reset_options_are_refused_not_ignored(env_id):
    env = gymnasium.make(env_id)
    with pytest.raises(ValueError, match="no options"):
        env.reset(seed=0, options={"task": 3})
    env.reset(seed=0, options={})
    env.reset(seed=0, options=None)


def test_bad_seeds_are_refused_by_name():
    with pytest.raises(ValueError, match="world_seed"):
        gymnasium.make("tes/GridTask-v0", world_seed=-1)
    structure = tes.adapters.frozen_lake(gymnasium.make("FrozenLake-v1"))
    for make in (tes.agents.LoreRL, tes.agents.FEpsG, tes.agents.TES):
        with pytest.raises(ValueError, match="seed must be a whole number"):
            make(structure, seed=-1)


def test_the_native_exception_is_tes_library_file_error():
    assert tes.LibraryFileError.__module__ == "tes"
    assert repr(tes.LibraryFileError("x")) == "LibraryFileError('x')"
    assert f"{tes.LibraryFileError.__module__}.{tes.LibraryFileError.__name__}" == (
        "tes.LibraryFileError"
    )
