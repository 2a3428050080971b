//! Reply telegrams: `02 <opcode> <status> <body…>`.

use super::wire::{Reader, Writer, check_len};
use super::{
    DecodeError, MAX_TELEGRAM_LEN, Mode, Opcode, Port, RegulationMode, RunState, Status, Telegram,
    telegram_type,
};

/// The body of a GETOUTPUTSTATE reply (22 bytes after the status).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct OutputState {
    /// Echo of the port.
    pub port: Port,
    /// Power set-point as last set.
    pub power: i8,
    /// Mode bits as last set.
    pub mode: Mode,
    /// Regulation mode as last set.
    pub regulation: RegulationMode,
    /// Turn ratio as last set.
    pub turn_ratio: i8,
    /// Current run state.
    pub run_state: RunState,
    /// Tacho limit as last set.
    pub tacho_limit: u32,
    /// Degrees turned since the last reset of the count.
    pub tacho_count: i32,
    /// Degrees turned since the last block reset (RESETMOTORPOSITION relative).
    pub block_tacho_count: i32,
    /// Degrees turned since the last program reset (RESETMOTORPOSITION absolute).
    pub rotation_count: i32,
}

/// A `major.minor` version pair, as GETFIRMWAREVERSION reports it (minor byte first on the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Version {
    /// Major version.
    pub major: u8,
    /// Minor version.
    pub minor: u8,
}

/// The body of a GETDEVICEINFO reply (30 bytes after the status).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct DeviceInfo {
    /// Brick name, NUL-padded ASCII.
    pub name: [u8; 15],
    /// Bluetooth address; the 7th byte is unused (0).
    pub address: [u8; 7],
    /// Link quality of the four possible Bluetooth connections.
    pub signal_strength: [u8; 4],
    /// Free user flash, bytes.
    pub free_flash: u32,
}

impl DeviceInfo {
    /// The name up to its first NUL, if it is UTF-8.
    pub fn name_str(&self) -> &str {
        let end = self
            .name
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(self.name.len());
        core::str::from_utf8(&self.name[..end]).unwrap_or("")
    }

    /// Builds the NUL-padded name field from `name` (truncated to 14 bytes).
    pub fn name_field(name: &str) -> [u8; 15] {
        let mut out = [0u8; 15];
        for (dst, src) in out.iter_mut().take(14).zip(name.bytes()) {
            *dst = src;
        }
        out
    }
}

/// A reply telegram.
///
/// Replies that carry a body have their own variant; a reply that is only a status (the
/// acknowledgements of SETOUTPUTSTATE, RESETMOTORPOSITION, PLAYTONE, and the short error
/// replies the firmware sends for an unknown opcode) is [`Reply::Status`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Reply {
    /// `02 <opcode> <status>`: the opcode is kept raw, since a brick answers unknown opcodes too.
    Status {
        /// The opcode byte being answered.
        opcode: u8,
        /// The status.
        status: Status,
    },
    /// `02 06 <status> <OutputState>`.
    OutputState {
        /// The status (0xC0 and an all-zero body for a bad port).
        status: Status,
        /// The motor state.
        state: OutputState,
    },
    /// `02 0B <status> <millivolts u16>`.
    BatteryLevel {
        /// The status.
        status: Status,
        /// Battery voltage, mV.
        millivolts: u16,
    },
    /// `02 0D <status> <sleep timeout u32 ms>`.
    KeepAlive {
        /// The status.
        status: Status,
        /// The brick's sleep timeout, ms.
        sleep_timeout_ms: u32,
    },
    /// `02 88 <status> <protocol minor> <protocol major> <firmware minor> <firmware major>`.
    FirmwareVersion {
        /// The status.
        status: Status,
        /// Protocol version.
        protocol: Version,
        /// Firmware version.
        firmware: Version,
    },
    /// `02 9B <status> <DeviceInfo>`.
    DeviceInfo {
        /// The status.
        status: Status,
        /// The information.
        info: DeviceInfo,
    },
}

impl Reply {
    /// The opcode byte being answered.
    pub fn opcode(&self) -> u8 {
        match self {
            Reply::Status { opcode, .. } => *opcode,
            Reply::OutputState { .. } => Opcode::GetOutputState as u8,
            Reply::BatteryLevel { .. } => Opcode::GetBatteryLevel as u8,
            Reply::KeepAlive { .. } => Opcode::KeepAlive as u8,
            Reply::FirmwareVersion { .. } => Opcode::GetFirmwareVersion as u8,
            Reply::DeviceInfo { .. } => Opcode::GetDeviceInfo as u8,
        }
    }

