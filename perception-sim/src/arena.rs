//! The robot arenas of the paper's §5.2: a LEGO NXT robot on hand-made surfaces, seen from above.
//!
//! A three-wheeled differential-drive robot (wheel diameter 8.16 cm, track width 11.2 cm) moves
//! in a square arena. The floor is plain (Berber carpet in Env 1 and Env 3, smooth paper board in
//! Env 2) except under some of the coloured marks, where the surface (loose beans, a
//! hay-covered slope) makes the wheels slip. The robot's pose is
//! continuous ([`Pose`]: position in cm, heading in rad); the agent sees it discretised into a
//! cell `(x, y)` and one of 8 orientations, and each state through the paper's 312 binary
//! features (§5.2.1, see [`feature_name`]): distance rings to the green marks, to the blue marks
//! and to the blue ball, the orientation, and whether the cell holds a green or blue mark.
//!
//! Three arenas ([`ArenaId`]): Env 1 and Env 3 are 6×6 ft discretised to 10×10 cells, Env 2
//! is 5×5 ft discretised to 8×8 cells; all have 8 orientations and one more, absorbing, "out of
//! the area" state. In Env 1 and Env 3 the **blue** marks sit on loose beans (both wheels
//! lose traction) and the green marks are decoys; in Env 2 the **green** marks sit on a hay
//! slope (the right wheel drags and the robot slides downhill) and the blue marks are decoys.
//! Env 1 and Env 3 share their surfaces; their ball, death spots and green marks differ. Env 2's
//! floor is paper board, on which the wheels skid everywhere, so — as the paper says of its
//! Env 2 — it is very different from Env 1 and Env 3 across the whole arena, not only under its
//! marks.
//!
//! # Coordinates and numbering
//!
//! * Positions are in cm from the arena's south-west corner, `x` east, `y` north; the area is
//!   `[0, side) × [0, side)`. Cell `(x, y)` covers `[x·c, (x+1)·c) × [y·c, (y+1)·c)` with
//!   `c = side / cells`.
//! * Headings are in radians, counter-clockwise from east. Orientation `k` (0..8) covers the
//!   headings within ±22.5° of `k·45°`; so 0 faces east, 2 north, 4 west, 6 south.
//! * State `(y·cells + x)·8 + orientation`; the out state is `cells·cells·8`, the last one
//!   (the numbering of `tes_topics::WorldMap`; its attributes are `x = y = u16::MAX`).
//! * Effect `move·5 + turn` ([`Effect`]): moves forward, diagonally forward-left, diagonally
//!   forward-right, did not move; turns none, 1 left, 2 left, 1 right, 2 right — all relative
//!   to the orientation. "Forward" from orientation `k` is the neighbouring cell in direction
//!   `k·45°` (diagonals included); forward-left is the neighbour at `(k+1)·45°`.
//! * Actions ([`ACTIONS`]): 0 both wheels +246°, 1 left +90° and right −90°, 2 left +90°.
//!
//! # Physics and slip
//!
//! [`Arena::move_robot`] turns a pair of wheel rotations (the tacho deltas the brick reports)
//! into a new pose. The surface of the cell the robot starts in scales each wheel's effective
//! rotation (its *traction*) and adds seeded noise; the robot then follows the exact
//! differential-drive arc. The surfaces ([`Surface`]):
//!
//! * **carpet** (the floor of Env 1 and Env 3) — grip: traction `1 ± 3 %` per wheel, heading
//!   noise σ = 1.5°;
//! * **board** (the floor of Env 2) — smooth paper board, the wheels skid: a common traction
//!   `0.65 ± 0.08` (clamped to [0.45, 0.85]) times `1 ± 8 %` per wheel; heading noise σ = 5°;
//! * **beans** (under Env 1 and Env 3's blue marks) — both wheels lose traction: in the
//!   cell's inner 60 % square (deep beans) the wheels spin almost freely (traction < 0.1)
//!   40 % of the time, near the cell's edges 12 % of the time; otherwise a common traction
//!   `0.6 ± 0.1` (clamped to [0.3, 0.9]) times `1 ± 12 %` per wheel; heading noise σ = 4°;
//! * **slope** (under Env 2's green marks) — hay on a ramp falling to the south drags the right
//!   wheel (traction `0.5 ± 0.08` against `0.95 ± 0.04` on the left, so the robot veers right),
//!   when facing uphill (heading within 30°–150°) both wheels lose another 40 %, and every
//!   move slides the robot 2.5 cm downhill (per 246° of mean wheel rotation); σ = 3°.
//!
//! The effect distribution that results is far from a logistic model of the features: it
//! depends on thresholds of the continuous pose inside the cell and on the exact heading
//! inside its 45° sector. Ideal motion: action 0 drives 17.5 cm (≈ one cell in Env 1),
//! action 1 spins clockwise by 65.6° in place, action 2 pivots clockwise by 32.8° about the
//! right wheel. (The paper calls actions 1 and 2 "turn left" and "turn right"; with the left
//! wheel driven forward both turn the robot clockwise — the agent learns their effects anyway.)
//!
//! # Mapping to the paper's §5.2
//!
//! | paper | here |
//! |---|---|
//! | Env 1, 2, 3; 6×6 ft and 5×5 ft; 10×10×8 and 8×8×8 states | [`ArenaId`], [`Arena::new`], [`ArenaLayout::paper`] |
//! | three-wheel NXT robot, track width 11.2 cm | [`WHEEL_DIAMETER_CM`], [`TRACK_WIDTH_CM`], [`Arena::move_robot`] |
//! | actions: 246°/246°, 90°/−90°, 90°/0° | [`ACTIONS`], [`Arena::step`] |
//! | 4 moves × 5 turns = 20 effects | [`Effect`], [`Arena::apply_effect`], [`Arena::effect_between`] |
//! | 312 features: 3 × 100 rings, 8 orientations, 4 mark bits | [`Arena::features`], [`feature_name`] |
//! | +2 ball, −1 death spot or out of the area, −0.05 otherwise | [`Arena::reward`], [`Arena::is_terminal`] |
//! | episode ends when terminal or stuck 4 actions | [`Episode`] |
//! | random start | [`Arena::random_start`] |
//! | man-loreRL's 12 features | [`MAN_FEATURES`], [`Arena::man_features`] |
//! | the factors fRmax/fEpsG are told | [`Arena::oracle_features`], [`Arena::oracle_context`] |
//!
//! # Building the agent's CMDP
//!
//! Everything `tes_learning::cmdp::CmdpStructure::new` needs is here (the `structure`
//! feature's `structure::arena` builds it so, for the experiments and the Python package):
//!
//! ```text
//! let arena = Arena::new(ArenaId::Env3);
//! let cmdp = CmdpStructure::new(
//!     arena.n_states(), arena.n_actions(), arena.n_effects(), arena.n_features(),
//!     |s, e| arena.apply_effect(s, e),
//!     arena.rewards().to_vec(), arena.terminals().to_vec(),
//!     |s| arena.features(s),
//! )?;
//! // man-loreRL: n_features = MAN_FEATURES.len() (12) and |s| arena.man_features(s).
//! ```
//!
//! The episode also ends when the robot is stuck; [`Episode`] applies that rule.
//!
//! # What the paper fixes and what is ours
//!
//! The paper gives the sizes, discretisation, robot, actions, effects, features, rewards, the
//! stuck rule and which colour governs the dynamics in which arena. It does not give the
//! layouts or the physics of its surfaces (beans, soil, hay, leaves, slopes, ...). The layouts
//! ([`ArenaLayout::paper`]), the three surface models above, the mark positions inside their
//! cells, the rule that the start cell's surface governs a whole move, the motor noise of
//! [`Arena::step`] and the start jitter are our reconstruction.
//!
//! ```
//! use rand::SeedableRng;
//! use tes_perception_sim::arena::{ACTIONS, ARENA_FEATURES, Arena, ArenaId};
//!
//! let arena = Arena::new(ArenaId::Env1);
//! assert_eq!(arena.n_states(), 10 * 10 * 8 + 1);
//! assert_eq!(arena.n_features(), ARENA_FEATURES);
//! let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
//! let start = arena.random_start(&mut rng);
//! let s = arena.discretise(start);
//! assert!(!arena.is_terminal(s));
//! let (left, right) = ACTIONS[0];
//! let pose = arena.move_robot(start, left, right, &mut rng);
//! let next = arena.discretise(pose);
//! let effect = arena.effect_between(s, next);
//! assert!(effect < arena.n_effects());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::f64::consts::{FRAC_PI_4, PI, TAU};
use std::fmt;

