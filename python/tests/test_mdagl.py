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


def paper(n_classes: int) -> tes.Mdagl:
    """The paper's fixed setting (as `tes fit` without `auto`), ready for every class."""
    model = tes.Mdagl(lam=0.05, alpha=1.5, intercept=False)
    return model


def prequential(model: tes.Mdagl, X, y) -> float:
    """Row by row: predict, then learn; the mean of -ln P(label). The first row is learned
    with every class named, so the model exists to predict the second."""
    classes = np.arange(int(y.max()) + 1)
    model.partial_fit(X[:1], y[:1], classes=classes)
    loss = np.log(len(classes))  # the first row's prediction: no model yet, uniform
    for r in range(1, X.shape[0]):
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
    model = paper(int(y.max()) + 1)
    assert prequential(model, X, y) == pytest.approx(reference["mean_logloss"], abs=1e-9)
    assert model.selected_.tolist() == reference["selected"]
    assert model.n_updates_ == reference["n"]


def test_sparse_rows_match_tes_fit(reference):
    sparse = pytest.importorskip("scipy.sparse")
    X, y = demo()
    model = paper(int(y.max()) + 1)
    csr = sparse.csr_matrix(X)
    model.partial_fit(csr[0], y[:1], classes=np.arange(int(y.max()) + 1))
    loss = np.log(int(y.max()) + 1)
    for r in range(1, X.shape[0]):
        loss -= np.log(model.predict_proba(csr[r])[0, y[r]])
        model.partial_fit(csr[r], y[r : r + 1])
    assert loss / X.shape[0] == pytest.approx(reference["mean_logloss"], abs=1e-9)
    assert model.selected_.tolist() == reference["selected"]


def test_a_batch_learns_as_its_rows_do(reference):
    X, y = demo()
    model = paper(int(y.max()) + 1)
    model.partial_fit(X, y, classes=np.arange(int(y.max()) + 1))
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


def as_dense(X):
    return X


def as_sparse(X):
    sparse = pytest.importorskip("scipy.sparse")
    return sparse.csr_matrix(np.atleast_2d(X)) if np.ndim(X) == 2 else X


def as_sparse_reals(X):
    """A sparse matrix of real values (the dense path behind a sparse input)."""
    sparse = pytest.importorskip("scipy.sparse")
    X = np.asarray(X, dtype=float) * 2.0
    return sparse.csr_matrix(X) if X.ndim == 2 else X


@pytest.mark.parametrize("form", [as_dense, as_sparse, as_sparse_reals])
@pytest.mark.parametrize(
    "X, y, words",
    [
        (np.zeros((2, 3)), [0, 1], ["3 features", "4 features"]),
        (np.zeros((2, 5)), [0, 1], ["5 features", "4 features"]),
        (np.array([[0.0, 1.0, 0.0, 1.0]]), [7], ["row 0", "label 7"]),
        (np.array([[0.0, 1.0, 0.0, 1.0]]), [-1], ["label -1"]),
        (np.zeros((2, 4)), [0], ["inconsistent numbers of samples"]),
        (np.zeros(4), [0], ["2D array"]),
    ],
)
def test_bad_input_is_refused_alike_on_both_paths_and_changes_nothing(form, X, y, words):
    """One rule for a dense array, a sparse matrix of ones and one of real values: the same
    refusal, and the model as it was. A sparse matrix too narrow or too wide is refused even
    when every stored index would fit."""
    model = tes.Mdagl(lam=0.05, alpha=1.5)
    model.partial_fit(np.eye(4)[:2], [0, 1], classes=[0, 1, 2])
    before = model.coef_.copy()
    with pytest.raises(ValueError) as err:
        model.partial_fit(form(X), y)
    for w in words:
        assert w in str(err.value), str(err.value)
    if np.ndim(X) == 2 and np.shape(X)[1] != 4:
        with pytest.raises(ValueError, match="features"):
            model.predict_proba(form(X))
    assert model.n_updates_ == 2
    np.testing.assert_array_equal(model.coef_, before)


def test_the_native_model_refuses_a_wrong_width_on_both_paths():
    """Beneath the estimator: a CSR matrix's width is checked as a dense array's is, not only
    its stored indices."""
    native = tes._tes.Mdagl(4, 2, 0.05, 1.5, False)
    indptr, indices = np.array([0, 1], dtype=np.int64), np.array([0], dtype=np.uint32)
    y = np.array([1], dtype=np.int64)
    for width in (3, 5):
        with pytest.raises(ValueError, match=f"X has {width} features, but Mdagl is expecting 4 features as input"):
            native.partial_fit_sparse(indptr, indices, width, y)
        with pytest.raises(ValueError, match=f"X has {width} features, but Mdagl is expecting 4 features as input"):
            native.predict_proba_sparse(indptr, indices, width)
        with pytest.raises(ValueError, match=f"X has {width} features, but Mdagl is expecting 4 features as input"):
            native.partial_fit_dense(np.zeros((1, width)), y)
    native.partial_fit_sparse(indptr, indices, 4, y)
    assert native.n_updates == 1


