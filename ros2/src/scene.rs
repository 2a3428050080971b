//! The group's samples as ROS 2 messages: what the ROS 2 node publishes and a rosbag2 file
//! holds (see [`Topic`] for the topics, types and QoS).
//!
//! [`RosScene`] follows the run as the Foxglove scene does (`tes_viewer::scene`): the world
//! map, each observation (the robot's pose, the episode's path, its end), each command (a
//! decision and its latency), each motor report (the robot moving between observations, dead
//! reckoned from its wheels) and the processes' log lines; it hands each message to a
//! [`Sink`].

use tes_perception_sim::arena::{self, Arena, ArenaId, MarkColour, Surface};
use tes_topics::{
    Command, KEEP_ALIVE_ACTION, MotorState, Observation, WorldMap, motor_flags, observation_flags,
};
use tes_viewer::robot::{FloorPose, Odometry};

use crate::msg::{
    self, ColorRgba, Float64, Header, Log, Marker, MarkerArray, Path, Point, Pose, PoseStamped,
    Quaternion, TfMessage, Time, Transform, TransformStamped, UInt32, Vector3, log_level, marker,
};

/// The frame the arena is in: x east, y north, z up, the origin at its south-west corner, m.
pub const ARENA_FRAME: &str = "arena";
/// The robot's own frame: x ahead, y to its left, z up, between its wheels.
pub const ROBOT_FRAME: &str = "robot";

/// Metres per centimetre (the worlds are in centimetres, ROS 2 in metres).
const M_PER_CM: f64 = 0.01;

mod grid;
use grid::GridWorld;

/// How a topic's messages are delivered (ROS 2's QoS profile, as `ros2 topic info -v` says).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Samples kept per writer (history `KEEP_LAST`).
    pub depth: i32,
    /// Durability `TRANSIENT_LOCAL`: a late subscriber gets the last `depth` samples
    /// ("latched"); else `VOLATILE`.
    pub transient_local: bool,
}

/// The group's ROS 2 topics. All are reliable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Topic {
    /// `/tf`, `tf2_msgs/msg/TFMessage`: `arena → robot` at each observation and as it moves.
    Tf,
    /// `/tes/arena`, `visualization_msgs/msg/MarkerArray`, latched: the arena and the robot's
    /// body.
    Arena,
    /// `/tes/path`, `nav_msgs/msg/Path`: the episode's poses so far.
    Path,
    /// `/tes/decision/action`, `std_msgs/msg/UInt32`: each decision's action.
    Action,
    /// `/tes/decision/latency_us`, `std_msgs/msg/Float64`: each decision's latency, µs.
    Latency,
    /// `/tes/episode/reward`, `std_msgs/msg/Float64`: each episode's reward.
    Reward,
    /// `/tes/episode/end`, `std_msgs/msg/String`: `episode N: reward R, A actions, OUTCOME`.
    EpisodeEnd,
    /// `/rosout`, `rcl_interfaces/msg/Log`: the processes' log lines (logger = the role).
    Rosout,
}

impl Topic {
    /// Every topic.
    pub const ALL: [Topic; 8] = [
        Topic::Tf,
        Topic::Arena,
        Topic::Path,
        Topic::Action,
        Topic::Latency,
        Topic::Reward,
        Topic::EpisodeEnd,
        Topic::Rosout,
    ];

