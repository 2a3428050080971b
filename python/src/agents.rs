//! `tes._tes.Agent`: the learning crate's agents — loreRL, TES, LWT and factored ε-greedy — on
//! a [`Structure`], stepped in state and effect ids. The Python side (`tes.agents`) turns an
//! environment's observations into those ids through the structure protocol.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

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

// Named `tes.LibraryFileError`, as users import and see it (the native module is private).
pyo3::create_exception!(
    tes,
    LibraryFileError,
    pyo3::exceptions::PyValueError,
    "A view library file that cannot be read or written: corrupt, foreign, of another \
     environment's shape, or unwritable. The message names the file and the problem."
);

/// Re-plans this many times at most when a greedy policy is asked for; each re-plan runs up to
/// the planner's sweep limit and stops once the values hold still.
const MAX_REPLANS: usize = 10_000;

/// A transfer agent (TES or LWT) and what it needs to start the next task.
#[derive(Clone)]
struct Transfer {
    /// `None` only while a task is being finished.
    agent: Option<Tes>,
    structure: Arc<CmdpStructure>,
    params: TesParams,
    seed: u64,
    /// Where the library is kept, if anywhere.
    path: Option<PathBuf>,
    /// The library the agent started on (what a pickle carries, with the steps since).
    initial: ViewLibrary,
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
    fn end_task(&mut self, write: bool) -> PyResult<TaskSummary> {
        let agent = self.agent.take().ok_or_else(|| {
            PyRuntimeError::new_err("the agent failed while ending an earlier task")
        })?;
        let (library, report) = agent
            .finish_task()
            .map_err(|e| PyValueError::new_err(format!("ending the task: {e}")))?;
        let stored = self.stored(library);
        if let Some(path) = self.path.as_ref().filter(|_| write) {
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

#[derive(Clone)]
enum Kind {
    LoreRl(LoreRl),
    Counting(CountingAgent),
    Transfer(Box<Transfer>),
}

/// One call that changed an agent, as its log keeps it: the agent is its settings and these
/// calls, in order (all of them deterministic), which is what a pickle carries.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Step {
    Begin(u32),
    Act(u32),
    Observe(u32, u32, u32),
    EndTask,
}

impl Step {
    /// Four little-endian `u32`s: a tag, then the step's ids (zeros where it has fewer).
    fn encode(self, out: &mut Vec<u8>) {
        let words = match self {
            Step::Begin(s) => [0, s, 0, 0],
            Step::Act(s) => [1, s, 0, 0],
            Step::Observe(s, a, e) => [2, s, a, e],
            Step::EndTask => [3, 0, 0, 0],
        };
        words
            .iter()
            .for_each(|w| out.extend_from_slice(&w.to_le_bytes()));
    }

    fn decode(bytes: &[u8]) -> PyResult<Vec<Step>> {
        if !bytes.len().is_multiple_of(16) {
            return Err(PyValueError::new_err(
                "a saved agent's log is not a whole number of steps",
            ));
        }
        bytes
            .chunks_exact(16)
            .map(|chunk| {
                let (words, _) = chunk.as_chunks::<4>();
                let w: Vec<u32> = words.iter().map(|b| u32::from_le_bytes(*b)).collect();
                match w[0] {
                    0 => Ok(Step::Begin(w[1])),
                    1 => Ok(Step::Act(w[1])),
                    2 => Ok(Step::Observe(w[1], w[2], w[3])),
                    3 => Ok(Step::EndTask),
                    tag => Err(PyValueError::new_err(format!(
                        "a saved agent's log has a step of unknown kind {tag}"
                    ))),
                }
            })
            .collect()
    }
}

/// How an agent was made: its constructor's name and arguments, kept for pickling.
struct Made {
    constructor: &'static str,
    settings: Py<PyDict>,
}

/// The agent and its log, held together under one lock.
#[derive(Clone)]
struct Learning {
    kind: Kind,
    log: Vec<Step>,
}

/// An agent of the paper on a known structure, stepped in state, action and effect ids.
///
/// The native class behind `tes.agents.LoreRL`, `TES`, `LWT` and `FEpsG`; use those, which
/// read observations through the structure protocol. One object may be used from several
/// threads: each call holds the agent for its whole length, so calls take turns.
#[pyclass(module = "tes._tes", name = "Agent", frozen)]
pub struct Agent {
    learning: Mutex<Learning>,
    structure: Py<Structure>,
    cmdp: Arc<CmdpStructure>,
    made: Made,
}

#[pymethods]
impl Agent {
    /// loreRL (the paper's Algorithm 6): one mDAGL view per action, value iteration on the
    /// learned model, ε-greedy.
    #[staticmethod]
    #[pyo3(signature = (structure, lam = 0.05, alpha = 1.5, intercept = false, epsilon = 0.05, gamma = 0.95, seed = 0))]
    #[allow(clippy::too_many_arguments)]
    fn lore_rl(
        py: Python<'_>,
        structure: Bound<'_, Structure>,
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
        let cmdp = structure.get().cmdp.clone();
        let agent = LoreRl::new(cmdp, params, seed).map_err(agent_error)?;
        let settings = PyDict::new(py);
        settings.set_item("lam", lam)?;
        settings.set_item("alpha", alpha)?;
        settings.set_item("intercept", intercept)?;
        settings.set_item("epsilon", epsilon)?;
        settings.set_item("gamma", gamma)?;
        settings.set_item("seed", seed)?;
        Ok(Self::of(
            Kind::LoreRl(agent),
            structure,
            "lore_rl",
            settings,
        ))
    }

    /// Factored ε-greedy (the paper's fEpsG): effect counts per (context, action) — the
    /// contexts are the structure's factors — on the maximum-likelihood model.
    #[staticmethod]
    #[pyo3(signature = (structure, epsilon = 0.1, gamma = 0.95, seed = 0))]
    fn fepsg(
        py: Python<'_>,
        structure: Bound<'_, Structure>,
        epsilon: f64,
        gamma: f64,
        seed: u64,
    ) -> PyResult<Self> {
        let native = structure.get();
        let agent = CountingAgent::factored_epsilon_greedy(
            native.cmdp.clone(),
            native.contexts.clone(),
            epsilon,
            planner(gamma),
            seed,
        )
        .map_err(agent_error)?;
        let settings = PyDict::new(py);
        settings.set_item("epsilon", epsilon)?;
        settings.set_item("gamma", gamma)?;
        settings.set_item("seed", seed)?;
        Ok(Self::of(
            Kind::Counting(agent),
            structure,
            "fepsg",
            settings,
        ))
    }

    /// TES (`policy="tes"`, the paper's Algorithms 2–3) or LWT (`policy="lwt"`) on the view
    /// library at `library` — loaded if the file exists, refused with `LibraryFileError` if it
    /// is corrupt or of another shape — or on an empty library.
    #[staticmethod]
    #[pyo3(signature = (structure, library = None, policy = "tes", lam = 0.05, alpha = 1.5, intercept = false, epsilon = 0.05, gamma = 0.95, max_views = 20, seed = 0, world = String::new(), action_names = Vec::new(), feature_names = Vec::new()))]
    #[allow(clippy::too_many_arguments)]
    fn transfer(
        py: Python<'_>,
        structure: Bound<'_, Structure>,
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
        let cmdp = structure.get().cmdp.clone();
        let loaded = match &library {
            Some(path) if path.exists() => Some(
                store::load_for(path, cmdp.n_actions(), cmdp.n_effects(), cmdp.n_features())
                    .map_err(library_error)?,
            ),
            _ => None,
        };
        let settings = PyDict::new(py);
        settings.set_item("library", library.clone())?;
        settings.set_item("policy", policy)?;
        settings.set_item("lam", lam)?;
        settings.set_item("alpha", alpha)?;
        settings.set_item("intercept", intercept)?;
        settings.set_item("epsilon", epsilon)?;
        settings.set_item("gamma", gamma)?;
        settings.set_item("max_views", max_views)?;
        settings.set_item("seed", seed)?;
        settings.set_item("world", world.clone())?;
        settings.set_item("action_names", action_names.clone())?;
        settings.set_item("feature_names", feature_names.clone())?;
        let transfer = Transfer::start(
            &cmdp,
            loaded.map(|stored| stored.library),
            TransferSettings {
                policy,
                mdagl: MdaglParams {
                    lambda: lam,
                    alpha,
                    intercept,
                },
                epsilon,
                gamma,
                max_views,
                seed,
            },
            (library, world, action_names, feature_names),
        )?;
        Ok(Self::of(
            Kind::Transfer(Box::new(transfer)),
            structure,
            "transfer",
            settings,
        ))
    }

    /// The agent's short name ("loreRL", "TES", "LWT", "fEpsG").
    #[getter]
    fn name(&self, py: Python<'_>) -> PyResult<String> {
        self.with(py, |l| {
            Ok(match &l.kind {
                Kind::LoreRl(a) => a.name().to_owned(),
                Kind::Counting(a) => a.name().to_owned(),
                Kind::Transfer(t) => t.agent()?.name().to_owned(),
            })
        })
    }

    /// Steps the agent has taken and learned from since it was made (what its pickle replays).
    #[getter]
    fn steps_logged(&self, py: Python<'_>) -> PyResult<usize> {
        self.with(py, |l| Ok(l.log.len()))
    }

    /// Called when an episode starts in `state`.
    fn begin_episode(&self, py: Python<'_>, state: usize) -> PyResult<()> {
        self.check_state(state)?;
        let state = id(state)?;
        self.with(py, |l| l.apply(Step::Begin(state)).map(|_| ()))
    }

    /// The action to take in `state` (ε-greedy on the current plan).
    fn act(&self, py: Python<'_>, state: usize) -> PyResult<usize> {
        self.check_state(state)?;
        let state = id(state)?;
        self.with(py, |l| l.apply(Step::Act(state)))
    }

    /// Learns that `action` in `state` had `effect`.
    fn observe(&self, py: Python<'_>, state: usize, action: usize, effect: usize) -> PyResult<()> {
        let step = Step::Observe(id(state)?, id(action)?, id(effect)?);
        self.with(py, |l| l.apply(step).map(|_| ()))
    }

    /// For every state, the action the current model's plan takes, planned to convergence on
    /// a copy: asking changes nothing the agent does next.
    fn greedy_policy<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<i64>>> {
        let policy = self.with(py, |l| converged_policy(l.kind.clone()))?;
        Ok(policy.into_pyarray(py))
    }

    /// TES and LWT: ends the task — grows and prunes the library (TES; LWT's stays as it was),
    /// writes it to the library file if there is one, and goes on with a new task on the
    /// grown library. Returns what changed: `{"task", "added", "updated", "removed"}`.
    fn end_task<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let summary = self.with(py, |l| {
            l.transfer()?;
            let summary = l.end_task(true)?;
            l.log.push(Step::EndTask);
            Ok(summary)
        })?;
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
    fn save(&self, py: Python<'_>, path: Option<PathBuf>) -> PyResult<()> {
        self.with(py, |l| {
            let transfer = l.transfer()?;
            let Some(path) = path.or_else(|| transfer.path.clone()) else {
                return Err(PyValueError::new_err(
                    "no library path: give one here or as library= when making the agent",
                ));
            };
            let stored = transfer.stored(transfer.agent()?.library().clone());
            store::save(&path, &stored).map_err(library_error)
        })
    }

    /// TES and LWT: how many views the library holds, and how many tasks it has seen.
    fn library_size(&self, py: Python<'_>) -> PyResult<(usize, u32)> {
        self.with(py, |l| {
            let library = l.transfer()?.agent()?.library();
            Ok((library.len(), library.tasks_seen()))
        })
    }

    /// A copy with its own state: it acts and learns on exactly as this one would.
    fn __copy__(&self, py: Python<'_>) -> PyResult<Self> {
        let learning = self.with(py, |l| Ok(l.clone()))?;
        Ok(Self {
            learning: Mutex::new(learning),
            structure: self.structure.clone_ref(py),
            cmdp: self.cmdp.clone(),
            made: Made {
                constructor: self.made.constructor,
                settings: self.made.settings.clone_ref(py),
            },
        })
    }

    fn __deepcopy__(&self, py: Python<'_>, _memo: &Bound<'_, PyAny>) -> PyResult<Self> {
        self.__copy__(py)
    }

    /// Pickles as its structure, its settings, the library it started on (TES, LWT) and the
    /// log of its steps; `tes._tes._restore_agent` makes it again and replays the log, which
    /// gives the same agent to the bit (every step is deterministic) at the cost of learning
    /// those steps again.
    #[allow(clippy::type_complexity)]
    fn __reduce__<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<(
        Bound<'py, PyAny>,
        (
            Py<Structure>,
            &'static str,
            Py<PyDict>,
            Option<Vec<u8>>,
            Vec<u8>,
        ),
    )> {
        let (initial, log) = self.with(py, |l| {
            let initial = match &l.kind {
                Kind::Transfer(t) => Some(store::encode(&t.stored(t.initial.clone()))),
                _ => None,
            };
            let mut log = Vec::with_capacity(l.log.len() * 16);
            l.log.iter().for_each(|step| step.encode(&mut log));
            Ok((initial, log))
        })?;
        let restore = py.import("tes._tes")?.getattr("_restore_agent")?;
        Ok((
            restore,
            (
                self.structure.clone_ref(py),
                self.made.constructor,
                self.made.settings.clone_ref(py),
                initial,
                log,
            ),
        ))
    }
}

/// Makes a pickled agent again (see `Agent.__reduce__`): its constructor with its settings and
/// the library it started on, then its logged steps replayed (the library file is not written
/// while replaying).
#[pyfunction]
pub fn _restore_agent(
    py: Python<'_>,
    structure: Bound<'_, Structure>,
    constructor: &str,
    settings: Bound<'_, PyDict>,
    initial: Option<Vec<u8>>,
    log: Vec<u8>,
) -> PyResult<Agent> {
    let steps = Step::decode(&log)?;
    let agent = match (constructor, initial) {
        ("lore_rl" | "fepsg", None) => {
            let make = py.get_type::<Agent>().getattr(constructor)?;
            make.call((structure,), Some(&settings))?
                .cast_into::<Agent>()?
                .get()
                .__copy__(py)?
        }
        ("transfer", Some(bytes)) => restore_transfer(structure, &settings, &bytes)?,
        _ => {
            return Err(PyValueError::new_err(format!(
                "a saved agent of unknown kind {constructor:?}"
            )));
        }
    };
    agent.with(py, |l| {
        for &step in &steps {
            l.replay(step)?;
        }
        Ok(())
    })?;
    Ok(agent)
}

/// A TES or LWT agent on the library a pickle carried, with its saved settings.
fn restore_transfer(
    structure: Bound<'_, Structure>,
    settings: &Bound<'_, PyDict>,
    bytes: &[u8],
) -> PyResult<Agent> {
    let get = |key: &str| -> PyResult<Bound<'_, PyAny>> {
        settings
            .get_item(key)?
            .ok_or_else(|| PyValueError::new_err(format!("a saved agent has no {key}")))
    };
    let cmdp = structure.get().cmdp.clone();
    let stored = store::decode(bytes)
        .map_err(|e| LibraryFileError::new_err(format!("a pickled agent's library: {e}")))?;
    let (a, e, f) = (cmdp.n_actions(), cmdp.n_effects(), cmdp.n_features());
    let library = stored.library;
    if (
        library.n_actions(),
        library.n_effects(),
        library.n_features(),
    ) != (a, e, f)
    {
        return Err(LibraryFileError::new_err(
            "a pickled agent's library is of another shape than its structure",
        ));
    }
    let policy: String = get("policy")?.extract()?;
    let transfer = Transfer::start(
        &cmdp,
        Some(library),
        TransferSettings {
            policy: &policy,
            mdagl: MdaglParams {
                lambda: get("lam")?.extract()?,
                alpha: get("alpha")?.extract()?,
                intercept: get("intercept")?.extract()?,
            },
            epsilon: get("epsilon")?.extract()?,
            gamma: get("gamma")?.extract()?,
            max_views: get("max_views")?.extract()?,
            seed: get("seed")?.extract()?,
        },
        (
            get("library")?.extract()?,
            get("world")?.extract()?,
            get("action_names")?.extract()?,
            get("feature_names")?.extract()?,
        ),
    )?;
    Ok(Agent::of(
        Kind::Transfer(Box::new(transfer)),
        structure,
        "transfer",
        settings.copy()?,
    ))
}

/// What a TES or LWT agent is made with, beside its structure and library.
struct TransferSettings<'a> {
    policy: &'a str,
    mdagl: MdaglParams,
    epsilon: f64,
    gamma: f64,
    max_views: usize,
    seed: u64,
}

