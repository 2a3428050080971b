//! The channels of a TES recording and how each message is written: JSON, described by a JSON
//! Schema (MCAP's registered `json` message encoding and `jsonschema` schema encoding, which
//! Foxglove and other generic viewers decode), converted exactly to and from the fixed-size
//! payloads the processes exchange (floats print in their shortest round-trip form).

use serde::{Deserialize, Serialize};
use tes_topics::{
    Command, FEATURE_CAPACITY, FeatureBits, MAX_ACTIONS, MAX_EFFECTS, MAX_STATES, MotorState,
    Observation, StateAttributes, WorldMap,
};

/// The version of the channels' layout this crate writes and reads. A file of a later
/// version is refused (its fields may mean something else).
pub const FORMAT_VERSION: u32 = 1;

/// MCAP message encoding of every channel.
pub const MESSAGE_ENCODING: &str = "json";
/// MCAP schema encoding of every channel.
pub const SCHEMA_ENCODING: &str = "jsonschema";
/// Key of each channel's metadata holding [`FORMAT_VERSION`].
pub const VERSION_KEY: &str = "tes.format_version";

/// One channel of a recording.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Topic {
    /// The world's structure, once (`/tes/world-map`).
    WorldMap,
    /// Every observation perception published (`/tes/observation`).
    Observation,
    /// Every decision the controller published (`/tes/command`).
    Command,
    /// Every keep-alive the controller sent the bridge's watchdog (`/tes/keep-alive`).
    KeepAlive,
    /// Every motor state the bridge published (`/tes/motor-state`).
    MotorState,
}

impl Topic {
    /// Every channel, in the order a file declares them.
    pub const ALL: [Topic; 5] = [
        Topic::WorldMap,
        Topic::Observation,
        Topic::Command,
        Topic::KeepAlive,
        Topic::MotorState,
    ];

    /// The MCAP topic name.
    pub fn name(self) -> &'static str {
        match self {
            Topic::WorldMap => "/tes/world-map",
            Topic::Observation => "/tes/observation",
            Topic::Command => "/tes/command",
            Topic::KeepAlive => "/tes/keep-alive",
            Topic::MotorState => "/tes/motor-state",
        }
    }

    /// The channel a topic name is, if it is one of ours.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The name of its schema.
    pub fn schema_name(self) -> &'static str {
        match self {
            Topic::WorldMap => "tes.WorldMap",
            Topic::Observation => "tes.Observation",
            Topic::Command | Topic::KeepAlive => "tes.Command",
            Topic::MotorState => "tes.MotorState",
        }
    }

    /// Its JSON Schema.
    pub fn schema(self) -> &'static str {
        match self {
            Topic::WorldMap => WORLD_MAP_SCHEMA,
            Topic::Observation => OBSERVATION_SCHEMA,
            Topic::Command | Topic::KeepAlive => COMMAND_SCHEMA,
            Topic::MotorState => MOTOR_STATE_SCHEMA,
        }
    }

    /// A file name stem for it (`tes replay --export-csv`).
    pub fn stem(self) -> &'static str {
        match self {
            Topic::WorldMap => "world-map",
            Topic::Observation => "observation",
            Topic::Command => "command",
            Topic::KeepAlive => "keep-alive",
            Topic::MotorState => "motor-state",
        }
    }
}

