//! `tes._tes.Structure`: the agent-known part of a CMDP (the paper's §3.1) — what an effect
//! does in each state, rewards, terminal states and each state's binary features — built once
//! from NumPy arrays and shared by every agent on that environment.

use std::sync::Arc;

use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use tes_learning::agents::Contexts;
use tes_learning::cmdp::CmdpStructure;

/// The agent-known structure of an environment, checked.
///
/// The native class behind `tes.structure.compile`; build it from a structure object with
/// that function, which reads the protocol `tes.structure.Structure` describes.
#[pyclass(module = "tes._tes", name = "Structure", frozen)]
pub struct Structure {
    /// The CMDP the agents plan on.
    pub(crate) cmdp: Arc<CmdpStructure>,
    /// Which states share counts for the factored counting agents (each state its own, unless
    /// the environment named its factors).
    pub(crate) contexts: Contexts,
    /// The factor of each state and how many there are, as given (what a pickle carries).
    pub(crate) factors: Option<(Vec<u32>, usize)>,
}

#[pymethods]
impl Structure {
    /// * `next_state` — `(n_states, n_effects)` int64: where each effect leads from each state;
    /// * `reward` — `(n_states,)` float64: the reward for entering each state;
    /// * `terminal` — `(n_states,)` bool: whether entering the state ends the episode;
    /// * `feature_indptr`, `feature_indices` — the states' binary features as CSR (int64 row
    ///   pointers, uint32 sorted column indices below `n_features`);
    /// * `contexts` — optional `(n_states,)` int64: the factor each state belongs to, for
    ///   `FEpsG` (default: every state its own), and `n_contexts` how many factors there are
    ///   (default: one more than the largest id);
    /// * `step_reward` — optional `(n_states, n_actions, n_effects)` float64: the reward of
    ///   each action from each state when it has each effect (so leads to `next_state[s, e]`),
    ///   which the planner then uses instead of the reward for entering where the step leads
    ///   (a reward that depends on the action or the state left, not only on where it ends).
    #[new]
    #[pyo3(signature = (next_state, reward, terminal, feature_indptr, feature_indices, n_features, n_actions, contexts = None, n_contexts = None, step_reward = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        next_state: PyReadonlyArray2<'_, i64>,
        reward: PyReadonlyArray1<'_, f64>,
        terminal: PyReadonlyArray1<'_, bool>,
        feature_indptr: PyReadonlyArray1<'_, i64>,
        feature_indices: PyReadonlyArray1<'_, u32>,
        n_features: usize,
        n_actions: usize,
        contexts: Option<PyReadonlyArray1<'_, i64>>,
        n_contexts: Option<usize>,
        step_reward: Option<PyReadonlyArray3<'_, f64>>,
    ) -> PyResult<Self> {
        let next = next_state.as_array();
        let (n_states, n_effects) = next.dim();
        let next = checked_states(next.iter().copied(), n_states, "next_state")?;
        let indptr = feature_indptr.as_array();
        let indices = feature_indices.as_array();
        let offsets = checked_offsets(indptr.iter().copied(), n_states, indices.len())?;
        let indices: Vec<u32> = indices.iter().copied().collect();
        let cmdp = CmdpStructure::new(
            n_states,
            n_actions,
            n_effects,
            n_features,
            |s, e| next[s * n_effects + e],
            reward.as_array().to_vec(),
            terminal.as_array().to_vec(),
            |s| &indices[offsets[s]..offsets[s + 1]],
        )
        .map_err(|e| PyValueError::new_err(format!("structure: {e}")))?;
        let cmdp = match step_reward {
            None => cmdp,
            Some(table) => with_step_rewards(cmdp, &table)?,
        };
        let (contexts, factors) = match contexts {
            None => (Contexts::tabular(n_states), None),
            Some(of_state) => {
                let (of_state, n) = factor_ids(&of_state, n_states, n_contexts)?;
                let contexts = Contexts::new(of_state.clone(), n)
                    .ok_or_else(|| PyValueError::new_err("contexts are out of range"))?;
                (contexts, Some((of_state, n)))
            }
        };
        Ok(Self {
            cmdp: Arc::new(cmdp),
            contexts,
            factors,
        })
    }

    /// Pickles as the arrays it was made from (`Structure(*args)` makes it again).
    fn __reduce__<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyTuple>)> {
        let c = &self.cmdp;
        let (n, a, e) = (c.n_states(), c.n_actions(), c.n_effects());
        let next = Array2::from_shape_fn((n, e), |(s, e)| c.next_state(s, e) as i64);
        let reward: Vec<f64> = (0..n).map(|s| c.reward(s)).collect();
        let terminal: Vec<bool> = (0..n).map(|s| c.is_terminal(s)).collect();
        let mut indptr = vec![0i64];
        let mut indices: Vec<u32> = Vec::new();
        for s in 0..n {
            indices.extend_from_slice(c.features(s));
            indptr.push(indices.len() as i64);
        }
        let (contexts, n_contexts) = match &self.factors {
            Some((of_state, k)) => (
                Some(of_state.iter().map(|&c| i64::from(c)).collect::<Vec<_>>()),
                Some(*k),
            ),
            None => (None, None),
        };
        let step_reward = c.has_step_rewards().then(|| {
            Array3::from_shape_fn((n, a, e), |(s, a, e)| c.step_reward(s, a, e)).into_pyarray(py)
        });
        let args = PyTuple::new(
            py,
            [
                next.into_pyarray(py).into_any(),
                reward.into_pyarray(py).into_any(),
                terminal.into_pyarray(py).into_any(),
                indptr.into_pyarray(py).into_any(),
                indices.into_pyarray(py).into_any(),
                c.n_features().into_pyobject(py)?.into_any(),
                c.n_actions().into_pyobject(py)?.into_any(),
                contexts
                    .map(|v| v.into_pyarray(py))
                    .into_pyobject(py)?
                    .into_any(),
                n_contexts.into_pyobject(py)?.into_any(),
                step_reward.into_pyobject(py)?.into_any(),
            ],
        )?;
        Ok((py.get_type::<Structure>().into_any(), args))
    }

    /// Number of states.
    #[getter]
    fn n_states(&self) -> usize {
        self.cmdp.n_states()
    }

    /// Number of actions.
    #[getter]
    fn n_actions(&self) -> usize {
        self.cmdp.n_actions()
    }

    /// Number of effects.
    #[getter]
    fn n_effects(&self) -> usize {
        self.cmdp.n_effects()
    }

    /// Number of binary features.
    #[getter]
    fn n_features(&self) -> usize {
        self.cmdp.n_features()
    }

    /// Where `effect` leads from `state`.
    fn next_state(&self, state: usize, effect: usize) -> PyResult<usize> {
        self.check(state)?;
        if effect >= self.cmdp.n_effects() {
            return Err(PyValueError::new_err(format!(
                "effect {effect} is out of range ({} effects)",
                self.cmdp.n_effects()
            )));
        }
        Ok(self.cmdp.next_state(state, effect))
    }

    /// The reward for entering `state`.
    fn reward(&self, state: usize) -> PyResult<f64> {
        self.check(state)?;
        Ok(self.cmdp.reward(state))
    }

    /// The reward the planner counts for `action` in `state` when it has `effect`: the
    /// reward for entering where that leads, unless the structure was given step rewards.
    fn step_reward(&self, state: usize, action: usize, effect: usize) -> PyResult<f64> {
        self.next_state(state, effect)?;
        if action >= self.cmdp.n_actions() {
            return Err(PyValueError::new_err(format!(
                "action {action} is out of range ({} actions)",
                self.cmdp.n_actions()
            )));
        }
        Ok(self.cmdp.step_reward(state, action, effect))
    }

    /// Whether entering `state` ends the episode.
    fn terminal(&self, state: usize) -> PyResult<bool> {
        self.check(state)?;
        Ok(self.cmdp.is_terminal(state))
    }

    /// The indices of the binary features on in `state`, sorted.
    fn features(&self, state: usize) -> PyResult<Vec<u32>> {
        self.check(state)?;
        Ok(self.cmdp.features(state).to_vec())
    }

    fn __repr__(&self) -> String {
        format!(
            "Structure(n_states={}, n_actions={}, n_effects={}, n_features={})",
            self.cmdp.n_states(),
            self.cmdp.n_actions(),
            self.cmdp.n_effects(),
            self.cmdp.n_features()
        )
    }
}

