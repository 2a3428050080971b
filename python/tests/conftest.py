"""Shared helpers of the Python tests."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def tes_binary() -> str:
    """The `tes` executable: $TES_BIN, else one built in the repository, else on PATH."""
    candidates = [os.environ.get("TES_BIN")]
    candidates += [str(REPO / "target" / p / "tes") for p in ("release", "debug")]
    candidates.append(shutil.which("tes"))
    for c in candidates:
        if c and Path(c).is_file() and os.access(c, os.X_OK):
            return c
    pytest.fail("no tes executable: set TES_BIN or run `cargo build -p tes` first")