pub use glam::DVec2;

mod layout;
pub use layout::{ArenaError, ArenaId, ArenaLayout, MarkColour};
#[cfg(test)]
use layout::{ENV1_MAP, ENV2_MAP, ENV3_MAP};
mod motion;
pub use motion::{Pose, StepOutcome, Surface};

mod effects;
pub use effects::{Effect, Move, Turn};
mod episode;
pub use episode::{Episode, EpisodeStatus, EpisodeStep};
mod picture;
pub use picture::Path;

use rand::{Rng, RngExt};
use thiserror::Error;

/// One foot in cm.
pub const FOOT_CM: f64 = 30.48;
/// Orientations per cell (45° sectors).
pub const N_ORIENTATIONS: usize = tes_topics::arena_features::ORIENTATIONS;
/// Actions: both wheels 246°; left 90° and right −90°; left 90°.
pub const N_ACTIONS: usize = 3;
/// Relative moves an effect can have (forward, forward-left, forward-right, did not move).
pub const N_MOVES: usize = 4;
/// Turns an effect can have (none, 1 left, 2 left, 1 right, 2 right).
pub const N_TURNS: usize = 5;
/// Effects: [`N_MOVES`] × [`N_TURNS`].
pub const N_EFFECTS: usize = N_MOVES * N_TURNS;
pub use tes_topics::arena_features::{
    ARENA_FEATURES, BALL_RINGS, BLUE_IN_CELL, BLUE_RINGS, GREEN_IN_CELL, GREEN_RINGS,
    NO_BLUE_IN_CELL, NO_GREEN_IN_CELL, ORIENTATION_FEATURES, RINGS,
};
/// The 12 features man-loreRL is given (8 orientation indicators, then the 4 mark bits), as
/// indices into the 312; [`Arena::man_features`] numbers them 0..12 in this order.
pub const MAN_FEATURES: [u32; 12] = [
    ORIENTATION_FEATURES as u32,
    ORIENTATION_FEATURES as u32 + 1,
    ORIENTATION_FEATURES as u32 + 2,
    ORIENTATION_FEATURES as u32 + 3,
    ORIENTATION_FEATURES as u32 + 4,
    ORIENTATION_FEATURES as u32 + 5,
    ORIENTATION_FEATURES as u32 + 6,
    ORIENTATION_FEATURES as u32 + 7,
    GREEN_IN_CELL as u32,
    NO_GREEN_IN_CELL as u32,
    BLUE_IN_CELL as u32,
    NO_BLUE_IN_CELL as u32,
];
/// Reward for reaching the blue ball (terminal).
pub const BALL_REWARD: f64 = 2.0;
/// Reward for entering a death spot (terminal).
pub const DEATH_REWARD: f64 = -1.0;
/// Reward for leaving the area (terminal).
pub const OUT_REWARD: f64 = -1.0;
/// Reward for entering any other state.
pub const STEP_REWARD: f64 = -0.05;
/// An episode ends after this many consecutive actions that left the state unchanged.
pub const STUCK_ACTIONS: usize = 4;
/// Wheel diameter of the NXT robot, cm.
pub const WHEEL_DIAMETER_CM: f64 = 8.16;
/// Distance between the two driven wheels, cm.
pub const TRACK_WIDTH_CM: f64 = 11.2;
/// Wheel targets (left, right), degrees, of each action.
pub const ACTIONS: [(f64, f64); N_ACTIONS] = [(246.0, 246.0), (90.0, -90.0), (90.0, 0.0)];
/// Short names of the actions.
pub const ACTION_NAMES: [&str; N_ACTIONS] = ["forward", "spin", "pivot"];
/// Largest wheel rotation [`Arena::move_robot`] accepts per call; larger ones are clamped.
pub const MAX_WHEEL_DEG: f64 = 3600.0;
/// Half-width of the uniform position jitter of a random start, cm.
pub const START_JITTER_CM: f64 = 1.0;
/// Half-width of the uniform heading jitter of a random start, degrees.
pub const START_JITTER_DEG: f64 = 5.0;