    /// Its ROS 2 name.
    pub fn name(self) -> &'static str {
        match self {
            Topic::Tf => "/tf",
            Topic::Arena => "/tes/arena",
            Topic::Path => "/tes/path",
            Topic::Action => "/tes/decision/action",
            Topic::Latency => "/tes/decision/latency_us",
            Topic::Reward => "/tes/episode/reward",
            Topic::EpisodeEnd => "/tes/episode/end",
            Topic::Rosout => "/rosout",
        }
    }

    /// Its message type.
    pub fn definition(self) -> &'static msg::Definition {
        match self {
            Topic::Tf => &msg::defs::TF_MESSAGE,
            Topic::Arena => &msg::defs::MARKER_ARRAY,
            Topic::Path => &msg::defs::PATH,
            Topic::Action => &msg::defs::UINT32,
            Topic::Latency | Topic::Reward => &msg::defs::FLOAT64,
            Topic::EpisodeEnd => &msg::defs::STRING,
            Topic::Rosout => &msg::defs::LOG,
        }
    }

    /// Its QoS, as ROS 2's own publishers of these topics use: `/tf` as tf2's broadcaster
    /// (depth 100), `/rosout` as rcl's (latched, depth 1000), the arena latched.
    pub fn qos(self) -> Qos {
        match self {
            Topic::Tf => Qos {
                depth: 100,
                transient_local: false,
            },
            Topic::Arena => Qos {
                depth: 1,
                transient_local: true,
            },
            Topic::Rosout => Qos {
                depth: 1000,
                transient_local: true,
            },
            _ => Qos {
                depth: 10,
                transient_local: false,
            },
        }
    }
}

/// One message of the group on its topic.
#[derive(Debug, Clone, PartialEq)]
pub enum RosMessage {
    /// On [`Topic::Tf`].
    Tf(TfMessage),
    /// On [`Topic::Arena`].
    Arena(MarkerArray),
    /// On [`Topic::Path`].
    Path(Path),
    /// On [`Topic::Action`].
    Action(UInt32),
    /// On [`Topic::Latency`].
    Latency(Float64),
    /// On [`Topic::Reward`].
    Reward(Float64),
    /// On [`Topic::EpisodeEnd`].
    EpisodeEnd(msg::Text),
    /// On [`Topic::Rosout`].
    Rosout(Log),
}

impl RosMessage {
    /// Its topic.
    pub fn topic(&self) -> Topic {
        match self {
            RosMessage::Tf(_) => Topic::Tf,
            RosMessage::Arena(_) => Topic::Arena,
            RosMessage::Path(_) => Topic::Path,
            RosMessage::Action(_) => Topic::Action,
            RosMessage::Latency(_) => Topic::Latency,
            RosMessage::Reward(_) => Topic::Reward,
            RosMessage::EpisodeEnd(_) => Topic::EpisodeEnd,
            RosMessage::Rosout(_) => Topic::Rosout,
        }
    }

    /// Its CDR bytes, encapsulation header first.
    pub fn encode(&self) -> Result<Vec<u8>, msg::EncodeError> {
        match self {
            RosMessage::Tf(m) => msg::encode(m),
            RosMessage::Arena(m) => msg::encode(m),
            RosMessage::Path(m) => msg::encode(m),
            RosMessage::Action(m) => msg::encode(m),
            RosMessage::Latency(m) | RosMessage::Reward(m) => msg::encode(m),
            RosMessage::EpisodeEnd(m) => msg::encode(m),
            RosMessage::Rosout(m) => msg::encode(m),
        }
    }
}

/// Whether a message pictures the robot's motion, which a live peer may get at a screen's
/// pace instead of every one (a file gets every one).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Delivery {
    /// Every one.
    Always,
    /// The robot's motion: the newest supersedes the rest.
    Motion,
}

/// Where the scene's messages go: the ROS 2 node, a rosbag2 file, a test's list.
pub trait Sink {
    /// Why a message could not be taken.
    type Error;
    /// Takes `message`, stamped `wall_ns` (ns since the Unix epoch).
    fn put(
        &mut self,
        message: &RosMessage,
        wall_ns: u64,
        delivery: Delivery,
    ) -> Result<(), Self::Error>;
}

/// A sink that keeps every message (for tests and examples).
#[derive(Debug, Default)]
pub struct Collected(pub Vec<RosMessage>);

impl Sink for Collected {
    type Error = std::convert::Infallible;
    fn put(&mut self, m: &RosMessage, _: u64, _: Delivery) -> Result<(), Self::Error> {
        self.0.push(m.clone());
        Ok(())
    }
}

/// Every sink of a list, in turn; the first error stops the rest.
impl<S: Sink> Sink for [S] {
    type Error = S::Error;
    fn put(&mut self, m: &RosMessage, wall_ns: u64, d: Delivery) -> Result<(), S::Error> {
        self.iter_mut().try_for_each(|s| s.put(m, wall_ns, d))
    }
}

