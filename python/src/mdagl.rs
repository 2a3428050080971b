//! `tes._tes.Mdagl`: the learning crate's mDAGL (online sparse multinomial logistic
//! regression with group lasso by dual averaging), fed a batch of rows at a time from NumPy
//! arrays. A batch is checked whole before any row is learned, and the learning runs with the
//! GIL released, holding the model's lock: one object is safe to share between threads.

use std::sync::{Mutex, MutexGuard};

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use tes_learning::mdagl::{Features, Mdagl as Model, MdaglConfigError, MdaglError, MdaglParams};
use tes_learning::tuning::{EntrantState, MdaglRace, RaceSchedule, RaceState, Standing, auto_grid};

/// Rows of one batch, borrowed from NumPy arrays.
#[derive(Clone, Copy)]
enum Rows<'a> {
    /// Real values, `width` per row, row-major (`rows` of them: a width of 0 still has rows).
    Dense {
        values: &'a [f64],
        rows: usize,
        width: usize,
    },
    /// The column indices of each row's ones (SciPy's CSR without its data array):
    /// row `r` is `indices[indptr[r]..indptr[r + 1]]`.
    Sparse {
        indptr: &'a [i64],
        indices: &'a [u32],
    },
}

impl<'a> Rows<'a> {
    /// Dense rows from a C-contiguous 2-D array.
    fn dense(x: &'a PyReadonlyArray2<'_, f64>) -> PyResult<Self> {
        let (rows, width) = x.as_array().dim();
        let values = x.as_slice().map_err(|_| {
            PyValueError::new_err("X must be C-contiguous (numpy.ascontiguousarray(X))")
        })?;
        Ok(Self::Dense {
            values,
            rows,
            width,
        })
    }

    /// Sparse rows from CSR arrays, whose row pointers are checked here.
    fn sparse(
        indptr: &'a PyReadonlyArray1<'_, i64>,
        indices: &'a PyReadonlyArray1<'_, u32>,
    ) -> PyResult<Self> {
        let contiguous = |_| PyValueError::new_err("indptr and indices must be contiguous");
        let indptr = indptr.as_slice().map_err(contiguous)?;
        let indices = indices.as_slice().map_err(contiguous)?;
        check_indptr(indptr, indices.len()).map_err(PyValueError::new_err)?;
        Ok(Self::Sparse { indptr, indices })
    }

    fn len(&self) -> usize {
        match *self {
            Rows::Dense { rows, .. } => rows,
            Rows::Sparse { indptr, .. } => indptr.len().saturating_sub(1),
        }
    }

    fn row(&self, r: usize) -> Features<'a> {
        match *self {
            Rows::Dense { values, width, .. } => {
                Features::Dense(&values[r * width..(r + 1) * width])
            }
            Rows::Sparse { indptr, indices } => {
                // In range: `check_indptr` accepted these pointers.
                let (start, end) = (indptr[r] as usize, indptr[r + 1] as usize);
                Features::SparseBinary(&indices[start..end])
            }
        }
    }
}

/// CSR row pointers: at least one, starting at 0, never decreasing, ending at `nnz`.
fn check_indptr(indptr: &[i64], nnz: usize) -> Result<(), String> {
    let (Some(&first), Some(&last)) = (indptr.first(), indptr.last()) else {
        return Err("indptr is empty; a CSR matrix has n_rows + 1 row pointers".into());
    };
    if first != 0 || usize::try_from(last).ok() != Some(nnz) {
        return Err(format!(
            "indptr must run from 0 to the number of stored entries ({nnz}), not {first} to {last}"
        ));
    }
    match indptr.windows(2).position(|w| w[1] < w[0]) {
        Some(r) => Err(format!("indptr decreases at row {r}")),
        None => Ok(()),
    }
}

/// The labels as class indices, each checked against the class count.
fn labels(y: &[i64], rows: usize, classes: usize) -> PyResult<Vec<usize>> {
    if y.len() != rows {
        return Err(PyValueError::new_err(format!(
            "y holds {} labels for {rows} rows",
            y.len()
        )));
    }
    y.iter()
        .enumerate()
        .map(|(r, &label)| match usize::try_from(label) {
            Ok(label) if label < classes => Ok(label),
            _ => Err(PyValueError::new_err(format!(
                "row {r}: label {label} is out of range for {classes} classes (0 to {})",
                classes - 1
            ))),
        })
        .collect()
}