/// Cell steps of the 8 orientations (counter-clockwise from east, `y` north).
pub const DIRS: [(i32, i32); N_ORIENTATIONS] = [
    (1, 0),
    (1, 1),
    (0, 1),
    (-1, 1),
    (-1, 0),
    (-1, -1),
    (0, -1),
    (1, -1),
];

/// Where a mark sits inside its cell, in cells from the centre, by `(x + 2y) % 4`.
const MARK_OFFSETS: [(f64, f64); 4] = [(0.0, 0.0), (0.2, -0.15), (-0.2, 0.1), (0.15, 0.2)];

const FLAG_GREEN: u8 = 1;
const FLAG_BLUE: u8 = 2;
const FLAG_DEATH: u8 = 4;
const FLAG_BALL: u8 = 8;

/// The attributes of a state: the discretised pose, as the messages carry it.
pub use tes_topics::StateAttributes;

/// A readable name for feature `i` (< 312): "green ring 12", "blue ring 0", "ball ring 99",
/// "facing NW", "green mark in cell", "no green mark in cell", "blue mark in cell",
/// "no blue mark in cell" — [`tes_topics::names::arena_feature_name`], the names saved view
/// libraries give the features of the layout perception extracts them by.
pub fn feature_name(i: usize) -> Option<String> {
    tes_topics::names::arena_feature_name(i)
}

