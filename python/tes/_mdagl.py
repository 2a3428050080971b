"""``tes.Mdagl``: the native model as a scikit-learn classifier (``fit``, ``partial_fit``,
``predict_proba``, ``score``, ``get_params`` …), usable in ``clone``, ``Pipeline``,
``GridSearchCV`` and ``cross_val_score``."""

from __future__ import annotations

import copy
import numbers
import threading
from typing import Any

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils import check_random_state
from sklearn.utils.validation import _check_sample_weight, check_is_fitted, validate_data

from tes import _tes

# Rows handed to the native model per call when a sparse matrix of real values is learned
# through the dense path (bounds the dense copy).
_BLOCK = 4096


def _setting(value: Any, name: str, positive: bool) -> float | None:
    """``"auto"`` as ``None`` (the native race), else the number, checked."""
    if isinstance(value, str):
        if value == "auto":
            return None
        raise ValueError(f'{name} must be "auto" or a number, not {value!r}')
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        raise ValueError(f'{name} must be "auto" or a number, not {value!r}')
    value = float(value)
    if not np.isfinite(value) or value < 0 or (positive and value == 0):
        bound = "> 0" if positive else "≥ 0"
        raise ValueError(f"{name} must be finite and {bound}, not {value!r}")
    return value


def _plain(x: Any) -> bool:
    """Whether ``x`` needs no conversion: a C-contiguous 2-D float64 NumPy array, or a SciPy
    CSR matrix (scikit-learn's validation can then be skipped: the native model checks the
    width, the values and the labels' count by the same rules)."""
    if type(x) is np.ndarray:
        return x.ndim == 2 and x.dtype == np.float64 and x.flags.c_contiguous
    return _is_sparse(x) and getattr(x, "format", None) == "csr" and x.ndim == 2


def _is_sparse(x: Any) -> bool:
    """Whether ``x`` is a SciPy sparse matrix or array."""
    return hasattr(x, "tocsr") and hasattr(x, "nnz")


def _ones_only(csr: Any) -> bool:
    """Whether every stored entry of a canonical CSR matrix is 1 (mDAGL's sparse path)."""
    data = np.asarray(csr.data)
    return bool(np.all(data == 1))


def _canonical(x: Any) -> Any:
    """A CSR matrix with sorted, duplicate-free rows and no stored zeros (a copy when the
    caller's is not already so; the caller's matrix is never changed)."""
    csr = x.tocsr()
    if not csr.has_canonical_format or (csr.data.size and np.any(csr.data == 0)):
        csr = csr.copy()
        csr.sum_duplicates()
        csr.eliminate_zeros()
    return csr


def _csr_arrays(csr: Any) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.ascontiguousarray(csr.indptr, dtype=np.int64),
        np.ascontiguousarray(csr.indices, dtype=np.uint32),
    )


