"""`python -m tes.bench` runs end to end on a small budget and reports every figure."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from conftest import tes_binary


def test_the_bench_reports_every_figure():
    out = subprocess.run(
        [sys.executable, "-m", "tes.bench", "--steps", "300", "--rows", "3000",
         "--repeats", "1", "--json", "--tes", tes_binary()],
        capture_output=True, text=True, check=True, env={**os.environ},
    )
    figures = json.loads(out.stdout)
    assert set(figures["steps_per_sec"]) == {"tes/GridTask-v0", "tes/Arena-v0", "FrozenLake-v1"}
    assert set(figures["updates_per_sec"]) == {
        "tes.Mdagl, one batch", "tes.Mdagl, row by row", "tes fit"
    }
    assert all(v > 0 for group in ("steps_per_sec", "updates_per_sec") for v in figures[group].values())


def test_the_rl_bench_reports_every_method_on_every_toy_text():
    """`python -m tes.bench --rl` on a sliver of its budgets, one seed: every method on every
    toy text, Stable-Baselines3's DQN too where it imports, and where it does not, why."""
    from tes._rl_bench import DQN, dqn_absent

    out = subprocess.run(
        [sys.executable, "-m", "tes.bench", "--rl", "--seeds", "1", "--scale", "0.005", "--json"],
        capture_output=True, text=True, check=True,
    )
    figures = json.loads(out.stdout)
    runs = {(r["task"], r["method"]) for r in figures["results"]}
    tasks = {"FrozenLake 4x4", "FrozenLake 8x8", "CliffWalking", "Taxi"}
    methods = {"loreRL", "fEpsG", "Q-learning"}
    absent = dqn_absent()
    if absent:
        assert figures["absent"] == {DQN: absent} and absent in out.stderr
        assert "Stable-Baselines3 does not import" in absent
    else:
        methods.add(DQN)
    assert runs == {(t, m) for t in tasks for m in methods}
    for r in figures["results"]:
        assert 0 <= r["final_success"] <= r["optimum"] + 1e-9 <= 1 + 1e-9, r
        budget = figures["budgets"][r["task"]]
        assert r["episodes_to_90"] is None or 1 <= r["episodes_to_90"] <= budget, r


def test_the_dqn_row_sees_the_state_one_hot():
    """What the DQN row's network is given: each state as a one-hot vector, and every state's
    at once for judging its greedy policy."""
    import gymnasium
    import numpy as np

    from tes._rl_bench import OneHot

    env = OneHot(gymnasium.make("Taxi-v4"))
    obs, _ = env.reset(seed=3)
    state = int(env.unwrapped.s)
    assert obs.shape == (500,) and obs.dtype == np.float32
    assert obs[state] == 1.0 and obs.sum() == 1.0
    assert np.array_equal(env.all_states()[state], obs)
    assert env.observation_space.contains(env.step(0)[0])


def test_the_bench_says_where_it_looked_for_tes(tmp_path, monkeypatch):
    import pytest

    from tes.bench import find_tes

    monkeypatch.delenv("TES_BIN", raising=False)
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    monkeypatch.chdir(tmp_path)
    if find_tes(str(tmp_path / "absent")) is not None:
        pytest.skip("a tes binary is built beside this package: the bench finds it")
    out = subprocess.run(
        [sys.executable, "-m", "tes.bench", "--steps", "50", "--rows", "200", "--repeats", "1",
         "--tes", str(tmp_path / "absent")],
        capture_output=True, text=True, check=True, cwd=tmp_path,
        env={k: v for k, v in os.environ.items() if k != "TES_BIN"} | {"PATH": "/usr/bin:/bin"},
    )
    assert "tes fit skipped: no tes binary (looked at --tes, $TES_BIN" in out.stderr
    assert "target/debug/tes" in out.stderr and "cargo build --release -p tes" in out.stderr