impl Structure {
    fn check(&self, state: usize) -> PyResult<()> {
        if state < self.cmdp.n_states() {
            Ok(())
        } else {
            Err(PyValueError::new_err(format!(
                "state {state} is out of range ({} states)",
                self.cmdp.n_states()
            )))
        }
    }
}

/// State ids as indices, each below `n_states`.
fn checked_states(
    ids: impl Iterator<Item = i64>,
    n_states: usize,
    table: &str,
) -> PyResult<Vec<usize>> {
    ids.enumerate()
        .map(|(i, id)| match usize::try_from(id) {
            Ok(s) if s < n_states => Ok(s),
            _ => Err(PyValueError::new_err(format!(
                "{table}[{i}] = {id} is not a state (0 to {})",
                n_states.saturating_sub(1)
            ))),
        })
        .collect()
}

/// CSR row pointers for `n_states` rows over `nnz` entries, as offsets.
fn checked_offsets(
    indptr: impl ExactSizeIterator<Item = i64>,
    n_states: usize,
    nnz: usize,
) -> PyResult<Vec<usize>> {
    if indptr.len() != n_states + 1 {
        return Err(PyValueError::new_err(format!(
            "feature_indptr has {} entries for {n_states} states (needs {})",
            indptr.len(),
            n_states + 1
        )));
    }
    let offsets: Vec<usize> = indptr
        .map(|p| usize::try_from(p).unwrap_or(usize::MAX))
        .collect();
    let ordered = offsets.windows(2).all(|w| w[0] <= w[1]);
    if offsets.first() != Some(&0) || offsets.last() != Some(&nnz) || !ordered {
        return Err(PyValueError::new_err(format!(
            "feature_indptr must rise from 0 to the {nnz} feature indices"
        )));
    }
    Ok(offsets)
}

