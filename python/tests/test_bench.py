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
