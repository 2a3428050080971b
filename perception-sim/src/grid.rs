//! The grid tasks of the paper's §5.1: feature-rich navigation with surface-dependent dynamics.
//!
//! An agent moves on a grid of cells. Each cell has a surface — sand, soil, water, brick or
//! fire — and may have walls on any side (the border counts as walls). The agent has 4 actions
//! (move north, east, south, west) and each action has one of 5 *effects*: moved north, east,
//! south, west, or stayed. Which effect happens is drawn from the task's true dynamics, a
//! multinomial logistic model per action over the cell's surface and walls; a move through a
//! wall has probability 0 and its mass is spread evenly over the effects that remain possible.
//! Entering fire costs −1 and ends the episode, entering an exit earns +1 and ends it, every
//! other action costs −0.01. Episodes start in a uniformly random non-terminal cell.
//!
//! The agent sees each cell through binary features (see [`GridTask::features`]): a bias, the
//! surface (one-hot), the four wall indicators — the only features the dynamics depend on — and
//! `N` irrelevant random coin flips per cell (200 in the paper), which a good learner ignores.
//!
//! # What the paper fixes and what is ours
//!
//! The paper gives the shape (15 tasks, 20×20 to 30×30, the surfaces, walls, 200 irrelevant
//! features, 4 moves and 5 effects, three sets of logistic dynamics, the rewards, zeroed
//! through-wall moves, random starts) but not the weights, layouts or exits. Those are our
//! reconstruction: surfaces come in clustered patches (each cell takes the surface of the
//! nearest of 8–20 random patch centres, drawn from a task-specific surface mix), walls are
//! random interior edges (6–14 % of them), fire covers a few percent of cells, 1–3 exits; every
//! non-terminal cell can reach an exit without crossing fire (checked by breadth-first search
//! and repaired by opening walls). The three dynamics sets ([`DYNAMICS_SETS`]) are hand-chosen
//! logistic weights that differ in which surfaces are fast, slippery or sticky and in how
//! walls beside or ahead of the mover shift the odds; the intended move is usually the most
//! likely effect. The step cap ([`GridTask::step_cap`]) is ours too.
//!
//! # Mapping to the paper's §5.1
//!
//! | paper | here |
//! |---|---|
//! | 15 tasks, 20×20 to 30×30 | [`GridSuite::paper`]; task 0 is the 900-state world of Fig. 3 |
//! | sand, soil, water, brick, fire; walls between cells | [`Surface`], [`GridTask::has_wall`] |
//! | 4 moves, 5 effects | actions and effects 0..4 = N, E, S, W ([`Dir`]); effect 4 = [`STAY`] |
//! | three sets of multinomial logistic models | [`DYNAMICS_SETS`], [`DynamicsSet::weights`] (`W_a`, 5×10) |
//! | through-wall probability 0, mass spread evenly | [`GridTask::true_effect_probs`] |
//! | −0.01 per action, −1 fire, +1 exit (terminal) | [`GridTask::reward`], [`GridTask::is_terminal`] |
//! | random start each episode | [`GridTask::random_start`] |
//! | 200 irrelevant binary features (210 in all) | [`GridTask::features`], `n_irrelevant` |
//! | oracle DBN structure for factored Rmax | [`GridTask::oracle_context`], [`GridTask::relevant_features`] |
//!
//! ```
//! use rand::SeedableRng;
//! use tes_perception_sim::grid::{GridSuite, Surface};
//!
//! let tasks = GridSuite::paper(2017, 200);
//! assert_eq!(tasks.len(), 15);
//! let task = &tasks[0];
//! assert_eq!(task.n_states(), 900);
//! assert_eq!(task.n_features(), 210);
//! let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
//! let s = task.random_start(&mut rng);
//! let p = task.true_effect_probs(s, 0);
//! assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
//! let out = task.step(s, 0, &mut rng);
//! assert_eq!(out.next_state, task.apply_effect(s, out.effect));
//! assert_ne!(task.surface(s), Surface::Fire);
//! ```

use std::collections::VecDeque;
use std::fmt;

use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

/// Number of actions: move north, east, south, west.
pub const N_ACTIONS: usize = 4;
/// Number of effects: moved north, east, south, west, stayed.
pub const N_EFFECTS: usize = 5;
/// The "stayed" effect.
pub const STAY: usize = 4;
/// Features the true dynamics use: bias, 5 surface indicators, 4 wall indicators.
pub const N_RELEVANT_FEATURES: usize = 10;
/// Reward for an ordinary action.
pub const STEP_REWARD: f64 = -0.01;
/// Reward for entering fire (terminal).
pub const FIRE_REWARD: f64 = -1.0;
/// Reward for entering an exit (terminal).
pub const EXIT_REWARD: f64 = 1.0;

/// A cell's surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Surface {
    /// Sand (fast in sets 0 and 2, sticky in set 1; see [`DYNAMICS_SETS`]).
    Sand,
    /// Soil (fast in sets 1 and 2, mildly noisy in set 0).
    Soil,
    /// Water (slippery in sets 0 and 1, drifts backwards in set 2).
    Water,
    /// Brick (sticky in set 0, fast in set 1, drifts backwards and sticks in set 2).
    Brick,
    /// Fire: entering it costs −1 and ends the episode.
    Fire,
}

