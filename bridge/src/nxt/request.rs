//! Request telegrams: the direct and system commands a client sends the brick.

use super::wire::{Reader, Writer, check_len};
use super::{
    DecodeError, MAX_TELEGRAM_LEN, Mode, Opcode, Port, PortSelector, RegulationMode, RunState,
    Telegram, telegram_type,
};

/// The arguments of SETOUTPUTSTATE (0x04).
///
/// Wire layout after `<type> 04`: port (u8, 0xFF = all), power (i8, −100..100), mode (u8),
/// regulation mode (u8), turn ratio (i8), run state (u8), tacho limit (u32 LE, 0 = run forever).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SetOutputState {
    /// Which port(s).
    pub port: PortSelector,
    /// Power or speed set-point, −100..=100 (the firmware clamps larger magnitudes).
    pub power: i8,
    /// Mode bits.
    pub mode: Mode,
    /// Regulation mode.
    pub regulation: RegulationMode,
    /// Turn ratio for synchronised motors, −100..=100.
    pub turn_ratio: i8,
    /// Requested run state.
    pub run_state: RunState,
    /// Degrees to turn, relative to the previous target; 0 runs forever.
    pub tacho_limit: u32,
}

impl SetOutputState {
    /// Brake and hold every port: power 0, MOTORON|BRAKE|REGULATED, speed regulation,
    /// run state RUNNING, no limit — what nxt-python's `Motor.brake()` sends.
    pub const BRAKE_ALL: SetOutputState = SetOutputState {
        port: PortSelector::All,
        power: 0,
        mode: Mode(0x07),
        regulation: RegulationMode::Speed,
        turn_ratio: 0,
        run_state: RunState::Running,
        tacho_limit: 0,
    };

    /// Float every port: power 0, mode IDLE, run state IDLE.
    pub const COAST_ALL: SetOutputState = SetOutputState {
        port: PortSelector::All,
        power: 0,
        mode: Mode::IDLE,
        regulation: RegulationMode::Idle,
        turn_ratio: 0,
        run_state: RunState::Idle,
        tacho_limit: 0,
    };
}

/// A command telegram this codec implements.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Request {
    /// PLAYTONE (0x03): frequency (u16 Hz, 200..14000), duration (u16 ms).
    PlayTone {
        /// Tone frequency in Hz.
        frequency_hz: u16,
        /// Duration in ms.
        duration_ms: u16,
    },
    /// SETOUTPUTSTATE (0x04).
    SetOutputState(SetOutputState),
    /// GETOUTPUTSTATE (0x06): port (u8).
    GetOutputState {
        /// The port to read.
        port: Port,
    },
    /// RESETMOTORPOSITION (0x0A): port (u8), relative (bool: 1 = block count, 0 = rotation count).
    ResetMotorPosition {
        /// The port.
        port: Port,
        /// `true` resets the block tacho count, `false` the rotation count.
        relative: bool,
    },
    /// GETBATTERYLEVEL (0x0B): no arguments.
    GetBatteryLevel,
    /// KEEPALIVE (0x0D): no arguments.
    KeepAlive,
    /// GETFIRMWAREVERSION (system 0x88): no arguments.
    GetFirmwareVersion,
    /// GETDEVICEINFO (system 0x9B): no arguments.
    GetDeviceInfo,
}

impl Request {
    /// The request's opcode.
    pub fn opcode(&self) -> Opcode {
        match self {
            Request::PlayTone { .. } => Opcode::PlayTone,
            Request::SetOutputState(_) => Opcode::SetOutputState,
            Request::GetOutputState { .. } => Opcode::GetOutputState,
            Request::ResetMotorPosition { .. } => Opcode::ResetMotorPosition,
            Request::GetBatteryLevel => Opcode::GetBatteryLevel,
            Request::KeepAlive => Opcode::KeepAlive,
            Request::GetFirmwareVersion => Opcode::GetFirmwareVersion,
            Request::GetDeviceInfo => Opcode::GetDeviceInfo,
        }
    }

