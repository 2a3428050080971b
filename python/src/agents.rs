//! `tes._tes.Agent`: the learning crate's agents — loreRL, TES, LWT and factored ε-greedy — on
//! a [`Structure`], stepped in state and effect ids. The Python side (`tes.agents`) turns an
//! environment's observations into those ids through the structure protocol.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::{IntoPyArray, PyArray1};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use tes_learning::agents::{
    Agent as _, AgentError, CountingAgent, LoreRl, LoreRlParams, Tes, TesParams, ViewPolicy,
};
use tes_learning::cmdp::CmdpStructure;
use tes_learning::library::store::{self, StoreError, StoreProblem, StoredLibrary};
use tes_learning::library::{LibraryParams, ViewLibrary};
use tes_learning::mdagl::MdaglParams;
use tes_learning::plan::{PlannedModel, PlannerParams};

use crate::structure::Structure;

pyo3::create_exception!(
    _tes,
    LibraryFileError,
    pyo3::exceptions::PyValueError,
    "A view library file that cannot be read or written: corrupt, foreign, of another \
     environment's shape, or unwritable. The message names the file and the problem."
);

/// Re-plans this many times at most when a greedy policy is asked for; each re-plan runs up to
/// the planner's sweep limit and stops once the values hold still.
const MAX_REPLANS: usize = 10_000;

/// A transfer agent (TES or LWT) and what it needs to start the next task.
struct Transfer {
    /// `None` only while a task is being finished.
    agent: Option<Tes>,
    structure: Arc<CmdpStructure>,
    params: TesParams,
    seed: u64,
    /// Where the library is kept, if anywhere.
    path: Option<PathBuf>,
    /// What the stored library names.
    world: String,
    action_names: Vec<String>,
    feature_names: Vec<String>,
}

impl Transfer {
    fn agent(&self) -> PyResult<&Tes> {
        self.agent
            .as_ref()
            .ok_or_else(|| PyRuntimeError::new_err("the agent failed while ending a task"))
    }

    fn agent_mut(&mut self) -> PyResult<&mut Tes> {
        self.agent
            .as_mut()
            .ok_or_else(|| PyRuntimeError::new_err("the agent failed while ending a task"))
    }

    fn stored(&self, library: ViewLibrary) -> StoredLibrary {
        StoredLibrary {
            library,
            world: self.world.clone(),
            action_names: self.action_names.clone(),
            feature_names: self.feature_names.clone(),
        }
    }

    /// Grows the library with this task's views, keeps it on disk, and starts the next task
    /// on the same structure with the grown library.
    fn end_task(&mut self) -> PyResult<TaskSummary> {
        let agent = self.agent.take().ok_or_else(|| {
            PyRuntimeError::new_err("the agent failed while ending an earlier task")
        })?;
        let (library, report) = agent
            .finish_task()
            .map_err(|e| PyValueError::new_err(format!("ending the task: {e}")))?;
        let stored = self.stored(library);
        if let Some(path) = &self.path {
            store::save(path, &stored).map_err(library_error)?;
        }
        let next_seed = self
            .seed
            .wrapping_add(u64::from(stored.library.tasks_seen()));
        self.agent = Some(
            Tes::new(
                self.structure.clone(),
                stored.library,
                self.params,
                next_seed,
            )
            .map_err(agent_error)?,
        );
        Ok(TaskSummary {
            task: report.task,
            added: report.added,
            updated: report.updated,
            removed: report.removed,
        })
    }
}

/// What `end_task` reports.
struct TaskSummary {
    task: u32,
    added: Vec<u64>,
    updated: Vec<u64>,
    removed: Vec<u64>,
}

enum Kind {
    LoreRl(LoreRl),
    Counting(CountingAgent),
    Transfer(Box<Transfer>),
}

/// An agent of the paper on a known structure, stepped in state, action and effect ids.
///
/// The native class behind `tes.agents.LoreRL`, `TES`, `LWT` and `FEpsG`; use those, which
/// read observations through the structure protocol.
#[pyclass(module = "tes._tes", name = "Agent")]
pub struct Agent {
    kind: Kind,
    structure: Arc<CmdpStructure>,
}