impl Surface {
    /// All surfaces, in feature order.
    pub const ALL: [Surface; 5] = [
        Surface::Sand,
        Surface::Soil,
        Surface::Water,
        Surface::Brick,
        Surface::Fire,
    ];

    /// Index 0..5 (the surface feature is `1 + index`).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Surface::Sand => "sand",
            Surface::Soil => "soil",
            Surface::Water => "water",
            Surface::Brick => "brick",
            Surface::Fire => "fire",
        }
    }

    fn letter(self) -> char {
        match self {
            Surface::Sand => '.',
            Surface::Soil => ':',
            Surface::Water => '~',
            Surface::Brick => '#',
            Surface::Fire => 'F',
        }
    }
}

/// A compass direction; also the action "move that way" and the effect "moved that way".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dir {
    /// Up on the map (towards row 0).
    North = 0,
    /// Right.
    East = 1,
    /// Down.
    South = 2,
    /// Left.
    West = 3,
}

impl Dir {
    /// All directions, in action/effect order.
    pub const ALL: [Dir; 4] = [Dir::North, Dir::East, Dir::South, Dir::West];

    /// The direction of action or effect id `i` (< 4).
    pub fn from_index(i: usize) -> Option<Dir> {
        Dir::ALL.get(i).copied()
    }

    fn opposite(self) -> Dir {
        Dir::ALL[(self as usize + 2) % 4]
    }

    fn bit(self) -> u8 {
        1 << (self as u8)
    }
}

/// Logistic weights of one dynamics set, per surface: the score of each effect relative to
/// the intended direction of the move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceDynamics {
    /// Moving the intended way.
    pub intended: f64,
    /// Sliding to either side.
    pub sideways: f64,
    /// Going backwards.
    pub backwards: f64,
    /// Not moving.
    pub stay: f64,
}

/// One of the three sets of true dynamics: weights per surface and the effect of walls.
///
/// A set is a compact way of writing, for each action `a`, the 5×10 weight matrix `W_a` of a
/// multinomial logistic model over the relevant features φ = (bias, surface one-hot, wall
/// bits N/E/S/W): see [`DynamicsSet::weights`]. The weights are written relative to the
/// action's direction so that the four moves behave alike up to rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynamicsSet {
    /// Per surface, in [`Surface::ALL`] order.
    pub surfaces: [SurfaceDynamics; 5],
    /// Added to "stay" for each wall beside the mover (perpendicular to the move).
    pub wall_beside_stay: f64,
    /// Added to "sideways" towards an open side when a wall is straight ahead.
    pub wall_ahead_sideways: f64,
}

impl DynamicsSet {
    /// The weight matrix `W_a` of `action` (< 4): row `e` holds the logit weights of effect
    /// `e` over the relevant features (column `j` = feature `j`, see [`GridTask::features`]),
    /// so the unmasked true dynamics are `softmax(W_a · φ)`. The bias and fire columns are 0
    /// (fire is terminal, so its dynamics never matter).
    pub fn weights(&self, action: usize) -> [[f64; N_RELEVANT_FEATURES]; N_EFFECTS] {
        let mut w = [[0.0; N_RELEVANT_FEATURES]; N_EFFECTS];
        let a = action % N_ACTIONS;
        let (left, right, back) = ((a + 3) % 4, (a + 1) % 4, (a + 2) % 4);
        for (k, sd) in self.surfaces.iter().enumerate() {
            let col = 1 + k;
            w[a][col] = sd.intended;
            w[left][col] = sd.sideways;
            w[right][col] = sd.sideways;
            w[back][col] = sd.backwards;
            w[STAY][col] = sd.stay;
        }
        // Walls beside the mover (perpendicular to the move) make it stay more often.
        w[STAY][6 + left] += self.wall_beside_stay;
        w[STAY][6 + right] += self.wall_beside_stay;
        // A wall straight ahead deflects the mover sideways.
        w[left][6 + a] += self.wall_ahead_sideways;
        w[right][6 + a] += self.wall_ahead_sideways;
        w
    }
}

const fn sd(intended: f64, sideways: f64, backwards: f64, stay: f64) -> SurfaceDynamics {
    SurfaceDynamics {
        intended,
        sideways,
        backwards,
        stay,
    }
}