const OBSERVATION_SCHEMA: &str = r#"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "tes.Observation",
  "description": "What perception published when the robot came to rest: the discretised pose and its binary features.",
  "type": "object",
  "properties": {
    "seq": {"type": "integer", "description": "strictly increasing per publisher, from 1"},
    "stamp_ns": {"type": "integer", "description": "CLOCK_MONOTONIC ns when published"},
    "after_command": {"type": "integer", "description": "seq of the command whose motion led here (0 at an episode start)"},
    "episode": {"type": "integer"},
    "step": {"type": "integer", "description": "action index within the episode"},
    "x": {"type": "integer"},
    "y": {"type": "integer"},
    "orientation": {"type": "integer", "description": "heading sector of 45 degrees, counter-clockwise from +x"},
    "n_features": {"type": "integer"},
    "features": {"type": "array", "items": {"type": "integer"}, "description": "indices of the features that are on"},
    "reward": {"type": "number", "description": "reward on entering this state"},
    "flags": {"type": "integer", "description": "1 terminal, 2 episode start, 4 truncated, 8 resync"}
  },
  "required": ["seq", "stamp_ns", "after_command", "episode", "step", "x", "y", "orientation", "n_features", "features", "reward", "flags"]
}"#;

const COMMAND_SCHEMA: &str = r#"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "tes.Command",
  "description": "What the controller sent the bridge: an abstract action and its wheel targets (or a keep-alive).",
  "type": "object",
  "properties": {
    "seq": {"type": "integer"},
    "answers": {"type": "integer", "description": "seq of the observation answered (keep-alive: of the command in flight)"},
    "stamp_ns": {"type": "integer", "description": "CLOCK_MONOTONIC ns when decided"},
    "observed_ns": {"type": "integer", "description": "the answered observation's stamp_ns"},
    "action": {"type": "integer", "description": "action id; 4294967295 for a keep-alive"},
    "left_deg": {"type": "integer"},
    "right_deg": {"type": "integer"},
    "in_flight_action": {"type": "integer"},
    "plans": {"type": "integer", "description": "plans the controller had adopted when it decided"}
  },
  "required": ["seq", "answers", "stamp_ns", "observed_ns", "action", "left_deg", "right_deg", "in_flight_action", "plans"]
}"#;

const MOTOR_STATE_SCHEMA: &str = r#"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "tes.MotorState",
  "description": "What the bridge read from the brick: tacho and rotation counts and run states of ports A, B, C.",
  "type": "object",
  "properties": {
    "seq": {"type": "integer"},
    "after_command": {"type": "integer"},
    "stamp_ns": {"type": "integer"},
    "tacho_count": {"type": "array", "items": {"type": "integer"}, "minItems": 3, "maxItems": 3},
    "rotation_count": {"type": "array", "items": {"type": "integer"}, "minItems": 3, "maxItems": 3},
    "run_state": {"type": "array", "items": {"type": "integer"}, "minItems": 3, "maxItems": 3},
    "battery_mv": {"type": "integer"},
    "action": {"type": "integer", "description": "the action of the command after_command (65535: none that fits)"},
    "flags": {"type": "integer", "description": "1 settled, 2 watchdog braked, 4 link down"}
  },
  "required": ["seq", "after_command", "stamp_ns", "tacho_count", "rotation_count", "run_state", "battery_mv", "flags"]
}"#;

const WORLD_MAP_SCHEMA: &str = r#"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "tes.WorldMap",
  "description": "The world's structure perception gave the controller: per state, the state each effect leads to, its reward, whether it is terminal, and its features.",
  "type": "object",
  "properties": {
    "seq": {"type": "integer"},
    "world": {"type": "integer"},
    "n_states": {"type": "integer"},
    "n_actions": {"type": "integer"},
    "n_effects": {"type": "integer"},
    "n_features": {"type": "integer"},
    "width": {"type": "integer"},
    "height": {"type": "integer"},
    "orientations": {"type": "integer"},
    "action_wheels": {"type": "array", "items": {"type": "array", "items": {"type": "integer"}}},
    "next_state": {"type": "array", "items": {"type": "array", "items": {"type": "integer"}}},
    "reward": {"type": "array", "items": {"type": "number"}},
    "terminal": {"type": "array", "items": {"type": "integer"}},
    "features": {"type": "array", "items": {"type": "array", "items": {"type": "integer"}}}
  },
  "required": ["seq", "world", "n_states", "n_actions", "n_effects", "n_features", "width", "height", "orientations", "action_wheels", "next_state", "reward", "terminal", "features"]
}"#;