class Mdagl(ClassifierMixin, BaseEstimator):
    """Online sparse multinomial logistic regression with group lasso (mDAGL), learned by
    dual averaging: it keeps the few features that predict the class out of many.

    Parameters
    ----------
    lam:
        Group-lasso strength λ ≥ 0 — larger switches more features off, 0 keeps them all — or
        ``"auto"`` (the default): race the settings ``tes fit --lambda auto`` races (the
        paper's 0.05 and four smaller) on the rows' prequential log-loss, and use the leader.
    alpha:
        Step-size scale α > 0 of ``β_t = α√t`` — smaller learns faster — or ``"auto"`` (the
        default): race 1.5 (the paper's), 0.3 and 0.05 as ``tes fit --alpha auto`` does.
    intercept:
        Add an always-on, unregularised intercept column (default ``True``).
    max_iter:
        Passes ``fit`` makes over its rows (default 200); ``partial_fit`` makes one. With
        ``"auto"``, ``fit`` races on the first pass — the only one whose prequential losses
        are honest — and the leader alone makes the rest.
    shuffle:
        Whether ``fit`` visits the rows in a new random order each pass (``random_state``).
    random_state:
        Seed of ``fit``'s shuffling (an int, a ``numpy.random.RandomState`` or ``None``).

    Rows are learned in order, one update each, as ``tes fit`` learns a CSV: with fixed
    ``lam`` and ``alpha``, calling ``predict_proba`` then ``partial_fit`` row by row gives its
    prequential log-loss. A batch is checked whole before any row is learned, so a bad row
    changes nothing. One object may be shared between threads: the native model is held by
    one call at a time, readers see it before or after a batch, and learners take turns.
    """

    def __init__(
        self,
        lam: float | str = "auto",
        alpha: float | str = "auto",
        intercept: bool = True,
        max_iter: int = 200,
        shuffle: bool = True,
        random_state: Any = 0,
    ) -> None:
        self.lam = lam
        self.alpha = alpha
        self.intercept = intercept
        self.max_iter = max_iter
        self.shuffle = shuffle
        self.random_state = random_state

    # ---- learning -----------------------------------------------------------------------

    def fit(self, X: Any, y: Any, sample_weight: Any = None) -> "Mdagl":
        """Learns ``X``, ``y`` from scratch: ``max_iter`` passes over the rows, each row
        ``sample_weight`` times (whole numbers: mDAGL's updates are unweighted, so a weight of
        2 is the row learned twice in a row, 0 leaves it out)."""
        if not isinstance(self.max_iter, numbers.Integral) or self.max_iter < 1:
            raise ValueError(f"max_iter must be a whole number ≥ 1, not {self.max_iter!r}")
        X, y = validate_data(
            self, X, y, accept_sparse="csr", dtype=np.float64, ensure_all_finite=False
        )
        check_classification_targets(y)
        classes = np.unique(y)
        self._start(classes, X.shape[1])
        order = self._weighted_rows(len(y), sample_weight, X)
        labels = np.searchsorted(self.classes_, y)
        rng = check_random_state(self.random_state) if self.shuffle else None
        for iteration in range(int(self.max_iter)):
            rows = order[rng.permutation(len(order))] if rng is not None else order
            self._learn(X, labels, rows)
            if iteration == 0:
                # The race's losses are prequential, so honest, on the first pass only; later
                # passes revisit learned rows and would favour the least regularised setting.
                self._standings = self._model.standings()
                self._model.settle()
        self.n_iter_ = int(self.max_iter)
        return self

    def partial_fit(
        self, X: Any, y: Any, classes: Any = None, sample_weight: Any = None
    ) -> "Mdagl":
        """Learns the rows of ``X`` (a 2-D array, or a SciPy sparse matrix: one of 0/1
        features takes mDAGL's sparse path) with labels ``y``, in order, one pass. The first
        call needs ``classes`` (every label there will be), later ones may repeat it."""
        first = not hasattr(self, "classes_")
        if first and classes is None:
            raise ValueError("the first partial_fit needs classes= (every label there will be)")
        if not first and _plain(X):
            # Row by row, scikit-learn's validation would cost more than learning the row; the
            # native model checks the width, the values and the length by the same rules.
            self._same_classes(classes)
            y = np.asarray(y)
            if y.ndim != 1:
                raise ValueError(f"y must be 1-D (one label per row), got shape {y.shape}")
            if len(y) != X.shape[0]:
                raise ValueError(
                    "Found input variables with inconsistent numbers of samples: "
                    f"[{X.shape[0]}, {len(y)}]"
                )
            self._learn(X, self._encode(y), self._weighted_rows(len(y), sample_weight, X))
            self.n_iter_ = 1
            return self
        X, y = validate_data(
            self,
            X,
            y,
            accept_sparse="csr",
            dtype=np.float64,
            ensure_all_finite=False,
            reset=first,
        )
        check_classification_targets(y)
        if first:
            self._start(np.unique(np.asarray(classes)), X.shape[1])
        else:
            self._same_classes(classes)
        labels = self._encode(y)
        self._learn(X, labels, self._weighted_rows(len(y), sample_weight, X))
        self.n_iter_ = 1
        return self

    def _same_classes(self, classes: Any) -> None:
        """A later call's ``classes=``, if given, must be the first call's."""
        if classes is None:
            return
        given = np.unique(np.asarray(classes))
        if not np.array_equal(given, self.classes_):
            raise ValueError(
                f"classes={given.tolist()} differs from the first call's {self.classes_.tolist()}"
            )

    def _start(self, classes: np.ndarray, n_features: int) -> None:
        self._standings: list[tuple[float, float, float, int, bool]] = []
        if len(classes) < 2:
            raise ValueError(
                f"mDAGL needs at least 2 classes; the data has {len(classes)} class"
            )
        lam = _setting(self.lam, "lam", positive=False)
        alpha = _setting(self.alpha, "alpha", positive=True)
        model = _tes.Mdagl(n_features, len(classes), lam, alpha, bool(self.intercept))
        self.classes_ = classes
        self._model = model
        self._lock = threading.Lock()
        self.log_loss_sum_ = 0.0

    def _encode(self, y: np.ndarray) -> np.ndarray:
        """Labels as class indices; a label outside ``classes_`` is refused, naming its row."""
        index = np.searchsorted(self.classes_, y)
        index = np.clip(index, 0, len(self.classes_) - 1)
        unknown = np.flatnonzero(self.classes_[index] != y)
        if unknown.size:
            r = int(unknown[0])
            raise ValueError(
                f"row {r}: label {y[r].item()!r} is not one of classes_ {self.classes_.tolist()}"
            )
        return index

    @staticmethod
    def _weighted_rows(n: int, sample_weight: Any, X: Any) -> np.ndarray:
        """Each row's index, repeated as many times as its weight says."""
        if sample_weight is None:
            return np.arange(n)
        w = _check_sample_weight(sample_weight, X, dtype=np.float64)
        if np.any(w < 0) or np.any(w != np.round(w)):
            raise ValueError(
                "sample_weight must hold whole numbers ≥ 0: mDAGL's updates are unweighted, "
                "so a weight is how many times the row is learned"
            )
        return np.repeat(np.arange(n), w.astype(np.int64))

    def _learn(self, X: Any, labels: np.ndarray, rows: np.ndarray) -> None:
        """Learns ``X[rows]`` with ``labels[rows]``, in that order."""
        y = np.ascontiguousarray(labels[rows], dtype=np.int64)
        with self._lock:
            if _is_sparse(X):
                in_order = len(rows) == X.shape[0] and np.array_equal(rows, np.arange(len(rows)))
                csr = _canonical(X if in_order else X[rows])
                if _ones_only(csr):
                    loss = self._model.partial_fit_sparse(*_csr_arrays(csr), csr.shape[1], y)
                else:
                    loss = 0.0
                    for start in range(0, csr.shape[0], _BLOCK):
                        block = np.ascontiguousarray(csr[start : start + _BLOCK].toarray())
                        loss += self._model.partial_fit_dense(block, y[start : start + _BLOCK])
            else:
                loss = self._model.partial_fit_dense(np.ascontiguousarray(X[rows]), y)
            self.log_loss_sum_ += loss

    # ---- predicting ---------------------------------------------------------------------

    def predict_proba(self, X: Any) -> np.ndarray:
        """``P(class | x)`` for every row: ``(n_rows, n_classes)``, columns as ``classes_``."""
        check_is_fitted(self, "_model")
        if not _plain(X):
            X = validate_data(
                self, X, accept_sparse="csr", dtype=np.float64, ensure_all_finite=False,
                reset=False,
            )
        if _is_sparse(X):
            csr = _canonical(X)
            if _ones_only(csr):
                return self._model.predict_proba_sparse(*_csr_arrays(csr), csr.shape[1])
            blocks = [
                self._model.predict_proba_dense(
                    np.ascontiguousarray(csr[start : start + _BLOCK].toarray())
                )
                for start in range(0, csr.shape[0], _BLOCK)
            ]
            return np.vstack(blocks) if blocks else np.zeros((0, len(self.classes_)))
        return self._model.predict_proba_dense(np.ascontiguousarray(X))

    def predict_log_proba(self, X: Any) -> np.ndarray:
        """``ln P(class | x)`` for every row."""
        with np.errstate(divide="ignore"):
            return np.log(self.predict_proba(X))

    def predict(self, X: Any) -> np.ndarray:
        """The most probable class of every row (the first in ``classes_`` on ties)."""
        proba = self.predict_proba(X)
        return self.classes_[np.argmax(proba, axis=1)]

    # ---- what it learned ----------------------------------------------------------------

    @property
    def selected_(self) -> np.ndarray:
        """The indices of the feature columns the model keeps (non-zero weights)."""
        check_is_fitted(self, "_model")
        return np.asarray(self._model.selected(), dtype=np.int64)

    @property
    def coef_(self) -> np.ndarray:
        """The weights, ``(n_classes, n_features)``; zero columns are switched-off features."""
        check_is_fitted(self, "_model")
        return self._model.coef()

    @property
    def intercept_(self) -> np.ndarray:
        """The intercept's weight per class (zeros without an intercept)."""
        check_is_fitted(self, "_model")
        return self._model.intercept_weights()

    @property
    def n_updates_(self) -> int:
        """Rows learned so far (a row of weight 2 counts twice; ``fit`` counts every pass)."""
        check_is_fitted(self, "_model")
        return self._model.n_updates

    @property
    def lam_(self) -> float:
        """The λ in use: ``lam``, or the race's leader's."""
        check_is_fitted(self, "_model")
        return self._model.lam

    @property
    def alpha_(self) -> float:
        """The α in use: ``alpha``, or the race's leader's."""
        check_is_fitted(self, "_model")
        return self._model.alpha

    @property
    def standings_(self) -> list[tuple[float, float, float, int, bool]]:
        """With ``"auto"``: every raced setting, best first, as ``(lam, alpha,
        mean_log_loss, rows, racing)``; empty for fixed settings."""
        check_is_fitted(self, "_model")
        return self._model.standings() or list(getattr(self, "_standings", []))

    # ---- copies and pickles -------------------------------------------------------------

    def __getstate__(self) -> dict[str, Any]:
        # A copy: the base class may hand back the live __dict__ itself.
        state = dict(super().__getstate__())
        state.pop("_lock", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        super().__setstate__(state)
        if "_model" in state:
            self._lock = threading.Lock()

    def __copy__(self) -> "Mdagl":
        """A copy that learns on its own: the native model is copied, never shared."""
        new = type(self).__new__(type(self))
        new.__dict__.update(self.__dict__)
        if "_model" in self.__dict__:
            new._model = copy.copy(self._model)
            new._lock = threading.Lock()
        return new

    def __deepcopy__(self, memo: dict[int, Any]) -> "Mdagl":
        new = type(self).__new__(type(self))
        memo[id(self)] = new
        for key, value in self.__dict__.items():
            if key == "_lock":
                new._lock = threading.Lock()
            else:
                setattr(new, key, copy.deepcopy(value, memo))
        return new

    def __sklearn_tags__(self) -> Any:
        tags = super().__sklearn_tags__()
        tags.input_tags.sparse = True
        tags.input_tags.allow_nan = False
        return tags