/// The three dynamics sets. Scores are logits relative to each other (softmax over effects).
///
/// On an open cell (no walls) they give, as P(intended, each side, backwards, stay):
///
/// | set | sand | soil | water | brick |
/// |---|---|---|---|---|
/// | 0 | .81 .05 .01 .07 | .49 .15 .07 .15 | .36 .25 .08 .06 | .45 .07 .03 .39 |
/// | 1 | .44 .09 .03 .35 | .83 .05 .02 .05 | .22 .31 .10 .05 | .70 .09 .02 .09 |
/// | 2 | .49 .15 .07 .15 | .81 .05 .01 .07 | .35 .14 .26 .11 | .36 .12 .18 .22 |
///
/// The intended move is the most likely effect everywhere but on water in set 1, where the
/// agent slides sideways more often than it goes where it meant to.
pub const DYNAMICS_SETS: [DynamicsSet; 3] = [
    // Set 0: sand fast, soil noisy, water slippery, brick sticky; walls beside slow you.
    DynamicsSet {
        surfaces: [
            sd(3.0, 0.3, -1.0, 0.5),
            sd(2.0, 0.8, 0.0, 0.8),
            sd(1.5, 1.15, 0.0, -0.3),
            sd(1.6, -0.3, -1.0, 1.45),
            sd(0.0, 0.0, 0.0, 0.0),
        ],
        wall_beside_stay: 0.4,
        wall_ahead_sideways: 0.0,
    },
    // Set 1: sand sticky, soil fast, water very slippery, brick fast; walls ahead deflect.
    DynamicsSet {
        surfaces: [
            sd(1.6, 0.0, -1.0, 1.35),
            sd(3.0, 0.2, -1.0, 0.2),
            sd(1.0, 1.35, 0.2, -0.5),
            sd(2.5, 0.5, -1.0, 0.5),
            sd(0.0, 0.0, 0.0, 0.0),
        ],
        wall_beside_stay: 0.0,
        wall_ahead_sideways: 0.8,
    },
    // Set 2: sand noisy, soil fast, water and brick drift backwards; both wall effects.
    DynamicsSet {
        surfaces: [
            sd(2.0, 0.8, 0.0, 0.8),
            sd(3.0, 0.3, -1.0, 0.5),
            sd(1.5, 0.6, 1.2, 0.3),
            sd(1.6, 0.5, 0.9, 1.1),
            sd(0.0, 0.0, 0.0, 0.0),
        ],
        wall_beside_stay: 0.8,
        wall_ahead_sideways: 0.4,
    },
];

/// Settings of one generated task, validated by [`GridTask::generate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridParams {
    /// Columns (2..=200).
    pub width: usize,
    /// Rows (2..=200).
    pub height: usize,
    /// Which of the [`DYNAMICS_SETS`] (0..3).
    pub dynamics_set: usize,
    /// Irrelevant random binary features per cell.
    pub n_irrelevant: usize,
    /// Probability that an interior edge between two cells is a wall, in [0, 0.5].
    pub wall_density: f64,
    /// Fraction of cells on fire, in [0, 0.3].
    pub fire_fraction: f64,
    /// Exit cells (≥ 1).
    pub exits: usize,
    /// Surface patches (≥ 1): more makes a finer mosaic.
    pub patches: usize,
    /// Relative frequency of sand, soil, water and brick among the patches (finite, ≥ 0,
    /// positive sum): how tasks differ in their surface distribution.
    pub surface_weights: [f64; 4],
}

impl Default for GridParams {
    /// A 20×20 task of dynamics set 0 with 200 irrelevant features.
    fn default() -> Self {
        Self {
            width: 20,
            height: 20,
            dynamics_set: 0,
            n_irrelevant: 200,
            wall_density: 0.1,
            fire_fraction: 0.03,
            exits: 2,
            patches: 12,
            surface_weights: [1.0; 4],
        }
    }
}

/// Why a task could not be built.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GridError {
    /// Width or height outside 2..=200.
    #[error("grid size {width}x{height} is outside 2x2..200x200")]
    BadSize {
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
    },
    /// No such dynamics set.
    #[error("dynamics set {0} does not exist (0, 1 or 2)")]
    BadDynamicsSet(usize),
    /// Wall density outside [0, 0.5].
    #[error("wall density must be in [0, 0.5], got {0}")]
    BadWallDensity(f64),
    /// Fire fraction outside [0, 0.3].
    #[error("fire fraction must be in [0, 0.3], got {0}")]
    BadFireFraction(f64),
    /// No exits, or more exits than a quarter of the cells.
    #[error("{exits} exits do not fit a {cells}-cell grid (1 to a quarter of the cells)")]
    BadExits {
        /// Requested exits.
        exits: usize,
        /// Cells.
        cells: usize,
    },
    /// No patches.
    #[error("a grid needs at least one surface patch")]
    NoPatches,
    /// Surface weights negative, not finite, or all zero.
    #[error("surface weights must be finite, non-negative and not all zero, got {0:?}")]
    BadSurfaceWeights([f64; 4]),
    /// A hand-drawn map is malformed.
    #[error("map: {0}")]
    BadMap(String),
}

/// What one action did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutcome {
    /// The effect that happened (0..5).
    pub effect: usize,
    /// The state it led to.
    pub next_state: usize,
    /// The reward for entering `next_state`.
    pub reward: f64,
    /// Whether `next_state` ends the episode.
    pub terminal: bool,
}

/// One grid task: layout, true dynamics and the features the agent sees.
#[derive(Debug, Clone, PartialEq)]
pub struct GridTask {
    width: usize,
    height: usize,
    dynamics_set: usize,
    dynamics: Dynamics,
    n_irrelevant: usize,
    surfaces: Vec<Surface>,
    /// Wall bits per cell ([`Dir::bit`]); borders included.
    walls: Vec<u8>,
    exit: Vec<bool>,
    starts: Vec<u32>,
    /// `probs[(s * 4 + a) * 5 + e]`.
    probs: Vec<f64>,
    /// Sparse features, CSR.
    offsets: Vec<usize>,
    indices: Vec<u32>,
}

