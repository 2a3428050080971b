"""``tes.Mdagl``: the native model with scikit-learn's habits (``partial_fit``,
``predict_proba``, ``predict``, fitted attributes ending in ``_``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from tes import _tes


def _is_sparse(x: Any) -> bool:
    """Whether ``x`` is a SciPy sparse matrix or array (without importing SciPy)."""
    return hasattr(x, "tocsr") and hasattr(x, "nnz")


def _csr_ones(x: Any) -> tuple[np.ndarray, np.ndarray]:
    """Row pointers (int64) and strictly increasing column indices (uint32) of a sparse
    matrix whose stored entries are all 1."""
    csr = x.tocsr()
    if not csr.has_canonical_format:
        # Sorted, duplicate-free rows are what the native side takes; tidy a copy, never
        # the caller's matrix.
        csr = csr.copy()
        csr.sum_duplicates()
    data = np.asarray(csr.data)
    if data.size and not np.all(data == 1):
        bad = int(np.flatnonzero(data != 1)[0])
        row = int(np.searchsorted(csr.indptr, bad, side="right") - 1)
        raise ValueError(
            f"row {row}: the sparse path takes 0/1 features, found {data[bad]!r}; "
            "pass a dense array for real values"
        )
    return (
        np.ascontiguousarray(csr.indptr, dtype=np.int64),
        np.ascontiguousarray(csr.indices, dtype=np.uint32),
    )


def _dense(x: Any) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"X must be 2-D (n_rows, n_features), got shape {arr.shape}")
    return np.ascontiguousarray(arr)


def _labels(y: Any) -> np.ndarray:
    arr = np.asarray(y)
    if arr.ndim != 1:
        raise ValueError(f"y must be 1-D (one label per row), got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.round(arr)):
            raise ValueError("y must hold integer class labels")
    return np.ascontiguousarray(arr, dtype=np.int64)


class Mdagl:
    """Online sparse multinomial logistic regression with group lasso (mDAGL), learned by
    dual averaging: it keeps the few features that predict the class out of many.

    Parameters
    ----------
    n_features, n_classes:
        The input width ``d`` and the class count ``K`` (at least 2).
    lam:
        Group-lasso strength λ ≥ 0 (the paper's 0.05); larger switches more features off,
        0 keeps them all.
    alpha:
        Step-size scale α > 0 of ``β_t = α√t`` (the paper's 1.5); smaller learns faster.
    intercept:
        Add an always-on, unregularised intercept column.

    Rows are learned in order, one at a time, exactly as ``tes fit`` learns a CSV: calling
    ``predict_proba`` then ``partial_fit`` row by row gives its prequential log-loss. A batch
    is checked whole before any row is learned, so a bad row changes nothing. The learning
    runs with the GIL released.
    """

    def __init__(
        self,
        n_features: int,
        n_classes: int,
        lam: float = 0.05,
        alpha: float = 1.5,
        intercept: bool = False,
    ) -> None:
        self._model = _tes.Mdagl(n_features, n_classes, lam, alpha, intercept)
        self.log_loss_sum_ = 0.0

    def partial_fit(self, X: Any, y: Any) -> "Mdagl":
        """Learns the rows of ``X`` (a 2-D float array, or a SciPy CSR matrix of 0/1
        features, which takes the sparse path) with integer labels ``y``, in order."""
        labels = _labels(y)
        if _is_sparse(X):
            indptr, indices = _csr_ones(X)
            loss = self._model.partial_fit_sparse(indptr, indices, labels)
        else:
            loss = self._model.partial_fit_dense(_dense(X), labels)
        self.log_loss_sum_ += loss
        return self

    def predict_proba(self, X: Any) -> np.ndarray:
        """``P(class | x)`` for every row: an ``(n_rows, n_classes)`` array."""
        if _is_sparse(X):
            return self._model.predict_proba_sparse(*_csr_ones(X))
        return self._model.predict_proba_dense(_dense(X))

    def predict(self, X: Any) -> np.ndarray:
        """The most probable class of every row (the lowest index on ties)."""
        return np.argmax(self.predict_proba(X), axis=1)

    @property
    def selected_(self) -> np.ndarray:
        """The indices of the feature columns the model keeps (non-zero weights)."""
        return np.asarray(self._model.selected(), dtype=np.int64)

    @property
    def coef_(self) -> np.ndarray:
        """The weights, ``(n_classes, n_features)``; zero columns are switched-off features."""
        return self._model.coef()

    @property
    def intercept_(self) -> np.ndarray:
        """The intercept's weight per class (zeros without an intercept)."""
        return self._model.intercept_weights()

    @property
    def n_updates_(self) -> int:
        """Rows learned so far."""
        return self._model.n_updates

    @property
    def n_features_in_(self) -> int:
        """The feature count ``d``."""
        return self._model.n_features

    @property
    def classes_(self) -> np.ndarray:
        """The class labels, ``0 … n_classes − 1``."""
        return np.arange(self._model.n_classes)

    def __repr__(self) -> str:
        return repr(self._model)