/// Where a TES or LWT library lives and what it names: `(path, world, action names, feature
/// names)`.
type LibraryNames = (Option<PathBuf>, String, Vec<String>, Vec<String>);

impl Transfer {
    /// A TES or LWT agent on `library`, or on an empty library of the settings' shape.
    fn start(
        cmdp: &Arc<CmdpStructure>,
        library: Option<ViewLibrary>,
        settings: TransferSettings<'_>,
        (path, world, action_names, feature_names): LibraryNames,
    ) -> PyResult<Self> {
        let policy = match settings.policy {
            "tes" => ViewPolicy::Tes,
            "lwt" => ViewPolicy::Lwt,
            other => {
                return Err(PyValueError::new_err(format!(
                    "policy must be \"tes\" or \"lwt\", not {other:?}"
                )));
            }
        };
        let params = LibraryParams {
            max_views: settings.max_views,
            mdagl: settings.mdagl,
            ..LibraryParams::default()
        };
        let views = match library {
            Some(library) => library,
            None => ViewLibrary::new(
                cmdp.n_actions(),
                cmdp.n_effects(),
                cmdp.n_features(),
                params,
            )
            .map_err(|e| PyValueError::new_err(format!("library settings: {e}")))?,
        };
        let tes_params = TesParams {
            planner: planner(settings.gamma),
            epsilon: settings.epsilon,
            policy,
        };
        let agent = Tes::new(cmdp.clone(), views.clone(), tes_params, settings.seed)
            .map_err(agent_error)?;
        Ok(Transfer {
            agent: Some(agent),
            structure: cmdp.clone(),
            params: tes_params,
            seed: settings.seed,
            path,
            initial: views,
            world,
            action_names,
            feature_names,
        })
    }
}