impl GridTask {
    /// Generates a task from validated settings; the seed fixes layout and irrelevant features.
    ///
    /// The layout does not depend on `n_irrelevant`, so tasks that differ only in it share
    /// their map and dynamics.
    pub fn generate(params: GridParams, seed: u64) -> Result<Self, GridError> {
        let dynamics = Dynamics::paper(params.dynamics_set)
            .ok_or(GridError::BadDynamicsSet(params.dynamics_set))?;
        Self::generate_with(params, dynamics, seed)
    }

    /// [`GridTask::generate`] with dynamics of the caller's own (drawn at random for the
    /// lifelong benchmark, say); `params.dynamics_set` is then only the id
    /// [`GridTask::dynamics_set`] reports. The same seed gives the same layout and features
    /// whatever the dynamics.
    pub fn generate_with(
        params: GridParams,
        dynamics: Dynamics,
        seed: u64,
    ) -> Result<Self, GridError> {
        let sw_total = check_params(&params)?;
        let (w, h) = (params.width, params.height);
        // One generator for the layout, drawn from in this order: patches, fires, exits,
        // walls (the same seed must give the same world, bit for bit).
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut surfaces = draw_surfaces(&params, sw_total, &mut rng);
        let exit = draw_exits(params.exits, &surfaces, &mut rng);
        let mut walls = border_walls(w, h);
        draw_interior_walls(w, h, params.wall_density, &mut walls, &mut rng);
        repair_reachability(w, h, &mut surfaces, &mut walls, &exit);

        let mut features_rng = ChaCha8Rng::seed_from_u64(seed ^ 0x1EE1_E7A7_F00D_5EED);
        Ok(Self::assemble(
            w,
            h,
            (params.dynamics_set, dynamics),
            params.n_irrelevant,
            surfaces,
            walls,
            exit,
            &mut features_rng,
        ))
    }

