//! Abstract actions → SETOUTPUTSTATE commands, from config.
//!
//! The paper's robot (§5.2) has three actions: both wheels 246°; left wheel 90° and right
//! −90°; left wheel 90°. Each becomes, per wheel that turns, one SETOUTPUTSTATE with the
//! configured power (signed by the direction), mode, regulation and a tacho limit of the
//! rotation's magnitude. Ports, power, mode and the action table are configuration
//! ([`ActionConfig`], the `[motors]` table and `[[actions]]` array of the bridge config).
//!
//! ```
//! use tes_bridge::actions::ActionMap;
//! use tes_bridge::nxt::{Port, PortSelector};
//!
//! let map = ActionMap::paper_default();
//! let cmds = map.for_action(1)?; // turn left: left +90°, right −90°
//! let [Some(left), Some(right)] = cmds.commands else { panic!("two wheels turn") };
//! assert_eq!((left.port, left.power, left.tacho_limit), (PortSelector::One(Port::B), 75, 90));
//! assert_eq!((right.port, right.power, right.tacho_limit), (PortSelector::One(Port::C), -75, 90));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use serde::{Deserialize, Serialize};

use crate::nxt::{Mode, Port, PortSelector, RegulationMode, RunState, SetOutputState};

/// The largest wheel rotation one action may ask for, degrees (100 turns).
pub const MAX_ACTION_DEG: i32 = 36_000;

/// The range of `[motors] power`.
pub const POWER_RANGE: std::ops::RangeInclusive<i8> = 1..=100;

/// How the wheel motors are wired and driven (the `[motors]` table). Each field's doc is its
/// key's entry in the launch file's reference (`tes launch --print-config`), as for
/// [`BridgeSettings`](crate::config::BridgeSettings).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct MotorsConfig {
    /// Output port of the left wheel motor.
    ///
    /// Values: `"A"` | `"B"` | `"C"`.
    pub left_port: Port,
    /// Output port of the right wheel motor.
    ///
    /// Values: `"A"` | `"B"` | `"C"`; not `left_port`.
    pub right_port: Port,
    /// Power (the speed set-point with regulation).
    ///
    /// Values: [`POWER_RANGE`].
    pub power: i8,
    /// Brake at the tacho limit (MODE bit BRAKE) rather than coast.
    ///
    /// Values: `true` | `false`.
    pub brake: bool,
    /// Turn on regulation (MODE bit REGULATED) with `regulation`.
    ///
    /// Values: `true` | `false`.
    pub regulated: bool,
    /// The regulation mode.
    ///
    /// Values: `"idle"` | `"speed"` | `"sync"`; not `idle` when `regulated`.
    pub regulation: RegulationMode,
    /// The left motor is mounted so that positive power drives the wheel backwards.
    ///
    /// Values: `true` | `false`.
    pub left_reversed: bool,
    /// The right motor is mounted so that positive power drives the wheel backwards.
    ///
    /// Values: `true` | `false`.
    pub right_reversed: bool,
    /// Ask the brick to acknowledge each SETOUTPUTSTATE (a Bluetooth round trip each).
    ///
    /// Values: `true` | `false`.
    pub acknowledge: bool,
}

impl Default for MotorsConfig {
    fn default() -> Self {
        Self {
            left_port: Port::B,
            right_port: Port::C,
            power: 75,
            brake: true,
            regulated: true,
            regulation: RegulationMode::Speed,
            left_reversed: false,
            right_reversed: false,
            acknowledge: false,
        }
    }
}

/// One abstract action: how far each wheel turns (an `[[actions]]` entry). Each field's doc is
/// its key's entry in the launch file's reference, as for [`MotorsConfig`].
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ActionSpec {
    /// The action id the controller sends. Required in each entry.
    ///
    /// Values: integer, at least 0, unique.
    pub id: u32,
    /// A name for logs (optional: empty when left out).
    ///
    /// Values: text.
    #[serde(default)]
    pub name: String,
    /// Signed rotation of the left wheel. Required in each entry.
    ///
    /// Values: degrees, within ±[`MAX_ACTION_DEG`].
    pub left_deg: i32,
    /// Signed rotation of the right wheel. Required in each entry.
    ///
    /// Values: degrees, within ±[`MAX_ACTION_DEG`].
    pub right_deg: i32,
}