/// Why a message of one of our channels cannot be read back.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Not JSON of the channel's schema.
    #[error("not a {schema} message: {why}")]
    Json {
        /// The schema expected.
        schema: &'static str,
        /// What the JSON parser said.
        why: String,
    },
    /// A value out of the payload's range.
    #[error("{what} out of range in a {schema} message")]
    OutOfRange {
        /// The schema.
        schema: &'static str,
        /// The field.
        what: &'static str,
    },
}

fn json<'a, T: Deserialize<'a>>(bytes: &'a [u8], schema: &'static str) -> Result<T, DecodeError> {
    serde_json::from_slice(bytes).map_err(|e| DecodeError::Json {
        schema,
        why: e.to_string(),
    })
}

fn to_json<T: Serialize>(value: &T) -> Vec<u8> {
    // Plain structs of numbers and vectors: serialising cannot fail.
    serde_json::to_vec(value).unwrap_or_default()
}

fn features_of(bits: &FeatureBits) -> Vec<u32> {
    bits.iter_ones().map(|i| i as u32).collect()
}

fn bits_of(features: &[u32], schema: &'static str) -> Result<FeatureBits, DecodeError> {
    let mut bits = FeatureBits::EMPTY;
    for &f in features {
        if f as usize >= FEATURE_CAPACITY {
            return Err(DecodeError::OutOfRange {
                schema,
                what: "feature index",
            });
        }
        bits.set(f as usize);
    }
    Ok(bits)
}

/// An [`Observation`] as JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ObservationJson {
    seq: u64,
    stamp_ns: u64,
    after_command: u64,
    episode: u32,
    step: u32,
    x: u16,
    y: u16,
    orientation: u16,
    n_features: u32,
    features: Vec<u32>,
    reward: f32,
    flags: u32,
}

/// An observation's JSON message.
pub fn encode_observation(o: &Observation) -> Vec<u8> {
    to_json(&ObservationJson {
        seq: o.seq,
        stamp_ns: o.stamp_ns,
        after_command: o.after_command,
        episode: o.episode,
        step: o.step,
        x: o.state.x,
        y: o.state.y,
        orientation: o.state.orientation,
        n_features: o.n_features,
        features: features_of(&o.features),
        reward: o.reward,
        flags: o.flags,
    })
}

/// The observation a JSON message holds.
pub fn decode_observation(bytes: &[u8]) -> Result<Observation, DecodeError> {
    const S: &str = "tes.Observation";
    let j: ObservationJson = json(bytes, S)?;
    Ok(Observation {
        seq: j.seq,
        stamp_ns: j.stamp_ns,
        after_command: j.after_command,
        episode: j.episode,
        step: j.step,
        state: StateAttributes::at(j.x, j.y, j.orientation),
        n_features: j.n_features,
        features: bits_of(&j.features, S)?,
        reward: j.reward,
        flags: j.flags,
    })
}

/// A [`Command`] as JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CommandJson {
    seq: u64,
    answers: u64,
    stamp_ns: u64,
    observed_ns: u64,
    action: u32,
    left_deg: i32,
    right_deg: i32,
    in_flight_action: u32,
    plans: u64,
}

/// A command's JSON message.
pub fn encode_command(c: &Command) -> Vec<u8> {
    to_json(&CommandJson {
        seq: c.seq,
        answers: c.answers,
        stamp_ns: c.stamp_ns,
        observed_ns: c.observed_ns,
        action: c.action,
        left_deg: c.left_deg,
        right_deg: c.right_deg,
        in_flight_action: c.in_flight_action,
        plans: c.plans,
    })
}