    /// Builds a small task from an ASCII map, for tests and examples: one line per row, one
    /// character per cell — `.` sand, `:` soil, `~` water, `#` brick, `F` fire, `E` an exit
    /// (on sand). Only border walls (see [`GridTask::from_map_with_walls`] for more).
    /// Irrelevant features are drawn from `seed`. At least one exit is required; unlike
    /// [`GridTask::generate`], reachability is not enforced, so a test can build a trap.
    ///
    /// ```
    /// use tes_perception_sim::grid::{GridTask, Surface};
    ///
    /// let task = GridTask::from_map("..F\n.~.\nE..", 0, 0, 1)?;
    /// assert_eq!(task.surface(4), Surface::Water);
    /// assert!(task.is_exit(6) && task.is_terminal(2));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn from_map(
        map: &str,
        dynamics_set: usize,
        n_irrelevant: usize,
        seed: u64,
    ) -> Result<Self, GridError> {
        Self::from_map_with_walls(map, &[], dynamics_set, n_irrelevant, seed)
    }

    /// Like [`GridTask::from_map`], plus interior walls: each `(state, dir)` puts a wall on
    /// side `dir` of cell `state` (and the matching side of its neighbour). A wall on the
    /// border is already there; a state outside the map is an error.
    ///
    /// ```
    /// use tes_perception_sim::grid::{Dir, GridTask};
    ///
    /// let task = GridTask::from_map_with_walls("...\n...\n..E", &[(0, Dir::East)], 0, 0, 1)?;
    /// assert!(task.has_wall(0, Dir::East) && task.has_wall(1, Dir::West));
    /// assert_eq!(task.apply_effect(0, Dir::East as usize), 0);
    /// assert_eq!(task.true_effect_probs(0, 1)[Dir::East as usize], 0.0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn from_map_with_walls(
        map: &str,
        interior_walls: &[(usize, Dir)],
        dynamics_set: usize,
        n_irrelevant: usize,
        seed: u64,
    ) -> Result<Self, GridError> {
        let rows: Vec<&str> = map
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect();
        let h = rows.len();
        let w = rows.first().map_or(0, |r| r.chars().count());
        if !(2..=200).contains(&w) || !(2..=200).contains(&h) {
            return Err(GridError::BadSize {
                width: w,
                height: h,
            });
        }
        if dynamics_set >= DYNAMICS_SETS.len() {
            return Err(GridError::BadDynamicsSet(dynamics_set));
        }
        let mut surfaces = Vec::with_capacity(w * h);
        let mut exit = Vec::with_capacity(w * h);
        for (y, row) in rows.iter().enumerate() {
            if row.chars().count() != w {
                return Err(GridError::BadMap(format!(
                    "row {y} has {} cells, row 0 has {w}",
                    row.chars().count()
                )));
            }
            for c in row.chars() {
                let (s, e) = match c {
                    '.' => (Surface::Sand, false),
                    ':' => (Surface::Soil, false),
                    '~' => (Surface::Water, false),
                    '#' => (Surface::Brick, false),
                    'F' => (Surface::Fire, false),
                    'E' => (Surface::Sand, true),
                    other => {
                        return Err(GridError::BadMap(format!(
                            "unknown cell {other:?} in row {y}"
                        )));
                    }
                };
                surfaces.push(s);
                exit.push(e);
            }
        }
        if !exit.iter().any(|&e| e) {
            return Err(GridError::BadExits {
                exits: 0,
                cells: w * h,
            });
        }
        let mut walls = vec![0u8; w * h];
        for (s, wall) in walls.iter_mut().enumerate() {
            for d in Dir::ALL {
                if neighbour(w, h, s, d).is_none() {
                    *wall |= d.bit();
                }
            }
        }
        for &(s, d) in interior_walls {
            if s >= w * h {
                return Err(GridError::BadMap(format!(
                    "wall at state {s}, outside the {w}x{h} map"
                )));
            }
            walls[s] |= d.bit();
            if let Some(t) = neighbour(w, h, s, d) {
                walls[t] |= d.opposite().bit();
            }
        }
        let dynamics =
            Dynamics::paper(dynamics_set).ok_or(GridError::BadDynamicsSet(dynamics_set))?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        Ok(Self::assemble(
            w,
            h,
            (dynamics_set, dynamics),
            n_irrelevant,
            surfaces,
            walls,
            exit,
            &mut rng,
        ))
    }

    #[allow(clippy::too_many_arguments)]
    fn assemble(
        width: usize,
        height: usize,
        (dynamics_set, dynamics): (usize, Dynamics),
        n_irrelevant: usize,
        surfaces: Vec<Surface>,
        walls: Vec<u8>,
        exit: Vec<bool>,
        rng: &mut ChaCha8Rng,
    ) -> Self {
        let n = width * height;
        let mut offsets = Vec::with_capacity(n + 1);
        let mut indices = Vec::new();
        offsets.push(0);
        for s in 0..n {
            indices.push(0);
            indices.push(1 + surfaces[s].index() as u32);
            for d in Dir::ALL {
                if walls[s] & d.bit() != 0 {
                    indices.push(6 + d as u32);
                }
            }
            for i in 0..n_irrelevant {
                if rng.random::<f64>() < 0.5 {
                    indices.push((N_RELEVANT_FEATURES + i) as u32);
                }
            }
            offsets.push(indices.len());
        }
        let mut task = Self {
            width,
            height,
            dynamics_set,
            dynamics,
            n_irrelevant,
            starts: Vec::new(),
            probs: vec![0.0; n * N_ACTIONS * N_EFFECTS],
            surfaces,
            walls,
            exit,
            offsets,
            indices,
        };
        task.starts = (0..n)
            .filter(|&s| !task.is_terminal(s))
            .map(|s| s as u32)
            .collect();
        for s in 0..n {
            for a in 0..N_ACTIONS {
                let p = task.compute_probs(s, a);
                task.probs[(s * N_ACTIONS + a) * N_EFFECTS..][..N_EFFECTS].copy_from_slice(&p);
            }
        }
        task
    }

    /// The true `P(effect | state, action)` ([`Dynamics::unmasked`]: for the logistic sets
    /// `softmax(W_a · φ(s))` over the relevant features), with blocked moves zeroed and
    /// their mass spread evenly over the effects still possible.
    fn compute_probs(&self, s: usize, a: usize) -> [f64; N_EFFECTS] {
        let walls = self.walls[s];
        let mut p = self
            .dynamics
            .unmasked(self.features(s), self.surfaces[s], walls, a);
        let blocked: f64 = Dir::ALL
            .iter()
            .filter(|d| walls & d.bit() != 0)
            .map(|&d| std::mem::replace(&mut p[d as usize], 0.0))
            .sum();
        let open = N_EFFECTS - walls.count_ones() as usize;
        for e in 0..N_EFFECTS {
            let is_open = e == STAY || walls & Dir::ALL[e].bit() == 0;
            if is_open {
                p[e] += blocked / open as f64;
            }
        }
        p
    }

    /// Columns.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of states (cells): state `y * width + x`.
    pub fn n_states(&self) -> usize {
        self.width * self.height
    }

    /// Number of actions (4 moves).
    pub fn n_actions(&self) -> usize {
        N_ACTIONS
    }

    /// Number of effects (4 moves and "stayed").
    pub fn n_effects(&self) -> usize {
        N_EFFECTS
    }

    /// Which dynamics set the task uses: the paper's set, or the id given to
    /// [`GridTask::generate_with`].
    pub fn dynamics_set(&self) -> usize {
        self.dynamics_set
    }

    /// The task's true dynamics.
    pub fn dynamics(&self) -> &Dynamics {
        &self.dynamics
    }

    /// The surface of a cell.
    pub fn surface(&self, state: usize) -> Surface {
        self.surfaces[state]
    }

    /// Whether a wall (or the border) is on side `dir` of a cell.
    pub fn has_wall(&self, state: usize, dir: Dir) -> bool {
        self.walls[state] & dir.bit() != 0
    }

    /// Whether the cell is an exit.
    pub fn is_exit(&self, state: usize) -> bool {
        self.exit[state]
    }

    /// Whether entering the cell ends the episode (fire or exit).
    pub fn is_terminal(&self, state: usize) -> bool {
        self.exit[state] || self.surfaces[state] == Surface::Fire
    }

    /// The reward of a transition, determined by the cell entered: −1 for fire, +1 for an exit,
    /// −0.01 otherwise.
    pub fn reward(&self, next_state: usize) -> f64 {
        if self.surfaces[next_state] == Surface::Fire {
            FIRE_REWARD
        } else if self.exit[next_state] {
            EXIT_REWARD
        } else {
            STEP_REWARD
        }
    }

    /// Where `effect` takes the agent from `state`: the neighbour in that direction, or the
    /// same cell for "stayed" or when a wall or the border is in the way. This is the meaning
    /// of an effect, which the agent knows.
    pub fn apply_effect(&self, state: usize, effect: usize) -> usize {
        match Dir::from_index(effect) {
            Some(d) if self.walls[state] & d.bit() == 0 => {
                neighbour(self.width, self.height, state, d).unwrap_or(state)
            }
            _ => state,
        }
    }

    /// A uniformly random non-terminal start cell.
    pub fn random_start<R: Rng + ?Sized>(&self, rng: &mut R) -> usize {
        self.starts[rng.random_range(0..self.starts.len())] as usize
    }

    /// Actions after which an unfinished episode is cut off: 4·(width + height), enough to
    /// cross the grid several times, so a lost agent's episode still ends.
    pub fn step_cap(&self) -> usize {
        4 * (self.width + self.height)
    }

    /// The true effect distribution of `action` in `state`.
    pub fn true_effect_probs(&self, state: usize, action: usize) -> [f64; N_EFFECTS] {
        let mut p = [0.0; N_EFFECTS];
        p.copy_from_slice(&self.probs[(state * N_ACTIONS + action) * N_EFFECTS..][..N_EFFECTS]);
        p
    }

    /// Draws an effect of `action` in `state` from the true dynamics.
    pub fn sample_effect<R: Rng + ?Sized>(
        &self,
        state: usize,
        action: usize,
        rng: &mut R,
    ) -> usize {
        let p = &self.probs[(state * N_ACTIONS + action) * N_EFFECTS..][..N_EFFECTS];
        let u: f64 = rng.random();
        let mut acc = 0.0;
        for (e, &pe) in p.iter().enumerate() {
            acc += pe;
            if u < acc {
                return e;
            }
        }
        // Rounding left `acc` just below 1: take the last possible effect.
        p.iter().rposition(|&pe| pe > 0.0).unwrap_or(STAY)
    }

    /// Takes `action` in `state` under the true dynamics.
    pub fn step<R: Rng + ?Sized>(&self, state: usize, action: usize, rng: &mut R) -> StepOutcome {
        let effect = self.sample_effect(state, action, rng);
        let next_state = self.apply_effect(state, effect);
        StepOutcome {
            effect,
            next_state,
            reward: self.reward(next_state),
            terminal: self.is_terminal(next_state),
        }
    }

    /// Number of binary features: 10 relevant + the irrelevant ones.
    pub fn n_features(&self) -> usize {
        N_RELEVANT_FEATURES + self.n_irrelevant
    }

    /// The features on in a cell, sorted: 0 bias (always), `1 + surface`, `6 + d` for a wall
    /// on side `d` (N, E, S, W), and `10 + i` for each irrelevant feature `i` that is on.
    pub fn features(&self, state: usize) -> &[u32] {
        &self.indices[self.offsets[state]..self.offsets[state + 1]]
    }

    /// A readable name for feature `i`.
    pub fn feature_name(&self, i: usize) -> String {
        match i {
            0 => "bias".to_owned(),
            1..=5 => format!("surface={}", Surface::ALL[i - 1].name()),
            6..=9 => format!("wall={}", ["N", "E", "S", "W"][i - 6]),
            _ => format!("irrelevant{}", i - N_RELEVANT_FEATURES),
        }
    }

    /// The weight matrix `W_a` of the true dynamics for `action` (see
    /// [`DynamicsSet::weights`]); before wall masking, `P(e | s, a) = softmax(W_a · φ(s))`
    /// with φ the relevant features of `s`.
    /// `None` for dynamics that are not logistic.
    pub fn true_weights(&self, action: usize) -> Option<[[f64; N_RELEVANT_FEATURES]; N_EFFECTS]> {
        match &self.dynamics {
            Dynamics::Logistic(set) => Some(set.weights(action)),
            Dynamics::Table(_) => None,
        }
    }

    /// The features the true dynamics depend on (bias, surfaces, walls).
    pub fn relevant_features(&self) -> &'static [u32] {
        &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    }

    /// The true DBN context of a cell: `surface × 16 + wall bits`.
    pub fn oracle_context(&self, state: usize) -> usize {
        self.surfaces[state].index() * 16 + self.walls[state] as usize
    }

    /// Number of oracle contexts (5 surfaces × 16 wall patterns).
    pub fn n_oracle_contexts(&self) -> usize {
        80
    }
}