/// What the scene needs beyond the samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneSettings {
    /// Wall clock minus the monotonic clock, ns (the samples carry monotonic stamps).
    pub wall_offset_ns: i128,
    /// The brick's output ports of the left and right wheels.
    pub wheel_ports: [usize; 2],
}

impl SceneSettings {
    /// The settings of a run starting now, its wheels on the brick's ports `wheel_ports`.
    pub fn from_now(wheel_ports: [usize; 2]) -> Self {
        let wall_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as i128);
        Self {
            wall_offset_ns: wall_ns - i128::from(tes_runtime::clock::monotonic_ns()),
            wheel_ports,
        }
    }
}

impl Default for SceneSettings {
    fn default() -> Self {
        Self {
            wall_offset_ns: 0,
            wheel_ports: [1, 2],
        }
    }
}

/// The episode being followed.
#[derive(Debug, Default)]
struct Episode {
    number: Option<u32>,
    path: Vec<PoseStamped>,
    reward: f64,
}

/// Turns the group's samples into ROS 2 messages (see [`Topic`]).
#[derive(Debug)]
pub struct RosScene {
    settings: SceneSettings,
    arena: Option<Arena>,
    /// A world that is not an arena, drawn from its map.
    grid: Option<GridWorld>,
    odometry: Odometry,
    observed_ns: u64,
    episode: Episode,
    /// The world number of a map that is not an arena, said once.
    not_drawn: Option<u32>,
}

impl RosScene {
    /// A scene that has seen nothing yet.
    pub fn new(settings: SceneSettings) -> Self {
        Self {
            settings,
            arena: None,
            grid: None,
            odometry: Odometry::default(),
            observed_ns: 0,
            episode: Episode::default(),
            not_drawn: None,
        }
    }

    fn wall_ns(&self, stamp_ns: u64) -> u64 {
        (i128::from(stamp_ns) + self.settings.wall_offset_ns).clamp(0, i128::from(u64::MAX)) as u64
    }

    fn header(&self, stamp_ns: u64, frame: &str) -> Header {
        Header {
            stamp: Time::from_ns(self.wall_ns(stamp_ns)),
            frame_id: frame.to_owned(),
        }
    }

    /// The world map: the arena's markers (latched), or a grid world's drawn from its map
    /// (`scene/grid.rs`). A map that is neither has no markers, pose or path; its numbers and logs
    /// still go out.
    pub fn world_map<S: Sink + ?Sized>(
        &mut self,
        map: &WorldMap,
        stamp_ns: u64,
        sink: &mut S,
    ) -> Result<(), S::Error> {
        let header = self.header(stamp_ns, ARENA_FRAME);
        let markers = if let Ok(id) = ArenaId::from_number(map.world) {
            let arena = Arena::new(id);
            let markers = arena_markers(&arena, &header);
            self.arena = Some(arena);
            markers
        } else if let Some(grid) = GridWorld::from_map(map) {
            let markers = grid.markers(&header);
            self.grid = Some(grid);
            markers
        } else {
            if self.not_drawn.replace(map.world).is_none() {
                tracing::info!(
                    "world {} is neither an arena nor a grid: no markers, pose or path",
                    map.world
                );
            }
            return Ok(());
        };
        sink.put(
            &RosMessage::Arena(markers),
            self.wall_ns(stamp_ns),
            Delivery::Always,
        )
    }