/// One arena: layout, physics, discretisation, effects, rewards and features.
#[derive(Debug, Clone, PartialEq)]
pub struct Arena {
    id: Option<ArenaId>,
    layout: ArenaLayout,
    cell_cm: f64,
    /// [`FLAG_GREEN`] etc. per cell `y · cells + x`.
    cell_flags: Vec<u8>,
    /// Non-terminal cells.
    starts: Vec<u32>,
    /// Each state's reward, terminality and features.
    states: StateTables,
}

impl Arena {
    /// The paper's arena `id` ([`ArenaLayout::paper`]).
    pub fn new(id: ArenaId) -> Self {
        let mut arena =
            Self::from_layout(ArenaLayout::paper(id)).expect("the paper's layouts are valid");
        arena.id = Some(id);
        arena
    }

    /// Builds and checks an arena from a layout: marks and ball inside the area, death spots
    /// inside the grid and not under the ball, at least one cell to start in.
    pub fn from_layout(layout: ArenaLayout) -> Result<Self, ArenaError> {
        let grid = Grid::of(&layout)?;
        let cell_flags = grid.mark_cells(&layout)?;
        let starts = start_cells(&cell_flags)?;
        let states = StateTables::build(&layout, &grid, &cell_flags);
        Ok(Self {
            id: None,
            layout,
            cell_cm: grid.cell_cm,
            cell_flags,
            starts,
            states,
        })
    }

    /// Which of the paper's arenas this is (`None` for one built with [`Arena::from_layout`]).
    pub fn id(&self) -> Option<ArenaId> {
        self.id
    }

    /// The layout it was built from.
    pub fn layout(&self) -> &ArenaLayout {
        &self.layout
    }

    /// Cells per side (the grid is square).
    pub fn cells(&self) -> usize {
        self.layout.cells
    }

    /// Side length of the area, cm.
    pub fn side_cm(&self) -> f64 {
        self.layout.side_cm
    }

    /// Side length of a cell, cm.
    pub fn cell_cm(&self) -> f64 {
        self.cell_cm
    }

    /// The feature distance unit: the arena's width / 100, cm.
    pub fn unit_cm(&self) -> f64 {
        self.layout.side_cm / RINGS as f64
    }

    /// The colour whose marks lie on the dynamics-changing surface.
    pub fn governing_colour(&self) -> MarkColour {
        self.layout.governing
    }

    /// Number of states: `cells² · 8` in the area plus the out state.
    pub fn n_states(&self) -> usize {
        self.out_state() + 1
    }

    /// The absorbing "out of the area" state, the last one.
    pub fn out_state(&self) -> usize {
        self.layout.cells * self.layout.cells * N_ORIENTATIONS
    }

    /// Number of actions (3).
    pub fn n_actions(&self) -> usize {
        N_ACTIONS
    }

    /// Number of effects (20).
    pub fn n_effects(&self) -> usize {
        N_EFFECTS
    }

    /// Number of binary features (312).
    pub fn n_features(&self) -> usize {
        ARENA_FEATURES
    }

    /// The state with these attributes, if it exists ([`StateAttributes::OUT`] gives the out
    /// state).
    pub fn state_index(&self, a: StateAttributes) -> Option<usize> {
        if a.is_out() {
            return Some(self.out_state());
        }
        let (x, y, o) = (
            usize::from(a.x),
            usize::from(a.y),
            usize::from(a.orientation),
        );
        let n = self.layout.cells;
        (x < n && y < n && o < N_ORIENTATIONS).then_some((y * n + x) * N_ORIENTATIONS + o)
    }

    /// The attributes of `state` ([`StateAttributes::OUT`] for the out state), if it exists.
    pub fn attributes(&self, state: usize) -> Option<StateAttributes> {
        let out = self.out_state();
        if state >= out {
            return (state == out).then_some(StateAttributes::OUT);
        }
        let cell = state / N_ORIENTATIONS;
        let n = self.layout.cells;
        Some(StateAttributes::at(
            (cell % n) as u16,
            (cell / n) as u16,
            (state % N_ORIENTATIONS) as u16,
        ))
    }