impl fmt::Display for GridTask {
    /// An ASCII map: surface letters (`.` sand, `:` soil, `~` water, `#` brick, `F` fire,
    /// `E` exit), `|` and `-` for interior walls.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let w = self.width;
        for y in 0..self.height {
            let mut cells = String::new();
            let mut below = String::new();
            for x in 0..w {
                let s = y * w + x;
                cells.push(if self.exit[s] {
                    'E'
                } else {
                    self.surfaces[s].letter()
                });
                if x + 1 < w {
                    cells.push(if self.has_wall(s, Dir::East) {
                        '|'
                    } else {
                        ' '
                    });
                }
                below.push(if y + 1 < self.height && self.has_wall(s, Dir::South) {
                    '-'
                } else {
                    ' '
                });
                below.push(' ');
            }
            writeln!(f, "{cells}")?;
            if y + 1 < self.height {
                writeln!(f, "{}", below.trim_end())?;
            }
        }
        Ok(())
    }
}

/// Checks `params` ([`GridTask::generate`]'s rules); returns the surface weights' sum.
fn check_params(params: &GridParams) -> Result<f64, GridError> {
    let (w, h) = (params.width, params.height);
    if !(2..=200).contains(&w) || !(2..=200).contains(&h) {
        return Err(GridError::BadSize {
            width: w,
            height: h,
        });
    }
    if !(0.0..=0.5).contains(&params.wall_density) {
        return Err(GridError::BadWallDensity(params.wall_density));
    }
    if !(0.0..=0.3).contains(&params.fire_fraction) {
        return Err(GridError::BadFireFraction(params.fire_fraction));
    }
    let n = w * h;
    if params.exits == 0 || params.exits > n / 4 {
        return Err(GridError::BadExits {
            exits: params.exits,
            cells: n,
        });
    }
    if params.patches == 0 {
        return Err(GridError::NoPatches);
    }
    let sw = params.surface_weights;
    let sw_total: f64 = sw.iter().sum();
    if sw.iter().any(|&v| !v.is_finite() || v < 0.0) || sw_total <= 0.0 || !sw_total.is_finite() {
        return Err(GridError::BadSurfaceWeights(sw));
    }
    Ok(sw_total)
}

