//! `tes._tes.Structure`: the agent-known part of a CMDP (the paper's §3.1) — what an effect
//! does in each state, rewards, terminal states and each state's binary features — built once
//! from NumPy arrays and shared by every agent on that environment.

use std::sync::Arc;

use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
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
}

#[pymethods]
impl Structure {
    /// * `next_state` — `(n_states, n_effects)` int64: where each effect leads from each state;
    /// * `reward` — `(n_states,)` float64: the reward for entering each state;
    /// * `terminal` — `(n_states,)` bool: whether entering the state ends the episode;
    /// * `feature_indptr`, `feature_indices` — the states' binary features as CSR (int64 row
    ///   pointers, uint32 sorted column indices below `n_features`);
    /// * `contexts` — optional `(n_states,)` int64: the factor each state belongs to, for
    ///   `FEpsG` (default: every state its own).
    #[new]
    #[pyo3(signature = (next_state, reward, terminal, feature_indptr, feature_indices, n_features, n_actions, contexts = None))]
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
        let contexts = match contexts {
            None => Contexts::tabular(n_states),
            Some(of_state) => factor_contexts(&of_state, n_states)?,
        };
        Ok(Self {
            cmdp: Arc::new(cmdp),
            contexts,
        })
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

/// Oracle factors for the counting agents: one id per state, numbered from 0.
fn factor_contexts(of_state: &PyReadonlyArray1<'_, i64>, n_states: usize) -> PyResult<Contexts> {
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
    let n_contexts = ids.iter().max().map_or(0, |&m| m as usize + 1);
    Contexts::new(ids, n_contexts).ok_or_else(|| PyValueError::new_err("contexts are out of range"))
}
