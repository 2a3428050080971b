//! `tes._tes.Mdagl`: the learning crate's mDAGL (online sparse multinomial logistic
//! regression with group lasso by dual averaging), fed a batch of rows at a time from NumPy
//! arrays. A batch is checked whole before any row is learned, and the learning runs with the
//! GIL released.

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use tes_learning::mdagl::{Features, Mdagl as Model, MdaglError, MdaglParams};

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
fn labels(y: &PyReadonlyArray1<'_, i64>, rows: usize, classes: usize) -> PyResult<Vec<usize>> {
    let y = y.as_array();
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

/// Online sparse multinomial logistic regression with group lasso (mDAGL).
///
/// The native class behind `tes.Mdagl`; use that, which takes NumPy arrays and SciPy CSR
/// matrices directly.
#[pyclass(module = "tes._tes", name = "Mdagl")]
pub struct Mdagl {
    model: Model,
}

#[pymethods]
impl Mdagl {
    #[new]
    #[pyo3(signature = (n_features, n_classes, lam = 0.05, alpha = 1.5, intercept = false))]
    fn new(
        n_features: usize,
        n_classes: usize,
        lam: f64,
        alpha: f64,
        intercept: bool,
    ) -> PyResult<Self> {
        let params = MdaglParams {
            lambda: lam,
            alpha,
            intercept,
        };
        let model = Model::new(n_classes, n_features, params)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(Self { model })
    }

    /// Learns from dense rows `x` (C-contiguous float64, `(n, n_features)`) with labels `y`
    /// (int64), in order. Returns the prequential log-loss summed over the rows: each row's
    /// `-ln P(y | x)` before it was learned.
    fn partial_fit_dense(
        &mut self,
        py: Python<'_>,
        x: PyReadonlyArray2<'_, f64>,
        y: PyReadonlyArray1<'_, i64>,
    ) -> PyResult<f64> {
        let rows = Rows::dense(&x)?;
        self.learn(py, rows, &y)
    }

    /// Learns from sparse 0/1 rows given as CSR row pointers (int64) and column indices
    /// (uint32, strictly increasing within a row) with labels `y`. Returns the summed
    /// prequential log-loss, as `partial_fit_dense`.
    fn partial_fit_sparse(
        &mut self,
        py: Python<'_>,
        indptr: PyReadonlyArray1<'_, i64>,
        indices: PyReadonlyArray1<'_, u32>,
        y: PyReadonlyArray1<'_, i64>,
    ) -> PyResult<f64> {
        let rows = Rows::sparse(&indptr, &indices)?;
        self.learn(py, rows, &y)
    }

    /// `P(k | x)` for dense rows: an `(n, n_classes)` array.
    fn predict_proba_dense<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let rows = Rows::dense(&x)?;
        self.probabilities(py, rows)
    }

    /// `P(k | x)` for sparse 0/1 rows (CSR row pointers and column indices).
    fn predict_proba_sparse<'py>(
        &self,
        py: Python<'py>,
        indptr: PyReadonlyArray1<'_, i64>,
        indices: PyReadonlyArray1<'_, u32>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let rows = Rows::sparse(&indptr, &indices)?;
        self.probabilities(py, rows)
    }

    /// The feature count `d`.
    #[getter]
    fn n_features(&self) -> usize {
        self.model.n_features()
    }

    /// The class count `K`.
    #[getter]
    fn n_classes(&self) -> usize {
        self.model.n_classes()
    }

    /// Rows learned so far.
    #[getter]
    fn n_updates(&self) -> u64 {
        self.model.n_updates()
    }

    /// The group-lasso strength λ.
    #[getter]
    fn lam(&self) -> f64 {
        self.model.params().lambda
    }

    /// The step-size scale α.
    #[getter]
    fn alpha(&self) -> f64 {
        self.model.params().alpha
    }

    /// Whether the model has an unregularised intercept column.
    #[getter]
    fn intercept(&self) -> bool {
        self.model.params().intercept
    }

    /// The indices of the features whose weight column is not zero, increasing.
    fn selected(&self) -> Vec<usize> {
        self.model.selected_features().collect()
    }

    /// The weights, `(n_classes, n_features)`; the intercept's column is `intercept_weights`.
    fn coef<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (k, d) = (self.model.n_classes(), self.model.n_features());
        let mut coef = Array2::zeros((k, d));
        let mut column = vec![0.0; k];
        for i in 0..d {
            self.model
                .weight_column(i, &mut column)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            coef.column_mut(i)
                .iter_mut()
                .zip(&column)
                .for_each(|(c, &w)| *c = w);
        }
        Ok(coef.into_pyarray(py))
    }

    /// The intercept's weights, one per class (zeros without an intercept).
    fn intercept_weights<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let mut column = vec![0.0; self.model.n_classes()];
        if self.model.params().intercept {
            self.model
                .weight_column(self.model.n_features(), &mut column)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
        }
        Ok(column.into_pyarray(py))
    }

    fn __repr__(&self) -> String {
        let p = self.model.params();
        format!(
            "Mdagl(n_features={}, n_classes={}, lam={}, alpha={}, intercept={}) after {} updates",
            self.model.n_features(),
            self.model.n_classes(),
            p.lambda,
            p.alpha,
            if p.intercept { "True" } else { "False" },
            self.model.n_updates()
        )
    }
}

impl Mdagl {
    /// Checks every row and label, then learns them in order with the GIL released.
    fn learn(
        &mut self,
        py: Python<'_>,
        rows: Rows<'_>,
        y: &PyReadonlyArray1<'_, i64>,
    ) -> PyResult<f64> {
        let labels = labels(y, rows.len(), self.model.n_classes())?;
        self.check(rows)?;
        let model = &mut self.model;
        py.detach(|| {
            let mut loss = 0.0;
            for (r, &label) in labels.iter().enumerate() {
                let seen = model.update(rows.row(r), label).map_err(|e| (r, e))?;
                loss -= seen.log_prob;
            }
            Ok(loss)
        })
        .map_err(|(r, e)| row_error(r, e))
    }

    /// Every row's shape and values against the model's feature count.
    fn check(&self, rows: Rows<'_>) -> PyResult<()> {
        if let Rows::Dense { width, .. } = rows
            && width != self.model.n_features()
        {
            return Err(PyValueError::new_err(format!(
                "X has {width} columns but the model has {} features",
                self.model.n_features()
            )));
        }
        (0..rows.len()).try_for_each(|r| {
            rows.row(r)
                .validate(self.model.n_features())
                .map_err(|e| row_error(r, e))
        })
    }

    fn probabilities<'py>(
        &self,
        py: Python<'py>,
        rows: Rows<'_>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        self.check(rows)?;
        let (n, k) = (rows.len(), self.model.n_classes());
        let model = &self.model;
        let mut out = vec![0.0; n * k];
        py.detach(|| {
            out.chunks_mut(k.max(1))
                .enumerate()
                .try_for_each(|(r, p)| model.predict_into(rows.row(r), p).map_err(|e| (r, e)))
        })
        .map_err(|(r, e)| row_error(r, e))?;
        let out = Array2::from_shape_vec((n, k), out)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(out.into_pyarray(py))
    }
}

#[cfg(test)]
mod tests {
    use super::check_indptr;

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
