"""tes.Mdagl against `tes fit` on the same CSV, and its errors."""

from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import tes
from conftest import tes_binary

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "data" / "fit-demo.csv"


def demo() -> tuple[np.ndarray, np.ndarray]:
    rows = np.loadtxt(DEMO, delimiter=",", dtype=np.float64)
    return rows[:, 1:], rows[:, 0].astype(np.int64)


def prequential(model: tes.Mdagl, X, y) -> float:
    """Row by row: predict, then learn; the mean of -ln P(label)."""
    loss = 0.0
    for r in range(X.shape[0]):
        row = X[r : r + 1]
        loss -= np.log(model.predict_proba(row)[0, y[r]])
        model.partial_fit(row, y[r : r + 1])
    return loss / X.shape[0]


@pytest.fixture(scope="module")
def reference() -> dict:
    out = subprocess.run(
        [tes_binary(), "fit", str(DEMO), "--json"], check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout)


def test_dense_rows_match_tes_fit(reference):
    X, y = demo()
    model = tes.Mdagl(X.shape[1], int(y.max()) + 1)
    assert prequential(model, X, y) == pytest.approx(reference["mean_logloss"], abs=1e-9)
    assert model.selected_.tolist() == reference["selected"]
    assert model.n_updates_ == reference["n"]


def test_sparse_rows_match_tes_fit(reference):
    sparse = pytest.importorskip("scipy.sparse")
    X, y = demo()
    model = tes.Mdagl(X.shape[1], int(y.max()) + 1)
    csr = sparse.csr_matrix(X)
    loss = 0.0
    for r in range(X.shape[0]):
        loss -= np.log(model.predict_proba(csr[r])[0, y[r]])
        model.partial_fit(csr[r], y[r : r + 1])
    assert loss / X.shape[0] == pytest.approx(reference["mean_logloss"], abs=1e-9)
    assert model.selected_.tolist() == reference["selected"]


def test_a_batch_learns_as_its_rows_do(reference):
    X, y = demo()
    model = tes.Mdagl(X.shape[1], int(y.max()) + 1)
    model.partial_fit(X, y)
    assert model.log_loss_sum_ / len(y) == pytest.approx(reference["mean_logloss"], abs=1e-9)
    assert model.selected_.tolist() == reference["selected"]
    coef = model.coef_
    assert coef.shape == (5, X.shape[1])
    kept = np.flatnonzero(np.abs(coef).sum(axis=0) > 0)
    assert kept.tolist() == reference["selected"]
    p = model.predict_proba(X[:10])
    assert p.shape == (10, 5)
    np.testing.assert_allclose(p.sum(axis=1), 1.0, rtol=1e-12)
    assert model.predict(X[:10]).tolist() == np.argmax(p, axis=1).tolist()


@pytest.mark.parametrize(
    "X, y, words",
    [
        (np.zeros((2, 3)), [0, 1], ["3 columns", "4 features"]),
        (np.array([[0.0, np.nan, 0.0, 1.0]]), [0], ["row 0", "NaN"]),
        (np.array([[0.0, 1.0, 0.0, 1.0]]), [7], ["row 0", "label 7", "3 classes"]),
        (np.array([[0.0, 1.0, 0.0, 1.0]]), [-1], ["label -1"]),
        (np.zeros((2, 4)), [0], ["2 rows"]),
        (np.zeros(4), [0], ["2-D"]),
    ],
)
def test_bad_input_names_the_problem_and_changes_nothing(X, y, words):
    model = tes.Mdagl(4, 3)
    model.partial_fit(np.eye(4)[:2], [0, 1])
    before = model.coef_.copy()
    with pytest.raises(ValueError) as err:
        model.partial_fit(X, y)
    for w in words:
        assert w in str(err.value), str(err.value)
    assert model.n_updates_ == 2
    np.testing.assert_array_equal(model.coef_, before)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="class"):
        tes.Mdagl(4, 1)
    with pytest.raises(ValueError, match="λ|lambda"):
        tes.Mdagl(4, 3, lam=float("nan"))
    with pytest.raises(ValueError, match="α|alpha"):
        tes.Mdagl(4, 3, alpha=0.0)


def test_sparse_path_takes_only_ones():
    sparse = pytest.importorskip("scipy.sparse")
    model = tes.Mdagl(4, 2)
    with pytest.raises(ValueError, match="row 1.*0/1"):
        model.partial_fit(sparse.csr_matrix(np.array([[1.0, 0, 0, 0], [0, 2.0, 0, 0]])), [0, 1])
    # Unsorted indices within a row are sorted, not refused.
    csr = sparse.csr_matrix((np.ones(2), np.array([3, 1]), np.array([0, 2])), shape=(1, 4))
    model.partial_fit(csr, [1])
    assert model.n_updates_ == 1


def test_learning_releases_the_gil():
    """A Python thread keeps running in the middle of a long batch: with the GIL held by the
    native call it could not run at all there."""
    rng = np.random.default_rng(7)
    X = (rng.random((300_000, 50)) < 0.1).astype(np.float64)
    y = rng.integers(0, 4, size=len(X))
    model = tes.Mdagl(50, 4)
    stamps: list[float] = []
    done = threading.Event()

    def count():
        i = 0
        while not done.is_set():
            i += 1
            if i % 1000 == 0:
                stamps.append(time.perf_counter())

    counter = threading.Thread(target=count)
    counter.start()
    try:
        start = time.perf_counter()
        model.partial_fit(X, y)
        end = time.perf_counter()
    finally:
        done.set()
        counter.join()
    assert model.n_updates_ == len(X)
    margin = (end - start) / 5
    middle = [t for t in stamps if start + margin < t < end - margin]
    assert len(middle) > 10, (len(middle), len(stamps), end - start)


def test_the_package_docstring_example_runs():
    import doctest

    assert doctest.testmod(tes).failed == 0


def test_an_intercept_only_model_learns_rows_of_no_features():
    model = tes.Mdagl(0, 2, intercept=True)
    model.partial_fit(np.zeros((3, 0)), [1, 1, 0])
    assert model.n_updates_ == 3
    assert model.predict_proba(np.zeros((2, 0))).shape == (2, 2)
    assert model.intercept_.shape == (2,)
