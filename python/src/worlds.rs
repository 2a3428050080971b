//! `tes._tes.GridWorld` and `tes._tes.ArenaWorld`: the perception-sim crate's worlds — the
//! paper's §5.1 grid tasks and §5.2 robot arenas — with their seeded random source, stepped
//! from Python. The Gymnasium environments (`tes.envs`) are thin over these.

use std::sync::Arc;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tes_learning::agents::Contexts;
use tes_perception_sim::arena::{
    self, Arena, ArenaId, Episode, EpisodeStatus, MarkColour, Pose, StateAttributes,
};
use tes_perception_sim::grid::{Dir, GridSuite, GridTask, STAY};
use tes_perception_sim::structure::{self as world_structure, ArenaFeatures};

use crate::structure::Structure;

/// One step of a world: `(next_state, effect, reward, terminal)`.
type Step = (usize, usize, f64, bool);

/// A grid task of the paper's §5.1 suite, with its start and dynamics drawn from a seeded
/// source.
#[pyclass(module = "tes._tes", name = "GridWorld")]
#[derive(Clone)]
pub struct GridWorld {
    task: GridTask,
    rng: ChaCha8Rng,
    state: usize,
    /// What it was made with: `(task, irrelevant, world_seed)`.
    made: (usize, usize, u64),
    /// Whether the episode has ended (a terminal state was entered).
    over: bool,
}

#[pymethods]
impl GridWorld {
    /// Task `task` (0–14) of the suite with `irrelevant` irrelevant features, its layout drawn
    /// from `world_seed` exactly as `tes experiment grid` draws the suite from its world seed.
    #[new]
    #[pyo3(signature = (task = 0, irrelevant = 200, world_seed = 0))]
    fn new(task: usize, irrelevant: usize, world_seed: u64) -> PyResult<Self> {
        let task_id = task;
        if task >= GridSuite::TASKS {
            return Err(PyValueError::new_err(format!(
                "task must be 0 to {}, not {task}",
                GridSuite::TASKS - 1
            )));
        }
        let seed = world_seed.wrapping_mul(1_000_003).wrapping_add(task as u64);
        let task = GridTask::generate(GridSuite::params(task, irrelevant), seed)
            .map_err(|e| PyValueError::new_err(format!("grid task: {e}")))?;
        let made = (task_id, irrelevant, world_seed);
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let state = task.random_start(&mut rng);
        Ok(Self {
            task,
            rng,
            state,
            made,
            over: false,
        })
    }

    /// Starts an episode in a random start cell, drawn from `seed` if given (then every later
    /// step's dynamics follow from it), and returns the state.
    #[pyo3(signature = (seed = None))]
    fn reset(&mut self, seed: Option<u64>) -> usize {
        if let Some(seed) = seed {
            self.rng = ChaCha8Rng::seed_from_u64(seed);
        }
        self.state = self.task.random_start(&mut self.rng);
        self.over = false;
        self.state
    }

    /// Takes `action` (0 N, 1 E, 2 S, 3 W) under the true dynamics:
    /// `(next_state, effect, reward, terminal)`.
    fn step(&mut self, action: usize) -> PyResult<Step> {
        if self.over {
            return Err(PyValueError::new_err(
                "the episode is over; reset() starts the next",
            ));
        }
        if action >= self.task.n_actions() {
            return Err(PyValueError::new_err(format!(
                "action must be 0 to {}, not {action}",
                self.task.n_actions() - 1
            )));
        }
        let outcome = self.task.step(self.state, action, &mut self.rng);
        self.state = outcome.next_state;
        self.over = outcome.terminal;
        Ok((
            outcome.next_state,
            outcome.effect,
            outcome.reward,
            outcome.terminal,
        ))
    }

    /// The current state (`y · width + x`).
    #[getter]
    fn state(&self) -> usize {
        self.state
    }

    /// Whether the episode has ended: `step` refuses until `reset`.
    #[getter]
    fn over(&self) -> bool {
        self.over
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    /// Pickles as what it was made with, its random source's exact position and its state.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, SavedGrid)> {
        let restore = py.import("tes._tes")?.getattr("_restore_grid_world")?;
        Ok((
            restore,
            (self.made, save_rng(&self.rng), self.state, self.over),
        ))
    }

    /// Columns.
    #[getter]
    fn width(&self) -> usize {
        self.task.width()
    }

    /// Rows (row 0 is the north edge).
    #[getter]
    fn height(&self) -> usize {
        self.task.height()
    }

    /// Number of states (cells).
    #[getter]
    fn n_states(&self) -> usize {
        self.task.n_states()
    }

    /// Number of binary features (10 relevant + the irrelevant ones).
    #[getter]
    fn n_features(&self) -> usize {
        self.task.n_features()
    }

