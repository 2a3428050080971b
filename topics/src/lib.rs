//! The messages the TES processes exchange, and the names of the services that carry them.
//!
//! TES runs as three processes — `perception-sim` (world + camera), `controller` (learn, plan,
//! act) and `bridge` (LEGO NXT motors) — that share fixed-size buffers through iceoryx2
//! zero-copy publish–subscribe:
//!
//! ```text
//!  perception-sim ──Observation──▶ controller ──Command──▶ bridge ──▶ brick
//!       ▲                                                   │
//!       └───────────────────── MotorState ◀─────────────────┘
//! ```
//!
//! Every payload here is `#[repr(C)]`, `Copy`, pointer-free and of fixed size, so it is written
//! straight into shared memory — by a publisher (`loan_uninit().write_payload(..)`) or, for
//! the controller's `Command`, into a blackboard entry (`tes_runtime::board::LatestOutbox`,
//! which allocates nothing per message) — and no process serialises one. This crate holds only
//! the messages and the services' names; the channels that carry them are in `tes-runtime`.
//!
//! ```
//! use tes_topics::{FeatureBits, Observation, StateAttributes};
//!
//! let mut features = FeatureBits::EMPTY;
//! features.set(3);
//! features.set(311);
//! let obs = Observation {
//!     state: StateAttributes { x: 2, y: 7, orientation: 5, reserved: 0 },
//!     n_features: 312,
//!     features,
//!     ..Observation::default()
//! };
//! assert_eq!(obs.features.iter_ones().collect::<Vec<_>>(), vec![3, 311]);
//! ```

#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;

pub mod names;
pub mod wire;
mod world_map;

pub use world_map::{MAX_ACTIONS, MAX_EFFECTS, MAX_STATES, WorldMap};

pub use arena_features::ARENA_FEATURES;

/// The layout of the robot arenas' binary state features (the paper's §5.2.1): which bit of an
/// [`Observation`]'s [`FeatureBits`] means what. The one definition; perception extracts them
/// by it and libraries name them by it.
pub mod arena_features {
    /// Distance rings per kind of object (green marks, blue marks, the ball).
    pub const RINGS: usize = 100;
    /// Orientation indicators: one per heading sector of 45°.
    pub const ORIENTATIONS: usize = 8;
    /// First green-ring feature: `GREEN_RINGS + i` is on iff a green mark is `i` to `i + 1`
    /// units from the cell's centre.
    pub const GREEN_RINGS: usize = 0;
    /// First blue-ring feature.
    pub const BLUE_RINGS: usize = GREEN_RINGS + RINGS;
    /// First ball-ring feature.
    pub const BALL_RINGS: usize = BLUE_RINGS + RINGS;
    /// First orientation indicator: `ORIENTATION_FEATURES + k` is on iff the orientation is `k`.
    pub const ORIENTATION_FEATURES: usize = BALL_RINGS + RINGS;
    /// On iff the cell holds a green mark.
    pub const GREEN_IN_CELL: usize = ORIENTATION_FEATURES + ORIENTATIONS;
    /// On iff the cell holds no green mark.
    pub const NO_GREEN_IN_CELL: usize = GREEN_IN_CELL + 1;
    /// On iff the cell holds a blue mark.
    pub const BLUE_IN_CELL: usize = GREEN_IN_CELL + 2;
    /// On iff the cell holds no blue mark.
    pub const NO_BLUE_IN_CELL: usize = GREEN_IN_CELL + 3;
    /// Binary features per state: 100 green-mark, 100 blue-mark and 100 ball-distance rings,
    /// 8 orientation indicators and 4 mark bits — the paper's 312.
    pub const ARENA_FEATURES: usize = NO_BLUE_IN_CELL + 1;
    const _: () = assert!(ARENA_FEATURES == 312);
}

/// Capacity, in bits, of a [`FeatureBits`] vector: [`ARENA_FEATURES`] rounded up to whole words.
pub const FEATURE_CAPACITY: usize = FEATURE_WORDS * 64;

/// Number of 64-bit words in a [`FeatureBits`] vector.
pub const FEATURE_WORDS: usize = ARENA_FEATURES.div_ceil(64);