/// Each cell's surface: that of its nearest patch centre (patches drawn by the surface
/// weights, whose sum is `sw_total`), then the fires.
fn draw_surfaces(params: &GridParams, sw_total: f64, rng: &mut ChaCha8Rng) -> Vec<Surface> {
    let (w, h) = (params.width, params.height);
    let n = w * h;
    let sw = params.surface_weights;
    let centres: Vec<(usize, usize, Surface)> = (0..params.patches)
        .map(|_| {
            let mut u = rng.random::<f64>() * sw_total;
            let mut k = sw.iter().rposition(|&v| v > 0.0).unwrap_or(0);
            for (i, &v) in sw.iter().enumerate() {
                if v > 0.0 && u < v {
                    k = i;
                    break;
                }
                u -= v;
            }
            let s = Surface::ALL[k];
            (rng.random_range(0..w), rng.random_range(0..h), s)
        })
        .collect();
    let mut surfaces: Vec<Surface> = (0..n)
        .map(|s| {
            let (x, y) = (s % w, s / w);
            centres
                .iter()
                .min_by_key(|(cx, cy, _)| x.abs_diff(*cx).pow(2) + y.abs_diff(*cy).pow(2))
                .map_or(Surface::Sand, |c| c.2)
        })
        .collect();
    let fires = ((n as f64) * params.fire_fraction).round() as usize;
    for _ in 0..fires {
        let s = rng.random_range(0..n);
        surfaces[s] = Surface::Fire;
    }
    surfaces
}

/// `exits` exit cells, drawn among the cells not on fire.
fn draw_exits(exits: usize, surfaces: &[Surface], rng: &mut ChaCha8Rng) -> Vec<bool> {
    let n = surfaces.len();
    let mut exit = vec![false; n];
    let mut placed = 0;
    while placed < exits {
        let s = rng.random_range(0..n);
        if surfaces[s] != Surface::Fire && !exit[s] {
            exit[s] = true;
            placed += 1;
        }
    }
    exit
}

/// The walls of a `w`×`h` grid's border, per cell ([`Dir::bit`]).
fn border_walls(w: usize, h: usize) -> Vec<u8> {
    let mut walls = vec![0u8; w * h];
    for (s, cell) in walls.iter_mut().enumerate() {
        let (x, y) = (s % w, s / w);
        if y == 0 {
            *cell |= Dir::North.bit();
        }
        if y == h - 1 {
            *cell |= Dir::South.bit();
        }
        if x == 0 {
            *cell |= Dir::West.bit();
        }
        if x == w - 1 {
            *cell |= Dir::East.bit();
        }
    }
    walls
}

/// Random interior walls: each edge between two cells (drawn cell by cell, east then south)
/// is a wall with probability `density`.
fn draw_interior_walls(w: usize, h: usize, density: f64, walls: &mut [u8], rng: &mut ChaCha8Rng) {
    for s in 0..w * h {
        for d in [Dir::East, Dir::South] {
            if let Some(t) = neighbour(w, h, s, d)
                && rng.random::<f64>() < density
            {
                walls[s] |= d.bit();
                walls[t] |= d.opposite().bit();
            }
        }
    }
}