/// The command a JSON message holds.
pub fn decode_command(bytes: &[u8]) -> Result<Command, DecodeError> {
    let j: CommandJson = json(bytes, "tes.Command")?;
    Ok(Command {
        seq: j.seq,
        answers: j.answers,
        stamp_ns: j.stamp_ns,
        observed_ns: j.observed_ns,
        action: j.action,
        left_deg: j.left_deg,
        right_deg: j.right_deg,
        in_flight_action: j.in_flight_action,
        reserved: 0,
        plans: j.plans,
    })
}

/// A [`MotorState`] as JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct MotorStateJson {
    seq: u64,
    after_command: u64,
    stamp_ns: u64,
    tacho_count: [i32; 3],
    rotation_count: [i32; 3],
    run_state: [u8; 3],
    battery_mv: u16,
    /// Absent in files recorded before motor states carried their command's action.
    #[serde(default)]
    action: u16,
    flags: u32,
}

/// A motor state's JSON message.
pub fn encode_motor_state(m: &MotorState) -> Vec<u8> {
    to_json(&MotorStateJson {
        seq: m.seq,
        after_command: m.after_command,
        stamp_ns: m.stamp_ns,
        tacho_count: m.tacho_count,
        rotation_count: m.rotation_count,
        run_state: m.run_state,
        battery_mv: m.battery_mv,
        action: m.action,
        flags: m.flags,
    })
}

/// The motor state a JSON message holds.
pub fn decode_motor_state(bytes: &[u8]) -> Result<MotorState, DecodeError> {
    let j: MotorStateJson = json(bytes, "tes.MotorState")?;
    Ok(MotorState {
        seq: j.seq,
        after_command: j.after_command,
        stamp_ns: j.stamp_ns,
        tacho_count: j.tacho_count,
        rotation_count: j.rotation_count,
        run_state: j.run_state,
        battery_mv: j.battery_mv,
        action: j.action,
        flags: j.flags,
        ..MotorState::default()
    })
}

/// A [`WorldMap`] as JSON: only its `n_states` rows and `n_effects` columns.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct WorldMapJson {
    seq: u64,
    world: u32,
    n_states: u32,
    n_actions: u32,
    n_effects: u32,
    n_features: u32,
    width: u16,
    height: u16,
    orientations: u16,
    action_wheels: Vec<[i32; 2]>,
    next_state: Vec<Vec<u16>>,
    reward: Vec<f32>,
    terminal: Vec<u8>,
    features: Vec<Vec<u32>>,
}

/// A world map's JSON message.
pub fn encode_world_map(m: &WorldMap) -> Vec<u8> {
    let n = (m.n_states as usize).min(MAX_STATES);
    let e = (m.n_effects as usize).min(MAX_EFFECTS);
    to_json(&WorldMapJson {
        seq: m.seq,
        world: m.world,
        n_states: m.n_states,
        n_actions: m.n_actions,
        n_effects: m.n_effects,
        n_features: m.n_features,
        width: m.width,
        height: m.height,
        orientations: m.orientations,
        action_wheels: m.action_wheels.to_vec(),
        next_state: m.next_state[..n].iter().map(|r| r[..e].to_vec()).collect(),
        reward: m.reward[..n].to_vec(),
        terminal: m.terminal[..n].to_vec(),
        features: m.features[..n].iter().map(features_of).collect(),
    })
}