impl Learning {
    fn agent_mut(&mut self) -> PyResult<&mut (dyn tes_learning::agents::Agent + Send)> {
        Ok(match &mut self.kind {
            Kind::LoreRl(a) => a,
            Kind::Counting(a) => a,
            Kind::Transfer(t) => t.agent_mut()?,
        })
    }

    fn transfer(&self) -> PyResult<&Transfer> {
        match &self.kind {
            Kind::Transfer(t) => Ok(t),
            _ => Err(PyValueError::new_err(
                "only TES and LWT keep a view library",
            )),
        }
    }

    fn end_task(&mut self, write: bool) -> PyResult<TaskSummary> {
        match &mut self.kind {
            Kind::Transfer(t) => t.end_task(write),
            _ => Err(PyValueError::new_err(
                "only TES and LWT keep a view library",
            )),
        }
    }

    /// Takes one step and logs it when it succeeds (a refused step changes nothing). Returns
    /// the action for `Act`, else 0.
    fn apply(&mut self, step: Step) -> PyResult<usize> {
        let action = self.run(step, true)?;
        self.log.push(step);
        Ok(action)
    }

    /// Takes a logged step again, as it was taken (the library file is not written).
    fn replay(&mut self, step: Step) -> PyResult<()> {
        self.run(step, false)?;
        self.log.push(step);
        Ok(())
    }

