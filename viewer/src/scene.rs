//! The run as a scene: each sample of the group becomes the Foxglove messages that draw it.
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/arena` | `foxglove.SceneUpdate` | the arena, once (again for a late live client) |
//! | `/arena/points` | `foxglove.PointCloud` | the same as coloured points (Rerun draws these) |
//! | `/tf` | `foxglove.FrameTransform` | `arena → robot`: where the world has the robot, moving as its wheels turn |
//! | `/tf/belief` | `foxglove.FrameTransform` | `arena → belief`: what the controller believes (the observed cell, odometry between) |
//! | `/robot` | `foxglove.SceneUpdate` | the robot's body, the belief's outline, its episode's path, its last decision |
//! | `/robot/pose` | `foxglove.PoseInFrame` | the robot's pose at each observation |
//! | `/robot/path` | `foxglove.PosesInFrame` | the episode's poses so far |
//! | `/log` | `foxglove.Log` | the processes' log lines |
//! | `/tes/decision` | `tes.Decision` | each decision: its action and latency |
//! | `/tes/episode` | `tes.EpisodeEnd` | each episode's reward, length and end |
//! | `/tes/decision/latency_us` | `std_msgs/msg/Float64MultiArray` | the latency alone (Rerun plots it) |
//! | `/tes/episode/reward` | `std_msgs/msg/Float64MultiArray` | the reward alone (Rerun plots it) |

use foxglove::Encode;
use foxglove::messages::{
    LinePrimitive, Log, Point3, PoseInFrame, PosesInFrame, SceneEntity, SceneUpdate, TextPrimitive,
    Timestamp, line_primitive, log,
};
use tes_perception_sim::arena::{self, Arena, ArenaId, Effect};
use tes_topics::{
    Command, KEEP_ALIVE_ACTION, MotorState, Observation, WorldMap, WorldPose, motor_flags,
    observation_flags,
};

use crate::arena::{ARENA_FRAME, arena_points, arena_scene, at, rgb};
use crate::canvas::{Canvas, Channel, Drawing};
use crate::robot::{
    BELIEF_FRAME, FloorPose, Odometry, ROBOT_FRAME, WorldMotion, belief_body, body,
};
use crate::series::Sample;

/// Topic of the arena's scene.
pub const ARENA: &str = "/arena";
/// Topic of the arena's points.
pub const ARENA_POINTS: &str = "/arena/points";
/// Topic of the robot's transforms (`arena → robot`, where the world has it).
pub const TF: &str = "/tf";
/// Topic of the belief's transforms (`arena → belief`, what the controller believes).
pub const TF_BELIEF: &str = "/tf/belief";
/// Topic of the robot's scene entities.
pub const ROBOT: &str = "/robot";
/// Topic of the robot's observed poses.
pub const ROBOT_POSE: &str = "/robot/pose";
/// Topic of the episode's path.
pub const ROBOT_PATH: &str = "/robot/path";
/// Topic of the processes' log lines.
pub const LOG: &str = "/log";
/// Topic of the decisions.
pub const DECISION: &str = "/tes/decision";
/// Topic of the episodes' ends.
pub const EPISODE: &str = "/tes/episode";
/// Topic of each decision's latency as a plain series, µs.
pub const LATENCY_SERIES: &str = "/tes/decision/latency_us";
/// Topic of each episode's reward as a plain series.
pub const REWARD_SERIES: &str = "/tes/episode/reward";

/// One decision of the controller.
#[derive(Debug, Clone, Default, PartialEq, foxglove::Encode)]
pub struct Decision {
    /// Episode, from 0.
    pub episode: u32,
    /// Action index within the episode, from 0.
    pub step: u32,
    /// The action chosen.
    pub action: u32,
    /// Its name (`forward`, `spin`, `pivot`).
    pub action_name: String,
    /// Observation published → command published, µs.
    pub latency_us: f64,
}

/// The end of an episode.
#[derive(Debug, Clone, Default, PartialEq, foxglove::Encode)]
pub struct EpisodeEnd {
    /// Episode, from 0.
    pub episode: u32,
    /// Reward collected.
    pub reward: f64,
    /// Actions taken.
    pub actions: u32,
    /// How it ended: `ball`, `death spot`, `left the area`, or `cut short` (stuck, step cap).
    pub outcome: String,
}

/// The channels of a scene, each built once.
#[derive(Debug, Clone)]
pub(crate) struct Channels {
    pub(crate) arena: Channel,
    pub(crate) arena_points: Channel,
    pub(crate) tf: Channel,
    pub(crate) tf_belief: Channel,
    pub(crate) robot: Channel,
    pub(crate) robot_pose: Channel,
    pub(crate) robot_path: Channel,
    pub(crate) log: Channel,
    pub(crate) decision: Channel,
    pub(crate) episode: Channel,
    pub(crate) latency_series: Channel,
    pub(crate) reward_series: Channel,
}

impl Channels {
    fn new() -> Self {
        Self {
            arena: Channel::of::<SceneUpdate>(ARENA),
            arena_points: Channel::of::<foxglove::messages::PointCloud>(ARENA_POINTS),
            tf: Channel::of::<foxglove::messages::FrameTransform>(TF),
            tf_belief: Channel::of::<foxglove::messages::FrameTransform>(TF_BELIEF),
            robot: Channel::of::<SceneUpdate>(ROBOT),
            robot_pose: Channel::of::<PoseInFrame>(ROBOT_POSE),
            robot_path: Channel::of::<PosesInFrame>(ROBOT_PATH),
            log: Channel::of::<Log>(LOG),
            decision: Channel::of::<Decision>(DECISION),
            episode: Channel::of::<EpisodeEnd>(EPISODE),
            latency_series: Channel::of::<Sample>(LATENCY_SERIES),
            reward_series: Channel::of::<Sample>(REWARD_SERIES),
        }
    }

    /// Every channel, in the order of the table above.
    fn all(&self) -> [&Channel; 12] {
        [
            &self.arena,
            &self.arena_points,
            &self.tf,
            &self.tf_belief,
            &self.robot,
            &self.robot_pose,
            &self.robot_path,
            &self.log,
            &self.decision,
            &self.episode,
            &self.latency_series,
            &self.reward_series,
        ]
    }
}

/// What the scene needs to know of the run beyond its samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneSettings {
    /// Wall clock minus the monotonic clock, ns: the samples carry monotonic times, viewers
    /// show wall-clock ones.
    pub wall_offset_ns: i128,
    /// The brick's output ports of the left and right wheel motors.
    pub wheel_ports: [usize; 2],
}

impl Default for SceneSettings {
    fn default() -> Self {
        Self {
            wall_offset_ns: 0,
            wheel_ports: [1, 2],
        }
    }
}

/// The episode being drawn.
#[derive(Debug, Default)]
struct EpisodeTrack {
    number: Option<u32>,
    path: Vec<FloorPose>,
    reward: f64,
    last_state: Option<usize>,
}

/// How long after the first observation a world that has sent no pose is taken to send none
/// (its perception runs on another host), ns. Its poses follow each observation at once, but
/// the recorder takes a whole batch of observations before their poses, so a count of
/// observations would give up on a world that has one.
const WORLD_SILENT_NS: u64 = 1_000_000_000;

/// How many recent observations and decisions the scene remembers to label what answers or
/// follows them: far more than come between two drains of the recorder at the fastest pace.
const REMEMBERED: usize = 64;

/// Where in the run an observation was, as a decision answering it is labelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Observed {
    episode: u32,
    step: u32,
}

/// The last [`REMEMBERED`] items of a kind, found by their sequence number: the recorder
/// hands over observations and commands in batches, so "the last one seen" is not the one a
/// message refers to.
#[derive(Debug)]
struct Recent<T> {
    items: std::collections::VecDeque<(u64, T)>,
}

impl<T: Copy> Recent<T> {
    fn new() -> Self {
        Self {
            items: std::collections::VecDeque::with_capacity(REMEMBERED),
        }
    }

    fn remember(&mut self, seq: u64, item: T) {
        if self.items.len() == REMEMBERED {
            self.items.pop_front();
        }
        self.items.push_back((seq, item));
    }

    fn find(&self, seq: u64) -> Option<T> {
        self.items
            .iter()
            .rev()
            .find(|(s, _)| *s == seq)
            .map(|(_, t)| *t)
    }

    fn newest_seq(&self) -> Option<u64> {
        self.items.back().map(|(s, _)| *s)
    }
}

/// How a drawing may be delivered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Delivery {
    /// Always, as every drawing to a file.
    Always,
    /// A picture of the robot's motion: a live view may skip it ([`Drawing::motion`]).
    Motion,
}

/// Encodes messages onto the scene's channels, each once into a buffer it keeps, with times
/// moved to the wall clock; each channel's times never go back.
#[derive(Debug)]
pub(crate) struct Painter {
    channels: Channels,
    buffer: Vec<u8>,
    wall_offset_ns: i128,
    /// The time of each channel's last drawing (in the order of [`Channels::all`]).
    drawn_ns: [u64; 12],
}

impl Painter {
    pub(crate) fn new(wall_offset_ns: i128) -> Self {
        Self {
            channels: Channels::new(),
            buffer: Vec::with_capacity(4096),
            wall_offset_ns,
            drawn_ns: [0; 12],
        }
    }

    fn wall_ns(&self, stamp_ns: u64) -> u64 {
        (i128::from(stamp_ns) + self.wall_offset_ns).clamp(0, i128::from(u64::MAX)) as u64
    }

    /// A monotonic stamp as a Foxglove (wall-clock) timestamp.
    pub(crate) fn timestamp(&self, stamp_ns: u64) -> Timestamp {
        let wall = self.wall_ns(stamp_ns);
        Timestamp::new((wall / 1_000_000_000) as u32, (wall % 1_000_000_000) as u32)
    }

    /// Encodes `message` once and puts it on `canvas`, on the channel `pick` chooses.
    pub(crate) fn put<T: Encode, C: Canvas>(
        &mut self,
        pick: fn(&Channels) -> &Channel,
        message: &T,
        stamp_ns: u64,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        self.put_as(pick, message, stamp_ns, Delivery::Always, canvas)
    }

    /// [`put`](Self::put), saying how the drawing may be delivered.
    pub(crate) fn put_as<T: Encode, C: Canvas>(
        &mut self,
        pick: fn(&Channels) -> &Channel,
        message: &T,
        stamp_ns: u64,
        delivery: Delivery,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        self.buffer.clear();
        if let Err(e) = message.encode(&mut self.buffer) {
            // Only a buffer that cannot grow fails; a Vec grows.
            tracing::warn!("cannot encode a drawing: {e}");
            return Ok(());
        }
        let channel = pick(&self.channels);
        // The recorder hands samples on in time order; a straggler it could not wait for
        // (a publisher descheduled for longer than it waits) is drawn at its channel's last
        // time rather than before it, since viewers and MCAP readers expect each channel in
        // time order.
        let index = self
            .channels
            .all()
            .iter()
            .position(|c| std::ptr::eq(*c, channel));
        let stamp_ns = match index.and_then(|i| self.drawn_ns.get_mut(i)) {
            Some(last) => {
                *last = (*last).max(stamp_ns);
                *last
            }
            None => stamp_ns,
        };
        let wall_ns = self.wall_ns(stamp_ns);
        canvas.draw(Drawing {
            channel,
            data: &self.buffer,
            stamp_ns,
            wall_ns,
            motion: delivery == Delivery::Motion,
        })
    }

    /// Every channel, in the order of the module's table.
    pub(crate) fn channels(&self) -> [&Channel; 12] {
        self.channels.all()
    }
}

/// Turns the group's samples into drawings (see the module's table).
#[derive(Debug)]
pub struct Scene {
    settings: SceneSettings,
    painter: Painter,
    arena: Option<Arena>,
    odometry: Odometry,
    /// The world's motion of the robot, drawn from its poses and the wheels' reports.
    world: WorldMotion,
    /// The world's last pose of the robot: `None` until perception's first (a group whose
    /// perception runs on another host never sends one; the belief is drawn as `robot` then).
    world_pose: Option<FloorPose>,
    /// When the first observation was published: a world that has sent no pose
    /// [`WORLD_SILENT_NS`] after it is taken to send none, and the belief is drawn as `robot`.
    first_observed_ns: Option<u64>,
    /// The time of the last `arena → robot` transform: the world's motion is drawn after
    /// the fact, and never back in time.
    world_drawn_ns: u64,
    /// The command whose motion was drawn last.
    world_after: u64,
    /// When the last observation was published: motor reports from before it tell of a
    /// motion its pose already holds.
    observed_ns: u64,
    episode: EpisodeTrack,
    /// Recent observations, for the decisions answering them.
    observed: Recent<Observed>,
    /// Recent decisions' actions, for the observations they led to.
    decided: Recent<u32>,
    /// Decisions whose observation has not been drawn yet (the recorder took the command
    /// first), drawn as soon as it is.
    waiting: std::collections::VecDeque<Command>,
    /// The world number of a map that is not an arena, said once.
    not_drawn: Option<u32>,
}

impl Scene {
    /// An empty scene: nothing is drawn until the world map arrives.
    pub fn new(settings: SceneSettings) -> Self {
        Self {
            settings,
            painter: Painter::new(settings.wall_offset_ns),
            arena: None,
            odometry: Odometry::default(),
            world: WorldMotion::default(),
            world_pose: None,
            first_observed_ns: None,
            world_drawn_ns: 0,
            world_after: 0,
            observed_ns: 0,
            episode: EpisodeTrack::default(),
            observed: Recent::new(),
            decided: Recent::new(),
            waiting: std::collections::VecDeque::new(),
            not_drawn: None,
        }
    }

    /// Every channel the scene draws on (a live server advertises them all at once).
    pub fn channels(&self) -> impl Iterator<Item = &Channel> {
        self.painter.channels().into_iter()
    }

    fn timestamp(&self, stamp_ns: u64) -> Timestamp {
        self.painter.timestamp(stamp_ns)
    }

    /// The world map: draws the arena and the robot's body.
    pub fn world_map<C: Canvas>(
        &mut self,
        map: &WorldMap,
        stamp_ns: u64,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        match ArenaId::from_number(map.world) {
            Ok(id) => self.arena = Some(Arena::new(id)),
            Err(_) => {
                if self.not_drawn.replace(map.world).is_none() {
                    tracing::warn!("world {} is not an arena: not drawn", map.world);
                }
                return Ok(());
            }
        }
        self.redraw(stamp_ns, canvas)
    }

    /// Draws what is drawn once again (the arena, the robot's body): for a viewer that
    /// joined after the start.
    pub fn redraw<C: Canvas>(&mut self, stamp_ns: u64, canvas: &mut C) -> Result<(), C::Error> {
        let Some(arena) = &self.arena else {
            return Ok(());
        };
        let t = self.timestamp(stamp_ns);
        let (scene, points) = (arena_scene(arena, t), arena_points(arena, t));
        self.painter.put(|c| &c.arena, &scene, stamp_ns, canvas)?;
        self.painter
            .put(|c| &c.arena_points, &points, stamp_ns, canvas)?;
        let robot = SceneUpdate {
            deletions: Vec::new(),
            entities: vec![body(t, 1.0), belief_body(t)],
        };
        self.painter.put(|c| &c.robot, &robot, stamp_ns, canvas)?;
        if let Some(pose) = self.odometry.pose() {
            let belief = pose.transform_of(BELIEF_FRAME, t);
            self.painter
                .put(|c| &c.tf_belief, &belief, stamp_ns, canvas)?;
        }
        if let Some(pose) = self.world_pose.or(self.odometry.pose()) {
            let at = stamp_ns.max(self.world_drawn_ns);
            let t = self.timestamp(at);
            self.painter
                .put(|c| &c.tf, &pose.transform(t), at, canvas)?;
        }
        Ok(())
    }

    /// Where the world has the robot (perception's [`WorldPose`] after an observation): the
    /// robot drawn along the motion that led there, at each wheel report's time, then at
    /// its end.
    pub fn world_pose<C: Canvas>(&mut self, w: &WorldPose, canvas: &mut C) -> Result<(), C::Error> {
        if self.arena.is_none() {
            return Ok(());
        }
        let pose = |p: [f64; 3]| FloorPose {
            position: glam::DVec2::new(p[0], p[1]),
            heading: p[2],
        };
        let (from, to) = (pose(w.from), pose(w.to));
        self.world_pose = Some(to);
        if w.after_command != 0 && w.after_command == self.world_after {
            // An observation published again (no motion report came): the motion is drawn.
            return self.draw_world(to, w.stamp_ns, canvas);
        }
        self.world_after = w.after_command;
        for (stamp_ns, p) in self.world.along(w.after_command, from, to, w.stamp_ns) {
            self.draw_world(p, stamp_ns, canvas)?;
        }
        Ok(())
    }

    /// The robot at `pose` at `stamp_ns` (or just after the last drawn), as frame `robot`.
    fn draw_world<C: Canvas>(
        &mut self,
        pose: FloorPose,
        stamp_ns: u64,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        let at = stamp_ns.max(self.world_drawn_ns);
        self.world_drawn_ns = at;
        let t = self.timestamp(at);
        self.painter
            .put_as(|c| &c.tf, &pose.transform(t), at, Delivery::Motion, canvas)
    }

    /// What the controller believes at `stamp_ns`, as frame `belief` (and as `robot` while
    /// the world has said nothing).
    fn draw_belief<C: Canvas>(
        &mut self,
        pose: FloorPose,
        stamp_ns: u64,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        let t = self.timestamp(stamp_ns);
        let belief = pose.transform_of(BELIEF_FRAME, t);
        self.painter.put_as(
            |c| &c.tf_belief,
            &belief,
            stamp_ns,
            Delivery::Motion,
            canvas,
        )?;
        let silent = self
            .first_observed_ns
            .is_some_and(|first| stamp_ns > first + WORLD_SILENT_NS);
        if self.world_pose.is_none() && silent {
            self.draw_world(pose, stamp_ns, canvas)?;
        }
        Ok(())
    }

    /// An observation: the robot's pose, its path, the effect of the last decision and, at
    /// an episode's end, its reward.
    pub fn observation<C: Canvas>(
        &mut self,
        o: &Observation,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        let Some(arena) = &self.arena else {
            return Ok(());
        };
        let state = arena.state_index(o.state);
        let pose = state.and_then(|s| arena.state_pose(s)).map(|p| FloorPose {
            position: p.position,
            heading: p.heading,
        });
        let starts = o.flags & observation_flags::EPISODE_START != 0
            || self.episode.number != Some(o.episode);
        if starts {
            self.episode = EpisodeTrack {
                number: Some(o.episode),
                ..EpisodeTrack::default()
            };
        } else {
            self.episode.reward += f64::from(o.reward);
        }
        let effect = self.effect_of_last_decision(state, o.flags);
        self.episode.last_state = state;
        self.first_observed_ns.get_or_insert(o.stamp_ns);
        self.observed.remember(
            o.seq,
            Observed {
                episode: o.episode,
                step: o.step,
            },
        );
        self.odometry.observed(pose);
        self.observed_ns = self.observed_ns.max(o.stamp_ns);
        let t = self.timestamp(o.stamp_ns);
        if let Some(p) = pose {
            self.episode.path.push(p);
            self.draw_belief(p, o.stamp_ns, canvas)?;
            let observed = PoseInFrame {
                timestamp: Some(t),
                frame_id: ARENA_FRAME.into(),
                pose: Some(p.pose()),
            };
            self.painter.put_as(
                |c| &c.robot_pose,
                &observed,
                o.stamp_ns,
                Delivery::Motion,
                canvas,
            )?;
        }
        let path = PosesInFrame {
            timestamp: Some(t),
            frame_id: ARENA_FRAME.into(),
            poses: self.episode.path.iter().map(FloorPose::pose).collect(),
        };
        self.painter.put_as(
            |c| &c.robot_path,
            &path,
            o.stamp_ns,
            Delivery::Motion,
            canvas,
        )?;
        let robot = SceneUpdate {
            deletions: Vec::new(),
            entities: vec![self.path_entity(t), self.decision_entity(t, o, effect)],
        };
        self.painter
            .put_as(|c| &c.robot, &robot, o.stamp_ns, Delivery::Motion, canvas)?;
        if o.flags & (observation_flags::TERMINAL | observation_flags::TRUNCATED) != 0 {
            let end = self.episode_end(o);
            self.painter.put(|c| &c.episode, &end, o.stamp_ns, canvas)?;
            let reward = Sample::of(end.reward);
            self.painter
                .put(|c| &c.reward_series, &reward, o.stamp_ns, canvas)?;
        }
        self.draw_waiting_decisions(canvas)
    }

    /// The effect the last decision had, when it is known: the robot went from one state of
    /// the area to another, and the outcome was not lost.
    fn effect_of_last_decision(&self, state: Option<usize>, flags: u32) -> Option<Effect> {
        let arena = self.arena.as_ref()?;
        let (prev, next) = (self.episode.last_state?, state?);
        if flags & observation_flags::RESYNC != 0 || prev >= arena.out_state() {
            return None;
        }
        Effect::from_index(arena.effect_between(prev, next))
    }

    fn path_entity(&self, t: Timestamp) -> SceneEntity {
        path_entity(
            t,
            self.episode
                .path
                .iter()
                .map(|p| p.position * crate::arena::M_PER_CM),
        )
    }

    /// The text over the robot at observation `o`: where it is in the run and, when known,
    /// the decision whose motion led here (`o.after_command`) and the effect it had.
    fn decision_entity(
        &self,
        t: Timestamp,
        o: &Observation,
        effect: Option<Effect>,
    ) -> SceneEntity {
        let action = (o.after_command != 0)
            .then(|| self.decided.find(o.after_command))
            .flatten()
            .and_then(|a| arena::ACTION_NAMES.get(a as usize).copied());
        let text = match (action, effect) {
            (Some(a), Some(e)) => format!("episode {} step {}: {a} → {e}", o.episode, o.step),
            _ => format!("episode {} step {}", o.episode, o.step),
        };
        said_over_robot(t, text, 0.25)
    }

    fn episode_end(&self, o: &Observation) -> EpisodeEnd {
        let outcome = if o.flags & observation_flags::TRUNCATED != 0 {
            "cut short"
        } else if o.state.is_out() {
            "left the area"
        } else if o.reward > 0.0 {
            "ball"
        } else {
            "death spot"
        };
        EpisodeEnd {
            episode: o.episode,
            reward: self.episode.reward,
            actions: o.step,
            outcome: outcome.into(),
        }
    }

    /// A command: a decision (keep-alives are not drawn), labelled with the observation it
    /// answers; one whose observation is not drawn yet waits for it.
    pub fn command<C: Canvas>(&mut self, c: &Command, canvas: &mut C) -> Result<(), C::Error> {
        if c.action == KEEP_ALIVE_ACTION {
            return Ok(());
        }
        self.decided.remember(c.seq, c.action);
        let ahead = self.observed.newest_seq().is_none_or(|s| c.answers > s);
        // Behind one that waits, a decision waits too: decisions are drawn in their order.
        if (ahead || !self.waiting.is_empty()) && self.waiting.len() < REMEMBERED {
            self.waiting.push_back(*c);
            return Ok(());
        }
        self.decision(c, canvas)
    }

    /// The run is over: draws the decisions still waiting for an observation that will not
    /// come, each labelled with the newest one.
    pub fn finish<C: Canvas>(&mut self, canvas: &mut C) -> Result<(), C::Error> {
        while let Some(c) = self.waiting.pop_front() {
            self.decision(&c, canvas)?;
        }
        Ok(())
    }

    /// Draws the decisions that waited for an observation drawn now (or for one that will
    /// never come: an observation the recorder missed).
    fn draw_waiting_decisions<C: Canvas>(&mut self, canvas: &mut C) -> Result<(), C::Error> {
        let newest = self.observed.newest_seq().unwrap_or(0);
        while let Some(c) = self.waiting.front().copied() {
            if c.answers > newest {
                break;
            }
            self.waiting.pop_front();
            self.decision(&c, canvas)?;
        }
        Ok(())
    }

    /// Draws decision `c`: its action and latency, labelled with the observation it answers
    /// (else the newest one: an observation the recorder missed).
    fn decision<C: Canvas>(&mut self, c: &Command, canvas: &mut C) -> Result<(), C::Error> {
        let answered = self.observed.find(c.answers).or_else(|| {
            let newest = self.observed.newest_seq()?;
            self.observed.find(newest)
        });
        let decision = Decision {
            episode: answered.map_or(0, |o| o.episode),
            step: answered.map_or(0, |o| o.step),
            action: c.action,
            action_name: arena::ACTION_NAMES
                .get(c.action as usize)
                .map_or_else(|| c.action.to_string(), |n| (*n).to_owned()),
            latency_us: if c.observed_ns > 0 {
                c.stamp_ns.saturating_sub(c.observed_ns) as f64 / 1e3
            } else {
                0.0
            },
        };
        self.painter
            .put(|ch| &ch.decision, &decision, c.stamp_ns, canvas)?;
        let latency = Sample::of(decision.latency_us);
        self.painter
            .put(|ch| &ch.latency_series, &latency, c.stamp_ns, canvas)
    }

    /// A motor report: the robot moved by its wheels' rotation (the belief dead-reckons it;
    /// the world's motion is drawn from it when the world's pose comes).
    pub fn motor_state<C: Canvas>(
        &mut self,
        m: &MotorState,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        if m.flags & motor_flags::LINK_DOWN != 0 {
            return Ok(());
        }
        let [l, r] = self.settings.wheel_ports;
        let (Some(&left), Some(&right)) = (m.tacho_count.get(l), m.tacho_count.get(r)) else {
            return Ok(());
        };
        self.world
            .report(m.stamp_ns, m.after_command, [left, right]);
        if m.stamp_ns <= self.observed_ns {
            self.odometry.rebase([left, right]);
            return Ok(());
        }
        match self.odometry.wheels([left, right]) {
            Some(pose) => self.draw_belief(pose, m.stamp_ns, canvas),
            None => Ok(()),
        }
    }

    /// A process's log line (`role` names the process), at `stamp_ns` on the monotonic clock.
    pub fn log_line<C: Canvas>(
        &mut self,
        role: &str,
        text: &str,
        stamp_ns: u64,
        canvas: &mut C,
    ) -> Result<(), C::Error> {
        let line = Log {
            timestamp: Some(self.timestamp(stamp_ns)),
            level: level_of(text) as i32,
            message: text.to_owned(),
            name: role.to_owned(),
            ..Log::default()
        };
        self.painter.put(|c| &c.log, &line, stamp_ns, canvas)
    }
}

/// The line through `points` (m, on the floor) in the arena's frame: entity `path`.
pub(crate) fn path_entity(t: Timestamp, points: impl Iterator<Item = glam::DVec2>) -> SceneEntity {
    let points = points.map(|p| Point3 {
        x: p.x,
        y: p.y,
        z: 0.02,
    });
    SceneEntity {
        timestamp: Some(t),
        frame_id: ARENA_FRAME.into(),
        id: "path".into(),
        lines: vec![LinePrimitive {
            r#type: line_primitive::Type::LineStrip as i32,
            pose: Some(at(0.0, 0.0, 0.0)),
            thickness: 4.0,
            scale_invariant: true,
            points: points.collect(),
            color: Some(rgb(1.0, 0.85, 0.1)),
            ..LinePrimitive::default()
        }],
        ..SceneEntity::default()
    }
}

/// `text` floating `height` m over the robot, facing the viewer: entity `decision`.
pub(crate) fn said_over_robot(t: Timestamp, text: String, height: f64) -> SceneEntity {
    SceneEntity {
        timestamp: Some(t),
        frame_id: ROBOT_FRAME.into(),
        id: "decision".into(),
        frame_locked: true,
        texts: vec![TextPrimitive {
            pose: Some(at(0.0, 0.0, height)),
            billboard: true,
            font_size: 14.0,
            scale_invariant: true,
            color: Some(rgb(1.0, 1.0, 1.0)),
            text,
        }],
        ..SceneEntity::default()
    }
}

/// The level of a `tracing` line (`… WARN target: message`), from its first words.
fn level_of(text: &str) -> log::Level {
    let head: String = text.chars().take(48).collect();
    let words: Vec<&str> = head.split_whitespace().collect();
    let has = |w: &str| words.contains(&w);
    if has("ERROR") {
        log::Level::Error
    } else if has("WARN") {
        log::Level::Warning
    } else if has("INFO") {
        log::Level::Info
    } else if has("DEBUG") || has("TRACE") {
        log::Level::Debug
    } else {
        log::Level::Info
    }
}

#[cfg(test)]
mod tests;
