"""``python -m tes.bench``: is Python the bottleneck? Two measurements in one run.
(``python -m tes.bench --rl`` instead compares loreRL, fEpsG and Q-learning on Gymnasium's
toy texts: see ``tes._rl_bench``.)

1. **Environment steps per second** through ``gymnasium.make`` (with its default wrappers),
   random actions: our ``tes/GridTask-v0`` (task 0, 30×30, 210 features) and
   ``tes/Arena-v0`` against Gymnasium's own ``FrozenLake-v1`` (8×8), the same loop for each.
2. **mDAGL updates per second** on a synthetic stream of 312 binary features (15 on per row)
   and 20 classes: ``tes.Mdagl.partial_fit`` on the whole stream as one SciPy CSR batch and
   row by row, against ``tes fit`` on the same rows (written to a CSV).

Each figure is the median of ``--repeats`` timings. ``--json`` prints them as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium
import numpy as np

import tes

FEATURES, CLASSES, ON_PER_ROW, RELEVANT = 312, 20, 15, 10


def steps_per_second(env_id: str, kwargs: dict, steps: int, seed: int) -> float:
    """Random-action steps per second of ``gymnasium.make(env_id, **kwargs)``."""
    env = gymnasium.make(env_id, **kwargs)
    rng = np.random.default_rng(seed)
    actions = rng.integers(env.action_space.n, size=steps)
    env.reset(seed=seed)
    start = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(int(a))
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - start)


def stream(rows: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``rows`` rows of 15 distinct features out of 312 (sorted) and labels drawn from a
    softmax over the first 10 features' weights."""
    rng = np.random.default_rng(seed)
    weights = rng.normal(0, 2.0, size=(RELEVANT, CLASSES))
    on = np.sort(np.argsort(rng.random((rows, FEATURES)), axis=1)[:, :ON_PER_ROW], axis=1)
    logits = np.zeros((rows, CLASSES))
    for k in range(ON_PER_ROW):
        column = on[:, k]
        relevant = column < RELEVANT
        logits[relevant] += weights[column[relevant]]
    p = np.exp(logits - logits.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    labels = (p.cumsum(axis=1) > rng.random((rows, 1))).argmax(axis=1)
    return on.astype(np.uint32), labels.astype(np.int64)


def csr(on: np.ndarray):
    from scipy import sparse

    rows = on.shape[0]
    indptr = np.arange(0, rows * ON_PER_ROW + 1, ON_PER_ROW)
    data = np.ones(rows * ON_PER_ROW)
    return sparse.csr_matrix((data, on.reshape(-1), indptr), shape=(rows, FEATURES))


def python_updates_per_second(on: np.ndarray, labels: np.ndarray, batch: int) -> float:
    """``Mdagl.partial_fit`` updates per second, fed ``batch`` rows per call."""
    X = csr(on)
    # The paper's fixed setting, as `tes fit` without `auto`: one model, not a race.
    model = tes.Mdagl(lam=0.05, alpha=1.5, intercept=False)
    start = time.perf_counter()
    for lo in range(0, len(labels), batch):
        model.partial_fit(X[lo : lo + batch], labels[lo : lo + batch], classes=range(CLASSES))
    return len(labels) / (time.perf_counter() - start)


def write_csv(path: Path, on: np.ndarray, labels: np.ndarray) -> None:
    """The rows in `tes fit`'s format: the label, then 312 0/1 columns."""
    dense = np.zeros((len(labels), FEATURES), dtype=np.int8)
    np.put_along_axis(dense, on.astype(np.int64), 1, axis=1)
    table = np.column_stack([labels, dense])
    np.savetxt(path, table, fmt="%d", delimiter=",")


def tes_fit_updates_per_second(binary: str, path: Path) -> float:
    """``tes fit --json``'s own updates per second on the CSV."""
    out = subprocess.run(
        [binary, "fit", str(path), "--json"], capture_output=True, text=True, check=True
    )
    return float(json.loads(out.stdout)["updates_per_sec"])


def tes_candidates(explicit: str | None) -> list[tuple[str, str | None]]:
    """Where the `tes` binary is looked for, in order: --tes, $TES_BIN, a release then a debug
    build in the repository this package was installed from (or is run in), then PATH."""
    roots = [Path.cwd(), Path(__file__).resolve().parents[2]]
    candidates: list[tuple[str, str | None]] = [
        ("--tes", explicit),
        ("$TES_BIN", os.environ.get("TES_BIN")),
    ]
    for root in dict.fromkeys(roots):
        for profile in ("release", "debug"):
            path = root / "target" / profile / "tes"
            candidates.append((str(path), str(path)))
    candidates.append(("tes on PATH", shutil.which("tes")))
    return candidates


def find_tes(explicit: str | None) -> str | None:
    """The first `tes` binary of :func:`tes_candidates` that exists and runs."""
    for _, candidate in tes_candidates(explicit):
        if candidate and Path(candidate).is_file() and os.access(candidate, os.X_OK):
            return candidate
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tes.bench", description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20_000, help="environment steps per timing")
    parser.add_argument("--rows", type=int, default=50_000, help="rows of the mDAGL stream")
    parser.add_argument("--repeats", type=int, default=5, help="timings per figure (median)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tes", help="the tes binary (default: $TES_BIN or target/release/tes)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument(
        "--rl", action="store_true",
        help="instead: loreRL, fEpsG and Q-learning on the toy texts (tes._rl_bench)",
    )
    parser.add_argument("--seeds", type=int, default=3, help="--rl: seeds per method")
    parser.add_argument(
        "--scale", type=float, default=1.0, help="--rl: a share of each episode budget"
    )
    args = parser.parse_args(argv)
    if args.rl:
        from tes import _rl_bench

        return _rl_bench.main(args.seeds, args.json, args.scale)

    def median(measure) -> float:
        return statistics.median(measure(r) for r in range(args.repeats))

    envs = {
        "tes/GridTask-v0": ("tes/GridTask-v0", {"task": 0, "irrelevant": 200}),
        "tes/Arena-v0": ("tes/Arena-v0", {"arena": 3}),
        "FrozenLake-v1": ("FrozenLake-v1", {"map_name": "8x8"}),
    }
    results: dict = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "steps_per_sec": {},
        "updates_per_sec": {},
    }
    for name, (env_id, kwargs) in envs.items():
        results["steps_per_sec"][name] = median(
            lambda r: steps_per_second(env_id, kwargs, args.steps, args.seed + r)
        )
        print(f"{name}: {results['steps_per_sec'][name]:,.0f} steps/s", file=sys.stderr)

    on, labels = stream(args.rows, args.seed)
    updates = results["updates_per_sec"]
    updates["tes.Mdagl, one batch"] = median(
        lambda r: python_updates_per_second(on, labels, len(labels))
    )
    updates["tes.Mdagl, row by row"] = median(
        lambda r: python_updates_per_second(on[:10_000], labels[:10_000], 1)
    )
    binary = find_tes(args.tes)
    if binary is None:
        looked = ", ".join(where for where, _ in tes_candidates(args.tes))
        print(
            f"tes fit skipped: no tes binary (looked at {looked}); build one with "
            "`cargo build --release -p tes` in the repository, or pass --tes PATH",
            file=sys.stderr,
        )
        results["tes_binary"] = None
    else:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "stream.csv"
            write_csv(path, on, labels)
            updates["tes fit"] = median(lambda r: tes_fit_updates_per_second(binary, path))
        results["tes_binary"] = binary
    for name, value in updates.items():
        print(f"{name}: {value:,.0f} updates/s", file=sys.stderr)
    if args.json:
        print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
