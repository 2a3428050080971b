//! The payloads as bytes on a link between hosts, and the checks a payload that arrives from
//! another host must pass before any process of this one sees it.
//!
//! A link carries each payload as the fixed-size bytes of its `#[repr(C)]` struct
//! ([`as_bytes`], [`from_bytes`]), as iceoryx2 holds it in shared memory. A peer is another
//! machine: what it sends is input. [`Checker`] refuses a payload whose size, values or
//! sequence number could make a process act on nonsense — an action the world map does not
//! have, wheel targets other than the action's, a non-finite reward, features beyond the map's
//! count, a state the map does not have, a sequence number that goes back — and says why
//! ([`Refusal`]); the link counts and drops what it refuses, so nothing moves on it.
//!
//! ```
//! use tes_topics::wire::{Checker, as_bytes, from_bytes};
//! use tes_topics::{Command, KEEP_ALIVE_ACTION};
//!
//! let keep_alive = Command { seq: 1, action: KEEP_ALIVE_ACTION, ..Command::default() };
//! let bytes = as_bytes(&keep_alive).to_vec();
//! let back: Command = from_bytes(&bytes)?;
//! assert_eq!(back, keep_alive);
//! // Without the world map no command is taken, a keep-alive aside.
//! let mut checker = Checker::default();
//! assert!(checker.command(&back).is_ok());
//! assert!(checker.command(&Command { seq: 2, action: 0, ..Command::default() }).is_err());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::{
    Command, KEEP_ALIVE_ACTION, MotorState, Observation, Progress, Role, WorldMap, motor_flags,
    observation_flags, progress_flags,
};

/// A payload whose bytes a link may carry: `#[repr(C)]`, `Copy`, no pointers, and every bit
/// pattern of its size a value (integers, floats and arrays of them; no `bool`, no enum).
///
/// # Safety
///
/// Implement it only for types that hold the above: [`from_bytes`] makes a value of any
/// bytes of the right size.
pub unsafe trait Wire: Copy + 'static {}

// SAFETY: each is `#[repr(C)]` of integers, floats and arrays of them (sizes pinned by the
// tests of lib.rs), so every bit pattern is a value, and none holds a pointer.
unsafe impl Wire for Observation {}
// SAFETY: as above.
unsafe impl Wire for Command {}
// SAFETY: as above.
unsafe impl Wire for MotorState {}
// SAFETY: as above.
unsafe impl Wire for Progress {}
// SAFETY: as above.
unsafe impl Wire for WorldMap {}

/// The bytes of `value`, as shared memory holds it.
pub fn as_bytes<T: Wire>(value: &T) -> &[u8] {
    // SAFETY: `T: Wire` is plain old data of `size_of::<T>()` bytes; the slice borrows
    // `value` and lives no longer. (Padding bytes, where a type has any, are sent as they
    // are, as iceoryx2's own tunnel sends a sample's bytes.)
    unsafe { std::slice::from_raw_parts((value as *const T).cast::<u8>(), size_of::<T>()) }
}

/// The value `bytes` hold, if they are exactly a `T`'s size.
pub fn from_bytes<T: Wire>(bytes: &[u8]) -> Result<T, Refusal> {
    if bytes.len() != size_of::<T>() {
        return Err(Refusal::Size {
            expected: size_of::<T>(),
            got: bytes.len(),
        });
    }
    // SAFETY: the length is `size_of::<T>()` and every bit pattern is a `T` (`Wire`); the
    // read is unaligned since the bytes may sit anywhere.
    Ok(unsafe { std::ptr::read_unaligned(bytes.as_ptr().cast::<T>()) })
}

/// Why a payload from a peer was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Refusal {
    /// The bytes are not one payload of the type.
    #[error("{got} bytes, not the {expected} of the payload")]
    Size {
        /// The payload's size.
        expected: usize,
        /// What came.
        got: usize,
    },
    /// An observation or command came before any valid world map.
    #[error("no world map yet to check it against")]
    NoMap,
    /// The world map itself is inconsistent.
    #[error("an inconsistent world map")]
    BadMap,
    /// Its sequence number is not after the last one taken.
    #[error("sequence number {got} does not follow {last}")]
    OutOfOrder {
        /// The last one taken.
        last: u64,
        /// What came.
        got: u64,
    },
    /// An action the world map does not have.
    #[error("action {0} is not one of the world map's")]
    Action(u32),
    /// Wheel targets other than the world map's for the action.
    #[error("wheel targets {left}/{right} degrees are not the action's")]
    Wheels {
        /// Left wheel, degrees.
        left: i32,
        /// Right wheel, degrees.
        right: i32,
    },
    /// A reward that is not a finite number.
    #[error("a non-finite reward")]
    Reward,
    /// Features of another count than the world map's, or bits beyond it.
    #[error("features of the wrong size")]
    Features,
    /// A state the world map does not have.
    #[error("a state not in the world map")]
    State,
    /// Flags no sender sets.
    #[error("unknown flags {0:#x}")]
    Flags(u32),
    /// A progress report of another role than its service's.
    #[error("a progress report of role {0} on another role's service")]
    Role(u32),
}