/// The names of the iceoryx2 services, in one place so no process can disagree on them.
pub mod service {
    /// Publish–subscribe service carrying [`crate::Observation`]s from perception to the controller.
    pub const OBSERVATION: &str = "tes/observation";
    /// Event service perception notifies after publishing an observation (wakes a blocked controller).
    pub const OBSERVATION_EVENT: &str = "tes/observation/event";
    /// Publish–subscribe service carrying [`crate::Command`]s from the controller to the bridge.
    pub const COMMAND: &str = "tes/command";
    /// Event service the controller notifies after publishing a command.
    pub const COMMAND_EVENT: &str = "tes/command/event";
    /// Blackboard ring holding the controller's last commands, each by its sequence number
    /// (`tes_runtime::ring`), written after the command is out and notifying nobody: what a
    /// recorder reads every command from.
    pub const COMMAND_LOG: &str = "tes/command/log";
    /// Publish–subscribe service carrying [`crate::MotorState`]s from the bridge to perception.
    pub const MOTOR_STATE: &str = "tes/motor-state";
    /// Event service the bridge notifies after publishing a motor state.
    pub const MOTOR_STATE_EVENT: &str = "tes/motor-state/event";
    /// Publish–subscribe service carrying [`crate::HeadsUp`]s: perception's word, as the robot
    /// starts to settle, of when its next observation is due, so a receiver that waits by
    /// `anticipate` sleeps until shortly before it.
    pub const OBSERVATION_DUE: &str = "tes/observation/due";
    /// Event service perception notifies after publishing a heads-up.
    pub const OBSERVATION_DUE_EVENT: &str = "tes/observation/due/event";
    /// Publish–subscribe service (with history) carrying the [`crate::WorldMap`] from
    /// perception to the controller.
    pub const WORLD_MAP: &str = "tes/world-map";
    /// Event service perception notifies after publishing a world map.
    pub const WORLD_MAP_EVENT: &str = "tes/world-map/event";
    /// Publish–subscribe services (history 1), one per process (`tes/progress/controller`,
    /// …), on which each process of the group says how far it got, a few times a second
    /// ([`crate::Progress`]): the launcher watches them for a group that stopped making
    /// progress and names the process that went silent.
    pub const PROGRESS: &str = "tes/progress";
    /// Publish–subscribe service (no event: nothing waits on it) carrying the
    /// [`crate::WorldPose`]s perception publishes after each observation: where the simulated
    /// world has the robot, for viewers (the recorder), never for the controller.
    pub const WORLD_POSE: &str = "tes/world/pose";
    /// Event service of [`WORLD_POSE`] (notified; nobody listens to it).
    pub const WORLD_POSE_EVENT: &str = "tes/world/pose/event";
}

/// Every service name of one process group, each [`service`] name behind the group's prefix
/// (so that groups with different prefixes never share a service). The one place a prefixed
/// name is built.
///
/// ```
/// let names = tes_topics::ServiceNames::with_prefix("run-42/");
/// assert_eq!(names.command, "run-42/tes/command");
/// assert_eq!(names.observation_event, "run-42/tes/observation/event");
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    /// [`service::OBSERVATION`].
    pub observation: String,
    /// [`service::OBSERVATION_EVENT`].
    pub observation_event: String,
    /// [`service::COMMAND`].
    pub command: String,
    /// [`service::COMMAND_EVENT`].
    pub command_event: String,
    /// [`service::COMMAND_LOG`].
    pub command_log: String,
    /// [`service::MOTOR_STATE`].
    pub motor_state: String,
    /// [`service::MOTOR_STATE_EVENT`].
    pub motor_state_event: String,
    /// [`service::OBSERVATION_DUE`].
    pub observation_due: String,
    /// [`service::OBSERVATION_DUE_EVENT`].
    pub observation_due_event: String,
    /// [`service::WORLD_MAP`].
    pub world_map: String,
    /// [`service::WORLD_MAP_EVENT`].
    pub world_map_event: String,
    /// [`service::PROGRESS`] of each [`Role`], in [`Role::ALL`] order.
    pub progress: [String; 3],
    /// [`service::WORLD_POSE`].
    pub world_pose: String,
    /// [`service::WORLD_POSE_EVENT`].
    pub world_pose_event: String,
}

impl Default for ServiceNames {
    fn default() -> Self {
        Self::with_prefix("")
    }
}