    /// An observation: the robot's pose on `/tf`, the episode's path, and at its end the
    /// reward and how it ended.
    pub fn observation<S: Sink + ?Sized>(
        &mut self,
        o: &Observation,
        sink: &mut S,
    ) -> Result<(), S::Error> {
        let starts = o.flags & observation_flags::EPISODE_START != 0
            || self.episode.number != Some(o.episode);
        if starts {
            self.episode = Episode {
                number: Some(o.episode),
                ..Episode::default()
            };
        } else {
            self.episode.reward += f64::from(o.reward);
        }
        self.observed_ns = self.observed_ns.max(o.stamp_ns);
        let wall = self.wall_ns(o.stamp_ns);
        let drawn = self.arena.is_some() || self.grid.is_some();
        if drawn {
            let pose = self.pose_of(o.state);
            self.odometry.observed(pose);
            if let Some(p) = pose {
                sink.put(&self.tf(p, o.stamp_ns), wall, Delivery::Motion)?;
                self.episode.path.push(PoseStamped {
                    header: self.header(o.stamp_ns, ARENA_FRAME),
                    pose: ros_pose(p),
                });
                let path = Path {
                    header: self.header(o.stamp_ns, ARENA_FRAME),
                    poses: self.episode.path.clone(),
                };
                sink.put(&RosMessage::Path(path), wall, Delivery::Motion)?;
            }
        }
        if o.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED) != 0 {
            self.episode_end(o, wall, sink)?;
        }
        Ok(())
    }

    /// Where the robot is drawn in state `s` (`None` out of the area or in no drawn world).
    fn pose_of(&self, s: tes_topics::StateAttributes) -> Option<FloorPose> {
        if let Some(arena) = &self.arena {
            return arena
                .state_index(s)
                .and_then(|i| arena.state_pose(i))
                .map(|p| FloorPose {
                    position: p.position,
                    heading: p.heading,
                });
        }
        self.grid.as_ref().and_then(|g| g.pose(s))
    }

    fn episode_end<S: Sink + ?Sized>(
        &self,
        o: &Observation,
        wall: u64,
        sink: &mut S,
    ) -> Result<(), S::Error> {
        let outcome = if o.flags & observation_flags::TRUNCATED != 0 {
            "cut short"
        } else if o.state.is_out() {
            "left the area"
        } else if o.reward > 0.0 {
            "goal"
        } else {
            "failed"
        };
        let reward = self.episode.reward;
        sink.put(
            &RosMessage::Reward(Float64 { data: reward }),
            wall,
            Delivery::Always,
        )?;
        let text = format!(
            "episode {}: reward {reward:.3}, {} actions, {outcome}",
            o.episode, o.step
        );
        sink.put(
            &RosMessage::EpisodeEnd(msg::Text { data: text }),
            wall,
            Delivery::Always,
        )
    }

    /// A command: the decision's action and latency (keep-alives are not decisions).
    pub fn command<S: Sink + ?Sized>(&mut self, c: &Command, sink: &mut S) -> Result<(), S::Error> {
        if c.action == KEEP_ALIVE_ACTION {
            return Ok(());
        }
        let wall = self.wall_ns(c.stamp_ns);
        sink.put(
            &RosMessage::Action(UInt32 { data: c.action }),
            wall,
            Delivery::Always,
        )?;
        let latency_us = if c.observed_ns > 0 {
            c.stamp_ns.saturating_sub(c.observed_ns) as f64 / 1e3
        } else {
            0.0
        };
        sink.put(
            &RosMessage::Latency(Float64 { data: latency_us }),
            wall,
            Delivery::Always,
        )
    }

    /// A motor report: the robot's pose as its wheels turn.
    pub fn motor_state<S: Sink + ?Sized>(
        &mut self,
        m: &MotorState,
        sink: &mut S,
    ) -> Result<(), S::Error> {
        if m.flags & motor_flags::LINK_DOWN != 0 || self.arena.is_none() {
            return Ok(());
        }
        let [l, r] = self.settings.wheel_ports;
        let (Some(&left), Some(&right)) = (m.tacho_count.get(l), m.tacho_count.get(r)) else {
            return Ok(());
        };
        if m.stamp_ns <= self.observed_ns {
            self.odometry.rebase([left, right]);
            return Ok(());
        }
        match self.odometry.wheels([left, right]) {
            Some(pose) => sink.put(
                &self.tf(pose, m.stamp_ns),
                self.wall_ns(m.stamp_ns),
                Delivery::Motion,
            ),
            None => Ok(()),
        }
    }

    /// A process's log line (`role` names the process) on `/rosout`.
    pub fn log_line<S: Sink + ?Sized>(
        &mut self,
        role: &str,
        text: &str,
        stamp_ns: u64,
        sink: &mut S,
    ) -> Result<(), S::Error> {
        let wall = self.wall_ns(stamp_ns);
        let line = Log {
            stamp: Time::from_ns(wall),
            level: level_of(text),
            name: role.to_owned(),
            msg: text.to_owned(),
            ..Log::default()
        };
        sink.put(&RosMessage::Rosout(line), wall, Delivery::Always)
    }

    fn tf(&self, pose: FloorPose, stamp_ns: u64) -> RosMessage {
        let p = ros_pose(pose);
        RosMessage::Tf(TfMessage {
            transforms: vec![TransformStamped {
                header: self.header(stamp_ns, ARENA_FRAME),
                child_frame_id: ROBOT_FRAME.to_owned(),
                transform: Transform {
                    translation: Vector3 {
                        x: p.position.x,
                        y: p.position.y,
                        z: p.position.z,
                    },
                    rotation: p.orientation,
                },
            }],
        })
    }
}