/// A row's error as Python's `ValueError`, naming the row.
fn row_error(r: usize, e: MdaglError) -> PyErr {
    PyValueError::new_err(format!("row {r}: {e}"))
}

/// The one width rule of both paths: a batch is exactly as wide as the model.
fn check_width(width: usize, features: usize) -> PyResult<()> {
    if width == features {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!(
            "X has {width} features, but Mdagl is expecting {features} features as input"
        )))
    }
}

/// What learns: one setting, or the race of `tes fit --lambda auto` over a grid.
#[derive(Clone)]
enum Learner {
    Fixed(Model),
    Race(Box<MdaglRace>),
}

impl Learner {
    /// The model that predicts: the fixed one, or the race's leader.
    fn model(&self) -> &Model {
        match self {
            Learner::Fixed(m) => m,
            Learner::Race(r) => r.model(),
        }
    }

    fn update(&mut self, x: Features<'_>, label: usize) -> Result<f64, MdaglError> {
        match self {
            Learner::Fixed(m) => m.update(x, label).map(|p| p.log_prob),
            Learner::Race(r) => r.update(x, label).map(|p| p.log_prob),
        }
    }
}

/// Locks a model for one call; a model whose earlier call panicked is refused, not used.
fn lock(learner: &Mutex<Learner>) -> PyResult<MutexGuard<'_, Learner>> {
    learner.lock().map_err(|_| {
        PyRuntimeError::new_err("the model is unusable: an earlier call on it panicked")
    })
}

/// Online sparse multinomial logistic regression with group lasso (mDAGL).
///
/// The native class behind `tes.Mdagl`; use that, which takes NumPy arrays and SciPy CSR
/// matrices directly. One object may be used from several threads: each call holds the model
/// for its whole batch, so a read during learning sees the model before or after the batch,
/// and two learners take turns.
#[pyclass(module = "tes._tes", name = "Mdagl", frozen)]
pub struct Mdagl {
    learner: Mutex<Learner>,
}

#[pymethods]
impl Mdagl {
    /// `lam` or `alpha` `None` races the CLI's grid for it (`tes fit --lambda auto`).
    #[new]
    #[pyo3(signature = (n_features, n_classes, lam = None, alpha = None, intercept = false))]
    fn new(
        n_features: usize,
        n_classes: usize,
        lam: Option<f64>,
        alpha: Option<f64>,
        intercept: bool,
    ) -> PyResult<Self> {
        let config = |e: MdaglConfigError| PyValueError::new_err(e.to_string());
        let learner = match (lam, alpha) {
            (Some(lambda), Some(alpha)) => {
                let params = MdaglParams {
                    lambda,
                    alpha,
                    intercept,
                };
                Learner::Fixed(Model::new(n_classes, n_features, params).map_err(config)?)
            }
            _ => {
                let grid = auto_grid(lam, alpha, intercept);
                let race = MdaglRace::new(n_classes, n_features, &grid, RaceSchedule::default())
                    .map_err(config)?;
                Learner::Race(Box::new(race))
            }
        };
        Ok(Self::of(learner))
    }

    /// Learns from dense rows `x` (C-contiguous float64, `(n, n_features)`) with labels `y`
    /// (int64), in order. Returns the prequential log-loss summed over the rows: each row's
    /// `-ln P(y | x)` before it was learned (the race's mixture's, when racing).
    fn partial_fit_dense(
        &self,
        py: Python<'_>,
        x: PyReadonlyArray2<'_, f64>,
        y: PyReadonlyArray1<'_, i64>,
    ) -> PyResult<f64> {
        let width = x.as_array().ncols();
        let rows = Rows::dense(&x)?;
        self.learn(py, rows, width, &y)
    }

    /// Learns from sparse 0/1 rows of `n_columns` columns given as CSR row pointers (int64)
    /// and column indices (uint32, strictly increasing within a row) with labels `y`. Returns
    /// the summed prequential log-loss, as `partial_fit_dense`.
    fn partial_fit_sparse(
        &self,
        py: Python<'_>,
        indptr: PyReadonlyArray1<'_, i64>,
        indices: PyReadonlyArray1<'_, u32>,
        n_columns: usize,
        y: PyReadonlyArray1<'_, i64>,
    ) -> PyResult<f64> {
        let rows = Rows::sparse(&indptr, &indices)?;
        self.learn(py, rows, n_columns, &y)
    }