    /// Actions after which an unfinished episode is cut off.
    #[getter]
    fn step_cap(&self) -> usize {
        self.task.step_cap()
    }

    /// The indices of the binary features on in `state`, sorted (uint32).
    fn features<'py>(&self, py: Python<'py>, state: usize) -> PyResult<Bound<'py, PyArray1<u32>>> {
        self.check(state)?;
        Ok(self.task.features(state).to_vec().into_pyarray(py))
    }

    /// The effect that leads from `state` to `next_state`: the direction moved (0 N, 1 E, 2 S,
    /// 3 W) or 4, stayed (the true dynamics never move through a wall, so the two states
    /// decide it).
    fn effect_between(&self, state: usize, next_state: usize) -> PyResult<usize> {
        self.check(state)?;
        self.check(next_state)?;
        if state == next_state {
            return Ok(STAY);
        }
        (0..STAY)
            .find(|&e| self.task.apply_effect(state, e) == next_state)
            .ok_or_else(|| {
                PyValueError::new_err(format!(
                    "no effect leads from state {state} to state {next_state}"
                ))
            })
    }

    /// Feature `i`'s name ("bias", "surface=water", "wall=N", "irrelevant17").
    fn feature_name(&self, i: usize) -> String {
        self.task.feature_name(i)
    }

    /// The agent-known structure, with the true dynamics' contexts (surface × walls) as the
    /// factors `FEpsG` counts by.
    fn structure(&self) -> PyResult<Structure> {
        let task = &self.task;
        let cmdp = world_structure::grid(task)
            .map_err(|e| PyValueError::new_err(format!("grid structure: {e}")))?;
        let (of_state, n_contexts) = world_structure::grid_contexts(task);
        let contexts = Contexts::new(of_state.clone(), n_contexts)
            .ok_or_else(|| PyValueError::new_err("grid contexts out of range"))?;
        Ok(Structure {
            cmdp: Arc::new(cmdp),
            contexts,
            factors: Some((of_state, n_contexts)),
        })
    }

    /// The picture's data: each cell's surface index (sand, soil, water, brick, fire) as a
    /// `(height, width)` array, its walls as `(height, width, 4)` bools (N, E, S, W), and its
    /// exits as `(height, width)` bools.
    #[allow(clippy::type_complexity)]
    fn layout<'py>(
        &self,
        py: Python<'py>,
    ) -> (
        Bound<'py, PyArray2<u8>>,
        Bound<'py, PyArray3<bool>>,
        Bound<'py, PyArray2<bool>>,
    ) {
        let (w, h) = (self.task.width(), self.task.height());
        let surfaces = numpy::ndarray::Array2::from_shape_fn((h, w), |(y, x)| {
            self.task.surface(y * w + x).index() as u8
        });
        let walls = numpy::ndarray::Array3::from_shape_fn((h, w, 4), |(y, x, d)| {
            Dir::from_index(d).is_some_and(|d| self.task.has_wall(y * w + x, d))
        });
        let exits =
            numpy::ndarray::Array2::from_shape_fn((h, w), |(y, x)| self.task.is_exit(y * w + x));
        (
            surfaces.into_pyarray(py),
            walls.into_pyarray(py),
            exits.into_pyarray(py),
        )
    }
}

impl GridWorld {
    fn check(&self, state: usize) -> PyResult<()> {
        check_state(state, self.task.n_states())
    }
}

/// A robot arena of the paper's §5.2 (Env 1–3): the robot's continuous pose, its wheel slip,
/// the camera's 312 features and the episode rules (terminal states, stuck for 4 actions).
#[pyclass(module = "tes._tes", name = "ArenaWorld")]
#[derive(Clone)]
pub struct ArenaWorld {
    arena: Arena,
    rng: ChaCha8Rng,
    pose: Pose,
    episode: Episode,
    /// The arena's number (1–3).
    number: u32,
    /// The random source as the episode started, and the actions since: the episode's state
    /// replayed from them (what a pickle carries).
    at_reset: ChaCha8Rng,
    actions: Vec<u8>,
}

#[pymethods]
impl ArenaWorld {
    /// Arena `arena` (1, 2 or 3).
    #[new]
    #[pyo3(signature = (arena = 1))]
    fn new(arena: u32) -> PyResult<Self> {
        let arena_number = arena;
        let id = ArenaId::from_number(arena).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let arena = Arena::new(id);
        let at_reset = ChaCha8Rng::seed_from_u64(0);
        let mut rng = at_reset.clone();
        let pose = arena.random_start(&mut rng);
        let episode = Episode::new(&arena, arena.discretise(pose))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(Self {
            arena,
            rng,
            pose,
            episode,
            number: arena_number,
            at_reset,
            actions: Vec::new(),
        })
    }