fn ros_pose(p: FloorPose) -> Pose {
    Pose {
        position: Point {
            x: p.position.x * M_PER_CM,
            y: p.position.y * M_PER_CM,
            z: 0.0,
        },
        orientation: Quaternion::about_z(p.heading),
    }
}

/// The level of a `tracing` line (`… WARN target: message`), from its first words.
fn level_of(text: &str) -> u8 {
    let head: String = text.chars().take(48).collect();
    let has = |w: &str| head.split_whitespace().any(|x| x == w);
    if has("ERROR") {
        log_level::ERROR
    } else if has("WARN") {
        log_level::WARN
    } else if has("DEBUG") || has("TRACE") {
        log_level::DEBUG
    } else {
        log_level::INFO
    }
}

fn colour(c: foxglove::messages::Color) -> ColorRgba {
    ColorRgba {
        r: c.r as f32,
        g: c.g as f32,
        b: c.b as f32,
        a: c.a as f32,
    }
}

fn surface_colour(s: Surface) -> ColorRgba {
    colour(tes_viewer::arena::surface_colour(s))
}

fn at(x: f64, y: f64, z: f64) -> Pose {
    Pose {
        position: Point { x, y, z },
        orientation: Quaternion::default(),
    }
}

fn cm(p: arena::DVec2, z: f64) -> Point {
    Point {
        x: p.x * M_PER_CM,
        y: p.y * M_PER_CM,
        z,
    }
}

/// The arena as markers in [`ARENA_FRAME`] (namespace `arena`): the floor, the tiles of
/// other surfaces, the death spots, the marks, the ball, the cell grid; and the robot's body
/// in [`ROBOT_FRAME`] (namespace `robot`), which moves with `/tf`.
pub fn arena_markers(arena: &Arena, header: &Header) -> MarkerArray {
    let [floor, surfaces, death] = ground_markers(arena, header);
    let [marks, ball] = object_markers(arena, header);
    MarkerArray {
        markers: vec![
            floor,
            surfaces,
            death,
            marks,
            ball,
            grid_marker(arena, header),
            robot_body(header),
        ],
    }
}

/// A marker `id` of `type` in namespace `arena`, with `header`, to fill in.
fn arena_marker(header: &Header, id: i32, r#type: i32) -> Marker {
    Marker {
        header: header.clone(),
        ns: "arena".into(),
        id,
        r#type,
        action: marker::ADD,
        ..Marker::default()
    }
}