    /// The cell `(x, y)` a position lies in, or `None` outside the area (or not finite).
    pub fn cell_of(&self, position: DVec2) -> Option<(usize, usize)> {
        let side = self.layout.side_cm;
        if !((0.0..side).contains(&position.x) && (0.0..side).contains(&position.y)) {
            return None;
        }
        let n = self.layout.cells;
        let x = ((position.x / self.cell_cm) as usize).min(n - 1);
        let y = ((position.y / self.cell_cm) as usize).min(n - 1);
        Some((x, y))
    }

    /// The centre of cell `(x, y)`, cm.
    pub fn cell_centre(&self, x: usize, y: usize) -> DVec2 {
        DVec2::new(
            (x as f64 + 0.5) * self.cell_cm,
            (y as f64 + 0.5) * self.cell_cm,
        )
    }

    /// The orientation sector 0..8 of a heading: the nearest multiple of 45°.
    /// A non-finite heading counts as 0.
    pub fn orientation_of(heading: f64) -> u16 {
        if !heading.is_finite() {
            return 0;
        }
        ((heading.rem_euclid(TAU) / FRAC_PI_4).round() as i64).rem_euclid(N_ORIENTATIONS as i64)
            as u16
    }

    /// The discretised pose's attributes ([`StateAttributes::OUT`] outside the area).
    pub fn discretise_attributes(&self, pose: Pose) -> StateAttributes {
        match self.cell_of(pose.position) {
            Some((x, y)) => {
                StateAttributes::at(x as u16, y as u16, Self::orientation_of(pose.heading))
            }
            None => StateAttributes::OUT,
        }
    }

    /// The state a pose is in: its cell and heading sector, or the out state outside the
    /// area (including a non-finite position).
    pub fn discretise(&self, pose: Pose) -> usize {
        match self.cell_of(pose.position) {
            Some((x, y)) => {
                (y * self.layout.cells + x) * N_ORIENTATIONS
                    + usize::from(Self::orientation_of(pose.heading))
            }
            None => self.out_state(),
        }
    }

    /// The ideal pose of a state: its cell's centre, heading `orientation · 45°`; `None` for
    /// the out state or a state that does not exist.
    pub fn state_pose(&self, state: usize) -> Option<Pose> {
        let a = self.attributes(state).filter(|a| !a.is_out())?;
        Some(Pose {
            position: self.cell_centre(usize::from(a.x), usize::from(a.y)),
            heading: f64::from(a.orientation) * FRAC_PI_4,
        })
    }

    /// Whether cell `(x, y)` holds a mark of `colour` (false outside the grid).
    pub fn has_mark(&self, colour: MarkColour, x: usize, y: usize) -> bool {
        self.flags(x, y) & colour.flag() != 0
    }

    /// Whether cell `(x, y)` is a death spot.
    pub fn is_death_cell(&self, x: usize, y: usize) -> bool {
        self.flags(x, y) & FLAG_DEATH != 0
    }

    /// Whether cell `(x, y)` holds the ball.
    pub fn is_ball_cell(&self, x: usize, y: usize) -> bool {
        self.flags(x, y) & FLAG_BALL != 0
    }

    fn flags(&self, x: usize, y: usize) -> u8 {
        let n = self.layout.cells;
        if x < n && y < n {
            self.cell_flags[y * n + x]
        } else {
            0
        }
    }

    /// The positions of the marks of `colour`, cm.
    pub fn marks(&self, colour: MarkColour) -> &[DVec2] {
        match colour {
            MarkColour::Green => &self.layout.green_marks,
            MarkColour::Blue => &self.layout.blue_marks,
        }
    }

    /// The ball's position, cm.
    pub fn ball(&self) -> DVec2 {
        self.layout.ball
    }

    /// Where `effect` takes the robot from `state` (the effects' known meaning): the move's
    /// neighbour cell and the turned orientation; the out state if the move leaves the grid;
    /// the out state stays out.
    ///
    /// # Panics
    ///
    /// If `state ≥ n_states()` or `effect ≥ 20`.
    pub fn apply_effect(&self, state: usize, effect: usize) -> usize {
        let out = self.out_state();
        assert!(state <= out, "state {state} does not exist");
        let Some(e) = Effect::from_index(effect) else {
            panic!("effect {effect} does not exist");
        };
        if state == out {
            return out;
        }
        let n = self.layout.cells as i32;
        let cell = (state / N_ORIENTATIONS) as i32;
        let o = (state % N_ORIENTATIONS) as i32;
        let (mut x, mut y) = (cell % n, cell / n);
        if let Some(d) = e.movement.direction() {
            let (dx, dy) = DIRS[(o + d).rem_euclid(N_ORIENTATIONS as i32) as usize];
            (x, y) = (x + dx, y + dy);
            if !(0..n).contains(&x) || !(0..n).contains(&y) {
                return out;
            }
        }
        let o2 = (o + e.turn.delta()).rem_euclid(N_ORIENTATIONS as i32);
        ((y * n + x) * N_ORIENTATIONS as i32 + o2) as usize
    }