    fn run(&mut self, step: Step, write: bool) -> PyResult<usize> {
        match step {
            Step::Begin(s) => {
                self.agent_mut()?.begin_episode(s as usize);
                Ok(0)
            }
            Step::Act(s) => self.agent_mut()?.act(s as usize).map_err(agent_error),
            Step::Observe(s, a, e) => self
                .agent_mut()?
                .observe(s as usize, a as usize, e as usize)
                .map(|_| 0)
                .map_err(agent_error),
            Step::EndTask => self.end_task(write).map(|_| 0),
        }
    }
}

impl Agent {
    fn of(
        kind: Kind,
        structure: Bound<'_, Structure>,
        constructor: &'static str,
        settings: Bound<'_, PyDict>,
    ) -> Self {
        Self {
            learning: Mutex::new(Learning {
                kind,
                log: Vec::new(),
            }),
            cmdp: structure.get().cmdp.clone(),
            structure: structure.unbind(),
            made: Made {
                constructor,
                settings: settings.unbind(),
            },
        }
    }

    /// Runs `f` on the agent with the GIL released, holding its lock; an agent whose earlier
    /// call panicked is refused.
    fn with<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut Learning) -> PyResult<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| {
            let mut learning = self.learning.lock().map_err(|_| {
                PyRuntimeError::new_err("the agent is unusable: an earlier call on it panicked")
            })?;
            f(&mut learning)
        })
    }

    fn check_state(&self, state: usize) -> PyResult<()> {
        if state < self.cmdp.n_states() {
            Ok(())
        } else {
            Err(agent_error(AgentError::UnknownState {
                state,
                states: self.cmdp.n_states(),
            }))
        }
    }
}