/// The floor, the tiles of other surfaces and the death spots.
fn ground_markers(arena: &Arena, header: &Header) -> [Marker; 3] {
    let side = arena.side_cm() * M_PER_CM;
    let cell = arena.cell_cm() * M_PER_CM;
    let base = |id: i32, r#type: i32| arena_marker(header, id, r#type);
    let n = arena.cells();
    let cells = || (0..n).flat_map(move |y| (0..n).map(move |x| (x, y)));
    let floor = Marker {
        pose: at(side / 2.0, side / 2.0, -0.01),
        scale: Vector3 {
            x: side,
            y: side,
            z: 0.02,
        },
        color: surface_colour(arena.layout().floor),
        ..base(0, marker::CUBE)
    };
    let tiles: Vec<(usize, usize)> = cells()
        .filter(|&(x, y)| arena.surface(x, y) != arena.layout().floor)
        .collect();
    let surfaces = Marker {
        pose: at(0.0, 0.0, 0.0),
        scale: Vector3 {
            x: cell,
            y: cell,
            z: 0.002,
        },
        points: tiles
            .iter()
            .map(|&(x, y)| cm(arena.cell_centre(x, y), 0.001))
            .collect(),
        colors: tiles
            .iter()
            .map(|&(x, y)| surface_colour(arena.surface(x, y)))
            .collect(),
        color: surface_colour(arena.layout().floor),
        ..base(1, marker::CUBE_LIST)
    };
    let death = Marker {
        pose: at(0.0, 0.0, 0.0),
        scale: Vector3 {
            x: cell * 0.8,
            y: cell * 0.8,
            z: 0.006,
        },
        points: cells()
            .filter(|&(x, y)| arena.is_death_cell(x, y))
            .map(|(x, y)| cm(arena.cell_centre(x, y), 0.003))
            .collect(),
        color: colour(tes_viewer::arena::DEATH),
        ..base(2, marker::CUBE_LIST)
    };
    [floor, surfaces, death]
}

/// The marks and the ball.
fn object_markers(arena: &Arena, header: &Header) -> [Marker; 2] {
    let base = |id: i32, r#type: i32| arena_marker(header, id, r#type);
    let marks: Vec<(arena::DVec2, MarkColour)> = [MarkColour::Blue, MarkColour::Green]
        .into_iter()
        .flat_map(|c| arena.marks(c).iter().map(move |&m| (m, c)))
        .collect();
    let marks = Marker {
        pose: at(0.0, 0.0, 0.0),
        scale: Vector3 {
            x: 0.06,
            y: 0.06,
            z: 0.004,
        },
        points: marks.iter().map(|&(m, _)| cm(m, 0.004)).collect(),
        colors: marks
            .iter()
            .map(|&(_, c)| colour(tes_viewer::arena::mark_colour(c)))
            .collect(),
        color: colour(tes_viewer::arena::mark_colour(MarkColour::Blue)),
        ..base(3, marker::CUBE_LIST)
    };
    let ball_at = cm(arena.ball(), 0.035);
    let ball = Marker {
        pose: at(ball_at.x, ball_at.y, ball_at.z),
        scale: Vector3 {
            x: 0.07,
            y: 0.07,
            z: 0.07,
        },
        color: colour(tes_viewer::arena::BALL),
        ..base(4, marker::SPHERE)
    };
    [marks, ball]
}

/// The cell grid's lines.
fn grid_marker(arena: &Arena, header: &Header) -> Marker {
    let side = arena.side_cm() * M_PER_CM;
    let cell = arena.cell_cm() * M_PER_CM;
    let n = arena.cells();
    Marker {
        pose: at(0.0, 0.0, 0.0),
        scale: Vector3 {
            x: 0.003,
            ..Vector3::default()
        },
        points: (0..=n)
            .flat_map(|i| {
                let d = i as f64 * cell;
                [(d, 0.0), (d, side), (0.0, d), (side, d)]
            })
            .map(|(x, y)| Point { x, y, z: 0.0015 })
            .collect(),
        color: ColorRgba {
            r: 0.15,
            g: 0.15,
            b: 0.15,
            a: 0.5,
        },
        ..arena_marker(header, 5, marker::LINE_LIST)
    }
}