    /// The status.
    pub fn status(&self) -> Status {
        match *self {
            Reply::Status { status, .. }
            | Reply::OutputState { status, .. }
            | Reply::BatteryLevel { status, .. }
            | Reply::KeepAlive { status, .. }
            | Reply::FirmwareVersion { status, .. }
            | Reply::DeviceInfo { status, .. } => status,
        }
    }

    /// Encodes the reply. A [`Reply::Status`] for an opcode whose successful reply has a body
    /// encodes (as the firmware's short error replies do) but decodes only if the status is
    /// an error.
    pub fn encode(&self) -> Telegram {
        let mut t = Telegram::EMPTY;
        t.push(telegram_type::REPLY);
        t.push(self.opcode());
        t.push(self.status() as u8);
        match *self {
            Reply::Status { .. } => {}
            Reply::OutputState { state: s, .. } => {
                t.push(s.port as u8);
                t.push(s.power as u8);
                t.push(s.mode.bits());
                t.push(s.regulation as u8);
                t.push(s.turn_ratio as u8);
                t.push(s.run_state as u8);
                t.u32(s.tacho_limit);
                t.i32(s.tacho_count);
                t.i32(s.block_tacho_count);
                t.i32(s.rotation_count);
            }
            Reply::BatteryLevel { millivolts, .. } => t.u16(millivolts),
            Reply::KeepAlive {
                sleep_timeout_ms, ..
            } => t.u32(sleep_timeout_ms),
            Reply::FirmwareVersion {
                protocol, firmware, ..
            } => {
                t.push_slice(&[
                    protocol.minor,
                    protocol.major,
                    firmware.minor,
                    firmware.major,
                ]);
            }
            Reply::DeviceInfo { info, .. } => {
                t.push_slice(&info.name);
                t.push_slice(&info.address);
                t.push_slice(&info.signal_strength);
                t.u32(info.free_flash);
            }
        }
        t
    }