/// The world map a JSON message holds (boxed: it is large).
pub fn decode_world_map(bytes: &[u8]) -> Result<Box<WorldMap>, DecodeError> {
    const S: &str = "tes.WorldMap";
    let j: WorldMapJson = json(bytes, S)?;
    let n = j.n_states as usize;
    let e = j.n_effects as usize;
    let range = |what| DecodeError::OutOfRange { schema: S, what };
    if n > MAX_STATES
        || j.next_state.len() != n
        || j.reward.len() != n
        || j.terminal.len() != n
        || j.features.len() != n
    {
        return Err(range("n_states"));
    }
    if e > MAX_EFFECTS || j.next_state.iter().any(|r| r.len() != e) {
        return Err(range("n_effects"));
    }
    if j.action_wheels.len() != MAX_ACTIONS {
        return Err(range("action_wheels"));
    }
    let mut m = Box::new(WorldMap::EMPTY);
    m.seq = j.seq;
    m.world = j.world;
    (m.n_states, m.n_actions, m.n_effects, m.n_features) =
        (j.n_states, j.n_actions, j.n_effects, j.n_features);
    (m.width, m.height, m.orientations) = (j.width, j.height, j.orientations);
    m.action_wheels.copy_from_slice(&j.action_wheels);
    for s in 0..n {
        m.next_state[s][..e].copy_from_slice(&j.next_state[s]);
        m.reward[s] = j.reward[s];
        m.terminal[s] = j.terminal[s];
        m.features[s] = bits_of(&j.features[s], S)?;
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Every observation comes back from its JSON bit for bit (floats included).
        #[test]
        fn observations_round_trip(
            seq: u64, stamp_ns: u64, episode: u32, step: u32, x: u16, y: u16,
            orientation: u16, reward: f32, flags: u32,
            on in proptest::collection::vec(0usize..FEATURE_CAPACITY, 0..40),
        ) {
            prop_assume!(reward.is_finite());
            let mut features = FeatureBits::EMPTY;
            for i in on {
                features.set(i);
            }
            let o = Observation {
                seq, stamp_ns, after_command: seq / 2, episode, step,
                state: StateAttributes::at(x, y, orientation), n_features: 312, features,
                reward, flags,
            };
            let back = decode_observation(&encode_observation(&o)).unwrap();
            prop_assert_eq!(back, o);
            prop_assert_eq!(back.reward.to_bits(), o.reward.to_bits());
        }

        /// Every command and motor state comes back from its JSON.
        #[test]
        fn commands_and_motor_states_round_trip(
            seq: u64, answers: u64, action: u32, left: i32, right: i32, plans: u64,
            counts: [i32; 3], run: [u8; 3], mv: u16, flags: u32,
        ) {
            let c = Command { seq, answers, stamp_ns: 3, observed_ns: 2, action,
                left_deg: left, right_deg: right, in_flight_action: 1, reserved: 0, plans };
            prop_assert_eq!(decode_command(&encode_command(&c)).unwrap(), c);
            let m = MotorState { seq, after_command: answers, stamp_ns: 9, tacho_count: counts,
                rotation_count: counts, run_state: run, battery_mv: mv, flags,
                ..MotorState::default() };
            prop_assert_eq!(decode_motor_state(&encode_motor_state(&m)).unwrap(), m);
        }

        /// Arbitrary bytes never panic the decoders.
        #[test]
        fn garbage_is_refused_not_panicked_on(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = decode_observation(&bytes);
            let _ = decode_command(&bytes);
            let _ = decode_motor_state(&bytes);
            let _ = decode_world_map(&bytes);
        }
    }

    #[test]
    fn the_arena_map_round_trips() {
        use tes_perception_sim::arena::{Arena, ArenaId};
        let map = tes_perception_sim::process::world_map(&Arena::new(ArenaId::Env3)).unwrap();
        let back = decode_world_map(&encode_world_map(&map)).unwrap();
        assert_eq!(encode_world_map(&back), encode_world_map(&map));
        assert_eq!(back.n_states, map.n_states);
        for s in 0..map.n_states as usize {
            assert_eq!(back.next_state[s], map.next_state[s]);
            assert_eq!(back.features[s], map.features[s]);
            assert_eq!(back.reward[s].to_bits(), map.reward[s].to_bits());
        }
    }

    #[test]
    fn schemas_are_json() {
        for t in Topic::ALL {
            let v: serde_json::Value = serde_json::from_str(t.schema()).unwrap();
            assert_eq!(v["title"], t.schema_name());
            assert_eq!(Topic::from_name(t.name()), Some(t));
        }
    }
}
