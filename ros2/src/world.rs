//! A ROS 2 robot as the group's world: the process that plays perception's part (and the
//! bridge's) for a robot whose own node speaks ROS 2 (`[ros2_world]` in a launch file).
//!
//! The robot's node publishes, with standard message types (docs/ros2.md, "A ROS 2 robot
//! as the world"):
//!
//! * the world's structure once, on `/tes/world/map` (`std_msgs/msg/Float32MultiArray`,
//!   transient-local): per state its reward, whether it ends an episode, the state each
//!   effect leads to, and its features — what the paper's agent is told of a world (its CMDP
//!   without the dynamics), so the controller plans on it as on the arena's map;
//! * each step on `/tes/world/step` (`std_msgs/msg/Float64MultiArray`): the episode and step,
//!   the action it answers, the state, the observed effect, the reward, whether the episode
//!   ended, and the sensed features.
//!
//! This process turns the map into the group's [`WorldMap`] and each step into an
//! [`Observation`], and each of the controller's [`Command`]s into an action on
//! `/tes/world/action` (`std_msgs/msg/UInt32MultiArray`), plus, for a wheeled base, the
//! action's `geometry_msgs/msg/Twist` from the launch file's table on `cmd_vel`, held for the
//! action's time and then stopped. Everything arriving is checked against what the launch
//! file declares (the features, actions and effects, by count); a message that does not fit
//! is counted and dropped with a log line that says why, never a panic. The controller, its
//! library, planner and budget are the ones the arena has.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::prelude::{Node, ipc};
use serde::{Deserialize, Serialize};
use tes_runtime::board::LatestInbox;
use tes_runtime::channel::{self, Idle, IpcError, Outbox};
use tes_runtime::clock::monotonic_ns;
use tes_runtime::progress::{ProgressOutbox, ProgressWatch};
use tes_runtime::wait::WaitStrategy;
use tes_topics::{
    Command, FEATURE_CAPACITY, FeatureBits, MAX_ACTIONS, MAX_EFFECTS, MAX_STATES, Observation,
    Role, ServiceNames, WorldMap, observation_flags, progress_flags,
};

use ros2_client::Context;

use crate::dds::{DdsError, DiscoveryRange, Reach, create, reliable, topic};
use crate::msg::{Float32MultiArray, Float64MultiArray, Message, Twist, UInt32MultiArray, Vector3};

/// The topic the robot's node publishes the world's structure on, once (transient-local).
pub const MAP_TOPIC: &str = "/tes/world/map";
/// The topic the robot's node publishes each step on.
pub const STEP_TOPIC: &str = "/tes/world/step";
/// The topic TES publishes each chosen action on.
pub const ACTION_TOPIC: &str = "/tes/world/action";

/// The numbers before the features in a step: episode, step, answers, state, effect, reward,
/// flags.
pub const STEP_HEADER: usize = 7;
/// A step's `flags`: the state ends the episode (a terminal state).
pub const STEP_TERMINAL: u32 = 1;
/// A step's `flags`: the robot cut the episode short (its step cap, a reset).
pub const STEP_CUT: u32 = 4;

/// `[ros2_world]`: a ROS 2 robot as the world — what its node sends and what the actions do
/// (docs/ros2.md). Declared here and checked against every message that arrives.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSettings {
    /// The robot's states as a grid, cells across and down. States are numbered
    /// `(y · across + x) · orientations + orientation`, and one more state after them is "out
    /// of the area" (it may be unreachable), as for the arenas.
    /// Values: two whole numbers, at least 1 each.
    /// Example: `[20, 20]`.
    pub cells: [u16; 2],
    /// Orientations per cell (1 for a grid task, 8 for the arenas' headings).
    /// Values: at least 1; 1 if unset.
    /// Example: `1`.
    #[serde(default = "one")]
    pub orientations: u16,
    /// The actions' names, in index order: the index is what goes out on `/tes/world/action`.
    /// Values: 1 to 4 names.
    /// Example: `["north", "east", "south", "west"]`.
    pub actions: Vec<String>,
    /// The effects' names, in index order (a step's `effect` is an index into them).
    /// Values: 1 to 20 names.
    /// Example: `["north", "east", "south", "west", "stay"]`.
    pub effects: Vec<String>,
    /// Binary features per state (a map row's and a step's feature count).
    /// Values: 1 to 320 (the group's feature capacity).
    /// Example: `205`.
    pub features: u32,
    /// The topic the twists of `[[ros2_world.twist]]` go to.
    /// Values: a ROS 2 topic name; `"/cmd_vel"` if unset.
    /// Example: `"/cmd_vel"`.
    #[serde(default = "cmd_vel")]
    pub cmd_vel: String,
    /// How long to wait for the robot's map at start (DDS discovery included).
    /// Values: seconds, more than 0; 60 if unset.
    /// Example: `60.0`.
    #[serde(default = "map_timeout_s")]
    pub map_timeout_s: f64,
    /// For a wheeled base: each action's velocity, published as `geometry_msgs/msg/Twist` on
    /// `cmd_vel` for the action's time, then a zero twist. None: actions go out by index only.
    #[serde(default)]
    pub twist: Vec<TwistAction>,
}

fn one() -> u16 {
    1
}
fn cmd_vel() -> String {
    "/cmd_vel".to_owned()
}
fn map_timeout_s() -> f64 {
    60.0
}

/// One action's motion for a wheeled base (`[[ros2_world.twist]]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TwistAction {
    /// The action's name, as in `actions`.
    /// Values: one of `actions`.
    /// Example: `"north"`.
    pub action: String,
    /// Forward speed.
    /// Values: m/s.
    /// Example: `0.2`.
    #[serde(default)]
    pub linear_x: f64,
    /// Turning speed, counter-clockwise positive.
    /// Values: rad/s.
    /// Example: `0.0`.
    #[serde(default)]
    pub angular_z: f64,
    /// How long the speed is held.
    /// Values: seconds, more than 0.
    /// Example: `1.5`.
    pub seconds: f64,
}