/// Checks what arrives from peers, payload by payload, against the world map and the
/// sequence numbers taken so far. One per receiving link.
#[derive(Debug, Default)]
pub struct Checker {
    map: Option<Box<WorldMap>>,
    last_observation: Option<u64>,
    last_command: Option<u64>,
    last_motor_state: Option<u64>,
}

/// The flags perception sets on an observation.
const OBSERVATION_FLAGS: u32 = observation_flags::TERMINAL
    | observation_flags::EPISODE_START
    | observation_flags::TRUNCATED
    | observation_flags::RESYNC;

/// The flags the bridge sets on a motor state.
const MOTOR_FLAGS: u32 =
    motor_flags::SETTLED | motor_flags::WATCHDOG_BRAKED | motor_flags::LINK_DOWN;

/// The flags a progress report may carry.
const PROGRESS_FLAGS: u32 = progress_flags::LINK_DOWN | progress_flags::LINK_NEVER_UP;

impl Checker {
    /// The world map checks are made against, once one was taken.
    pub fn map(&self) -> Option<&WorldMap> {
        self.map.as_deref()
    }

    /// Takes `map` (from a peer, or published on this host) as the one to check against, if it
    /// is consistent.
    pub fn world_map(&mut self, map: &WorldMap) -> Result<(), Refusal> {
        map.check().map_err(|_| Refusal::BadMap)?;
        let kept = self.map.get_or_insert_with(|| Box::new(WorldMap::EMPTY));
        **kept = *map;
        Ok(())
    }

    /// Checks an observation: the map's feature count and states, a finite reward, known
    /// flags, and a sequence number after the last (a re-published observation, `RESYNC`,
    /// has a new one).
    pub fn observation(&mut self, o: &Observation) -> Result<(), Refusal> {
        let map = self.map.as_deref().ok_or(Refusal::NoMap)?;
        if !o.reward.is_finite() {
            return Err(Refusal::Reward);
        }
        if o.flags & !OBSERVATION_FLAGS != 0 {
            return Err(Refusal::Flags(o.flags));
        }
        if o.n_features != map.n_features || o.features.has_bits_beyond(map.n_features as usize) {
            return Err(Refusal::Features);
        }
        if map
            .state_index(o.state)
            .is_none_or(|s| s >= map.n_states as usize)
        {
            return Err(Refusal::State);
        }
        after(&mut self.last_observation, o.seq)
    }

    /// Checks a command: an action of the map with that action's wheel targets, or a
    /// keep-alive carrying such a command (or none), and a sequence number after the last.
    pub fn command(&mut self, c: &Command) -> Result<(), Refusal> {
        let (action, carries) = if c.action == KEEP_ALIVE_ACTION {
            (c.in_flight_action, c.answers != 0)
        } else {
            (c.action, true)
        };
        if carries {
            let map = self.map.as_deref().ok_or(Refusal::NoMap)?;
            if action >= map.n_actions {
                return Err(Refusal::Action(action));
            }
            if map.action_wheels[action as usize] != [c.left_deg, c.right_deg] {
                return Err(Refusal::Wheels {
                    left: c.left_deg,
                    right: c.right_deg,
                });
            }
        } else if (c.left_deg, c.right_deg) != (0, 0) {
            return Err(Refusal::Wheels {
                left: c.left_deg,
                right: c.right_deg,
            });
        }
        after(&mut self.last_command, c.seq)
    }

    /// Checks a motor state: known flags and a sequence number after the last.
    pub fn motor_state(&mut self, m: &MotorState) -> Result<(), Refusal> {
        if m.flags & !MOTOR_FLAGS != 0 {
            return Err(Refusal::Flags(m.flags));
        }
        after(&mut self.last_motor_state, m.seq)
    }

    /// Checks a progress report that came on `role`'s service.
    pub fn progress(&mut self, role: Role, p: &Progress) -> Result<(), Refusal> {
        if p.role != role as u32 {
            return Err(Refusal::Role(p.role));
        }
        if p.flags & !PROGRESS_FLAGS != 0 {
            return Err(Refusal::Flags(p.flags));
        }
        Ok(())
    }
}