    /// The effect that explains a transition from `prev` to `next`.
    ///
    /// The rule ([`tes_topics::effect_between`], which the controller uses too): the lowest-numbered effect
    /// `e` with `apply_effect(prev, e) == next` if there is one; otherwise the effect whose
    /// destination is nearest to `next` — fewest cells away (Chebyshev distance), then least
    /// turned (circular distance between orientations), then lowest-numbered. A destination
    /// out of the area counts as infinitely far from a state inside it and vice versa, so
    /// reaching the out state where no effect leads out gives effect 0 (forward, no turn).
    /// Real motion can skip cells, hence the rule.
    ///
    /// # Panics
    ///
    /// If either state is `≥ n_states()`.
    pub fn effect_between(&self, prev: usize, next: usize) -> usize {
        let out = self.out_state();
        assert!(next <= out, "state {next} does not exist");
        let pose = |s: usize| self.attributes(s).unwrap_or(StateAttributes::OUT);
        let outcomes = (0..N_EFFECTS).map(|e| pose(self.apply_effect(prev, e)));
        tes_topics::effect_between(outcomes, pose(next), N_ORIENTATIONS as u16)
    }

    /// The reward for entering `state`: +2 the ball's cell, −1 a death spot or the out state,
    /// −0.05 otherwise.
    ///
    /// # Panics
    ///
    /// If `state ≥ n_states()`.
    pub fn reward(&self, state: usize) -> f64 {
        self.states.reward[state]
    }

    /// Whether entering `state` ends the episode (the ball, a death spot, the out state).
    ///
    /// # Panics
    ///
    /// If `state ≥ n_states()`.
    pub fn is_terminal(&self, state: usize) -> bool {
        self.states.terminal[state]
    }

    /// The reward for entering each state, by state.
    pub fn rewards(&self) -> &[f64] {
        &self.states.reward
    }

    /// Whether each state is terminal, by state.
    pub fn terminals(&self) -> &[bool] {
        &self.states.terminal
    }

    /// The features on in `state`, sorted: the green, blue and ball rings that hold a mark
    /// (or the ball), the orientation indicator, and one of each pair of mark bits — the same
    /// for all 8 orientations of a cell but for the orientation. The out state has none.
    ///
    /// # Panics
    ///
    /// If `state ≥ n_states()`.
    pub fn features(&self, state: usize) -> &[u32] {
        &self.states.indices[self.states.offsets[state]..self.states.offsets[state + 1]]
    }

    /// The features the true dynamics depend on, over all states: the 8 orientation
    /// indicators and the governing colour's two mark bits (the dynamics also depend on the
    /// continuous pose inside the state, which no feature shows).
    pub fn dynamics_features(&self) -> [u32; 10] {
        let g = self.layout.governing;
        let mut f = [0u32; 10];
        for (k, v) in f.iter_mut().take(N_ORIENTATIONS).enumerate() {
            *v = (ORIENTATION_FEATURES + k) as u32;
        }
        f[8] = g.in_cell_feature() as u32;
        f[9] = g.not_in_cell_feature() as u32;
        f
    }

    /// The features of `state` the true dynamics depend on, sorted (the oracle factors the
    /// fRmax and fEpsG baselines are told): its orientation indicator and its governing-colour
    /// mark bit. Empty for the out state.
    ///
    /// # Panics
    ///
    /// If `state ≥ n_states()`.
    pub fn oracle_features(&self, state: usize) -> &[u32] {
        assert!(state < self.n_states(), "state {state} does not exist");
        self.states.oracle.get(state).map_or(&[], |f| f.as_slice())
    }

    /// The true dynamics context of `state`: `8 · (governing mark in the cell) + orientation`,
    /// in 0..[`Arena::n_oracle_contexts`]; `None` for the out state or a state that does not
    /// exist.
    pub fn oracle_context(&self, state: usize) -> Option<usize> {
        if state >= self.out_state() {
            return None;
        }
        let cell = state / N_ORIENTATIONS;
        let governing = self.cell_flags[cell] & self.layout.governing.flag() != 0;
        Some(usize::from(governing) * N_ORIENTATIONS + state % N_ORIENTATIONS)
    }