    /// `P(k | x)` for dense rows: an `(n, n_classes)` array.
    fn predict_proba_dense<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let width = x.as_array().ncols();
        let rows = Rows::dense(&x)?;
        self.probabilities(py, rows, width)
    }

    /// `P(k | x)` for sparse 0/1 rows of `n_columns` columns (CSR row pointers and column
    /// indices).
    fn predict_proba_sparse<'py>(
        &self,
        py: Python<'py>,
        indptr: PyReadonlyArray1<'_, i64>,
        indices: PyReadonlyArray1<'_, u32>,
        n_columns: usize,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let rows = Rows::sparse(&indptr, &indices)?;
        self.probabilities(py, rows, n_columns)
    }

    /// The feature count `d`.
    #[getter]
    fn n_features(&self, py: Python<'_>) -> PyResult<usize> {
        self.read(py, |l| l.model().n_features())
    }

    /// The class count `K`.
    #[getter]
    fn n_classes(&self, py: Python<'_>) -> PyResult<usize> {
        self.read(py, |l| l.model().n_classes())
    }

    /// Rows learned so far.
    #[getter]
    fn n_updates(&self, py: Python<'_>) -> PyResult<u64> {
        self.read(py, |l| l.model().n_updates())
    }

    /// The group-lasso strength λ (the leader's, when racing).
    #[getter]
    fn lam(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, |l| l.model().params().lambda)
    }

    /// The step-size scale α (the leader's, when racing).
    #[getter]
    fn alpha(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, |l| l.model().params().alpha)
    }

    /// Whether the model has an unregularised intercept column.
    #[getter]
    fn intercept(&self, py: Python<'_>) -> PyResult<bool> {
        self.read(py, |l| l.model().params().intercept)
    }

    /// Whether the model races a grid of settings (`lam` or `alpha` was `None`).
    #[getter]
    fn racing(&self, py: Python<'_>) -> PyResult<bool> {
        self.read(py, |l| matches!(l, Learner::Race(_)))
    }

    /// Ends the race, if racing: the leader goes on alone, as a fixed setting, from its state
    /// now (what `fit` does after its first pass, the last one on which the race's
    /// prequential losses are honest: later passes revisit rows the models have learned).
    fn settle(&self, py: Python<'_>) -> PyResult<()> {
        py.detach(|| {
            let mut learner = lock(&self.learner)?;
            if let Learner::Race(race) = &*learner {
                let leader = race.model().clone();
                *learner = Learner::Fixed(leader);
            }
            Ok(())
        })
    }

    /// The race's settings, best first: `(lam, alpha, mean_log_loss, rows, racing)` each (as
    /// `tes fit --json`'s `auto`); empty for a fixed setting.
    fn standings(&self, py: Python<'_>) -> PyResult<Vec<StandingRow>> {
        self.read(py, |l| match l {
            Learner::Fixed(_) => Vec::new(),
            Learner::Race(r) => r
                .standings()
                .iter()
                .map(|s| {
                    let p = s.params;
                    (p.lambda, p.alpha, s.mean_log_loss, s.rows, s.racing)
                })
                .collect(),
        })
    }

    /// The indices of the features whose weight column is not zero, increasing.
    fn selected(&self, py: Python<'_>) -> PyResult<Vec<usize>> {
        self.read(py, |l| l.model().selected_features().collect())
    }

    /// The weights, `(n_classes, n_features)`; the intercept's column is `intercept_weights`.
    fn coef<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let coef = self.read(py, |l| {
            let model = l.model();
            let (k, d) = (model.n_classes(), model.n_features());
            let mut coef = Array2::zeros((k, d));
            let mut column = vec![0.0; k];
            for i in 0..d {
                model.weight_column(i, &mut column)?;
                coef.column_mut(i)
                    .iter_mut()
                    .zip(&column)
                    .for_each(|(c, &w)| *c = w);
            }
            Ok(coef)
        })?;
        coef.map(|c| c.into_pyarray(py))
            .map_err(|e: MdaglError| PyValueError::new_err(e.to_string()))
    }

    /// The intercept's weights, one per class (zeros without an intercept).
    fn intercept_weights<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let column = self.read(py, |l| {
            let model = l.model();
            let mut column = vec![0.0; model.n_classes()];
            if model.params().intercept {
                model.weight_column(model.n_features(), &mut column)?;
            }
            Ok(column)
        })?;
        column
            .map(|c| c.into_pyarray(py))
            .map_err(|e: MdaglError| PyValueError::new_err(e.to_string()))
    }

    /// A copy with its own learning state: it predicts and learns on as this one would.
    fn __copy__(&self, py: Python<'_>) -> PyResult<Self> {
        Ok(Self::of(self.read(py, Learner::clone)?))
    }

    fn __deepcopy__(&self, py: Python<'_>, _memo: &Bound<'_, PyAny>) -> PyResult<Self> {
        self.__copy__(py)
    }

    /// Pickles as its whole learning state (gradient sums, update counts, the race's losses),
    /// restored exactly by `tes._tes._restore_mdagl`.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (SavedLearner,))> {
        let saved = self.read(py, save_learner)?;
        let restore = py.import("tes._tes")?.getattr("_restore_mdagl")?;
        Ok((restore, (saved,)))
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        self.read(py, |l| {
            let m = l.model();
            let p = m.params();
            format!(
                "Mdagl(n_features={}, n_classes={}, lam={}, alpha={}, intercept={}{}) after {} updates",
                m.n_features(),
                m.n_classes(),
                p.lambda,
                p.alpha,
                if p.intercept { "True" } else { "False" },
                if matches!(l, Learner::Race(_)) { ", racing" } else { "" },
                m.n_updates()
            )
        })
    }
}

