//! How the robot moves: the surfaces' slip, its continuous pose, and one action's motion.

use super::*;

/// What the floor of a cell is made of; it sets how the wheels slip (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Surface {
    /// Plain carpet: firm grip, little noise.
    Carpet,
    /// Smooth paper board: both wheels skid, so moves and turns fall short.
    Board,
    /// Loose beans: both wheels lose traction, and in the deep middle of the cell they often
    /// spin in place.
    Beans,
    /// Hay on a ramp falling to the south: the right wheel drags, climbing is harder, and the
    /// robot slides downhill.
    Slope,
}

impl Surface {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Surface::Carpet => "carpet",
            Surface::Board => "board",
            Surface::Beans => "beans",
            Surface::Slope => "slope",
        }
    }

    /// Draws this surface's slip for one move that starts at `offset` (cells from the cell's
    /// centre, each coordinate in [−0.5, 0.5)) with `heading`, and wheel rotations of
    /// `left_deg`, `right_deg`.
    fn slip<R: Rng + ?Sized>(
        self,
        offset: DVec2,
        heading: f64,
        left_deg: f64,
        right_deg: f64,
        rng: &mut R,
    ) -> Slip {
        match self {
            Surface::Carpet => Slip {
                left: (1.0 + 0.03 * normal(rng)).clamp(0.85, 1.15),
                right: (1.0 + 0.03 * normal(rng)).clamp(0.85, 1.15),
                slide: DVec2::ZERO,
                heading_noise: 1.5_f64.to_radians() * normal(rng),
            },
            Surface::Board => {
                let common = (0.65 + 0.08 * normal(rng)).clamp(0.45, 0.85);
                Slip {
                    left: common * (1.0 + 0.08 * normal(rng)).clamp(0.75, 1.25),
                    right: common * (1.0 + 0.08 * normal(rng)).clamp(0.75, 1.25),
                    slide: DVec2::ZERO,
                    heading_noise: 5.0_f64.to_radians() * normal(rng),
                }
            }
            Surface::Beans => {
                let deep = offset.x.abs() < 0.3 && offset.y.abs() < 0.3;
                let spin_probability = if deep { 0.4 } else { 0.12 };
                let common = if rng.random::<f64>() < spin_probability {
                    0.1 * rng.random::<f64>()
                } else {
                    (0.6 + 0.1 * normal(rng)).clamp(0.3, 0.9)
                };
                Slip {
                    left: common * (1.0 + 0.12 * normal(rng)).clamp(0.6, 1.4),
                    right: common * (1.0 + 0.12 * normal(rng)).clamp(0.6, 1.4),
                    slide: DVec2::ZERO,
                    heading_noise: 4.0_f64.to_radians() * normal(rng),
                }
            }
            Surface::Slope => {
                let uphill = if heading.sin() > 0.5 { 0.6 } else { 1.0 };
                let activity = ((left_deg.abs() + right_deg.abs()) / (2.0 * ACTIONS[0].0)).min(1.5);
                Slip {
                    left: uphill * (0.95 + 0.04 * normal(rng)).clamp(0.8, 1.1),
                    right: uphill * (0.5 + 0.08 * normal(rng)).clamp(0.25, 0.75),
                    slide: DVec2::new(0.0, -2.5 * activity),
                    heading_noise: 3.0_f64.to_radians() * normal(rng),
                }
            }
        }
    }
}

/// How one move slips: traction per wheel, a slide (cm, world frame) and extra heading (rad).
struct Slip {
    left: f64,
    right: f64,
    slide: DVec2,
    heading_noise: f64,
}

/// A standard normal draw (Box–Muller).
pub(super) fn normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    let u1 = 1.0 - rng.random::<f64>(); // (0, 1]: ln is finite
    let u2 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
}

/// `sin(x) / x`, 1 at 0.
pub(super) fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-9 { 1.0 } else { x.sin() / x }
}

/// The robot's continuous pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position of the point between the two driven wheels, cm from the south-west corner
    /// (`x` east, `y` north).
    pub position: DVec2,
    /// Heading, rad, counter-clockwise from east; [`Arena::move_robot`] keeps it in [0, 2π].
    pub heading: f64,
}

impl Pose {
    /// A pose from coordinates in cm and a heading in rad.
    pub fn new(x: f64, y: f64, heading: f64) -> Self {
        Self {
            position: DVec2::new(x, y),
            heading,
        }
    }
}

/// What one action did (see [`Arena::step`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutcome {
    /// The wheel rotations (left, right; degrees) the motors actually made — the tacho deltas.
    pub wheels_deg: (f64, f64),
    /// The robot's new pose.
    pub pose: Pose,
    /// The state it is in.
    pub state: usize,
    /// The reward for entering `state`.
    pub reward: f64,
    /// Whether `state` ends the episode.
    pub terminal: bool,
}

