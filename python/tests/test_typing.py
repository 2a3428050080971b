"""The native module's stubs say what it is (mypy's stubtest), and the documented calls type
check."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("mypy")


def test_stubtest_passes_on_the_native_module():
    out = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "tes._tes"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stdout + out.stderr


def test_the_documented_calls_type_check(tmp_path):
    program = tmp_path / "documented.py"
    program.write_text(
        textwrap.dedent(
            """
            import numpy as np
            import tes
            from tes.evaluate import success_probability

            P = {0: {0: [(1.0, 0, 1.0, True)]}}
            agent = tes.agents.FEpsG(tes.adapters.frozen_lake(object()))
            p: float = success_probability(P, agent.greedy_policy(), np.ones(1), 10)
            model = tes.Mdagl(lam="auto", alpha=0.3)
            proba: np.ndarray = model.predict_proba(np.zeros((1, 4)))
            """
        )
    )
    out = subprocess.run(
        [sys.executable, "-m", "mypy", "--ignore-missing-imports", str(program)],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stdout + out.stderr