    /// Number of oracle contexts (2 × 8).
    pub fn n_oracle_contexts(&self) -> usize {
        2 * N_ORIENTATIONS
    }

    /// man-loreRL's features of `state`, numbered 0..12 as in [`MAN_FEATURES`] (0..8
    /// orientation, 8 green mark in cell, 9 no green mark, 10 blue mark in cell, 11 no blue
    /// mark), sorted: three per state, none for the out state.
    ///
    /// # Panics
    ///
    /// If `state ≥ n_states()`.
    pub fn man_features(&self, state: usize) -> &[u32] {
        assert!(state < self.n_states(), "state {state} does not exist");
        self.states.man.get(state).map_or(&[], |f| f.as_slice())
    }
}

impl fmt::Display for Arena {
    /// The map, north row first: `.` plain, `g` green mark, `b` blue mark, `+` both, `O` the
    /// ball, `X` a death spot.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.layout.cells;
        for y in (0..n).rev() {
            let row: Vec<String> = (0..n)
                .map(|x| {
                    let c = match self.flags(x, y) {
                        fl if fl & FLAG_BALL != 0 => 'O',
                        fl if fl & FLAG_DEATH != 0 => 'X',
                        fl if fl & (FLAG_GREEN | FLAG_BLUE) == FLAG_GREEN | FLAG_BLUE => '+',
                        fl if fl & FLAG_GREEN != 0 => 'g',
                        fl if fl & FLAG_BLUE != 0 => 'b',
                        _ => '.',
                    };
                    c.to_string()
                })
                .collect();
            writeln!(f, "{}", row.join(" "))?;
        }
        Ok(())
    }
}

/// An arena's grid of cells: its size and a cell's side.
struct Grid {
    cells: usize,
    cell_cm: f64,
    side: f64,
}

impl Grid {
    /// The grid of `layout`, its size and side checked.
    fn of(layout: &ArenaLayout) -> Result<Self, ArenaError> {
        let cells = layout.cells;
        if !(2..=32).contains(&cells) {
            return Err(ArenaError::BadSize(cells));
        }
        let side = layout.side_cm;
        if !(side.is_finite() && side > 0.0) {
            return Err(ArenaError::BadSide(side));
        }
        Ok(Self {
            cells,
            cell_cm: side / cells as f64,
            side,
        })
    }

    /// The cell a point of the area lies in, if it is inside.
    fn cell_of(&self, p: DVec2) -> Option<usize> {
        let inside = (0.0..self.side).contains(&p.x) && (0.0..self.side).contains(&p.y);
        inside.then(|| {
            let x = ((p.x / self.cell_cm) as usize).min(self.cells - 1);
            let y = ((p.y / self.cell_cm) as usize).min(self.cells - 1);
            y * self.cells + x
        })
    }

    /// The centre of cell `c`.
    fn centre(&self, c: usize) -> DVec2 {
        DVec2::new(
            ((c % self.cells) as f64 + 0.5) * self.cell_cm,
            ((c / self.cells) as f64 + 0.5) * self.cell_cm,
        )
    }

    /// Each cell's flags: the marks, the ball and the death spots it holds, all checked to
    /// lie on the grid, the ball not on a death spot.
    fn mark_cells(&self, layout: &ArenaLayout) -> Result<Vec<u8>, ArenaError> {
        let cells = self.cells;
        let mut cell_flags = vec![0u8; cells * cells];
        for (what, colour, marks) in [
            ("green mark", MarkColour::Green, &layout.green_marks),
            ("blue mark", MarkColour::Blue, &layout.blue_marks),
        ] {
            for &m in marks {
                let c = self.cell_of(m).ok_or(ArenaError::OutsideArea {
                    what,
                    x: m.x,
                    y: m.y,
                })?;
                cell_flags[c] |= colour.flag();
            }
        }
        let ball_cell = self.cell_of(layout.ball).ok_or(ArenaError::OutsideArea {
            what: "ball",
            x: layout.ball.x,
            y: layout.ball.y,
        })?;
        cell_flags[ball_cell] |= FLAG_BALL;
        for &(x, y) in &layout.death_cells {
            if x >= cells || y >= cells {
                return Err(ArenaError::DeathOutside { x, y });
            }
            cell_flags[y * cells + x] |= FLAG_DEATH;
        }
        if cell_flags[ball_cell] & FLAG_DEATH != 0 {
            return Err(ArenaError::BallOnDeath);
        }
        Ok(cell_flags)
    }
}