impl ServiceNames {
    /// The names of [`service`], each prefixed by `prefix`.
    pub fn with_prefix(prefix: &str) -> Self {
        let name = |n: &str| format!("{prefix}{n}");
        Self {
            observation: name(service::OBSERVATION),
            observation_event: name(service::OBSERVATION_EVENT),
            command: name(service::COMMAND),
            command_event: name(service::COMMAND_EVENT),
            command_log: name(service::COMMAND_LOG),
            motor_state: name(service::MOTOR_STATE),
            motor_state_event: name(service::MOTOR_STATE_EVENT),
            observation_due: name(service::OBSERVATION_DUE),
            observation_due_event: name(service::OBSERVATION_DUE_EVENT),
            world_map: name(service::WORLD_MAP),
            world_map_event: name(service::WORLD_MAP_EVENT),
            progress: Role::ALL.map(|r| name(&format!("{}/{}", service::PROGRESS, r.name()))),
            world_pose: name(service::WORLD_POSE),
            world_pose_event: name(service::WORLD_POSE_EVENT),
        }
    }

    /// The progress service of `role`.
    pub fn progress_of(&self, role: Role) -> &str {
        &self.progress[role as usize - 1]
    }
}

/// A fixed-capacity set of binary features, stored as a little bitset.
///
/// Bit `i` of word `i / 64` is feature `i`. Bits at or beyond the observation's
/// `n_features` are always clear.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("tes::FeatureBits"))]
#[repr(C)]
pub struct FeatureBits {
    /// The raw bit words.
    pub words: [u64; FEATURE_WORDS],
}

impl FeatureBits {
    /// No feature set.
    pub const EMPTY: Self = Self {
        words: [0; FEATURE_WORDS],
    };

    /// Turns feature `i` on. Indices at or beyond [`FEATURE_CAPACITY`] are ignored and
    /// reported as `false`.
    #[inline]
    pub fn set(&mut self, i: usize) -> bool {
        match self.words.get_mut(i / 64) {
            Some(w) => {
                *w |= 1 << (i % 64);
                true
            }
            None => false,
        }
    }

    /// Whether feature `i` is on (`false` beyond the capacity).
    #[inline]
    pub fn get(&self, i: usize) -> bool {
        self.words
            .get(i / 64)
            .is_some_and(|w| w & (1 << (i % 64)) != 0)
    }

    /// Turns every feature off.
    #[inline]
    pub fn clear(&mut self) {
        self.words = [0; FEATURE_WORDS];
    }

    /// Number of features on.
    #[inline]
    pub fn count_ones(&self) -> u32 {
        self.words.iter().map(|w| w.count_ones()).sum()
    }

    /// The indices of the features that are on, in increasing order.
    pub fn iter_ones(&self) -> impl Iterator<Item = usize> + '_ {
        self.words.iter().enumerate().flat_map(|(wi, &word)| {
            let mut w = word;
            core::iter::from_fn(move || {
                if w == 0 {
                    return None;
                }
                let bit = w.trailing_zeros() as usize;
                w &= w - 1;
                Some(wi * 64 + bit)
            })
        })
    }

    /// Whether any bit at or beyond `n` is set (such a vector is malformed for `n` features).
    pub fn has_bits_beyond(&self, n: usize) -> bool {
        self.words.iter().enumerate().any(|(wi, &w)| {
            let lo = wi * 64;
            if n <= lo {
                w != 0
            } else if n >= lo + 64 {
                false
            } else {
                w >> (n - lo) != 0
            }
        })
    }
}

/// The state attributes that identify a state in the robot arenas: the discretised pose. The
/// "out of the area" state has [`StateAttributes::OUT`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[cfg_attr(
    feature = "ipc",
    derive(ZeroCopySend),
    type_name("tes::StateAttributes")
)]
#[repr(C)]
pub struct StateAttributes {
    /// Grid column of the robot's cell.
    pub x: u16,
    /// Grid row of the robot's cell.
    pub y: u16,
    /// Heading, one of 8 sectors of 45°, counter-clockwise from +x.
    pub orientation: u16,
    /// Padding; always 0.
    pub reserved: u16,
}

impl StateAttributes {
    /// The attributes of the "out of the area" state.
    pub const OUT: Self = Self {
        x: u16::MAX,
        y: u16::MAX,
        orientation: 0,
        reserved: 0,
    };

    /// The pose in cell (`x`, `y`) with heading sector `orientation`.
    pub const fn at(x: u16, y: u16, orientation: u16) -> Self {
        Self {
            x,
            y,
            orientation,
            reserved: 0,
        }
    }

