//! A grid task of §5.1 drawn as the arena is, and an agent's run on it ([`GridRun`]): the
//! cells in their surfaces' colours (fire orange, exits green), the walls between them, the
//! agent as the robot's frame moving cell to cell, its path, each decision and each episode's
//! reward, on the same topics as a run of the group, so the same layout shows it.
//!
//! A grid run has no clock of its own: its steps are laid [`STEP_NS`] apart from when the
//! drawing starts, so a viewer plays it back at ten steps a second.

use foxglove::messages::{CubePrimitive, SceneEntity, SceneUpdate, Timestamp};
use glam::DVec2;
use tes_perception_sim::grid::{Dir, GridTask, Surface};

use crate::arena::{ARENA_FRAME, WALL, WALL_THICKNESS_M, at, coloured_points, rgb, size};
use crate::canvas::Canvas;
use crate::robot::{FloorPose, body};
use crate::scene::{Decision, EpisodeEnd, Painter, path_entity, said_over_robot};
use crate::series::Sample;

/// A grid cell's side, m: a 30 × 30 task is 3 m across.
pub const CELL_M: f64 = 0.1;

/// The time between two drawn steps, ns.
pub const STEP_NS: u64 = 100_000_000;

/// The agent's size on the grid, relative to the NXT on the arena.
const AGENT_SCALE: f64 = 0.45;

/// The names of the grid's actions (moves) and effects (moves and "stayed").
const DIRECTIONS: [&str; 5] = ["north", "east", "south", "west", "stayed"];

/// A surface's colour.
pub fn surface_colour(surface: Surface) -> foxglove::messages::Color {
    match surface {
        Surface::Sand => rgb(0.87, 0.78, 0.55),
        Surface::Soil => rgb(0.45, 0.32, 0.20),
        Surface::Water => rgb(0.22, 0.46, 0.85),
        Surface::Brick => rgb(0.68, 0.26, 0.18),
        Surface::Fire => rgb(1.00, 0.40, 0.00),
    }
}

const EXIT: foxglove::messages::Color = foxglove::messages::Color {
    r: 0.10,
    g: 0.85,
    b: 0.30,
    a: 1.0,
};

/// The centre of `state`'s cell, m (row 0 is the north edge).
fn centre(task: &GridTask, state: usize) -> DVec2 {
    let (w, h) = (task.width(), task.height());
    let (x, y) = (state % w, state / w);
    DVec2::new(
        (x as f64 + 0.5) * CELL_M,
        ((h - 1 - y) as f64 + 0.5) * CELL_M,
    )
}

fn cell_colour(task: &GridTask, state: usize) -> foxglove::messages::Color {
    if task.is_exit(state) {
        EXIT
    } else {
        surface_colour(task.surface(state))
    }
}

/// The task as one scene entity `arena`: a tile per cell, a wall segment on every walled edge.
pub fn grid_scene(task: &GridTask, timestamp: Timestamp) -> SceneUpdate {
    let mut entity = SceneEntity {
        timestamp: Some(timestamp),
        frame_id: ARENA_FRAME.into(),
        id: "arena".into(),
        ..SceneEntity::default()
    };
    for s in 0..task.n_states() {
        let c = centre(task, s);
        entity.cubes.push(CubePrimitive {
            pose: Some(at(c.x, c.y, -0.002)),
            size: size(CELL_M * 0.96, CELL_M * 0.96, 0.004),
            color: Some(cell_colour(task, s)),
        });
        entity.cubes.extend(walls_of(task, s, c));
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![entity],
    }
}