/// What the launcher tells the ROS 2 world of its run, beside its settings.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldRun {
    /// Episodes to run (`[launch] episodes`).
    pub episodes: u32,
    /// The group's service prefix.
    pub service_prefix: String,
    /// Where to write the run's summary as JSON at exit.
    pub report: Option<PathBuf>,
}

/// The ROS 2 world's settings file, as the launcher writes it in the run folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldFile {
    /// The launch file's `[ros2_world]`.
    pub ros2_world: WorldSettings,
    /// The run's.
    pub run: WorldRun,
}

/// A setting of `[ros2_world]` that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("[ros2_world] {key}: {reason}")]
pub struct SettingsError {
    /// The key.
    pub key: &'static str,
    /// Why.
    pub reason: String,
}

impl WorldSettings {
    /// The number of states, the out state included.
    pub fn n_states(&self) -> usize {
        usize::from(self.cells[0]) * usize::from(self.cells[1]) * usize::from(self.orientations) + 1
    }

    /// Refuses settings the group's fixed-size messages cannot carry, and a twist table that
    /// names an action not declared.
    pub fn check(&self) -> Result<(), SettingsError> {
        let bad = |key, reason: String| Err(SettingsError { key, reason });
        if self.cells.contains(&0) || self.orientations == 0 {
            return bad("cells", "cells and orientations must be at least 1".into());
        }
        if self.n_states() > MAX_STATES {
            return bad(
                "cells",
                format!(
                    "{} states with the out state; the group's map holds at most {MAX_STATES}",
                    self.n_states()
                ),
            );
        }
        if self.actions.is_empty() || self.actions.len() > MAX_ACTIONS {
            return bad("actions", format!("1 to {MAX_ACTIONS} actions"));
        }
        if self.effects.is_empty() || self.effects.len() > MAX_EFFECTS {
            return bad("effects", format!("1 to {MAX_EFFECTS} effects"));
        }
        if self.features == 0 || self.features as usize > FEATURE_CAPACITY {
            return bad("features", format!("1 to {FEATURE_CAPACITY} features"));
        }
        if !(self.map_timeout_s.is_finite() && self.map_timeout_s > 0.0) {
            return bad("map_timeout_s", "a positive number of seconds".into());
        }
        for t in &self.twist {
            if !self.actions.contains(&t.action) {
                return bad(
                    "twist",
                    format!(
                        "{:?} is not one of the actions {:?}",
                        t.action, self.actions
                    ),
                );
            }
            let finite = [t.linear_x, t.angular_z, t.seconds]
                .iter()
                .all(|v| v.is_finite());
            if !finite || t.seconds <= 0.0 {
                return bad(
                    "twist",
                    format!("{:?}: finite speeds and a positive time", t.action),
                );
            }
        }
        Ok(())
    }

    /// The numbers per row of the map: reward, terminal, one next state per effect, the
    /// features.
    pub fn map_columns(&self) -> usize {
        2 + self.effects.len() + self.features as usize
    }

    /// The numbers in a step: [`STEP_HEADER`] and the features.
    pub fn step_len(&self) -> usize {
        STEP_HEADER + self.features as usize
    }
}

/// Why a map or a step from the robot is not taken.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Refusal {
    /// The message's bytes are not of its type.
    #[error("it cannot be decoded as its type: {0}")]
    Undecodable(String),
    /// The numbers are not as many as the declared counts make.
    #[error("{got} numbers where the declared {what} make {want}")]
    Size {
        /// What sets the size.
        what: String,
        /// Numbers received.
        got: usize,
        /// Numbers expected.
        want: usize,
    },
    /// A number is out of its range or not a whole number where one is needed.
    #[error("{what} is {value}: {want}")]
    Value {
        /// Which number.
        what: String,
        /// Its value.
        value: f64,
        /// What it must be.
        want: String,
    },
    /// A step's state is not where its effect leads.
    #[error("state {state} is not where effect {effect} leads from state {from} (state {to})")]
    Inconsistent {
        /// The step's state.
        state: usize,
        /// The step's effect.
        effect: usize,
        /// The state before.
        from: usize,
        /// Where the map says the effect leads.
        to: usize,
    },
    /// A step starts an episode that is not newer than the current one.
    #[error("it starts episode {episode}, but episode {current} has begun")]
    OldEpisode {
        /// The episode it starts.
        episode: u64,
        /// The robot's current episode.
        current: u64,
    },
    /// A step answers an action that is not the last one sent.
    #[error("it answers action {answers}, but the last action sent was {last}")]
    Stale {
        /// The action it answers.
        answers: u64,
        /// The last action sent (0: none).
        last: u64,
    },
}

/// A whole number in `0..end` from a float, or why not.
fn index(what: impl Fn() -> String, value: f64, end: usize) -> Result<usize, Refusal> {
    if value.fract() == 0.0 && value >= 0.0 && value < end as f64 {
        Ok(value as usize)
    } else {
        Err(Refusal::Value {
            what: what(),
            value,
            want: format!("a whole number from 0 to {}", end.saturating_sub(1)),
        })
    }
}

/// A 0 or 1 from a float, or why not.
fn bit(what: impl Fn() -> String, value: f64) -> Result<bool, Refusal> {
    index(what, value, 2).map(|b| b == 1)
}