#[pymethods]
impl Agent {
    /// loreRL (the paper's Algorithm 6): one mDAGL view per action, value iteration on the
    /// learned model, ε-greedy.
    #[staticmethod]
    #[pyo3(signature = (structure, lam = 0.05, alpha = 1.5, intercept = false, epsilon = 0.05, gamma = 0.95, seed = 0))]
    fn lore_rl(
        structure: &Structure,
        lam: f64,
        alpha: f64,
        intercept: bool,
        epsilon: f64,
        gamma: f64,
        seed: u64,
    ) -> PyResult<Self> {
        let params = LoreRlParams {
            mdagl: MdaglParams {
                lambda: lam,
                alpha,
                intercept,
            },
            planner: planner(gamma),
            epsilon,
        };
        let agent = LoreRl::new(structure.cmdp.clone(), params, seed).map_err(agent_error)?;
        Ok(Self::of(Kind::LoreRl(agent), structure))
    }

    /// Factored ε-greedy (the paper's fEpsG): effect counts per (context, action) — the
    /// contexts are the structure's factors — on the maximum-likelihood model.
    #[staticmethod]
    #[pyo3(signature = (structure, epsilon = 0.1, gamma = 0.95, seed = 0))]
    fn fepsg(structure: &Structure, epsilon: f64, gamma: f64, seed: u64) -> PyResult<Self> {
        let agent = CountingAgent::factored_epsilon_greedy(
            structure.cmdp.clone(),
            structure.contexts.clone(),
            epsilon,
            planner(gamma),
            seed,
        )
        .map_err(agent_error)?;
        Ok(Self::of(Kind::Counting(agent), structure))
    }

    /// TES (`policy="tes"`, the paper's Algorithms 2–3) or LWT (`policy="lwt"`) on the view
    /// library at `library` — loaded if the file exists, refused with `LibraryFileError` if it
    /// is corrupt or of another shape — or on an empty library.
    #[staticmethod]
    #[pyo3(signature = (structure, library = None, policy = "tes", lam = 0.05, alpha = 1.5, intercept = false, epsilon = 0.05, gamma = 0.95, max_views = 20, seed = 0, world = String::new(), action_names = Vec::new(), feature_names = Vec::new()))]
    #[allow(clippy::too_many_arguments)]
    fn transfer(
        structure: &Structure,
        library: Option<PathBuf>,
        policy: &str,
        lam: f64,
        alpha: f64,
        intercept: bool,
        epsilon: f64,
        gamma: f64,
        max_views: usize,
        seed: u64,
        world: String,
        action_names: Vec<String>,
        feature_names: Vec<String>,
    ) -> PyResult<Self> {
        let policy = match policy {
            "tes" => ViewPolicy::Tes,
            "lwt" => ViewPolicy::Lwt,
            other => {
                return Err(PyValueError::new_err(format!(
                    "policy must be \"tes\" or \"lwt\", not {other:?}"
                )));
            }
        };
        let cmdp = &structure.cmdp;
        let params = LibraryParams {
            max_views,
            mdagl: MdaglParams {
                lambda: lam,
                alpha,
                intercept,
            },
            ..LibraryParams::default()
        };
        let loaded = match &library {
            Some(path) if path.exists() => Some(
                store::load_for(path, cmdp.n_actions(), cmdp.n_effects(), cmdp.n_features())
                    .map_err(library_error)?,
            ),
            _ => None,
        };
        let views = match loaded {
            Some(stored) => stored.library,
            None => ViewLibrary::new(
                cmdp.n_actions(),
                cmdp.n_effects(),
                cmdp.n_features(),
                params,
            )
            .map_err(|e| PyValueError::new_err(format!("library settings: {e}")))?,
        };
        let tes_params = TesParams {
            planner: planner(gamma),
            epsilon,
            policy,
        };
        let agent = Tes::new(cmdp.clone(), views, tes_params, seed).map_err(agent_error)?;
        let transfer = Transfer {
            agent: Some(agent),
            structure: cmdp.clone(),
            params: tes_params,
            seed,
            path: library,
            world,
            action_names,
            feature_names,
        };
        Ok(Self::of(Kind::Transfer(Box::new(transfer)), structure))
    }

    /// The agent's short name ("loreRL", "TES", "LWT", "fEpsG").
    #[getter]
    fn name(&self) -> PyResult<String> {
        Ok(match &self.kind {
            Kind::LoreRl(a) => a.name().to_owned(),
            Kind::Counting(a) => a.name().to_owned(),
            Kind::Transfer(t) => t.agent()?.name().to_owned(),
        })
    }

    /// Called when an episode starts in `state`.
    fn begin_episode(&mut self, state: usize) -> PyResult<()> {
        self.check_state(state)?;
        self.agent_mut()?.begin_episode(state);
        Ok(())
    }

    /// The action to take in `state` (ε-greedy on the current plan).
    fn act(&mut self, py: Python<'_>, state: usize) -> PyResult<usize> {
        let agent = self.agent_mut()?;
        py.detach(|| agent.act(state)).map_err(agent_error)
    }