/// The walled edges of cell `s`: north and west of every cell, south and east on the last
/// row and column (the border), so each edge is drawn once.
fn walls_of(task: &GridTask, s: usize, c: DVec2) -> impl Iterator<Item = CubePrimitive> + '_ {
    let (w, h) = (task.width(), task.height());
    let (x, y) = (s % w, s / w);
    let half = CELL_M / 2.0;
    let (t, height) = (WALL_THICKNESS_M / 2.0, 0.04);
    Dir::ALL.into_iter().filter_map(move |d| {
        let drawn_here = match d {
            Dir::North | Dir::West => true,
            Dir::South => y + 1 == h,
            Dir::East => x + 1 == w,
        };
        if !(drawn_here && task.has_wall(s, d)) {
            return None;
        }
        let (offset, along_x) = match d {
            Dir::North => (DVec2::new(0.0, half), true),
            Dir::South => (DVec2::new(0.0, -half), true),
            Dir::East => (DVec2::new(half, 0.0), false),
            Dir::West => (DVec2::new(-half, 0.0), false),
        };
        let p = c + offset;
        let (sx, sy) = if along_x {
            (CELL_M + t, t)
        } else {
            (t, CELL_M + t)
        };
        Some(CubePrimitive {
            pose: Some(at(p.x, p.y, height / 2.0)),
            size: size(sx, sy, height),
            color: Some(WALL),
        })
    })
}

/// The task as coloured points: one per cell centre, in its surface's colour.
pub fn grid_points(task: &GridTask, timestamp: Timestamp) -> foxglove::messages::PointCloud {
    let points: Vec<_> = (0..task.n_states())
        .map(|s| {
            let c = centre(task, s);
            (c.x, c.y, 0.0, cell_colour(task, s))
        })
        .collect();
    coloured_points(&points, timestamp)
}

/// The heading of a move: north is +y.
fn heading_of(action: usize) -> Option<f64> {
    use std::f64::consts::{FRAC_PI_2, PI};
    match Dir::from_index(action)? {
        Dir::North => Some(FRAC_PI_2),
        Dir::East => Some(0.0),
        Dir::South => Some(-FRAC_PI_2),
        Dir::West => Some(PI),
    }
}

/// An agent's run on a grid task, drawn step by step.
#[derive(Debug)]
pub struct GridRun<'t> {
    task: &'t GridTask,
    painter: Painter,
    clock_ns: u64,
    pose: FloorPose,
    path: Vec<DVec2>,
    /// The agent's cell.
    state: usize,
    episode: u32,
    step: u32,
    reward: f64,
}

/// How many transforms a move between two cells is drawn with: the agent glides from cell to
/// cell, a quarter of a cell at a time, instead of jumping.
const GLIDE_STEPS: u64 = 4;

/// How a grid episode ended, from the cell it ended on: `exit`, `fire`, or `cut short` (the
/// step cap, or an episode not `finished`).
pub fn outcome(task: &GridTask, state: usize, finished: bool) -> &'static str {
    if !finished {
        "cut short"
    } else if task.is_exit(state) {
        "exit"
    } else if task.surface(state) == Surface::Fire {
        "fire"
    } else {
        "cut short"
    }
}

impl<'t> GridRun<'t> {
    /// Draws `task` (the cells, the walls, the agent's body) and starts the run's clock.
    pub fn start<C: Canvas>(task: &'t GridTask, canvas: &mut C) -> Result<Self, C::Error> {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as i128);
        let mut run = Self {
            task,
            painter: Painter::new(now),
            clock_ns: 0,
            pose: FloorPose {
                position: DVec2::ZERO,
                heading: 0.0,
            },
            path: Vec::new(),
            state: 0,
            episode: 0,
            step: 0,
            reward: 0.0,
        };
        let t = run.painter.timestamp(0);
        let (scene, points) = (grid_scene(task, t), grid_points(task, t));
        run.painter.put(|c| &c.arena, &scene, 0, canvas)?;
        run.painter.put(|c| &c.arena_points, &points, 0, canvas)?;
        let agent = SceneUpdate {
            deletions: Vec::new(),
            entities: vec![body(t, AGENT_SCALE)],
        };
        run.painter.put(|c| &c.robot, &agent, 0, canvas)?;
        Ok(run)
    }

    /// Episode `episode` starts in `state`.
    pub fn begin_episode<C: Canvas>(
        &mut self,
        episode: u32,
        state: usize,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        (self.episode, self.step, self.reward) = (episode, 0, 0.0);
        self.path.clear();
        self.clock_ns += STEP_NS;
        // A new episode puts the agent at its start: the one jump that is not a move.
        self.state = state;
        self.arrive(state, None, canvas)
    }