/// Oracle factors for the counting agents: one id per state, numbered from 0, and how many
/// there are (`n_contexts`, or one more than the largest id).
fn factor_ids(
    of_state: &PyReadonlyArray1<'_, i64>,
    n_states: usize,
    n_contexts: Option<usize>,
) -> PyResult<(Vec<u32>, usize)> {
    let of_state = of_state.as_array();
    if of_state.len() != n_states {
        return Err(PyValueError::new_err(format!(
            "contexts has {} entries for {n_states} states",
            of_state.len()
        )));
    }
    let ids = of_state
        .iter()
        .map(|&c| u32::try_from(c))
        .collect::<Result<Vec<u32>, _>>()
        .map_err(|_| PyValueError::new_err("contexts must be ids from 0 to 2^32 - 1"))?;
    let needed = ids.iter().max().map_or(0, |&m| m as usize + 1);
    let n = n_contexts.unwrap_or(needed);
    if n < needed {
        return Err(PyValueError::new_err(format!(
            "n_contexts is {n} but a context id is {}",
            needed - 1
        )));
    }
    Ok((ids, n))
}

/// `cmdp` with each step's reward from an `(n_states, n_actions, n_effects)` table.
fn with_step_rewards(
    cmdp: CmdpStructure,
    table: &PyReadonlyArray3<'_, f64>,
) -> PyResult<CmdpStructure> {
    let table = table.as_array();
    let shape = (cmdp.n_states(), cmdp.n_actions(), cmdp.n_effects());
    if table.dim() != shape {
        return Err(PyValueError::new_err(format!(
            "step_reward is {:?} but the structure has {} states, {} actions and {} effects",
            table.dim(),
            shape.0,
            shape.1,
            shape.2
        )));
    }
    cmdp.with_step_rewards(|s, a, e| table[(s, a, e)])
        .map_err(|e| PyValueError::new_err(format!("structure: {e}")))
}