/// The group's world map from the robot's map message, checked against `settings`.
pub fn map_from(m: &Float32MultiArray, settings: &WorldSettings) -> Result<Box<WorldMap>, Refusal> {
    let (n, cols) = (settings.n_states(), settings.map_columns());
    let data = m.data.get(m.layout.data_offset as usize..).unwrap_or(&[]);
    if data.len() != n * cols {
        return Err(Refusal::Size {
            what: format!(
                "{n} states × (2 + {} effects + {} features)",
                settings.effects.len(),
                settings.features
            ),
            got: data.len(),
            want: n * cols,
        });
    }
    let mut map = Box::new(WorldMap::EMPTY);
    map.seq = 1;
    (map.n_states, map.n_actions) = (n as u32, settings.actions.len() as u32);
    (map.n_effects, map.n_features) = (settings.effects.len() as u32, settings.features);
    (map.width, map.height) = (settings.cells[0], settings.cells[1]);
    map.orientations = settings.orientations;
    let n_effects = settings.effects.len();
    for (s, row) in data.chunks_exact(cols).enumerate() {
        let reward = row[0];
        if !reward.is_finite() {
            return Err(Refusal::Value {
                what: format!("state {s}'s reward"),
                value: f64::from(reward),
                want: "a finite number".into(),
            });
        }
        map.reward[s] = reward;
        map.terminal[s] = u8::from(bit(|| format!("state {s}'s terminal"), f64::from(row[1]))?);
        for (e, &next) in row[2..2 + n_effects].iter().enumerate() {
            let what = || format!("the state effect {e} leads to from state {s}");
            map.next_state[s][e] = index(what, f64::from(next), n)? as u16;
        }
        for (i, &f) in row[2 + n_effects..].iter().enumerate() {
            if bit(|| format!("state {s}'s feature {i}"), f64::from(f))? {
                map.features[s].set(i);
            }
        }
    }
    map.check().map_err(|reason| Refusal::Value {
        what: "the map".into(),
        value: f64::from(map.n_states),
        want: reason,
    })?;
    Ok(map)
}

/// One step of the robot, checked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    /// The robot's episode.
    pub episode: u64,
    /// The step within it (0: its start).
    pub step: u64,
    /// The action it answers (0 at a start).
    pub answers: u64,
    /// The state now.
    pub state: usize,
    /// The observed effect of the action, if the robot says it.
    pub effect: Option<usize>,
    /// The reward received on entering the state.
    pub reward: f32,
    /// [`STEP_TERMINAL`], [`STEP_CUT`] or 0.
    pub flags: u32,
    /// The sensed features.
    pub features: FeatureBits,
}

impl Step {
    /// Whether the episode ends with it.
    pub fn ends(&self) -> bool {
        self.flags != 0
    }
}

/// A step from the robot's message, checked against `settings` and the map.
pub fn step_from(
    m: &Float64MultiArray,
    settings: &WorldSettings,
    map: &WorldMap,
) -> Result<Step, Refusal> {
    let data = m.data.get(m.layout.data_offset as usize..).unwrap_or(&[]);
    if data.len() != settings.step_len() {
        return Err(Refusal::Size {
            what: format!(
                "{STEP_HEADER} step numbers + {} features",
                settings.features
            ),
            got: data.len(),
            want: settings.step_len(),
        });
    }
    let whole = |i: usize, name: &str| index(|| name.to_owned(), data[i], usize::MAX);
    let (episode, step, answers) = (
        whole(0, "episode")? as u64,
        whole(1, "step")? as u64,
        whole(2, "answers")? as u64,
    );
    let state = index(|| "state".into(), data[3], map.n_states as usize)?;
    let effect = if data[4] == -1.0 {
        None
    } else {
        Some(index(|| "effect".into(), data[4], map.n_effects as usize)?)
    };
    if !data[5].is_finite() {
        return Err(Refusal::Value {
            what: "reward".into(),
            value: data[5],
            want: "a finite number".into(),
        });
    }
    let flags = whole(6, "flags")? as u32;
    if ![0, STEP_TERMINAL, STEP_CUT].contains(&flags) {
        return Err(Refusal::Value {
            what: "flags".into(),
            value: data[6],
            want: format!("0, {STEP_TERMINAL} (terminal) or {STEP_CUT} (cut short)"),
        });
    }
    let mut features = FeatureBits::EMPTY;
    for (i, &f) in data[STEP_HEADER..].iter().enumerate() {
        if bit(|| format!("feature {i}"), f)? {
            features.set(i);
        }
    }
    Ok(Step {
        episode,
        step,
        answers,
        state,
        effect,
        reward: data[5] as f32,
        flags,
        features,
    })
}

/// The action message: action `action`, numbered `number` (from 1, per run), answering the
/// robot's step `(episode, step)`. (The robot's numbers go back as it sent them; a u32 holds
/// years of steps.)
pub fn action_message(number: u64, action: u32, episode: u64, step: u64) -> UInt32MultiArray {
    UInt32MultiArray {
        layout: crate::msg::MultiArrayLayout::of(&[("action", 4)]),
        data: vec![number as u32, action, episode as u32, step as u32],
    }
}

/// The last action sent: what it answered and the message, to send again on a repeat.
#[derive(Debug, Clone)]
struct Sent {
    /// Its number on [`ACTION_TOPIC`] (what a step's `answers` names).
    number: u64,
    /// The controller's command it carries.
    command: u64,
    /// The robot's step it answers.
    step: (u64, u64),
    /// The message.
    message: UInt32MultiArray,
}

/// The node of a ROS 2 world (`crate::world`): it reads the robot's map and steps, and sends
/// its actions (and, for a wheeled base, twists).
pub struct WorldNode {
    map: ros2_client::Subscription<Float32MultiArray>,
    step: ros2_client::Subscription<Float64MultiArray>,
    action: ros2_client::Publisher<UInt32MultiArray>,
    twist: Option<ros2_client::Publisher<Twist>>,
    _node: ros2_client::Node,
    _context: Context,
    reach: Reach,
}

impl std::fmt::Debug for WorldNode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorldNode")
            .field("reach", &self.reach)
            .finish_non_exhaustive()
    }
}