    /// One step: `action` had `effect` and took the agent to `next`, earning `reward`; the
    /// agent spent `agent_us` deciding and learning.
    pub fn step<C: Canvas>(
        &mut self,
        action: usize,
        effect: usize,
        next: usize,
        reward: f64,
        agent_us: f64,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        let decision = Decision {
            episode: self.episode,
            step: self.step,
            action: action as u32,
            action_name: DIRECTIONS.get(action).copied().unwrap_or("?").into(),
            latency_us: agent_us,
        };
        self.painter
            .put(|c| &c.decision, &decision, self.clock_ns, canvas)?;
        let latency = Sample::of(agent_us);
        self.painter
            .put(|c| &c.latency_series, &latency, self.clock_ns, canvas)?;
        (self.step, self.reward) = (self.step + 1, self.reward + reward);
        if let Some(h) = heading_of(action) {
            self.pose.heading = h;
        }
        self.glide(next, canvas)?;
        self.clock_ns += STEP_NS / GLIDE_STEPS;
        let said = format!(
            "episode {} step {}: {} → {}",
            self.episode,
            self.step,
            DIRECTIONS.get(action).copied().unwrap_or("?"),
            DIRECTIONS.get(effect).copied().unwrap_or("?")
        );
        self.arrive(next, Some(said), canvas)
    }

    /// The episode ended: `finished` (on an exit or fire) or cut off at the step cap; its
    /// outcome is the cell the agent ended on ([`outcome`]).
    pub fn end_episode<C: Canvas>(
        &mut self,
        finished: bool,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        let end = EpisodeEnd {
            episode: self.episode,
            reward: self.reward,
            actions: self.step,
            outcome: outcome(self.task, self.state, finished).into(),
        };
        self.painter
            .put(|c| &c.episode, &end, self.clock_ns, canvas)?;
        let reward = Sample::of(self.reward);
        self.painter
            .put(|c| &c.reward_series, &reward, self.clock_ns, canvas)
    }

    /// Moves the agent from its cell towards `next`'s over the step's time, a transform every
    /// [`GLIDE_STEPS`]th of it (none when it stayed), up to just before it arrives.
    fn glide<C: Canvas>(&mut self, next: usize, canvas: &mut C) -> Result<(), C::Error> {
        let (from, to) = (centre(self.task, self.state), centre(self.task, next));
        self.state = next;
        for k in 1..GLIDE_STEPS {
            self.clock_ns += STEP_NS / GLIDE_STEPS;
            if from == to {
                continue;
            }
            let along = from.lerp(to, k as f64 / GLIDE_STEPS as f64);
            let pose = FloorPose {
                position: along / crate::arena::M_PER_CM,
                ..self.pose
            };
            let t = self.painter.timestamp(self.clock_ns);
            self.painter
                .put(|c| &c.tf, &pose.transform(t), self.clock_ns, canvas)?;
        }
        Ok(())
    }

