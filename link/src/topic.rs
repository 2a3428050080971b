//! The services that cross the link, as [`Topic`]s: their keys, their writers and readers.

use std::fmt;
use std::sync::LazyLock;

use tes_topics::Role;

/// A service of the group that crosses the link: one Zenoh key under the group's name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Topic {
    /// Observations, perception → controller (publish–subscribe).
    Observation,
    /// The world map, perception → controller and every host (publish–subscribe, history 1).
    WorldMap,
    /// Commands, controller → bridge (blackboard).
    Command,
    /// Motor states, bridge → perception (publish–subscribe).
    MotorState,
    /// A role's progress reports, the role → everyone (publish–subscribe, history 1).
    Progress(Role),
}

/// The keys of the progress topics, in the order of [`Role::ALL`], built once from the
/// roles' names.
static PROGRESS_KEYS: LazyLock<[String; 3]> =
    LazyLock::new(|| Role::ALL.map(|role| format!("progress/{}", role.name())));

/// A role's place in [`Role::ALL`].
pub(crate) fn role_index(role: Role) -> usize {
    match role {
        Role::Perception => 0,
        Role::Controller => 1,
        Role::Bridge => 2,
    }
}

impl Topic {
    /// Every topic, in the order of [`Topic::index`] (and of [`crate::LinkCounts`]).
    pub const ALL: [Topic; 7] = [
        Topic::Observation,
        Topic::WorldMap,
        Topic::Command,
        Topic::MotorState,
        Topic::Progress(Role::Perception),
        Topic::Progress(Role::Controller),
        Topic::Progress(Role::Bridge),
    ];

    /// The topic's key under the group's name: `observation`, `world-map`, `command`,
    /// `motor-state`, `progress/ROLE`.
    pub fn key(self) -> &'static str {
        match self {
            Topic::Observation => "observation",
            Topic::WorldMap => "world-map",
            Topic::Command => "command",
            Topic::MotorState => "motor-state",
            Topic::Progress(role) => PROGRESS_KEYS[role_index(role)].as_str(),
        }
    }

    /// The topic's place in [`Topic::ALL`].
    pub fn index(self) -> usize {
        match self {
            Topic::Observation => 0,
            Topic::WorldMap => 1,
            Topic::Command => 2,
            Topic::MotorState => 3,
            Topic::Progress(role) => 4 + role_index(role),
        }
    }

    /// The role that writes the topic.
    pub fn writer(self) -> Role {
        match self {
            Topic::Observation | Topic::WorldMap => Role::Perception,
            Topic::Command => Role::Controller,
            Topic::MotorState => Role::Bridge,
            Topic::Progress(role) => role,
        }
    }

    /// Whether the topic is read on a host playing `local` (every host checks commands
    /// against the world map, and the launcher watches every role's progress).
    pub fn read_by(self, local: &[Role]) -> bool {
        let has = |r| local.contains(&r);
        match self {
            Topic::Observation => has(Role::Controller),
            Topic::WorldMap => true,
            Topic::Command => has(Role::Bridge),
            Topic::MotorState => has(Role::Perception),
            Topic::Progress(_) => true,
        }
    }

    /// Whether a host playing `local` takes the topic from its peers: it reads it and does
    /// not write it.
    pub fn comes_in(self, local: &[Role]) -> bool {
        !local.contains(&self.writer()) && self.read_by(local)
    }

    /// Whether a host playing `local` sends the topic to its peers: it writes it and a role
    /// played elsewhere reads it.
    pub fn goes_out(self, local: &[Role]) -> bool {
        let others: Vec<Role> = Role::ALL
            .into_iter()
            .filter(|r| !local.contains(r))
            .collect();
        local.contains(&self.writer()) && self.read_by(&others)
    }
}

/// The topic's [`key`](Topic::key).
impl fmt::Display for Topic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.key())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The keys are the ones peers of earlier builds send and expect.
    #[test]
    fn keys_are_the_wire_keys() {
        let keys: Vec<&str> = Topic::ALL.iter().map(|t| t.key()).collect();
        assert_eq!(
            keys,
            [
                "observation",
                "world-map",
                "command",
                "motor-state",
                "progress/perception-sim",
                "progress/controller",
                "progress/bridge",
            ]
        );
        assert_eq!(Topic::Progress(Role::Bridge).to_string(), "progress/bridge");
    }

    #[test]
    fn index_is_the_place_in_all() {
        for (i, t) in Topic::ALL.into_iter().enumerate() {
            assert_eq!(t.index(), i, "{t}");
        }
    }

    #[test]
    fn writers_and_readers() {
        use Role::{Bridge, Controller, Perception};
        let writers: Vec<Role> = Topic::ALL.iter().map(|t| t.writer()).collect();
        assert_eq!(
            writers,
            [
                Perception, Perception, Controller, Bridge, Perception, Controller, Bridge
            ]
        );
        // A robot host (perception and bridge) and a learning host (the controller).
        let robot = [Perception, Bridge];
        let learner = [Controller];
        let incoming = |local: &[Role]| -> Vec<Topic> {
            Topic::ALL
                .into_iter()
                .filter(|t| t.comes_in(local))
                .collect()
        };
        let outgoing = |local: &[Role]| -> Vec<Topic> {
            Topic::ALL
                .into_iter()
                .filter(|t| t.goes_out(local))
                .collect()
        };
        assert_eq!(
            incoming(&robot),
            [Topic::Command, Topic::Progress(Controller)]
        );
        assert_eq!(
            outgoing(&robot),
            [
                Topic::Observation,
                Topic::WorldMap,
                Topic::Progress(Perception),
                Topic::Progress(Bridge)
            ]
        );
        assert_eq!(
            incoming(&learner),
            [
                Topic::Observation,
                Topic::WorldMap,
                Topic::Progress(Perception),
                Topic::Progress(Bridge)
            ]
        );
        assert_eq!(
            outgoing(&learner),
            [Topic::Command, Topic::Progress(Controller)]
        );
        // Motor states cross only when the bridge and perception are on different hosts.
        assert!(Topic::MotorState.goes_out(&[Bridge]));
        assert!(Topic::MotorState.comes_in(&[Perception, Controller]));
    }
}