/// One raced setting: `(lam, alpha, mean_log_loss, rows, racing)`.
type StandingRow = (f64, f64, f64, u64, bool);

/// A model's saved settings and learning state: `(n_classes, n_features, lam, alpha,
/// intercept, n_updates, gradient sums)`.
type SavedModel = (usize, usize, f64, f64, bool, u64, Vec<f64>);

/// A saved learner: `("fixed", [model], [], (0, 0, 0, 0, 0))` or `("race", [(model, loss,
/// recent)], [retired standings], (first_cut, finalists, rows, next_cut, leader))`.
type SavedLearner = (
    String,
    Vec<(SavedModel, f64, f64)>,
    Vec<(f64, f64, bool, f64, u64)>,
    (u64, usize, u64, u64, usize),
);

fn save_model(m: &Model) -> SavedModel {
    let p = m.params();
    (
        m.n_classes(),
        m.n_features(),
        p.lambda,
        p.alpha,
        p.intercept,
        m.n_updates(),
        m.gradient_sums().to_vec(),
    )
}

fn restore_model(saved: SavedModel) -> PyResult<Model> {
    let (classes, features, lambda, alpha, intercept, updates, sums) = saved;
    let params = MdaglParams {
        lambda,
        alpha,
        intercept,
    };
    Model::from_state(classes, features, params, updates, sums)
        .map_err(|e| PyValueError::new_err(format!("a saved mDAGL model: {e}")))
}

fn save_learner(learner: &Learner) -> SavedLearner {
    match learner {
        Learner::Fixed(m) => (
            "fixed".into(),
            vec![(save_model(m), 0.0, 0.0)],
            Vec::new(),
            (0, 0, 0, 0, 0),
        ),
        Learner::Race(r) => {
            let state = r.state();
            let entrants = state
                .entrants
                .iter()
                .map(|e| (save_model(&e.model), e.loss, e.recent))
                .collect();
            let retired = state
                .retired
                .iter()
                .map(|s| {
                    let p = s.params;
                    (p.lambda, p.alpha, p.intercept, s.mean_log_loss, s.rows)
                })
                .collect();
            let schedule = state.schedule;
            (
                "race".into(),
                entrants,
                retired,
                (
                    schedule.first_cut,
                    schedule.finalists,
                    state.rows,
                    state.next_cut,
                    state.leader,
                ),
            )
        }
    }
}