impl Arena {
    /// The floor of cell `(x, y)`: the governing surface under a governing-colour mark,
    /// the arena's floor elsewhere (and outside the grid).
    pub fn surface(&self, x: usize, y: usize) -> Surface {
        if self.has_mark(self.layout.governing, x, y) {
            self.layout.governing_surface
        } else {
            self.layout.floor
        }
    }

    /// Moves the robot from `pose` by the wheel rotations `left_deg` and `right_deg` (degrees,
    /// forward positive: the tacho deltas the brick reports), with the slip of the surface of
    /// the cell it starts in (see the module docs), drawn from `rng`.
    ///
    /// A pose outside the area (including a non-finite position) is returned unchanged: the
    /// robot has left and the out state is absorbing. A non-finite rotation counts as 0 and
    /// rotations are clamped to ±[`MAX_WHEEL_DEG`]; a non-finite heading counts as 0. The
    /// heading of the result is in [0, 2π].
    pub fn move_robot<R: Rng + ?Sized>(
        &self,
        pose: Pose,
        left_deg: f64,
        right_deg: f64,
        rng: &mut R,
    ) -> Pose {
        let Some((x, y)) = self.cell_of(pose.position) else {
            return pose;
        };
        let clean = |d: f64| {
            if d.is_finite() {
                d.clamp(-MAX_WHEEL_DEG, MAX_WHEEL_DEG)
            } else {
                0.0
            }
        };
        let (left_deg, right_deg) = (clean(left_deg), clean(right_deg));
        let heading = if pose.heading.is_finite() {
            pose.heading.rem_euclid(TAU)
        } else {
            0.0
        };
        let offset = (pose.position - self.cell_centre(x, y)) / self.cell_cm;
        let slip = self
            .surface(x, y)
            .slip(offset, heading, left_deg, right_deg, rng);
        let cm_per_deg = PI * WHEEL_DIAMETER_CM / 360.0;
        let left = left_deg * cm_per_deg * slip.left;
        let right = right_deg * cm_per_deg * slip.right;
        // Exact differential-drive arc: the chord has length ds·sinc(dθ/2) along θ + dθ/2.
        let d_theta = (right - left) / TRACK_WIDTH_CM;
        let ds = 0.5 * (left + right);
        let mid = heading + 0.5 * d_theta;
        let chord = ds * sinc(0.5 * d_theta);
        Pose {
            position: pose.position + DVec2::new(mid.cos(), mid.sin()) * chord + slip.slide,
            heading: (heading + d_theta + slip.heading_noise).rem_euclid(TAU),
        }
    }

    /// Takes `action` from `pose`: the motors turn the wheels to the action's targets
    /// ([`ACTIONS`]) with ±2 % motor noise (a wheel with target 0 stays still), then
    /// [`Arena::move_robot`] moves the robot; the result is discretised.
    pub fn step<R: Rng + ?Sized>(
        &self,
        pose: Pose,
        action: usize,
        rng: &mut R,
    ) -> Result<StepOutcome, ArenaError> {
        let &(l, r) = ACTIONS.get(action).ok_or(ArenaError::BadAction(action))?;
        let mut motor = |target: f64| target * (1.0 + 0.02 * normal(rng));
        let wheels_deg = (motor(l), motor(r));
        let next = self.move_robot(pose, wheels_deg.0, wheels_deg.1, rng);
        let state = self.discretise(next);
        Ok(StepOutcome {
            wheels_deg,
            pose: next,
            state,
            reward: self.states.reward[state],
            terminal: self.states.terminal[state],
        })
    }

    /// A random start: a uniformly random non-terminal cell and orientation; the pose at the
    /// cell's centre ± [`START_JITTER_CM`] on each axis, heading `orientation · 45°` ±
    /// [`START_JITTER_DEG`] (uniform).
    pub fn random_start<R: Rng + ?Sized>(&self, rng: &mut R) -> Pose {
        let cell = self.starts[rng.random_range(0..self.starts.len())] as usize;
        let n = self.layout.cells;
        let o = rng.random_range(0..N_ORIENTATIONS);
        let jitter = |rng: &mut R, half: f64| (2.0 * rng.random::<f64>() - 1.0) * half;
        let dx = jitter(rng, START_JITTER_CM);
        let dy = jitter(rng, START_JITTER_CM);
        let dh = jitter(rng, START_JITTER_DEG.to_radians());
        Pose {
            position: self.cell_centre(cell % n, cell / n) + DVec2::new(dx, dy),
            heading: (o as f64 * FRAC_PI_4 + dh).rem_euclid(TAU),
        }
    }
}