    /// Puts the robot at a random start pose, drawn from `seed` if given (then every later
    /// step's motor noise and slip follow from it), and returns the state.
    #[pyo3(signature = (seed = None))]
    fn reset(&mut self, seed: Option<u64>) -> PyResult<usize> {
        if let Some(seed) = seed {
            self.rng = ChaCha8Rng::seed_from_u64(seed);
        }
        self.at_reset = self.rng.clone();
        self.actions.clear();
        self.pose = self.arena.random_start(&mut self.rng);
        self.episode = Episode::new(&self.arena, self.arena.discretise(self.pose))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(self.episode.state())
    }

    /// Takes `action` (0 forward, 1 spin, 2 pivot): `(next_state, effect, reward, terminal)`;
    /// then `stuck` says whether the episode ended by the stuck rule instead.
    fn step(&mut self, action: usize) -> PyResult<Step> {
        if self.episode.is_over() {
            return Err(PyValueError::new_err(
                "the episode is over; reset() starts the next",
            ));
        }
        let before = self.episode.state();
        let outcome = self
            .arena
            .step(self.pose, action, &mut self.rng)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let step = self
            .episode
            .observe(&self.arena, outcome.state)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        self.pose = outcome.pose;
        // An action below 3: the arena refused any other above.
        self.actions.push(action as u8);
        let effect = self.arena.effect_between(before, outcome.state);
        Ok((
            outcome.state,
            effect,
            step.reward,
            step.status == EpisodeStatus::Terminal,
        ))
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    /// Pickles as its arena, its random source as the episode started and the episode's
    /// actions, which `tes._tes._restore_arena_world` replays (the same pose and episode to
    /// the bit: every step is a function of them).
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, SavedArena)> {
        let restore = py.import("tes._tes")?.getattr("_restore_arena_world")?;
        Ok((
            restore,
            (self.number, save_rng(&self.at_reset), self.actions.clone()),
        ))
    }

    /// Whether the episode is over (a terminal state, or stuck): `step` refuses until `reset`.
    #[getter]
    fn over(&self) -> bool {
        self.episode.is_over()
    }

    /// Whether the episode ended because the robot was stuck for 4 actions.
    #[getter]
    fn stuck(&self) -> bool {
        self.episode.status() == EpisodeStatus::Stuck
    }

    /// The current state.
    #[getter]
    fn state(&self) -> usize {
        self.episode.state()
    }

    /// The robot's pose: `(x_cm, y_cm, heading_rad)` from the south-west corner, heading
    /// counter-clockwise from east.
    #[getter]
    fn pose(&self) -> (f64, f64, f64) {
        (
            self.pose.position.x,
            self.pose.position.y,
            self.pose.heading,
        )
    }

    /// Number of states (cells × 8 orientations, plus "out of the area").
    #[getter]
    fn n_states(&self) -> usize {
        self.arena.n_states()
    }

    /// Number of binary features (312).
    #[getter]
    fn n_features(&self) -> usize {
        self.arena.n_features()
    }

    /// Cells per side.
    #[getter]
    fn cells(&self) -> usize {
        self.arena.cells()
    }

    /// Side of the arena, cm.
    #[getter]
    fn side_cm(&self) -> f64 {
        self.arena.side_cm()
    }

    /// The state's attributes `(x, y, orientation)`; the out-of-area state is
    /// `(cells, cells, 0)`.
    fn attributes(&self, state: usize) -> PyResult<(usize, usize, usize)> {
        let a = self.arena.attributes(state).ok_or_else(|| {
            PyValueError::new_err(format!(
                "state {state} is out of range ({} states)",
                self.arena.n_states()
            ))
        })?;
        Ok(if a == StateAttributes::OUT {
            (self.arena.cells(), self.arena.cells(), 0)
        } else {
            (
                usize::from(a.x),
                usize::from(a.y),
                usize::from(a.orientation),
            )
        })
    }