    /// Encodes the request; `reply_required` chooses type 0x00/0x01 over 0x80/0x81.
    pub fn encode(&self, reply_required: bool) -> Telegram {
        let op = self.opcode();
        let base = if op.is_system() {
            telegram_type::SYSTEM
        } else {
            telegram_type::DIRECT
        };
        let ty = if reply_required {
            base
        } else {
            base | telegram_type::NO_REPLY
        };
        let mut t = Telegram::EMPTY;
        t.push(ty);
        t.push(op as u8);
        match *self {
            Request::PlayTone {
                frequency_hz,
                duration_ms,
            } => {
                t.u16(frequency_hz);
                t.u16(duration_ms);
            }
            Request::SetOutputState(s) => {
                t.push(s.port.to_u8());
                t.push(s.power as u8);
                t.push(s.mode.bits());
                t.push(s.regulation as u8);
                t.push(s.turn_ratio as u8);
                t.push(s.run_state as u8);
                t.u32(s.tacho_limit);
            }
            Request::GetOutputState { port } => t.push(port as u8),
            Request::ResetMotorPosition { port, relative } => {
                t.push(port as u8);
                t.push(u8::from(relative));
            }
            Request::GetBatteryLevel
            | Request::KeepAlive
            | Request::GetFirmwareVersion
            | Request::GetDeviceInfo => {}
        }
        debug_assert_eq!(t.len(), op.request_len());
        t
    }