impl WorldNode {
    /// Joins `domain` as node `/tes/world`, subscribed to the robot's map and steps, with a
    /// publisher of actions and, if `cmd_vel` is given, of twists on it.
    pub fn start(
        domain: u16,
        range: &DiscoveryRange,
        cmd_vel: Option<&str>,
    ) -> Result<Self, DdsError> {
        let crate::dds::Joined {
            mut node,
            context,
            reach,
        } = crate::dds::Joined::start(domain, range, "world")?;
        // The map is published once and kept (as `/map` is); steps and actions keep a
        // backlog a slow reader can catch up on.
        let (latched, queue) = (reliable(1, true), reliable(64, false));
        let t = topic(&mut node, MAP_TOPIC, Float32MultiArray::TYPE, &latched)?;
        let map = create(
            MAP_TOPIC,
            node.create_subscription(&t, Some(latched.clone())),
        )?;
        let t = topic(&mut node, STEP_TOPIC, Float64MultiArray::TYPE, &queue)?;
        let step = create(
            STEP_TOPIC,
            node.create_subscription(&t, Some(queue.clone())),
        )?;
        let t = topic(&mut node, ACTION_TOPIC, UInt32MultiArray::TYPE, &queue)?;
        let action = create(ACTION_TOPIC, node.create_publisher(&t, Some(queue.clone())))?;
        let twist = match cmd_vel {
            Some(name) => {
                // As a ROS 2 node's default publisher: reliable, keep-last 10.
                let q = reliable(10, false);
                let t = topic(&mut node, name, Twist::TYPE, &q)?;
                Some(create(name, node.create_publisher(&t, Some(q)))?)
            }
            None => None,
        };
        Ok(Self {
            map,
            step,
            action,
            twist,
            _node: node,
            _context: context,
            reach,
        })
    }

    /// Where it is reachable.
    pub fn reach(&self) -> &Reach {
        &self.reach
    }

    /// The next map received, if any, or why the next one cannot be read (its bytes are not
    /// a `Float32MultiArray`).
    pub fn take_map(&self) -> Result<Option<Float32MultiArray>, String> {
        self.map
            .take()
            .map(|m| m.map(|(m, _)| m))
            .map_err(|e| e.to_string())
    }

    /// The next step received, if any, or why the next one cannot be read.
    pub fn take_step(&self) -> Result<Option<Float64MultiArray>, String> {
        self.step
            .take()
            .map(|m| m.map(|(m, _)| m))
            .map_err(|e| e.to_string())
    }

    /// Sends an action; a reader that keeps DDS waiting loses it (the robot repeats its step
    /// and the action goes again).
    pub fn send_action(&self, m: UInt32MultiArray) {
        if self.action.publish(m).is_err() {
            tracing::debug!("DDS did not take an action");
        }
    }

    /// Sends a twist, if the node has a `cmd_vel` publisher.
    pub fn send_twist(&self, m: Twist) {
        if let Some(p) = &self.twist
            && p.publish(m).is_err()
        {
            tracing::debug!("DDS did not take a twist");
        }
    }
}

/// Why the ROS 2 world stopped.
#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    /// A bad setting.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// The ROS 2 node cannot start.
    #[error(transparent)]
    Dds(#[from] DdsError),
    /// An iceoryx2 failure.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// No usable map from the robot in time.
    #[error(
        "no usable map on {MAP_TOPIC} within {seconds} s{}; is the robot's node running in \
         this ROS_DOMAIN_ID, and does it publish the map transient-local?",
        last.as_ref().map(|r| format!(" (the last one was refused: {r})")).unwrap_or_default()
    )]
    NoMap {
        /// The wait.
        seconds: f64,
        /// Why the last map that came was refused.
        last: Option<Refusal>,
    },
    /// The summary cannot be written.
    #[error("cannot write the ROS 2 world's report {}", path.display())]
    Report {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        error: std::io::Error,
    },
}

/// What a run of the ROS 2 world did (written to `report`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct WorldSummary {
    /// Episodes that ended.
    pub episodes: u32,
    /// Steps taken in as observations.
    pub observations: u64,
    /// Actions sent (re-sends of the same action not counted).
    pub actions: u64,
    /// Actions sent again because the robot repeated the step they answer.
    pub resent: u64,
    /// Steps and maps dropped because they did not fit (each logged).
    pub malformed: u64,
    /// Steps dropped because they answered an action that was not the last one sent.
    pub stale: u64,
    /// Reward summed over the steps taken in.
    pub reward: f64,
    /// Each ended episode's reward, in order.
    pub episode_rewards: Vec<f64>,
}

/// Runs the ROS 2 world until its episodes are done or `stop` is raised.
pub fn run(file: &WorldFile, stop: &AtomicBool) -> Result<WorldSummary, WorldError> {
    let (settings, run) = (&file.ros2_world, &file.run);
    settings.check()?;
    let domain = crate::dds::domain_from_env()?;
    let range = crate::dds::range_from_env()?;
    let cmd_vel = (!settings.twist.is_empty()).then_some(settings.cmd_vel.as_str());
    let node = WorldNode::start(domain, &range, cmd_vel)?;
    tracing::info!(reach = %node.reach(), "the ROS 2 world's node is up");
    let names = ServiceNames::with_prefix(&run.service_prefix);
    let ipc = channel::group_node(&names, Role::Perception, false)?;
    let mut progress = ProgressOutbox::open(&ipc, &names, Role::Perception)?;
    let mut summary = WorldSummary::default();
    let Some(map) = wait_for_map(&node, settings, &mut progress, &mut summary, stop)? else {
        return write_report(run, summary);
    };
    let maps = Outbox::open(&ipc, &names.world_map, &names.world_map_event, 1)?;
    maps.send(*map)?;
    tracing::info!(
        states = settings.n_states(),
        "world map from the robot published"
    );
    let mut gateway = Gateway {
        settings,
        episodes: run.episodes,
        maps,
        observations: Outbox::open(&ipc, &names.observation, &names.observation_event, 0)?,
        commands: LatestInbox::open(
            &ipc,
            &names.command,
            &names.command_event,
            WaitStrategy::Block,
        )?,
        watch: ProgressWatch::open(&ipc, &names)?,
        ipc,
        progress,
        node,
        map,
        summary,
        // From the clock, as perception's: newer than anything a predecessor published.
        seq: monotonic_ns(),
        exchange: Exchange::default(),
        episode_reward: 0.0,
        twist_until: None,
        said: SaidOnce::default(),
    };
    gateway.run(stop)?;
    let summary = std::mem::take(&mut gateway.summary);
    drop(gateway);
    write_report(run, summary)
}