/// Rebuilds a pickled `Mdagl` (see `Mdagl.__reduce__`); a tampered state is refused with
/// `ValueError`.
#[pyfunction]
pub fn _restore_mdagl(saved: SavedLearner) -> PyResult<Mdagl> {
    let (kind, entrants, retired, (first_cut, finalists, rows, next_cut, leader)) = saved;
    let learner = match kind.as_str() {
        "fixed" => {
            let [(model, _, _)] = <[_; 1]>::try_from(entrants)
                .map_err(|_| PyValueError::new_err("a saved fixed model holds one model"))?;
            Learner::Fixed(restore_model(model)?)
        }
        "race" => {
            let entrants = entrants
                .into_iter()
                .map(|(model, loss, recent)| {
                    Ok(EntrantState {
                        model: restore_model(model)?,
                        loss,
                        recent,
                    })
                })
                .collect::<PyResult<Vec<_>>>()?;
            let retired = retired
                .into_iter()
                .map(|(lambda, alpha, intercept, mean_log_loss, rows)| Standing {
                    params: MdaglParams {
                        lambda,
                        alpha,
                        intercept,
                    },
                    mean_log_loss,
                    rows,
                    racing: false,
                })
                .collect();
            let state = RaceState {
                entrants,
                retired,
                schedule: RaceSchedule {
                    first_cut,
                    finalists,
                },
                rows,
                next_cut,
                leader,
            };
            let race = MdaglRace::from_state(state)
                .map_err(|e| PyValueError::new_err(format!("a saved race: {e}")))?;
            Learner::Race(Box::new(race))
        }
        other => {
            return Err(PyValueError::new_err(format!(
                "a saved mDAGL model is \"fixed\" or \"race\", not {other:?}"
            )));
        }
    };
    Ok(Mdagl::of(learner))
}

impl Mdagl {
    fn of(learner: Learner) -> Self {
        Self {
            learner: Mutex::new(learner),
        }
    }

    /// Runs `f` on the model with the GIL released (a learner on another thread may hold the
    /// model for a while; waiting for it must not block the interpreter).
    fn read<T: Send>(&self, py: Python<'_>, f: impl FnOnce(&Learner) -> T + Send) -> PyResult<T> {
        py.detach(|| lock(&self.learner).map(|l| f(&l)))
    }

    /// Checks every row and label, then learns them in order with the GIL released, holding
    /// the model throughout.
    fn learn(
        &self,
        py: Python<'_>,
        rows: Rows<'_>,
        width: usize,
        y: &PyReadonlyArray1<'_, i64>,
    ) -> PyResult<f64> {
        let y = y.as_array();
        let y: Vec<i64> = y.iter().copied().collect();
        py.detach(|| {
            let mut learner = lock(&self.learner)?;
            let labels = labels(&y, rows.len(), learner.model().n_classes())?;
            check(learner.model(), rows, width)?;
            let mut loss = 0.0;
            for (r, &label) in labels.iter().enumerate() {
                loss -= learner
                    .update(rows.row(r), label)
                    .map_err(|e| row_error(r, e))?;
            }
            Ok(loss)
        })
    }

    fn probabilities<'py>(
        &self,
        py: Python<'py>,
        rows: Rows<'_>,
        width: usize,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (out, k) = py.detach(|| {
            let learner = lock(&self.learner)?;
            let model = learner.model();
            check(model, rows, width)?;
            let (n, k) = (rows.len(), model.n_classes());
            let mut out = vec![0.0; n * k];
            out.chunks_mut(k.max(1))
                .enumerate()
                .try_for_each(|(r, p)| model.predict_into(rows.row(r), p).map_err(|e| (r, e)))
                .map_err(|(r, e)| row_error(r, e))?;
            Ok::<_, PyErr>((out, k))
        })?;
        let n = out.len() / k.max(1);
        let out = Array2::from_shape_vec((n, k), out)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(out.into_pyarray(py))
    }
}

/// Every row's width and values against the model's feature count: one rule for both paths.
fn check(model: &Model, rows: Rows<'_>, width: usize) -> PyResult<()> {
    check_width(width, model.n_features())?;
    (0..rows.len()).try_for_each(|r| {
        rows.row(r)
            .validate(model.n_features())
            .map_err(|e| row_error(r, e))
    })
}

#[cfg(test)]
mod tests {
    use super::{check_indptr, check_width};

    #[test]
    fn the_width_is_exact() {
        assert!(check_width(4, 4).is_ok());
        assert!(check_width(3, 4).is_err());
        assert!(check_width(5, 4).is_err());
    }

    #[test]
    fn row_pointers_are_checked() {
        assert!(check_indptr(&[0, 2, 2, 5], 5).is_ok());
        assert!(check_indptr(&[0], 0).is_ok());
        assert!(check_indptr(&[], 0).is_err());
        assert!(check_indptr(&[1, 5], 5).is_err());
        assert!(check_indptr(&[0, 4], 5).is_err());
        assert!(
            check_indptr(&[0, 3, 2, 5], 5)
                .unwrap_err()
                .contains("row 1")
        );
    }
}