    /// Decodes a request telegram into the request and whether a reply is required.
    ///
    /// Strict: the type byte must be 0x00/0x80 for a direct opcode or 0x01/0x81 for a system
    /// one, the length must be exactly the opcode's, and every enumerated field must hold a
    /// defined value.
    pub fn decode(bytes: &[u8]) -> Result<(Request, bool), DecodeError> {
        let len = bytes.len();
        if len > MAX_TELEGRAM_LEN {
            return Err(DecodeError::TooLong { len });
        }
        let (&ty, &op_byte) = match bytes {
            [ty, op, ..] => (ty, op),
            _ => return Err(DecodeError::TooShort { len }),
        };
        let reply_required = ty & telegram_type::NO_REPLY == 0;
        let system = match ty & !telegram_type::NO_REPLY {
            telegram_type::DIRECT => false,
            telegram_type::SYSTEM => true,
            _ => return Err(DecodeError::BadType(ty)),
        };
        let op = Opcode::from_u8(op_byte)
            .filter(|op| op.is_system() == system)
            .ok_or(DecodeError::UnknownOpcode {
                telegram_type: ty,
                opcode: op_byte,
            })?;
        check_len(bytes, op, op.request_len())?;
        let mut r = Reader::new(bytes, 2);
        let req = match op {
            Opcode::PlayTone => Request::PlayTone {
                frequency_hz: r.u16(),
                duration_ms: r.u16(),
            },
            Opcode::SetOutputState => {
                let port_byte = r.u8();
                let port =
                    PortSelector::from_u8(port_byte).ok_or(DecodeError::BadPort(port_byte))?;
                Request::SetOutputState(SetOutputState {
                    port,
                    power: r.i8(),
                    mode: r.mode()?,
                    regulation: r.regulation()?,
                    turn_ratio: r.i8(),
                    run_state: r.run_state()?,
                    tacho_limit: r.u32(),
                })
            }
            Opcode::GetOutputState => Request::GetOutputState { port: r.port()? },
            Opcode::ResetMotorPosition => Request::ResetMotorPosition {
                port: r.port()?,
                relative: r.bool()?,
            },
            Opcode::GetBatteryLevel => Request::GetBatteryLevel,
            Opcode::KeepAlive => Request::KeepAlive,
            Opcode::GetFirmwareVersion => Request::GetFirmwareVersion,
            Opcode::GetDeviceInfo => Request::GetDeviceInfo,
        };
        Ok((req, reply_required))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_layouts() {
        let t = Request::GetOutputState { port: Port::C }.encode(true);
        assert_eq!(t.as_bytes(), &[0x00, 0x06, 0x02]);
        let t = Request::ResetMotorPosition {
            port: Port::A,
            relative: true,
        }
        .encode(false);
        assert_eq!(t.as_bytes(), &[0x80, 0x0A, 0x00, 0x01]);
        let t = Request::PlayTone {
            frequency_hz: 440,
            duration_ms: 500,
        }
        .encode(false);
        assert_eq!(t.as_bytes(), &[0x80, 0x03, 0xB8, 0x01, 0xF4, 0x01]);
        assert_eq!(
            Request::GetBatteryLevel.encode(true).as_bytes(),
            &[0x00, 0x0B]
        );
        assert_eq!(Request::KeepAlive.encode(true).as_bytes(), &[0x00, 0x0D]);
        assert_eq!(
            Request::GetFirmwareVersion.encode(true).as_bytes(),
            &[0x01, 0x88]
        );
        assert_eq!(
            Request::GetDeviceInfo.encode(false).as_bytes(),
            &[0x81, 0x9B]
        );
        let t = Request::SetOutputState(SetOutputState::BRAKE_ALL).encode(true);
        assert_eq!(
            t.as_bytes(),
            &[0x00, 0x04, 0xFF, 0, 0x07, 0x01, 0, 0x20, 0, 0, 0, 0]
        );
        let neg = SetOutputState {
            power: -75,
            tacho_limit: 0x0102_0304,
            ..SetOutputState::BRAKE_ALL
        };
        let t = Request::SetOutputState(neg).encode(true);
        assert_eq!(&t.as_bytes()[3..4], &[0xB5]);
        assert_eq!(&t.as_bytes()[8..], &[0x04, 0x03, 0x02, 0x01]);
    }

    #[test]
    fn rejects_malformed() {
        use DecodeError as E;
        assert_eq!(Request::decode(&[0x00]), Err(E::TooShort { len: 1 }));
        assert_eq!(Request::decode(&[0x02, 0x06, 0x00]), Err(E::BadType(0x02)));
        assert_eq!(
            Request::decode(&[0x00, 0x7F]),
            Err(E::UnknownOpcode {
                telegram_type: 0,
                opcode: 0x7F
            })
        );
        // A system opcode in a direct telegram is unknown there.
        assert!(matches!(
            Request::decode(&[0x00, 0x88]),
            Err(E::UnknownOpcode { .. })
        ));
        assert!(matches!(
            Request::decode(&[0x00, 0x06]),
            Err(E::Truncated { .. })
        ));
        assert!(matches!(
            Request::decode(&[0x00, 0x06, 0, 0]),
            Err(E::TrailingBytes { .. })
        ));
        assert_eq!(Request::decode(&[0x00, 0x06, 0x03]), Err(E::BadPort(3)));
        assert_eq!(
            Request::decode(&[0x00, 0x0A, 0x01, 0x02]),
            Err(E::BadBool(2))
        );
        let mut sos = [0x00, 0x04, 0x01, 75, 0x07, 0x01, 0, 0x20, 0, 0, 0, 0];
        sos[4] = 0x08;
        assert_eq!(Request::decode(&sos), Err(E::BadMode(0x08)));
        sos[4] = 0x07;
        sos[5] = 0x03;
        assert_eq!(Request::decode(&sos), Err(E::BadRegulation(0x03)));
        sos[5] = 0x01;
        sos[7] = 0x30;
        assert_eq!(Request::decode(&sos), Err(E::BadRunState(0x30)));
        sos[7] = 0x20;
        sos[2] = 0xFE;
        assert_eq!(Request::decode(&sos), Err(E::BadPort(0xFE)));
    }
}