    /// Draws the agent in `state`'s cell with its path and what it did last.
    fn arrive<C: Canvas>(
        &mut self,
        state: usize,
        said: Option<String>,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        self.pose.position = centre(self.task, state) / crate::arena::M_PER_CM;
        self.path.push(centre(self.task, state));
        let t = self.painter.timestamp(self.clock_ns);
        self.painter
            .put(|c| &c.tf, &self.pose.transform(t), self.clock_ns, canvas)?;
        let text = said.unwrap_or_else(|| format!("episode {} starts", self.episode));
        let scene = SceneUpdate {
            deletions: Vec::new(),
            entities: vec![
                path_entity(t, self.path.iter().copied()),
                said_over_robot(t, text, 0.15),
            ],
        };
        self.painter
            .put(|c| &c.robot, &scene, self.clock_ns, canvas)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canvas::Collected;
    use crate::scene::{ARENA, EPISODE, ROBOT, TF};
    use foxglove::messages::FrameTransform;
    use prost::Message;

    const MAP: &str = "..E\n~#.\n:..";

    #[test]
    fn a_grid_run_draws_the_cells_walls_agent_and_episode() {
        let task = GridTask::from_map(MAP, 0, 0, 1).expect("a small task");
        let mut drawn = Collected::default();
        let ok = |r: Result<(), std::convert::Infallible>| r.unwrap_or_else(|e| match e {});
        let mut run = GridRun::start(&task, &mut drawn).unwrap_or_else(|e| match e {});
        ok(run.begin_episode(0, 6, &mut drawn));
        ok(run.step(0, 0, 3, -0.01, 12.0, &mut drawn));
        ok(run.end_episode(false, &mut drawn));

        let arena = SceneUpdate::decode(drawn.on(ARENA).next().expect("drawn")).expect("decodes");
        let cubes = &arena.entities[0].cubes;
        // A tile per cell, then at least the border (3 cells a side, 4 sides).
        assert!(cubes.len() >= 9 + 12, "{}", cubes.len());
        let tf: Vec<FrameTransform> = drawn
            .on(TF)
            .map(|b| FrameTransform::decode(b).expect("decodes"))
            .collect();
        // The start, three on the way, the arrival.
        assert_eq!(tf.len(), 2 + 3);
        // Cell 6 is the south-west corner; cell 3 is north of it.
        let ys: Vec<f64> = tf.iter().map(|t| t.translation.expect("at").y).collect();
        let a = tf[0].translation.expect("at");
        assert!(
            (a.x - 0.05).abs() < 1e-9 && (a.y - 0.05).abs() < 1e-9,
            "{a:?}"
        );
        assert!((ys[4] - 0.15).abs() < 1e-9, "{ys:?}");
        // Gliding: no transform moves the agent more than a quarter of a cell.
        assert!(
            ys.windows(2)
                .all(|w| (w[1] - w[0]).abs() <= CELL_M / 4.0 + 1e-9),
            "{ys:?}"
        );
        assert_eq!(drawn.on(ROBOT).count(), 3, "the body, then one per arrival");
        assert_eq!(drawn.on(EPISODE).count(), 1);
    }

    /// An episode's end as the file holds it (the derived schema numbers the fields 1..=n).
    #[derive(Clone, PartialEq, prost::Message)]
    struct EndTwin {
        #[prost(uint32, tag = "1")]
        episode: u32,
        #[prost(double, tag = "2")]
        reward: f64,
        #[prost(uint32, tag = "3")]
        actions: u32,
        #[prost(string, tag = "4")]
        outcome: String,
    }

    /// A long episode that reaches the exit has a negative total (−0.01 a step): it is an
    /// exit all the same; one that walks into fire is fire, one stopped at the cap cut short.
    #[test]
    fn an_episode_ends_as_the_cell_it_ended_on_whatever_its_total() {
        let task = GridTask::from_map("..E\nF#.\n:..", 0, 0, 1).expect("a small task");
        let mut drawn = Collected::default();
        let ok = |r: Result<(), std::convert::Infallible>| r.unwrap_or_else(|e| match e {});
        let mut run = GridRun::start(&task, &mut drawn).unwrap_or_else(|e| match e {});
        // From cell 1 west and back many times, then east onto the exit (cell 2).
        ok(run.begin_episode(0, 1, &mut drawn));
        for _ in 0..60 {
            ok(run.step(3, 3, 0, -0.01, 1.0, &mut drawn));
            ok(run.step(1, 1, 1, -0.01, 1.0, &mut drawn));
        }
        ok(run.step(1, 1, 2, 1.0, 1.0, &mut drawn));
        ok(run.end_episode(true, &mut drawn));
        // From the soil (cell 6) north into the fire (cell 3).
        ok(run.begin_episode(1, 6, &mut drawn));
        ok(run.step(0, 0, 3, -1.0, 1.0, &mut drawn));
        ok(run.end_episode(true, &mut drawn));
        ok(run.begin_episode(2, 7, &mut drawn));
        ok(run.end_episode(false, &mut drawn));
        let ends: Vec<EndTwin> = drawn
            .on(EPISODE)
            .map(|b| EndTwin::decode(b).expect("decodes"))
            .collect();
        assert!(ends[0].reward < 0.0, "{:?}", ends[0]);
        let outcomes: Vec<&str> = ends.iter().map(|e| e.outcome.as_str()).collect();
        assert_eq!(outcomes, ["exit", "fire", "cut short"]);
    }
}