fn neighbour(w: usize, h: usize, s: usize, d: Dir) -> Option<usize> {
    let (x, y) = (s % w, s / w);
    match d {
        Dir::North if y > 0 => Some(s - w),
        Dir::South if y + 1 < h => Some(s + w),
        Dir::West if x > 0 => Some(s - 1),
        Dir::East if x + 1 < w => Some(s + 1),
        _ => None,
    }
}

/// Cells from which an exit can be reached through open edges without entering fire.
fn reaching_cells(
    w: usize,
    h: usize,
    surfaces: &[Surface],
    walls: &[u8],
    exit: &[bool],
) -> Vec<bool> {
    let mut reached = exit.to_vec();
    let mut queue: VecDeque<usize> = (0..w * h).filter(|&s| exit[s]).collect();
    while let Some(s) = queue.pop_front() {
        for d in Dir::ALL {
            if walls[s] & d.bit() != 0 {
                continue;
            }
            if let Some(t) = neighbour(w, h, s, d)
                && !reached[t]
                && surfaces[t] != Surface::Fire
            {
                reached[t] = true;
                queue.push_back(t);
            }
        }
    }
    reached
}

/// Opens walls (and, where fire seals a pocket, cools a fire cell to sand) until every
/// non-terminal cell can reach an exit.
fn repair_reachability(
    w: usize,
    h: usize,
    surfaces: &mut [Surface],
    walls: &mut [u8],
    exit: &[bool],
) {
    loop {
        let reached = reaching_cells(w, h, surfaces, walls, exit);
        let stranded: Vec<usize> = (0..w * h)
            .filter(|&s| !reached[s] && surfaces[s] != Surface::Fire)
            .collect();
        if stranded.is_empty() {
            return;
        }
        let mut changed = false;
        // Open a wall between a stranded cell and a reaching neighbour.
        'open: for &s in &stranded {
            for d in Dir::ALL {
                if let Some(t) = neighbour(w, h, s, d)
                    && reached[t]
                    && walls[s] & d.bit() != 0
                {
                    walls[s] &= !d.bit();
                    walls[t] &= !d.opposite().bit();
                    changed = true;
                    break 'open;
                }
            }
        }
        if !changed {
            // Only fire separates the pocket from the rest: cool one fire neighbour.
            'cool: for &s in &stranded {
                for d in Dir::ALL {
                    if let Some(t) = neighbour(w, h, s, d)
                        && surfaces[t] == Surface::Fire
                    {
                        surfaces[t] = Surface::Sand;
                        walls[s] &= !d.bit();
                        walls[t] &= !d.opposite().bit();
                        changed = true;
                        break 'cool;
                    }
                }
            }
        }
        if !changed {
            // Unreachable without exits at all; cannot happen with ≥ 1 exit, but never loop.
            return;
        }
    }
}

/// The 15 tasks of the paper's §5.1.
pub struct GridSuite;

impl GridSuite {
    /// Number of tasks in the suite.
    pub const TASKS: usize = 15;

    /// The suite's settings for task `i` (< 15): sizes from 20×20 to 30×30 (task 0 is the
    /// 900-cell world of Fig. 3), dynamics set `i % 3` (5 tasks each), wall density 6–14 %,
    /// fire 2–5 % of cells, 1–3 exits, 8–20 surface patches with a task-specific mix of
    /// surfaces (one dominant, one rare).
    pub fn params(i: usize, n_irrelevant: usize) -> GridParams {
        const SIDES: [(usize, usize); 15] = [
            (30, 30),
            (20, 20),
            (22, 20),
            (24, 22),
            (25, 25),
            (26, 24),
            (28, 26),
            (20, 28),
            (30, 25),
            (27, 27),
            (21, 23),
            (23, 29),
            (29, 21),
            (26, 30),
            (24, 24),
        ];
        let (width, height) = SIDES[i % 15];
        // One surface dominates, one is rare, so the tasks' surface mixes differ.
        let mut surface_weights = [1.0; 4];
        surface_weights[(i + 2) % 4] = 0.3;
        surface_weights[(i + i / 4) % 4] = 3.0;
        GridParams {
            width,
            height,
            dynamics_set: i % 3,
            n_irrelevant,
            wall_density: 0.06 + 0.02 * (i % 5) as f64,
            fire_fraction: 0.02 + 0.01 * (i % 4) as f64,
            exits: 1 + i % 3,
            patches: 8 + (i * 5) % 13,
            surface_weights,
        }
    }

    /// The 15 tasks, all derived from `seed`, each with `n_irrelevant` irrelevant features.
    pub fn paper(seed: u64, n_irrelevant: usize) -> Vec<GridTask> {
        (0..Self::TASKS)
            .map(|i| {
                GridTask::generate(
                    Self::params(i, n_irrelevant),
                    seed.wrapping_mul(1_000_003).wrapping_add(i as u64),
                )
                .expect("the suite's settings are valid")
            })
            .collect()
    }
}

mod dynamics;
pub use dynamics::{Dynamics, InteractionTable};

#[cfg(test)]
mod tests;