/// Writes the summary to the settings' report file, if any, and returns it.
fn write_report(run: &WorldRun, summary: WorldSummary) -> Result<WorldSummary, WorldError> {
    if let Some(path) = &run.report {
        let text = serde_json::to_string_pretty(&summary).map_err(std::io::Error::other);
        text.and_then(|t| std::fs::write(path, t))
            .map_err(|error| WorldError::Report {
                path: path.clone(),
                error,
            })?;
    }
    Ok(summary)
}

/// The most messages of a topic taken in one look (the rest wait for the next).
const DRAIN: usize = 256;
/// How often a wait says it is still waiting.
const SAY_EVERY: Duration = Duration::from_secs(5);
/// How often the ROS 2 subscriptions are looked at while nothing comes over iceoryx2.
const ROS_POLL: Duration = Duration::from_millis(1);

/// Waits for the robot's map (DDS discovery included): `None` if `stop` was raised first.
fn wait_for_map(
    node: &WorldNode,
    settings: &WorldSettings,
    progress: &mut ProgressOutbox,
    summary: &mut WorldSummary,
    stop: &AtomicBool,
) -> Result<Option<Box<WorldMap>>, WorldError> {
    let started = Instant::now();
    let mut said = started;
    let mut last = None;
    let timeout = Duration::from_secs_f64(settings.map_timeout_s);
    while started.elapsed() < timeout {
        if stop.load(Ordering::Relaxed) {
            return Ok(None);
        }
        progress.publish_due(monotonic_ns())?;
        for _ in 0..DRAIN {
            let refusal = match node.take_map() {
                Ok(None) => break,
                Ok(Some(m)) => match map_from(&m, settings) {
                    Ok(map) => return Ok(Some(map)),
                    Err(refusal) => refusal,
                },
                Err(reason) => Refusal::Undecodable(reason),
            };
            summary.malformed += 1;
            tracing::warn!("dropped a map on {MAP_TOPIC}: {refusal}");
            last = Some(refusal);
        }
        if said.elapsed() >= SAY_EVERY {
            said = Instant::now();
            tracing::info!("waiting for the robot's map on {MAP_TOPIC}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Err(WorldError::NoMap {
        seconds: settings.map_timeout_s,
        last,
    })
}

/// Says a kind of refusal in full the first time and every 100th time after, so that a
/// robot that sends nothing but bad messages is heard without flooding the log.
#[derive(Debug, Default)]
struct SaidOnce {
    malformed: u64,
    stale: u64,
}

impl SaidOnce {
    fn due(count: &mut u64) -> bool {
        *count += 1;
        *count == 1 || (*count).is_multiple_of(100)
    }
}

/// How long the robot has been silent, said every [`SAY_EVERY`] while it is.
#[derive(Debug)]
struct Silence {
    since: Instant,
    said: Instant,
    /// Observations and actions when last looked at.
    counts: (u64, u64),
}

impl Default for Silence {
    fn default() -> Self {
        let now = Instant::now();
        Self {
            since: now,
            said: now,
            counts: (0, 0),
        }
    }
}

impl Silence {
    /// Notes the counts; says so if nothing moved for a while.
    fn say_if_long(&mut self, observations: u64, actions: u64) {
        let now = Instant::now();
        if (observations, actions) != self.counts {
            (self.counts, self.since, self.said) = ((observations, actions), now, now);
        } else if now.duration_since(self.said) >= SAY_EVERY {
            self.said = now;
            tracing::info!(
                observations,
                actions,
                "no new step from the robot for {:.0} s (it repeats its last step until an \
                 action answers it; DDS discovery alone can take 10 s or more)",
                now.duration_since(self.since).as_secs_f64()
            );
        }
    }
}

/// What a step from the robot is to the exchange.
#[derive(Debug, Clone, PartialEq)]
enum Taken {
    /// A new step: the next observation.
    New(Step),
    /// The step taken last, again; with the answer to send again if one was sent.
    Repeat(Option<UInt32MultiArray>),
}

/// The alternation of steps and actions: the last step taken in (and the observation it
/// became) and the last action sent.
#[derive(Debug, Default)]
struct Exchange {
    current: Option<(Step, u64)>,
    sent: Option<Sent>,
}

impl Exchange {
    /// What `step` is: new, a repeat, or refused (an older episode's start, an answer to an
    /// action that is not the last one sent, a state its effect does not lead to).
    fn take(&self, step: Step, map: &WorldMap) -> Result<Taken, Refusal> {
        let key = (step.episode, step.step);
        if let Some((current, _)) = &self.current
            && (current.episode, current.step) == key
        {
            let answer = self.sent.as_ref().filter(|s| s.step == key);
            return Ok(Taken::Repeat(answer.map(|s| s.message.clone())));
        }
        if step.step == 0 {
            return match self.current {
                Some((c, _)) if step.episode <= c.episode => Err(Refusal::OldEpisode {
                    episode: step.episode,
                    current: c.episode,
                }),
                _ => Ok(Taken::New(step)),
            };
        }
        let last = self.sent.as_ref().map_or(0, |s| s.number);
        if step.answers != last || last == 0 {
            return Err(Refusal::Stale {
                answers: step.answers,
                last,
            });
        }
        if let (Some(effect), Some((current, _))) = (step.effect, self.current) {
            let to = usize::from(map.next_state[current.state][effect]);
            if to != step.state {
                return Err(Refusal::Inconsistent {
                    state: step.state,
                    effect,
                    from: current.state,
                    to,
                });
            }
        }
        Ok(Taken::New(step))
    }
}

/// A run: the group's side of the exchange with the robot.
struct Gateway<'a> {
    settings: &'a WorldSettings,
    /// Episodes to run.
    episodes: u32,
    maps: Outbox<WorldMap>,
    observations: Outbox<Observation>,
    /// The controller's latest command (or keep-alive carrying it).
    commands: LatestInbox<Command>,
    watch: ProgressWatch,
    ipc: Node<ipc::Service>,
    progress: ProgressOutbox,
    node: WorldNode,
    map: Box<WorldMap>,
    summary: WorldSummary,
    /// The last observation's number.
    seq: u64,
    exchange: Exchange,
    episode_reward: f64,
    /// When the current twist is to stop.
    twist_until: Option<Instant>,
    said: SaidOnce,
}