/// An id as the log keeps it.
fn id(value: usize) -> PyResult<u32> {
    u32::try_from(value).map_err(|_| PyValueError::new_err(format!("{value} is not a valid id")))
}

/// Plans `kind` — a copy of the agent — until its values hold still, then reads its policy.
fn converged_policy(mut kind: Kind) -> PyResult<Vec<i64>> {
    let plan = |model: &mut PlannedModel| {
        for _ in 0..MAX_REPLANS {
            if model.replan().is_none() {
                break;
            }
        }
    };
    let policy = match &mut kind {
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

#[cfg(test)]
mod tests {
    use super::Step;

    #[test]
    fn a_log_decodes_to_the_steps_it_encoded() {
        let steps = [
            Step::Begin(3),
            Step::Act(3),
            Step::Observe(3, 1, u32::MAX),
            Step::EndTask,
        ];
        let mut bytes = Vec::new();
        steps.iter().for_each(|s| s.encode(&mut bytes));
        assert_eq!(bytes.len(), 16 * steps.len());
        assert_eq!(Step::decode(&bytes).ok(), Some(steps.to_vec()));
        assert!(Step::decode(&bytes[..15]).is_err());
        let mut unknown = bytes.clone();
        unknown[0] = 9;
        assert!(Step::decode(&unknown).is_err());
    }
}