    /// The indices of the binary features on in `state`, sorted (uint32).
    fn features<'py>(&self, py: Python<'py>, state: usize) -> PyResult<Bound<'py, PyArray1<u32>>> {
        check_state(state, self.arena.n_states())?;
        Ok(self.arena.features(state).to_vec().into_pyarray(py))
    }

    /// The effect (move × turn, 0–19) that best explains going from `state` to `next_state`:
    /// the arena's own rule, which the robot experiment and the controller use too.
    fn effect_between(&self, state: usize, next_state: usize) -> PyResult<usize> {
        check_state(state, self.arena.n_states())?;
        check_state(next_state, self.arena.n_states())?;
        Ok(self.arena.effect_between(state, next_state))
    }

    /// Effect `effect`'s name, e.g. "forward-left, 1 right".
    fn effect_name(&self, effect: usize) -> Option<String> {
        arena::Effect::from_index(effect).map(|e| e.to_string())
    }

    /// Feature `i`'s name.
    fn feature_name(&self, i: usize) -> Option<String> {
        arena::feature_name(i)
    }

    /// The agent-known structure (all 312 features), with the oracle's dynamics factors as
    /// the contexts `FEpsG` counts by.
    fn structure(&self) -> PyResult<Structure> {
        let a = &self.arena;
        let cmdp = world_structure::arena(a, ArenaFeatures::All)
            .map_err(|e| PyValueError::new_err(format!("arena structure: {e}")))?;
        // The out state has no oracle context: it gets one of its own.
        let out = a.n_oracle_contexts();
        let of_state: Vec<u32> = (0..a.n_states())
            .map(|s| a.oracle_context(s).unwrap_or(out) as u32)
            .collect();
        let contexts = Contexts::new(of_state.clone(), out + 1)
            .ok_or_else(|| PyValueError::new_err("arena contexts out of range"))?;
        Ok(Structure {
            cmdp: Arc::new(cmdp),
            contexts,
            factors: Some((of_state, out + 1)),
        })
    }

    /// The picture's data: `{"surfaces": (cells, cells) uint8 (carpet, board, beans, slope;
    /// row 0 is the south edge), "death": (cells, cells) bool, "ball": (x_cm, y_cm),
    /// "green": [(x_cm, y_cm)], "blue": [(x_cm, y_cm)]}`.
    fn layout<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let n = self.arena.cells();
        let surfaces =
            numpy::ndarray::Array2::from_shape_fn((n, n), |(y, x)| self.arena.surface(x, y) as u8);
        let death =
            numpy::ndarray::Array2::from_shape_fn((n, n), |(y, x)| self.arena.is_death_cell(x, y));
        let points = |colour| -> Vec<(f64, f64)> {
            self.arena
                .marks(colour)
                .iter()
                .map(|m| (m.x, m.y))
                .collect()
        };
        let layout = pyo3::types::PyDict::new(py);
        layout.set_item("surfaces", surfaces.into_pyarray(py))?;
        layout.set_item("death", death.into_pyarray(py))?;
        let ball = self.arena.ball();
        layout.set_item("ball", (ball.x, ball.y))?;
        layout.set_item("green", points(MarkColour::Green))?;
        layout.set_item("blue", points(MarkColour::Blue))?;
        Ok(layout)
    }
}

fn check_state(state: usize, n_states: usize) -> PyResult<()> {
    if state < n_states {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!(
            "state {state} is out of range ({n_states} states)"
        )))
    }
}

/// A ChaCha random source's exact position: its seed, stream and word position (as two
/// halves: Python pickles integers of any size, but the two halves keep the stub simple).
type SavedRng = (Vec<u8>, u64, (u64, u64));

/// A pickled grid world: `((task, irrelevant, world_seed), rng, state, over)`.
type SavedGrid = ((usize, usize, u64), SavedRng, usize, bool);

/// A pickled arena: `(arena, rng as the episode started, the episode's actions)`.
type SavedArena = (u32, SavedRng, Vec<u8>);

fn save_rng(rng: &ChaCha8Rng) -> SavedRng {
    let pos = rng.get_word_pos();
    (
        rng.get_seed().to_vec(),
        rng.get_stream(),
        ((pos >> 64) as u64, pos as u64),
    )
}

fn restore_rng((seed, stream, (high, low)): SavedRng) -> PyResult<ChaCha8Rng> {
    let seed: [u8; 32] = seed
        .try_into()
        .map_err(|_| PyValueError::new_err("a saved random source's seed is 32 bytes"))?;
    let mut rng = ChaCha8Rng::from_seed(seed);
    rng.set_stream(stream);
    rng.set_word_pos((u128::from(high) << 64) | u128::from(low));
    Ok(rng)
}

/// Makes a pickled `GridWorld` again (see `GridWorld.__reduce__`).
#[pyfunction]
pub fn _restore_grid_world(
    made: (usize, usize, u64),
    rng: SavedRng,
    state: usize,
    over: bool,
) -> PyResult<GridWorld> {
    let (task, irrelevant, world_seed) = made;
    let mut world = GridWorld::new(task, irrelevant, world_seed)?;
    world.check(state)?;
    world.rng = restore_rng(rng)?;
    world.state = state;
    world.over = over;
    Ok(world)
}

/// Makes a pickled `ArenaWorld` again (see `ArenaWorld.__reduce__`): the episode's start drawn
/// from the saved random source, then its actions replayed.
#[pyfunction]
pub fn _restore_arena_world(number: u32, rng: SavedRng, actions: Vec<u8>) -> PyResult<ArenaWorld> {
    let mut world = ArenaWorld::new(number)?;
    world.rng = restore_rng(rng)?;
    world.reset(None)?;
    for action in actions {
        world.step(usize::from(action))?;
    }
    Ok(world)
}