/// The cells an episode may start in: neither the ball's nor a death spot; at least one.
fn start_cells(cell_flags: &[u8]) -> Result<Vec<u32>, ArenaError> {
    let starts: Vec<u32> = (0..cell_flags.len())
        .filter(|&c| cell_flags[c] & (FLAG_BALL | FLAG_DEATH) == 0)
        .map(|c| c as u32)
        .collect();
    if starts.is_empty() {
        return Err(ArenaError::NoStartCell);
    }
    Ok(starts)
}

/// The per-state tables of an arena (a state per cell and orientation, then the out state):
/// reward, terminality, the features in CSR form, and the oracle's and the hand-made views'
/// features.
#[derive(Debug, Clone, PartialEq)]
struct StateTables {
    /// Reward for entering each state.
    reward: Vec<f64>,
    terminal: Vec<bool>,
    /// Sparse features, CSR.
    offsets: Vec<usize>,
    indices: Vec<u32>,
    /// Per in-area state: orientation indicator and the governing colour's mark bit.
    oracle: Vec<[u32; 2]>,
    /// Per in-area state: man-loreRL's features, numbered 0..12.
    man: Vec<[u32; 3]>,
}

impl StateTables {
    /// The tables of `layout`'s arena on `grid` with its cells' flags.
    fn build(layout: &ArenaLayout, grid: &Grid, cell_flags: &[u8]) -> Self {
        let n_in = grid.cells * grid.cells * N_ORIENTATIONS;
        let mut states = Self {
            reward: Vec::with_capacity(n_in + 1),
            terminal: Vec::with_capacity(n_in + 1),
            offsets: Vec::with_capacity(n_in + 2),
            indices: Vec::new(),
            oracle: Vec::with_capacity(n_in),
            man: Vec::with_capacity(n_in),
        };
        states.offsets.push(0);
        let mut rings = Vec::new();
        for (c, &flags) in cell_flags.iter().enumerate() {
            rings_around(layout, grid, grid.centre(c), &mut rings);
            states.push_cell(layout, flags, &rings);
        }
        // The out state: −1, terminal, no features.
        states.reward.push(OUT_REWARD);
        states.terminal.push(true);
        states.offsets.push(states.indices.len());
        states
    }

    /// The states of one cell with `flags`, one per orientation, whose ring features are
    /// `rings`.
    fn push_cell(&mut self, layout: &ArenaLayout, flags: u8, rings: &[u32]) {
        let green = flags & FLAG_GREEN != 0;
        let blue = flags & FLAG_BLUE != 0;
        let governing = flags & layout.governing.flag() != 0;
        let (r, t) = if flags & FLAG_BALL != 0 {
            (BALL_REWARD, true)
        } else if flags & FLAG_DEATH != 0 {
            (DEATH_REWARD, true)
        } else {
            (STEP_REWARD, false)
        };
        for o in 0..N_ORIENTATIONS {
            self.reward.push(r);
            self.terminal.push(t);
            self.indices.extend_from_slice(rings);
            self.indices.push((ORIENTATION_FEATURES + o) as u32);
            self.indices.push(if green {
                GREEN_IN_CELL
            } else {
                NO_GREEN_IN_CELL
            } as u32);
            self.indices
                .push(if blue { BLUE_IN_CELL } else { NO_BLUE_IN_CELL } as u32);
            self.offsets.push(self.indices.len());
            let g = layout.governing;
            let bit = if governing {
                g.in_cell_feature()
            } else {
                g.not_in_cell_feature()
            };
            self.oracle
                .push([(ORIENTATION_FEATURES + o) as u32, bit as u32]);
            self.man
                .push([o as u32, 8 + u32::from(!green), 10 + u32::from(!blue)]);
        }
    }
}

/// The ring features of a cell centred at `centre` into `rings` (sorted, once each): for
/// each mark and the ball, the ring of distance it lies in, if within [`RINGS`].
fn rings_around(layout: &ArenaLayout, grid: &Grid, centre: DVec2, rings: &mut Vec<u32>) {
    let unit = grid.side / RINGS as f64;
    rings.clear();
    for (base, points) in [
        (GREEN_RINGS, layout.green_marks.as_slice()),
        (BLUE_RINGS, layout.blue_marks.as_slice()),
        (BALL_RINGS, std::slice::from_ref(&layout.ball)),
    ] {
        for &p in points {
            let d = p.distance(centre) / unit;
            if d < RINGS as f64 {
                rings.push((base + d.floor() as usize) as u32);
            }
        }
    }
    rings.sort_unstable();
    rings.dedup();
}

#[cfg(test)]
mod tests;