def test_nan_and_infinity_are_refused_naming_the_row():
    model = tes.Mdagl(lam=0.05, alpha=1.5)
    model.partial_fit(np.eye(4)[:2], [0, 1], classes=[0, 1])
    for bad, word in ((np.nan, "NaN"), (np.inf, "inf")):
        X = np.eye(4)[:3].copy()
        X[2, 1] = bad
        with pytest.raises(ValueError, match=f"row 2: feature 1 is not finite.*{word}"):
            model.partial_fit(X, [0, 1, 0])
    assert model.n_updates_ == 2


def test_a_sparse_matrix_of_real_values_learns_as_its_dense_form():
    sparse = pytest.importorskip("scipy.sparse")
    rng = np.random.default_rng(2)
    X = (rng.random((40, 6)) < 0.3) * rng.integers(1, 4, size=(40, 6)).astype(float)
    y = rng.integers(0, 3, size=40)
    dense = tes.Mdagl(lam=0.01, alpha=0.3).partial_fit(X, y, classes=[0, 1, 2])
    other = tes.Mdagl(lam=0.01, alpha=0.3).partial_fit(sparse.csr_matrix(X), y, classes=[0, 1, 2])
    np.testing.assert_array_equal(dense.coef_, other.coef_)
    np.testing.assert_array_equal(dense.predict_proba(X), other.predict_proba(sparse.csr_matrix(X)))


def test_sparse_ones_take_the_sparse_path_as_their_dense_form():
    sparse = pytest.importorskip("scipy.sparse")
    # Unsorted indices within a row are sorted, not refused.
    csr = sparse.csr_matrix((np.ones(2), np.array([3, 1]), np.array([0, 2])), shape=(1, 4))
    a = tes.Mdagl(lam=0.05, alpha=1.5).partial_fit(csr, [1], classes=[0, 1])
    b = tes.Mdagl(lam=0.05, alpha=1.5).partial_fit(csr.toarray(), [1], classes=[0, 1])
    np.testing.assert_array_equal(a.coef_, b.coef_)
    assert a.n_updates_ == 1


def test_learning_releases_the_gil():
    """A Python thread keeps running in the middle of a long batch: with the GIL held by the
    native call it could not run at all there."""
    rng = np.random.default_rng(7)
    X = (rng.random((300_000, 50)) < 0.1).astype(np.float64)
    y = rng.integers(0, 4, size=len(X))
    model = tes.Mdagl(lam=0.05, alpha=1.5)
    model.partial_fit(X[:1], y[:1], classes=[0, 1, 2, 3])
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
    assert model.n_updates_ == len(X) + 1
    margin = (end - start) / 5
    middle = [t for t in stamps if start + margin < t < end - margin]
    assert len(middle) > 10, (len(middle), len(stamps), end - start)


def test_the_package_docstring_example_runs():
    import doctest

    assert doctest.testmod(tes).failed == 0


def test_an_intercept_only_native_model_learns_rows_of_no_features():
    # scikit-learn's estimators take at least one feature; the native model takes none.
    model = tes._tes.Mdagl(0, 2, 0.05, 1.5, True)
    model.partial_fit_dense(np.zeros((3, 0)), np.array([1, 1, 0], dtype=np.int64))
    assert model.n_updates == 3
    assert model.predict_proba_dense(np.zeros((2, 0))).shape == (2, 2)
    assert model.intercept_weights().shape == (2,)


def test_lam_auto_is_the_race_of_tes_fit(reference_auto):
    """lam="auto", alpha="auto" is `tes fit --lambda auto --alpha auto`: the same race, the
    same prequential log-loss and the same chosen setting."""
    X, y = demo()
    model = tes.Mdagl(intercept=False)
    model.partial_fit(X, y, classes=np.arange(int(y.max()) + 1))
    assert model.log_loss_sum_ / len(y) == pytest.approx(reference_auto["mean_logloss"], abs=1e-9)
    assert (model.lam_, model.alpha_) == (reference_auto["lambda"], reference_auto["alpha"])
    assert model.selected_.tolist() == reference_auto["selected"]
    assert len(model.standings_) == 15


@pytest.fixture(scope="module")
def reference_auto() -> dict:
    out = subprocess.run(
        [tes_binary(), "fit", str(DEMO), "--json", "--lambda", "auto", "--alpha", "auto"],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout)