    /// Decodes a reply telegram.
    ///
    /// Accepts exactly: the full reply for an implemented opcode (any defined status), or a
    /// 3-byte status-only reply — for any opcode whose successful reply has no body, and for
    /// any opcode at all when the status is an error.
    pub fn decode(bytes: &[u8]) -> Result<Reply, DecodeError> {
        let len = bytes.len();
        if len > MAX_TELEGRAM_LEN {
            return Err(DecodeError::TooLong { len });
        }
        let (&ty, &op_byte, &status_byte) = match bytes {
            [ty, op, st, ..] => (ty, op, st),
            _ => return Err(DecodeError::TooShort { len }),
        };
        if ty != telegram_type::REPLY {
            return Err(DecodeError::BadType(ty));
        }
        let status = Status::from_u8(status_byte).ok_or(DecodeError::UnknownStatus(status_byte))?;
        let Some(op) = Opcode::from_u8(op_byte) else {
            // A brick answers opcodes it does not know with a bare error status.
            if len == 3 && !status.is_success() {
                return Ok(Reply::Status {
                    opcode: op_byte,
                    status,
                });
            }
            return Err(DecodeError::UnknownOpcode {
                telegram_type: ty,
                opcode: op_byte,
            });
        };
        if len == 3 && (!status.is_success() || op.reply_len() == 3) {
            return Ok(Reply::Status {
                opcode: op_byte,
                status,
            });
        }
        check_len(bytes, op, op.reply_len())?;
        let mut r = Reader::new(bytes, 3);
        Ok(match op {
            Opcode::PlayTone | Opcode::SetOutputState | Opcode::ResetMotorPosition => {
                // Their full reply is 3 bytes, handled above.
                Reply::Status {
                    opcode: op_byte,
                    status,
                }
            }
            Opcode::GetOutputState => Reply::OutputState {
                status,
                state: OutputState {
                    port: r.port()?,
                    power: r.i8(),
                    mode: r.mode()?,
                    regulation: r.regulation()?,
                    turn_ratio: r.i8(),
                    run_state: r.run_state()?,
                    tacho_limit: r.u32(),
                    tacho_count: r.i32(),
                    block_tacho_count: r.i32(),
                    rotation_count: r.i32(),
                },
            },
            Opcode::GetBatteryLevel => Reply::BatteryLevel {
                status,
                millivolts: r.u16(),
            },
            Opcode::KeepAlive => Reply::KeepAlive {
                status,
                sleep_timeout_ms: r.u32(),
            },
            Opcode::GetFirmwareVersion => {
                let [pmin, pmaj, fmin, fmaj] = r.array();
                Reply::FirmwareVersion {
                    status,
                    protocol: Version {
                        major: pmaj,
                        minor: pmin,
                    },
                    firmware: Version {
                        major: fmaj,
                        minor: fmin,
                    },
                }
            }
            Opcode::GetDeviceInfo => Reply::DeviceInfo {
                status,
                info: DeviceInfo {
                    name: r.array(),
                    address: r.array(),
                    signal_strength: r.array(),
                    free_flash: r.u32(),
                },
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_state_layout() {
        let reply = Reply::OutputState {
            status: Status::Success,
            state: OutputState {
                port: Port::B,
                power: -75,
                mode: Mode::MOTOR_ON | Mode::BRAKE | Mode::REGULATED,
                regulation: RegulationMode::Speed,
                turn_ratio: 0,
                run_state: RunState::Running,
                tacho_limit: 246,
                tacho_count: -10,
                block_tacho_count: 5,
                rotation_count: 0x0102_0304,
            },
        };
        let t = reply.encode();
        assert_eq!(
            t.as_bytes(),
            &[
                0x02, 0x06, 0x00, 0x01, 0xB5, 0x07, 0x01, 0x00, 0x20, 246, 0, 0, 0, 0xF6, 0xFF,
                0xFF, 0xFF, 5, 0, 0, 0, 0x04, 0x03, 0x02, 0x01
            ]
        );
        assert_eq!(Reply::decode(t.as_bytes()), Ok(reply));
    }

    #[test]
    fn firmware_and_device_info_layout() {
        let fw = Reply::FirmwareVersion {
            status: Status::Success,
            protocol: Version {
                major: 1,
                minor: 124,
            },
            firmware: Version {
                major: 1,
                minor: 28,
            },
        };
        assert_eq!(fw.encode().as_bytes(), &[0x02, 0x88, 0x00, 124, 1, 28, 1]);
        let info = Reply::DeviceInfo {
            status: Status::Success,
            info: DeviceInfo {
                name: DeviceInfo::name_field("NXT"),
                address: [0x00, 0x16, 0x53, 0x01, 0x02, 0x03, 0x00],
                signal_strength: [0; 4],
                free_flash: 0x0001_0000,
            },
        };
        let t = info.encode();
        assert_eq!(t.len(), 33);
        assert_eq!(&t.as_bytes()[..6], &[0x02, 0x9B, 0x00, b'N', b'X', b'T']);
        assert_eq!(&t.as_bytes()[18..21], &[0x00, 0x16, 0x53]);
        match Reply::decode(t.as_bytes()) {
            Ok(Reply::DeviceInfo { info, .. }) => assert_eq!(info.name_str(), "NXT"),
            other => panic!("unexpected {other:?}"),
        }
    }

    #[test]
    fn short_replies() {
        assert_eq!(
            Reply::decode(&[0x02, 0x7F, 0xBE]),
            Ok(Reply::Status {
                opcode: 0x7F,
                status: Status::UnknownCommand
            })
        );
        assert_eq!(
            Reply::decode(&[0x02, 0x04, 0x00]),
            Ok(Reply::Status {
                opcode: 0x04,
                status: Status::Success
            })
        );
        // A successful GETBATTERYLEVEL reply must carry the voltage.
        assert!(matches!(
            Reply::decode(&[0x02, 0x0B, 0x00]),
            Err(DecodeError::Truncated { .. })
        ));
        assert_eq!(
            Reply::decode(&[0x02, 0x0B, 0x01]),
            Err(DecodeError::UnknownStatus(1))
        );
        assert_eq!(
            Reply::decode(&[0x00, 0x0B, 0x00]),
            Err(DecodeError::BadType(0))
        );
        assert!(matches!(
            Reply::decode(&[0x02, 0x7F, 0x00]),
            Err(DecodeError::UnknownOpcode { .. })
        ));
        assert_eq!(
            Reply::decode(&[0x02, 0x0B, 0x00, 0x40, 0x1F]),
            Ok(Reply::BatteryLevel {
                status: Status::Success,
                millivolts: 8000
            })
        );
    }
}