/// The robot's body in [`ROBOT_FRAME`] (namespace `robot`, frame-locked: it moves with `/tf`).
fn robot_body(header: &Header) -> Marker {
    Marker {
        header: Header {
            stamp: header.stamp,
            frame_id: ROBOT_FRAME.into(),
        },
        ns: "robot".into(),
        pose: at(0.0, 0.0, 0.05),
        scale: Vector3 {
            x: 0.16,
            y: 0.14,
            z: 0.10,
        },
        color: ColorRgba {
            r: 0.92,
            g: 0.55,
            b: 0.08,
            a: 1.0,
        },
        frame_locked: true,
        ..arena_marker(header, 0, marker::CUBE)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_topics::StateAttributes;

    fn arena_map() -> Box<WorldMap> {
        let mut map = Box::new(WorldMap::EMPTY);
        map.world = 3;
        map
    }

    #[test]
    fn an_episode_gives_tf_path_reward_and_its_end() {
        let mut scene = RosScene::new(SceneSettings::default());
        let mut out = Collected::default();
        scene.world_map(&arena_map(), 0, &mut out).unwrap();
        let RosMessage::Arena(markers) = &out.0[0] else {
            panic!("the arena first, got {:?}", out.0[0].topic());
        };
        assert_eq!(markers.markers.len(), 7);
        assert!(
            markers
                .markers
                .iter()
                .all(|m| m.header.frame_id == ARENA_FRAME
                    || (m.header.frame_id == ROBOT_FRAME && m.frame_locked))
        );
        let state = StateAttributes {
            x: 2,
            y: 3,
            orientation: 1,
            reserved: 0,
        };
        let first = Observation {
            episode: 0,
            step: 0,
            state,
            flags: observation_flags::EPISODE_START,
            stamp_ns: 1_000,
            ..Observation::default()
        };
        let last = Observation {
            step: 1,
            reward: -0.05,
            flags: observation_flags::TRUNCATED,
            stamp_ns: 2_000,
            ..first
        };
        scene.observation(&first, &mut out).unwrap();
        let command = Command {
            action: 1,
            observed_ns: 1_000,
            stamp_ns: 31_000,
            ..Command::default()
        };
        scene.command(&command, &mut out).unwrap();
        scene.observation(&last, &mut out).unwrap();
        let topics: Vec<Topic> = out.0.iter().map(RosMessage::topic).collect();
        use Topic::*;
        assert_eq!(
            topics,
            [
                Arena, Tf, Path, Action, Latency, Tf, Path, Reward, EpisodeEnd
            ]
        );
        let RosMessage::Path(path) = &out.0[6] else {
            unreachable!()
        };
        assert_eq!(path.poses.len(), 2);
        assert_eq!(out.0[4], RosMessage::Latency(Float64 { data: 30.0 }));
        assert_eq!(
            out.0[7],
            RosMessage::Reward(Float64 {
                data: f64::from(-0.05f32)
            })
        );
        let RosMessage::Tf(tf) = &out.0[1] else {
            unreachable!()
        };
        let t = &tf.transforms[0];
        assert_eq!(
            (t.header.frame_id.as_str(), t.child_frame_id.as_str()),
            ("arena", "robot")
        );
        // Cell (2, 3) of Env 3's 10 × 10 cells on a 6 ft side: its centre in metres.
        let cell_m = arena::Arena::new(ArenaId::Env3).cell_cm() * M_PER_CM;
        assert!((t.transform.translation.x - 2.5 * cell_m).abs() < 1e-9);
        assert!((t.transform.translation.y - 3.5 * cell_m).abs() < 1e-9);
    }

    #[test]
    fn a_log_line_keeps_its_level_and_role() {
        let mut scene = RosScene::new(SceneSettings {
            wall_offset_ns: 5_000_000_000,
            ..SceneSettings::default()
        });
        let mut out = Collected::default();
        scene
            .log_line("bridge", "2026 WARN tes_bridge: link slow", 7, &mut out)
            .unwrap();
        let RosMessage::Rosout(line) = &out.0[0] else {
            unreachable!()
        };
        assert_eq!(
            (line.level, line.name.as_str()),
            (log_level::WARN, "bridge")
        );
        assert_eq!(line.stamp, Time { sec: 5, nanosec: 7 });
    }

    #[test]
    fn every_topic_has_a_standard_type() {
        for t in Topic::ALL {
            assert!(t.name().starts_with('/'));
            let d = t.definition();
            assert!(
                [
                    "tf2_msgs",
                    "visualization_msgs",
                    "nav_msgs",
                    "std_msgs",
                    "rcl_interfaces"
                ]
                .contains(&d.package),
                "{}",
                d.full_name()
            );
        }
    }
}