    /// Whether these are the out state's attributes.
    pub fn is_out(self) -> bool {
        self.x == u16::MAX && self.y == u16::MAX
    }

    /// How far `self` is from `other` by the effect rule ([`effect_between`]): cells apart
    /// (Chebyshev distance), then heading sectors apart (circular, out of `orientations`).
    /// The out state is as far as it gets from any state inside the area and none from itself.
    pub fn distance(self, other: Self, orientations: u16) -> (u32, u32) {
        match (self.is_out(), other.is_out()) {
            (true, true) => (0, 0),
            (true, false) | (false, true) => (u32::MAX, 0),
            (false, false) => {
                let cells = self.x.abs_diff(other.x).max(self.y.abs_diff(other.y));
                let o = i32::from(orientations.max(1));
                let turn =
                    (i32::from(self.orientation) - i32::from(other.orientation)).rem_euclid(o);
                (u32::from(cells), turn.min(o - turn) as u32)
            }
        }
    }
}

/// The effect that explains a move: given each effect's known outcome from the state the robot
/// left (in effect order) and the pose it `reached`, the lowest-numbered effect whose outcome
/// is that pose; if none (real motion can skip cells or turn further than any effect says),
/// the one whose outcome is nearest ([`StateAttributes::distance`]), the lowest-numbered on a
/// tie. Reaching the out state where no effect leads out gives effect 0. The one home of this
/// rule: the worlds and the controller both use it. Allocation-free.
///
/// ```
/// use tes_topics::{StateAttributes, effect_between};
///
/// let from = StateAttributes::at(2, 2, 0);
/// // Effects: 0 forward (east), 1 stay, 2 turn left.
/// let outcomes = [StateAttributes::at(3, 2, 0), from, StateAttributes::at(2, 2, 1)];
/// assert_eq!(effect_between(outcomes, StateAttributes::at(2, 2, 1), 8), 2);
/// // Two cells forward: nearest to "forward".
/// assert_eq!(effect_between(outcomes, StateAttributes::at(4, 2, 0), 8), 0);
/// ```
pub fn effect_between(
    outcomes: impl IntoIterator<Item = StateAttributes>,
    reached: StateAttributes,
    orientations: u16,
) -> usize {
    let mut best = (0, (u32::MAX, u32::MAX));
    for (e, outcome) in outcomes.into_iter().enumerate() {
        let d = outcome.distance(reached, orientations);
        if d == (0, 0) {
            return e;
        }
        if d < best.1 {
            best = (e, d);
        }
    }
    best.0
}

/// Which process of the group a [`Progress`] report comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[repr(u32)]
pub enum Role {
    /// perception-sim: the world and its camera.
    Perception = 1,
    /// The controller: learn, plan, act.
    Controller = 2,
    /// The bridge to the brick.
    Bridge = 3,
}

impl Role {
    /// Every role, in the order the data flows.
    pub const ALL: [Role; 3] = [Role::Perception, Role::Controller, Role::Bridge];

    /// The role a [`Progress::role`] number names.
    pub fn from_number(n: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|r| *r as u32 == n)
    }

    /// The process's name, as the launcher calls it.
    pub fn name(self) -> &'static str {
        match self {
            Role::Perception => "perception-sim",
            Role::Controller => "controller",
            Role::Bridge => "bridge",
        }
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // `pad`, so that a width (`{:<14}`) lines members up in tables.
        f.pad(self.name())
    }
}

/// A name that is not one of the group's roles.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownRole(pub String);

impl std::fmt::Display for UnknownRole {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "unknown role {:?}: the roles are \"perception-sim\", \"controller\" and \"bridge\"",
            self.0
        )
    }
}

impl std::error::Error for UnknownRole {}

impl std::str::FromStr for Role {
    type Err = UnknownRole;

    /// A role by its [`Role::name`]: the one place a role's name is read.
    fn from_str(name: &str) -> Result<Self, UnknownRole> {
        Self::ALL
            .into_iter()
            .find(|r| r.name() == name)
            .ok_or_else(|| UnknownRole(name.to_owned()))
    }
}

impl serde::Serialize for Role {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for Role {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let name = <String as serde::Deserialize>::deserialize(deserializer)?;
        name.parse().map_err(serde::de::Error::custom)
    }
}