    /// Learns that `action` in `state` had `effect`.
    fn observe(
        &mut self,
        py: Python<'_>,
        state: usize,
        action: usize,
        effect: usize,
    ) -> PyResult<()> {
        let agent = self.agent_mut()?;
        py.detach(|| agent.observe(state, action, effect))
            .map_err(agent_error)
    }

    /// For every state, the action the current model's plan takes (re-planned to convergence
    /// first), as an int64 array.
    fn greedy_policy<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<i64>>> {
        let policy = py.detach(|| self.converged_policy())?;
        Ok(policy.into_pyarray(py))
    }

    /// TES and LWT: ends the task — grows and prunes the library (TES; LWT's stays as it was),
    /// writes it to the library file if there is one, and goes on with a new task on the
    /// grown library. Returns what changed: `{"task", "added", "updated", "removed"}`.
    fn end_task<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let Kind::Transfer(transfer) = &mut self.kind else {
            return Err(PyValueError::new_err(
                "only TES and LWT keep a view library",
            ));
        };
        let summary = transfer.end_task()?;
        let report = PyDict::new(py);
        report.set_item("task", summary.task)?;
        report.set_item("added", summary.added)?;
        report.set_item("updated", summary.updated)?;
        report.set_item("removed", summary.removed)?;
        Ok(report)
    }

    /// TES and LWT: writes the library as it stood at the start of this task to `path`
    /// (default: the library file the agent was made with), atomically.
    #[pyo3(signature = (path = None))]
    fn save(&self, path: Option<PathBuf>) -> PyResult<()> {
        let Kind::Transfer(transfer) = &self.kind else {
            return Err(PyValueError::new_err(
                "only TES and LWT keep a view library",
            ));
        };
        let Some(path) = path.or_else(|| transfer.path.clone()) else {
            return Err(PyValueError::new_err(
                "no library path: give one here or as library= when making the agent",
            ));
        };
        let stored = transfer.stored(transfer.agent()?.library().clone());
        store::save(&path, &stored).map_err(library_error)
    }

    /// TES and LWT: how many views the library holds, and how many tasks it has seen.
    fn library_size(&self) -> PyResult<(usize, u32)> {
        let Kind::Transfer(transfer) = &self.kind else {
            return Err(PyValueError::new_err(
                "only TES and LWT keep a view library",
            ));
        };
        let library = transfer.agent()?.library();
        Ok((library.len(), library.tasks_seen()))
    }
}

impl Agent {
    fn of(kind: Kind, structure: &Structure) -> Self {
        Self {
            kind,
            structure: structure.cmdp.clone(),
        }
    }

    fn agent_mut(&mut self) -> PyResult<&mut (dyn tes_learning::agents::Agent + Send)> {
        Ok(match &mut self.kind {
            Kind::LoreRl(a) => a,
            Kind::Counting(a) => a,
            Kind::Transfer(t) => t.agent_mut()?,
        })
    }

    fn check_state(&self, state: usize) -> PyResult<()> {
        if state < self.structure.n_states() {
            Ok(())
        } else {
            Err(agent_error(AgentError::UnknownState {
                state,
                states: self.structure.n_states(),
            }))
        }
    }

    /// Re-plans until the values hold still, then reads the policy.
    fn converged_policy(&mut self) -> PyResult<Vec<i64>> {
        let plan = |model: &mut PlannedModel| {
            for _ in 0..MAX_REPLANS {
                if model.replan().is_none() {
                    break;
                }
            }
        };
        let policy = match &mut self.kind {
            Kind::LoreRl(a) => {
                plan(a.model_mut());
                a.planner().policy()
            }
            Kind::Counting(a) => {
                for _ in 0..MAX_REPLANS {
                    let before = a.planner().values().to_vec();
                    a.replan();
                    if a.planner().values() == before.as_slice() {
                        break;
                    }
                }
                a.planner().policy()
            }
            Kind::Transfer(t) => {
                let agent = t.agent_mut()?;
                plan(agent.model_mut());
                agent.planner().policy()
            }
        };
        Ok(policy.iter().map(|&a| i64::from(a)).collect())
    }
}

/// Planner settings with the paper's tolerance and sweep limit and this discount.
fn planner(gamma: f64) -> PlannerParams {
    PlannerParams {
        gamma,
        ..PlannerParams::default()
    }
}

fn agent_error(e: AgentError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

fn library_error(e: StoreError) -> PyErr {
    match e.problem {
        StoreProblem::Io(_) => pyo3::exceptions::PyOSError::new_err(e.to_string()),
        _ => LibraryFileError::new_err(e.to_string()),
    }
}