/// The motors and the action table, as deserialised.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ActionConfig {
    /// The `[motors]` table.
    #[serde(default)]
    pub motors: MotorsConfig,
    /// The `[[actions]]` array (the paper's three actions if absent).
    #[serde(default = "paper_actions")]
    pub actions: Vec<ActionSpec>,
}

impl Default for ActionConfig {
    fn default() -> Self {
        Self {
            motors: MotorsConfig::default(),
            actions: paper_actions(),
        }
    }
}

/// The paper's three actions (§5.2): forward, turn left, turn right.
pub fn paper_actions() -> Vec<ActionSpec> {
    vec![
        ActionSpec {
            id: 0,
            name: "forward".into(),
            left_deg: 246,
            right_deg: 246,
        },
        ActionSpec {
            id: 1,
            name: "turn-left".into(),
            left_deg: 90,
            right_deg: -90,
        },
        ActionSpec {
            id: 2,
            name: "turn-right".into(),
            left_deg: 90,
            right_deg: 0,
        },
    ]
}

/// An invalid action configuration; `key` names the offending TOML key.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key}: {reason}")]
pub struct ActionConfigError {
    /// The key, e.g. `motors.power` or `actions[2].id`.
    pub key: String,
    /// What is wrong.
    pub reason: String,
}

/// A request for an action the table does not have.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("unknown action id {0}")]
pub struct UnknownAction(pub u32);

/// The motor commands of one action: one SETOUTPUTSTATE per wheel that turns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MotorCommands {
    /// Left wheel, right wheel (`None`: that wheel stays still).
    pub commands: [Option<SetOutputState>; 2],
    /// Whether to ask the brick to acknowledge each command.
    pub acknowledge: bool,
}

impl MotorCommands {
    /// The commands to send, in order.
    pub fn iter(&self) -> impl Iterator<Item = &SetOutputState> {
        self.commands.iter().flatten()
    }
}

/// A validated action table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ActionMap {
    cfg: ActionConfig,
}

impl ActionMap {
    /// Validates `cfg`: distinct wheel ports, power in [`POWER_RANGE`], a non-empty table with
    /// unique ids and rotations within ±[`MAX_ACTION_DEG`].
    pub fn new(cfg: ActionConfig) -> Result<Self, ActionConfigError> {
        let err = |key: &str, reason: String| ActionConfigError {
            key: key.to_owned(),
            reason,
        };
        let m = &cfg.motors;
        if m.left_port == m.right_port {
            return Err(err(
                "motors.right_port",
                format!("must differ from left_port ({:?})", m.left_port),
            ));
        }
        if !POWER_RANGE.contains(&m.power) {
            return Err(err(
                "motors.power",
                format!(
                    "must be in {}..={}, got {}",
                    POWER_RANGE.start(),
                    POWER_RANGE.end(),
                    m.power
                ),
            ));
        }
        if m.regulated && m.regulation == RegulationMode::Idle {
            return Err(err(
                "motors.regulation",
                "must be \"speed\" or \"sync\" when regulated = true".into(),
            ));
        }
        if cfg.actions.is_empty() {
            return Err(err(
                "actions",
                "at least one [[actions]] entry is required".into(),
            ));
        }
        for (i, a) in cfg.actions.iter().enumerate() {
            if cfg.actions[..i].iter().any(|b| b.id == a.id) {
                return Err(err(
                    &format!("actions[{i}].id"),
                    format!("duplicate action id {}", a.id),
                ));
            }
            for (key, deg) in [("left_deg", a.left_deg), ("right_deg", a.right_deg)] {
                if deg.unsigned_abs() > MAX_ACTION_DEG as u32 {
                    return Err(err(
                        &format!("actions[{i}].{key}"),
                        format!("must be within ±{MAX_ACTION_DEG}, got {deg}"),
                    ));
                }
            }
        }
        Ok(Self { cfg })
    }

    /// The paper's three actions on ports B (left) and C (right), power 75, braking, regulated.
    pub fn paper_default() -> Self {
        Self {
            cfg: ActionConfig::default(),
        }
    }

    /// The validated configuration.
    pub fn config(&self) -> &ActionConfig {
        &self.cfg
    }

    /// The wheel ports (left, right).
    pub fn wheel_ports(&self) -> [Port; 2] {
        [self.cfg.motors.left_port, self.cfg.motors.right_port]
    }