/// Bit flags of a [`Progress`] report.
pub mod progress_flags {
    /// The bridge's link to the brick is down (its transport failed and has not recovered).
    pub const LINK_DOWN: u32 = 1;
    /// The bridge's link has not been up yet since the bridge started.
    pub const LINK_NEVER_UP: u32 = 1 << 1;
    /// Perception waits on a peer outside the group that sets its own pace — a ROS 2
    /// robot's next step — so a group without new commands is not stalled.
    pub const AWAITING_PEER: u32 = 1 << 2;
}

/// How far one process of the group got: published on [`service::PROGRESS`] a few times a
/// second, off the acting path (after a command is out, or while idle), so that a watcher
/// can tell a group that stopped making progress and which process holds it up.
///
/// The three sequence fields follow the loop observation → command → motion: perception
/// publishes observation `out_seq` after using the motion of command `in_seq`; the controller
/// answers observation `in_seq` with command `out_seq`; the bridge executes command `in_seq`
/// and reports the motion of command `out_seq` settled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("tes::Progress"))]
#[repr(C)]
pub struct Progress {
    /// Monotonic clock (ns) when published.
    pub stamp_ns: u64,
    /// Monotonic clock (ns) when the process started.
    pub started_ns: u64,
    /// The process id.
    pub pid: u32,
    /// The [`Role`], as its number.
    pub role: u32,
    /// Episodes finished.
    pub episodes: u64,
    /// Steps done: observations published (perception), commands sent (controller),
    /// commands executed (bridge).
    pub steps: u64,
    /// The newest sequence number taken in (see the type's docs).
    pub in_seq: u64,
    /// The newest sequence number given out (see the type's docs).
    pub out_seq: u64,
    /// [`progress_flags`] bits.
    pub flags: u32,
    /// Padding; always 0.
    pub reserved: u32,
}

/// Bit flags of an [`Observation`].
pub mod observation_flags {
    /// The state is terminal: the episode ends with this observation.
    pub const TERMINAL: u32 = 1;
    /// This observation starts a new episode (no previous action to learn from).
    pub const EPISODE_START: u32 = 1 << 1;
    /// The episode was ended by the world (stuck, step cap) rather than a terminal state.
    pub const TRUNCATED: u32 = 1 << 2;
    /// The outcome of the last command is unknown (it was lost or never answered): nothing to
    /// learn from it; act from this state. The episode goes on.
    pub const RESYNC: u32 = 1 << 3;
}

/// What perception publishes each time the robot comes to rest: the state and its features.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("tes::Observation"))]
#[repr(C)]
pub struct Observation {
    /// Strictly increasing per publisher, starting at 1.
    pub seq: u64,
    /// Monotonic clock (`CLOCK_MONOTONIC`, ns) when the observation was published.
    pub stamp_ns: u64,
    /// Sequence number of the command whose motion led here (0 at an episode start).
    pub after_command: u64,
    /// Episode index, from 0.
    pub episode: u32,
    /// Action index within the episode, from 0.
    pub step: u32,
    /// The discretised pose.
    pub state: StateAttributes,
    /// Number of meaningful bits in `features`.
    pub n_features: u32,
    /// The binary state features `f(s)`.
    pub features: FeatureBits,
    /// Reward received on entering this state.
    pub reward: f32,
    /// [`observation_flags`] bits.
    pub flags: u32,
}

/// What the controller sends the bridge: one of the robot's abstract actions and its wheel targets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("tes::Command"))]
#[repr(C)]
pub struct Command {
    /// Strictly increasing per publisher, starting at 1.
    pub seq: u64,
    /// The `seq` of the observation this command answers. For a keep-alive: the `seq` of the
    /// command in flight (whose outcome the controller awaits), 0 if none.
    pub answers: u64,
    /// Monotonic clock (ns) when the command was published.
    pub stamp_ns: u64,
    /// The answered observation's `stamp_ns` (0 if none, e.g. a keep-alive): lets the
    /// receiver measure the whole observation → command latency.
    pub observed_ns: u64,
    /// Abstract action id (0..3 for the paper's robot).
    pub action: u32,
    /// Signed target rotation of the left wheel, degrees.
    pub left_deg: i32,
    /// Signed target rotation of the right wheel, degrees.
    pub right_deg: i32,
    /// For a keep-alive: the action of the command in flight (its wheel targets are in
    /// `left_deg`/`right_deg`, its `seq` in `answers`), so that a bridge that starts while
    /// the keep-alive is the latest command can still carry out the command in flight
    /// ([`Command::in_flight`]). 0 otherwise.
    pub in_flight_action: u32,
    /// Padding; always 0.
    pub reserved: u32,
    /// Plans the controller had adopted when it decided (its start-up plan included; 0 for a
    /// keep-alive): which model hand-over the deciding plan came from, since at most one plan
    /// is in flight and plans are adopted in hand-over order. A recording keeps it so that a
    /// replay adopts each plan at the same observation (`tes replay`).
    pub plans: u64,
}