/// Takes `seq` if it comes after `last`.
fn after(last: &mut Option<u64>, seq: u64) -> Result<(), Refusal> {
    match *last {
        Some(l) if seq <= l => Err(Refusal::OutOfOrder { last: l, got: seq }),
        _ => {
            *last = Some(seq);
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StateAttributes;
    use proptest::prelude::*;

    fn map() -> WorldMap {
        let mut m = WorldMap::EMPTY;
        (m.width, m.height, m.orientations) = (3, 2, 8);
        m.n_states = 3 * 2 * 8 + 1;
        (m.n_actions, m.n_effects, m.n_features) = (3, 20, 312);
        m.action_wheels[..3].copy_from_slice(&[[246, 246], [90, -90], [-90, 90]]);
        m
    }

    fn observation(seq: u64) -> Observation {
        Observation {
            seq,
            n_features: 312,
            state: StateAttributes::at(1, 1, 3),
            reward: -1.0,
            ..Observation::default()
        }
    }

    fn checker() -> Checker {
        let mut c = Checker::default();
        c.world_map(&map()).expect("a consistent map");
        c
    }

    #[test]
    fn bytes_round_trip_and_a_wrong_size_is_refused() {
        let o = observation(7);
        let back: Observation = from_bytes(as_bytes(&o)).expect("same size");
        assert_eq!(back, o);
        let short = &as_bytes(&o)[..95];
        assert_eq!(
            from_bytes::<Observation>(short),
            Err(Refusal::Size {
                expected: 96,
                got: 95
            })
        );
    }

    #[test]
    fn valid_payloads_pass_in_order() {
        let mut c = checker();
        assert_eq!(c.observation(&observation(1)), Ok(()));
        assert_eq!(c.observation(&observation(2)), Ok(()));
        let command = Command {
            seq: 1,
            action: 1,
            left_deg: 90,
            right_deg: -90,
            ..Command::default()
        };
        assert_eq!(c.command(&command), Ok(()));
        let keep_alive = Command::keep_alive(2, 0, Some(&command));
        assert_eq!(c.command(&keep_alive), Ok(()));
        assert_eq!(c.command(&Command::keep_alive(3, 0, None)), Ok(()));
    }

    #[test]
    fn each_kind_of_bad_payload_is_refused_with_its_reason() {
        let mut c = Checker::default();
        assert_eq!(c.observation(&observation(1)), Err(Refusal::NoMap));
        let mut bad = map();
        bad.reward[3] = f32::INFINITY;
        assert_eq!(c.world_map(&bad), Err(Refusal::BadMap));
        let mut c = checker();
        let cases: [(Observation, Refusal); 4] = [
            (
                Observation {
                    reward: f32::NAN,
                    ..observation(1)
                },
                Refusal::Reward,
            ),
            (
                Observation {
                    n_features: 52,
                    ..observation(1)
                },
                Refusal::Features,
            ),
            (
                Observation {
                    state: StateAttributes::at(3, 0, 0),
                    ..observation(1)
                },
                Refusal::State,
            ),
            (
                Observation {
                    flags: 1 << 9,
                    ..observation(1)
                },
                Refusal::Flags(1 << 9),
            ),
        ];
        for (o, why) in cases {
            assert_eq!(c.observation(&o), Err(why));
        }
        assert_eq!(c.observation(&observation(5)), Ok(()));
        assert_eq!(
            c.observation(&observation(5)),
            Err(Refusal::OutOfOrder { last: 5, got: 5 })
        );
        let command = |action, left_deg, right_deg| Command {
            seq: 9,
            action,
            left_deg,
            right_deg,
            ..Command::default()
        };
        assert_eq!(c.command(&command(3, 0, 0)), Err(Refusal::Action(3)));
        assert_eq!(
            c.command(&command(0, 9000, 246)),
            Err(Refusal::Wheels {
                left: 9000,
                right: 246
            })
        );
        let mut empty_keep_alive = Command::keep_alive(9, 0, None);
        empty_keep_alive.left_deg = 5;
        assert!(matches!(
            c.command(&empty_keep_alive),
            Err(Refusal::Wheels { .. })
        ));
        assert_eq!(
            c.progress(
                Role::Bridge,
                &Progress {
                    role: Role::Controller as u32,
                    ..Progress::default()
                }
            ),
            Err(Refusal::Role(Role::Controller as u32))
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

        /// Any bytes at all: decoding never panics, and a command the checker takes moves only
        /// by an action's own wheel targets.
        #[test]
        fn arbitrary_bytes_never_pass_as_a_wrong_command(bytes in proptest::collection::vec(any::<u8>(), 0..80)) {
            let mut c = checker();
            if let Ok(command) = from_bytes::<Command>(&bytes)
                && c.command(&command).is_ok()
                && let Some(moving) = command.in_flight()
            {
                let wheels = map().action_wheels[moving.action as usize];
                prop_assert_eq!(wheels, [moving.left_deg, moving.right_deg]);
            }
            if let Ok(o) = from_bytes::<Observation>(&bytes)
                && c.observation(&o).is_ok()
            {
                prop_assert!(o.reward.is_finite() && o.n_features == 312);
            }
        }
    }
}