impl Gateway<'_> {
    /// Takes the robot's steps in and sends the controller's actions out until the episodes
    /// are done or `stop` is raised.
    fn run(&mut self, stop: &AtomicBool) -> Result<(), WorldError> {
        self.wait_for_the_controller(stop)?;
        self.awaiting_the_robot(true);
        let mut silent = Silence::default();
        while self.summary.episodes < self.episodes {
            if self.progress.publish_due(monotonic_ns())? {
                // A (re)started controller's ports: its map and its commands reach us.
                self.maps.update_connections()?;
                // A respawned controller writes to a fresh board.
                self.commands.renew_if_abandoned(&self.ipc)?;
            }
            self.stop_twist_when_due();
            silent.say_if_long(self.summary.observations, self.summary.actions);
            for _ in 0..DRAIN {
                match self.node.take_step() {
                    Ok(None) => break,
                    Ok(Some(m)) => self.take_step(Ok(&m))?,
                    Err(reason) => self.take_step(Err(Refusal::Undecodable(reason)))?,
                }
            }
            // Commands wake it at once; the robot's steps are looked at every millisecond.
            match self.commands.next(ROS_POLL, stop)? {
                Err(Idle::Stopped) => return Ok(()),
                Err(Idle::Timeout) => {}
                Ok(command) => self.take_command(&command),
            }
        }
        // Let the controller see the last observation before the group is told it is done.
        self.progress.report_mut().episodes = u64::from(self.summary.episodes);
        self.progress.publish(monotonic_ns())?;
        tracing::info!(
            episodes = self.summary.episodes,
            "the ROS 2 world's episodes are done"
        );
        Ok(())
    }

    /// Says (in its progress reports) whether the group waits on the robot: then a group
    /// without new commands is not stalled.
    fn awaiting_the_robot(&mut self, waiting: bool) {
        let flags = &mut self.progress.report_mut().flags;
        if waiting {
            *flags |= progress_flags::AWAITING_PEER;
        } else {
            *flags &= !progress_flags::AWAITING_PEER;
        }
    }

    /// Waits until the controller has reported (it has the map, its library, a first plan).
    fn wait_for_the_controller(&mut self, stop: &AtomicBool) -> Result<(), WorldError> {
        let mut said = Instant::now();
        while self.watch.latest(Role::Controller).is_none() {
            if stop.load(Ordering::Relaxed) {
                return Ok(());
            }
            self.maps.update_connections()?;
            self.watch.poll()?;
            self.progress.publish_due(monotonic_ns())?;
            if said.elapsed() >= SAY_EVERY {
                said = Instant::now();
                tracing::info!("waiting for the controller before the robot's first step");
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        tracing::info!("the controller is ready; taking the robot's steps");
        Ok(())
    }

    /// Takes one step message in: dropped if it does not fit, the last action sent again if
    /// it repeats the step that action answered, else published as an observation.
    fn take_step(&mut self, m: Result<&Float64MultiArray, Refusal>) -> Result<(), WorldError> {
        let step = match m.and_then(|m| self.checked(m)) {
            Ok(Some(step)) => step,
            Ok(None) => return Ok(()),
            Err(refusal) => {
                let stale = matches!(refusal, Refusal::Stale { .. } | Refusal::OldEpisode { .. });
                let (count, said) = if stale {
                    (&mut self.summary.stale, &mut self.said.stale)
                } else {
                    (&mut self.summary.malformed, &mut self.said.malformed)
                };
                *count += 1;
                if SaidOnce::due(said) {
                    tracing::warn!(
                        dropped = *count,
                        "dropped a step on {STEP_TOPIC}: {refusal}"
                    );
                }
                return Ok(());
            }
        };
        self.publish(step)
    }

    /// The step `m` says, if it is a new one; `None` for a repeat (the answer, if sent, goes
    /// out again).
    fn checked(&mut self, m: &Float64MultiArray) -> Result<Option<Step>, Refusal> {
        let step = step_from(m, self.settings, &self.map)?;
        match self.exchange.take(step, &self.map)? {
            Taken::New(step) => Ok(Some(step)),
            Taken::Repeat(answer) => {
                // The robot did not hear the answer yet (discovery, a lost message).
                if let Some(message) = answer {
                    self.summary.resent += 1;
                    self.node.send_action(message);
                }
                Ok(None)
            }
        }
    }

    /// Publishes `step` as the group's next observation.
    fn publish(&mut self, step: Step) -> Result<(), WorldError> {
        let start = step.step == 0;
        if start {
            self.episode_reward = 0.0;
        } else {
            self.episode_reward += f64::from(step.reward);
            self.summary.reward += f64::from(step.reward);
        }
        let mut flags = if start {
            observation_flags::EPISODE_START
        } else {
            0
        };
        if step.flags == STEP_TERMINAL {
            flags |= observation_flags::TERMINAL;
        } else if step.flags == STEP_CUT {
            flags |= observation_flags::TRUNCATED;
        }
        self.seq += 1;
        let observation = Observation {
            seq: self.seq,
            stamp_ns: monotonic_ns(),
            after_command: match &self.exchange.sent {
                Some(sent) if !start => sent.command,
                _ => 0,
            },
            episode: self.summary.episodes,
            step: step.step as u32,
            state: self.map.attributes(step.state),
            n_features: self.settings.features,
            features: step.features,
            reward: if start { 0.0 } else { step.reward },
            flags,
        };
        self.observations.send(observation)?;
        self.exchange.current = Some((step, self.seq));
        // The controller answers now (or, after an episode's last step, the robot starts
        // the next).
        self.awaiting_the_robot(step.ends());
        self.summary.observations += 1;
        let report = self.progress.report_mut();
        (report.out_seq, report.steps) = (self.seq, self.summary.observations);
        if step.ends() {
            self.summary.episodes += 1;
            self.summary.episode_rewards.push(self.episode_reward);
            self.progress.report_mut().episodes = u64::from(self.summary.episodes);
            tracing::info!(
                episode = self.summary.episodes - 1,
                reward = self.episode_reward,
                actions = step.step,
                "episode over"
            );
        }
        Ok(())
    }

    /// Sends a command that answers the current observation out as the robot's action.
    fn take_command(&mut self, command: &Command) {
        let Some((step, seq)) = self.exchange.current else {
            return;
        };
        // A keep-alive carries the command in flight (without what it answered); the
        // controller answers only the latest observation, so a command newer than the last
        // one sent, while an answer is due, is that answer.
        let Some(command) = command.in_flight() else {
            return;
        };
        let last = self.exchange.sent.as_ref().map_or(0, |s| s.command);
        let answered = self
            .exchange
            .sent
            .as_ref()
            .is_some_and(|s| s.step == (step.episode, step.step));
        let answers_this = command.answers == seq || command.answers == 0;
        if command.seq <= last || answered || step.ends() || !answers_this {
            return;
        }
        self.summary.actions += 1;
        let number = self.summary.actions;
        let message = action_message(number, command.action, step.episode, step.step);
        self.node.send_action(message.clone());
        self.awaiting_the_robot(true);
        self.exchange.sent = Some(Sent {
            number,
            command: command.seq,
            step: (step.episode, step.step),
            message,
        });
        self.progress.report_mut().in_seq = command.seq;
        let name = self.settings.actions.get(command.action as usize);
        if let Some(t) = self.settings.twist.iter().find(|t| Some(&t.action) == name) {
            self.node.send_twist(Twist {
                linear: Vector3 {
                    x: t.linear_x,
                    ..Vector3::default()
                },
                angular: Vector3 {
                    z: t.angular_z,
                    ..Vector3::default()
                },
            });
            self.twist_until = Some(Instant::now() + Duration::from_secs_f64(t.seconds));
        }
    }

    /// Stops the base once the current twist's time is up.
    fn stop_twist_when_due(&mut self) {
        if self
            .twist_until
            .is_some_and(|until| Instant::now() >= until)
        {
            self.twist_until = None;
            self.node.send_twist(Twist::default());
        }
    }
}

impl Drop for Gateway<'_> {
    fn drop(&mut self) {
        // A base left moving is the one thing a stop must not do.
        if self.twist_until.take().is_some() {
            self.node.send_twist(Twist::default());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::MultiArrayLayout;

    /// Two cells in a row, one orientation (and the out state): effect 0 moves east, effect 1
    /// stays; 3 features.
    fn settings() -> WorldSettings {
        WorldSettings {
            cells: [2, 1],
            orientations: 1,
            actions: vec!["go".into(), "wait".into()],
            effects: vec!["east".into(), "stay".into()],
            features: 3,
            cmd_vel: cmd_vel(),
            map_timeout_s: 1.0,
            twist: vec![],
        }
    }

    fn map_message() -> Float32MultiArray {
        // reward, terminal, next state of each effect, 3 feature bits.
        let rows: [[f32; 7]; 3] = [
            [-0.05, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0],
            [1.0, 1.0, 2.0, 1.0, 0.0, 1.0, 1.0],
            [0.0, 1.0, 2.0, 2.0, 0.0, 0.0, 0.0],
        ];
        Float32MultiArray {
            layout: MultiArrayLayout::of(&[("states", 3), ("columns", 7)]),
            data: rows.concat(),
        }
    }

    fn step(data: &[f64]) -> Float64MultiArray {
        Float64MultiArray {
            layout: MultiArrayLayout::of(&[("step", data.len() as u32)]),
            data: data.to_vec(),
        }
    }

    #[test]
    fn the_docs_feature_count_is_the_groups_capacity() {
        assert_eq!(FEATURE_CAPACITY, 320, "WorldSettings::features says 320");
    }

    #[test]
    fn settings_the_group_cannot_carry_are_refused_naming_the_key() {
        assert_eq!(settings().check(), Ok(()));
        let mut s = settings();
        s.cells = [40, 40];
        assert_eq!(s.check().unwrap_err().key, "cells");
        let mut s = settings();
        s.actions = vec!["a".into(); 5];
        assert_eq!(s.check().unwrap_err().key, "actions");
        let mut s = settings();
        s.features = 321;
        assert_eq!(s.check().unwrap_err().key, "features");
        let mut s = settings();
        s.twist.push(TwistAction {
            action: "fly".into(),
            linear_x: 1.0,
            angular_z: 0.0,
            seconds: 1.0,
        });
        let e = s.check().unwrap_err();
        assert!(
            e.to_string().contains("\"fly\" is not one of the actions"),
            "{e}"
        );
    }

    #[test]
    fn a_map_becomes_the_groups_world_map() {
        let map = map_from(&map_message(), &settings()).expect("a good map");
        assert_eq!((map.n_states, map.n_actions, map.n_effects), (3, 2, 2));
        assert_eq!((map.width, map.height, map.orientations), (2, 1, 1));
        assert_eq!(map.next_state[0][..2], [1, 0]);
        assert_eq!(map.reward[1], 1.0);
        assert_eq!(map.terminal[..3], [0, 1, 1]);
        assert!(map.features[0].get(0) && !map.features[0].get(1));
        assert!(map.features[1].get(1) && map.features[1].get(2));
        assert_eq!(map.out_state(), 2);
    }

    #[test]
    fn a_map_that_does_not_fit_is_refused_saying_why() {
        let mut short = map_message();
        short.data.pop();
        let e = map_from(&short, &settings()).unwrap_err();
        assert!(
            matches!(
                e,
                Refusal::Size {
                    got: 20,
                    want: 21,
                    ..
                }
            ),
            "{e}"
        );
        assert!(
            e.to_string()
                .contains("3 states × (2 + 2 effects + 3 features)"),
            "{e}"
        );
        for (at, value, what) in [
            (1, 0.5, "state 0's terminal"),
            (2, 3.0, "the state effect 0 leads to from state 0"),
            (11, 2.0, "state 1's feature 0"),
            (0, f32::NAN, "state 0's reward"),
        ] {
            let mut bad = map_message();
            bad.data[at] = value;
            let e = map_from(&bad, &settings()).unwrap_err().to_string();
            assert!(e.starts_with(what), "{e}");
        }
    }

    #[test]
    fn a_step_is_read_and_checked_against_the_declared_counts() {
        let map = map_from(&map_message(), &settings()).unwrap();
        let s = step_from(
            &step(&[0., 3., 7., 1., 0., 1., 1., 0., 1., 1.]),
            &settings(),
            &map,
        )
        .expect("a good step");
        assert_eq!((s.episode, s.step, s.answers, s.state), (0, 3, 7, 1));
        assert_eq!((s.effect, s.reward, s.flags), (Some(0), 1.0, STEP_TERMINAL));
        assert!(!s.features.get(0) && s.features.get(2) && s.ends());
        let start = step_from(
            &step(&[1., 0., 0., 0., -1., 0., 0., 1., 0., 0.]),
            &settings(),
            &map,
        );
        assert_eq!(start.unwrap().effect, None);
        for (data, said) in [
            (
                vec![0.; 9],
                "9 numbers where the declared 7 step numbers + 3 features make 10",
            ),
            (vec![0., 0., 0., 3., -1., 0., 0., 0., 0., 0.], "state is 3"),
            (vec![0., 0., 0., 0., 2., 0., 0., 0., 0., 0.], "effect is 2"),
            (vec![0., 0., 0., 0., -1., 0., 2., 0., 0., 0.], "flags is 2"),
            (
                vec![0., 0.5, 0., 0., -1., 0., 0., 0., 0., 0.],
                "step is 0.5",
            ),
            (
                vec![0., 0., 0., 0., -1., f64::INFINITY, 0., 0., 0., 0.],
                "reward is inf",
            ),
            (
                vec![0., 0., 0., 0., -1., 0., 0., 0., 0., -1.],
                "feature 2 is -1",
            ),
        ] {
            let e = step_from(&step(&data), &settings(), &map)
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(said), "{e}");
        }
    }

    /// A step's checked form, for the exchange.
    fn at(episode: u64, step_no: u64, answers: u64, state: usize, effect: Option<usize>) -> Step {
        Step {
            episode,
            step: step_no,
            answers,
            state,
            effect,
            reward: -0.05,
            flags: 0,
            features: FeatureBits::EMPTY,
        }
    }

    #[test]
    fn the_exchange_takes_each_step_once_and_answers_repeats_again() {
        let map = map_from(&map_message(), &settings()).unwrap();
        let mut x = Exchange::default();
        let start = at(0, 0, 0, 0, None);
        assert_eq!(x.take(start, &map), Ok(Taken::New(start)));
        x.current = Some((start, 10));
        // A repeat before the controller answered: nothing to send again.
        assert_eq!(x.take(start, &map), Ok(Taken::Repeat(None)));
        let message = action_message(1, 0, 0, 0);
        x.sent = Some(Sent {
            number: 1,
            command: 99,
            step: (0, 0),
            message: message.clone(),
        });
        assert_eq!(x.take(start, &map), Ok(Taken::Repeat(Some(message))));
        // The answer to action 1: effect 0 from state 0 leads to state 1.
        let next = at(0, 1, 1, 1, Some(0));
        assert_eq!(x.take(next, &map), Ok(Taken::New(next)));
        assert_eq!(
            x.take(at(0, 1, 2, 1, Some(0)), &map),
            Err(Refusal::Stale {
                answers: 2,
                last: 1
            })
        );
        assert_eq!(
            x.take(at(0, 1, 1, 0, Some(0)), &map),
            Err(Refusal::Inconsistent {
                state: 0,
                effect: 0,
                from: 0,
                to: 1
            })
        );
        // Without an effect, any state is taken (TES derives the effect from the states).
        assert!(x.take(at(0, 1, 1, 0, None), &map).is_ok());
        x.current = Some((next, 11));
        assert_eq!(
            x.take(at(0, 0, 0, 0, None), &map),
            Err(Refusal::OldEpisode {
                episode: 0,
                current: 0
            })
        );
        assert!(matches!(
            x.take(at(1, 0, 0, 0, None), &map),
            Ok(Taken::New(_))
        ));
    }
}