    /// The action with this id.
    pub fn action(&self, id: u32) -> Option<&ActionSpec> {
        self.cfg.actions.iter().find(|a| a.id == id)
    }

    /// The commands for action `id`.
    pub fn for_action(&self, id: u32) -> Result<MotorCommands, UnknownAction> {
        let a = self.action(id).ok_or(UnknownAction(id))?;
        Ok(self.for_rotation(a.left_deg, a.right_deg))
    }

    /// The commands that turn the wheels by these signed amounts.
    pub fn for_rotation(&self, left_deg: i32, right_deg: i32) -> MotorCommands {
        let m = &self.cfg.motors;
        let mut mode = Mode::MOTOR_ON;
        if m.brake {
            mode = mode | Mode::BRAKE;
        }
        let regulation = if m.regulated {
            mode = mode | Mode::REGULATED;
            m.regulation
        } else {
            RegulationMode::Idle
        };
        let one = |port: Port, deg: i32, reversed: bool| {
            let deg = deg.clamp(-MAX_ACTION_DEG, MAX_ACTION_DEG);
            (deg != 0).then(|| {
                let forward = (deg > 0) != reversed;
                SetOutputState {
                    port: PortSelector::One(port),
                    power: if forward { m.power } else { -m.power },
                    mode,
                    regulation,
                    turn_ratio: 0,
                    run_state: RunState::Running,
                    tacho_limit: deg.unsigned_abs(),
                }
            })
        };
        MotorCommands {
            commands: [
                one(m.left_port, left_deg, m.left_reversed),
                one(m.right_port, right_deg, m.right_reversed),
            ],
            acknowledge: m.acknowledge,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_actions_map_to_tacho_limited_commands() {
        let map = ActionMap::paper_default();
        let fwd = map.for_action(0).expect("known");
        let [Some(l), Some(r)] = fwd.commands else {
            panic!("both wheels")
        };
        assert_eq!(
            (l.power, l.tacho_limit, r.power, r.tacho_limit),
            (75, 246, 75, 246)
        );
        assert_eq!(l.mode, Mode::MOTOR_ON | Mode::BRAKE | Mode::REGULATED);
        assert_eq!(
            (l.regulation, l.run_state),
            (RegulationMode::Speed, RunState::Running)
        );
        let right = map.for_action(2).expect("known");
        assert!(right.commands[0].is_some() && right.commands[1].is_none());
        assert_eq!(right.iter().count(), 1);
        assert_eq!(map.for_action(3), Err(UnknownAction(3)));
    }

    #[test]
    fn config_drives_the_mapping() {
        let cfg: ActionConfig = toml::from_str(
            r#"
            [motors]
            left_port = "A"
            right_port = "C"
            power = 60
            brake = false
            regulated = false
            right_reversed = true

            [[actions]]
            id = 7
            left_deg = -30
            right_deg = 30
            "#,
        )
        .expect("parses");
        let map = ActionMap::new(cfg).expect("valid");
        let [Some(l), Some(r)] = map.for_action(7).expect("known").commands else {
            panic!()
        };
        assert_eq!(
            (l.port, l.power, l.tacho_limit),
            (PortSelector::One(Port::A), -60, 30)
        );
        assert_eq!((r.port, r.power), (PortSelector::One(Port::C), -60));
        assert_eq!(
            (l.mode, l.regulation),
            (Mode::MOTOR_ON, RegulationMode::Idle)
        );
        assert!(map.for_action(0).is_err());
    }

    #[test]
    fn invalid_tables_name_the_key() {
        let bad = |s: &str| {
            let cfg: ActionConfig = toml::from_str(s).expect("parses");
            ActionMap::new(cfg).expect_err("invalid").key
        };
        assert_eq!(bad("[motors]\npower = 0"), "motors.power");
        assert_eq!(bad("[motors]\nleft_port = \"C\""), "motors.right_port");
        assert_eq!(
            bad(
                "[[actions]]\nid = 1\nleft_deg = 1\nright_deg = 1\n[[actions]]\nid = 1\nleft_deg = 2\nright_deg = 2"
            ),
            "actions[1].id"
        );
        assert_eq!(
            bad("[[actions]]\nid = 1\nleft_deg = 99999\nright_deg = 1"),
            "actions[0].left_deg"
        );
        assert_eq!(bad("actions = []"), "actions");
    }
}