impl Command {
    /// A keep-alive (see [`KEEP_ALIVE_ACTION`]) numbered `seq`, sent at `stamp_ns`, carrying
    /// the command in flight, if any.
    pub fn keep_alive(seq: u64, stamp_ns: u64, in_flight: Option<&Command>) -> Self {
        let mut k = Command {
            seq,
            stamp_ns,
            action: KEEP_ALIVE_ACTION,
            ..Command::default()
        };
        if let Some(c) = in_flight {
            (k.answers, k.in_flight_action) = (c.seq, c.action);
            (k.left_deg, k.right_deg) = (c.left_deg, c.right_deg);
        }
        k
    }

    /// The command this one stands for while it is the latest: itself, or for a keep-alive
    /// the command in flight it carries (`None` if it carries none).
    pub fn in_flight(&self) -> Option<Command> {
        if self.action != KEEP_ALIVE_ACTION {
            return Some(*self);
        }
        (self.answers != 0).then_some(Command {
            seq: self.answers,
            answers: 0,
            stamp_ns: self.stamp_ns,
            observed_ns: 0,
            action: self.in_flight_action,
            left_deg: self.left_deg,
            right_deg: self.right_deg,
            in_flight_action: 0,
            reserved: 0,
            plans: 0,
        })
    }
}

/// The [`Command::action`] that moves nothing and only tells the bridge the controller is
/// alive: it feeds the bridge's watchdog, which brakes the motors when neither a command nor
/// a keep-alive arrives within its deadline while a motor runs.
pub const KEEP_ALIVE_ACTION: u32 = u32::MAX;

/// [`MotorState::action`] when the command's action id does not fit.
pub const NO_ACTION: u16 = u16::MAX;

/// Where the simulated world has the robot, published by perception after each observation:
/// the pose before and after the motion that led to it (both the same at an episode's
/// start). The camera discretises this pose into the observation's state; the controller
/// never sees it. A viewer draws the robot from it (moving it along the motion as the
/// wheels turn) beside what the controller believes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("tes::WorldPose"))]
#[repr(C)]
pub struct WorldPose {
    /// The observation this pose was seen at ([`Observation::seq`]).
    pub observation: u64,
    /// Monotonic clock (ns) when it was published.
    pub stamp_ns: u64,
    /// The command whose motion went from `from` to `to` (0 at an episode's start).
    pub after_command: u64,
    /// Episode index, from 0.
    pub episode: u32,
    /// Padding; always 0.
    pub reserved: u32,
    /// Before the motion: x and y (cm from the arena's south-west corner) and heading (rad,
    /// counter-clockwise from east).
    pub from: [f64; 3],
    /// After the motion, as `from`.
    pub to: [f64; 3],
}

/// Motor run states as the NXT firmware reports them.
pub mod run_state {
    /// Motor is idle (coasting or braked, not running a command).
    pub const IDLE: u8 = 0x00;
    /// Ramping up.
    pub const RAMP_UP: u8 = 0x10;
    /// Running.
    pub const RUNNING: u8 = 0x20;
    /// Ramping down.
    pub const RAMP_DOWN: u8 = 0x40;
}

/// Bit flags of a [`MotorState`].
pub mod motor_flags {
    /// All commanded motion has finished (both wheel motors idle).
    pub const SETTLED: u32 = 1;
    /// The bridge's watchdog braked the motors because commands stopped arriving.
    pub const WATCHDOG_BRAKED: u32 = 1 << 1;
    /// The transport to the brick failed; the counts are the last known ones.
    pub const LINK_DOWN: u32 = 1 << 2;
}

/// A publisher's word of when its next message is due: perception sends one as the robot
/// starts to settle (the observation follows the settle time later), the latency floor's
/// source as it starts its pause. A receiver waiting by `anticipate` sleeps until shortly
/// before `due_ns` and polls only then.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("tes::HeadsUp"))]
#[repr(C)]
pub struct HeadsUp {
    /// The `seq` the announced message will carry.
    pub seq: u64,
    /// Monotonic clock (ns) at which it is due.
    pub due_ns: u64,
}

/// What the bridge reports from the brick: wheel rotation counts and motor states.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("tes::MotorState"))]
#[repr(C)]
pub struct MotorState {
    /// Strictly increasing per publisher, starting at 1.
    pub seq: u64,
    /// The `seq` of the command these counts follow.
    pub after_command: u64,
    /// Monotonic clock (ns) when the state was read.
    pub stamp_ns: u64,
    /// Tacho counts (degrees) of output ports A, B, C since the last reset.
    pub tacho_count: [i32; 3],
    /// Rotation counts (degrees) of ports A, B, C: the position relative to the last reset.
    pub rotation_count: [i32; 3],
    /// [`run_state`] of ports A, B, C.
    pub run_state: [u8; 3],
    /// Padding; always 0.
    pub reserved: u8,
    /// Battery voltage in millivolts.
    pub battery_mv: u16,
    /// The abstract action of the command `after_command` ([`Command::action`]; 0 before any
    /// command, [`NO_ACTION`] for an id beyond `u16`): for logs of what the robot did.
    pub action: u16,
    /// [`motor_flags`] bits.
    pub flags: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feature_bits_set_get_iterate() {
        let mut b = FeatureBits::EMPTY;
        for i in [0, 63, 64, 200, ARENA_FEATURES - 1] {
            assert!(b.set(i));
        }
        assert!(!b.set(FEATURE_CAPACITY));
        assert!(b.get(63) && b.get(64) && !b.get(65));
        assert_eq!(b.count_ones(), 5);
        assert_eq!(
            b.iter_ones().collect::<Vec<_>>(),
            vec![0, 63, 64, 200, ARENA_FEATURES - 1]
        );
        assert!(!b.has_bits_beyond(ARENA_FEATURES));
        assert!(b.has_bits_beyond(300));
        assert!(b.has_bits_beyond(0));
        b.clear();
        assert_eq!(b.count_ones(), 0);
        assert!(!b.has_bits_beyond(0));
    }

    #[test]
    fn payloads_are_fixed_size_and_pointer_free() {
        // The sizes are part of the wire contract between processes: a change here is a
        // protocol change and must be deliberate.
        assert_eq!(core::mem::size_of::<FeatureBits>(), 8 * FEATURE_WORDS);
        assert_eq!(core::mem::size_of::<Observation>(), 96);
        assert_eq!(core::mem::size_of::<Command>(), 64);
        assert_eq!(core::mem::size_of::<MotorState>(), 64);
        assert_eq!(core::mem::size_of::<Progress>(), 64);
        assert_eq!(core::mem::size_of::<WorldPose>(), 80);
        assert_eq!(FEATURE_CAPACITY, 320);
    }

    #[test]
    fn a_keep_alive_carries_the_command_in_flight() {
        let command = Command {
            seq: 7,
            answers: 3,
            action: 2,
            left_deg: 90,
            right_deg: -90,
            ..Command::default()
        };
        assert_eq!(command.in_flight(), Some(command));
        let k = Command::keep_alive(8, 55, Some(&command));
        assert_eq!(k.action, KEEP_ALIVE_ACTION);
        let carried = k.in_flight().expect("carried");
        assert_eq!(
            (
                carried.seq,
                carried.action,
                carried.left_deg,
                carried.right_deg
            ),
            (7, 2, 90, -90)
        );
        assert_eq!(Command::keep_alive(9, 56, None).in_flight(), None);
    }

    #[test]
    #[cfg(feature = "ipc")]
    fn type_names_are_stable() {
        // iceoryx2 matches services by payload type name; keep them independent of module paths.
        // SAFETY: `type_name` only returns a static string.
        unsafe {
            assert_eq!(
                <Observation as iceoryx2::prelude::ZeroCopySend>::type_name(),
                "tes::Observation"
            );
            assert_eq!(
                <Command as iceoryx2::prelude::ZeroCopySend>::type_name(),
                "tes::Command"
            );
        }
    }
}
