//! A simulated NXT brick that consumes telegrams and answers like firmware 1.28.
//!
//! The brick has no clock of its own: [`SimBrick::advance_to`] steps its three motors to the
//! time you pass in (1 ms steps, as the firmware's output loop), so a test drives it
//! deterministically and the transports drive it in real time. Every random draw (speed
//! noise per command, battery reading noise) comes from one `ChaCha8Rng` seeded at
//! construction: the same seed, telegrams and times give the same replies.
//!
//! ```
//! use std::time::Duration;
//! use tes_bridge::brick::{SimBrick, SimBrickConfig};
//! use tes_bridge::nxt::{Mode, Port, PortSelector, RegulationMode, Reply, Request, RunState, SetOutputState};
//!
//! let mut brick = SimBrick::new(SimBrickConfig::default(), 42)?;
//! let run = Request::SetOutputState(SetOutputState {
//!     port: PortSelector::One(Port::B),
//!     power: 75,
//!     mode: Mode::MOTOR_ON | Mode::BRAKE | Mode::REGULATED,
//!     regulation: RegulationMode::Speed,
//!     turn_ratio: 0,
//!     run_state: RunState::Running,
//!     tacho_limit: 246,
//! });
//! assert!(brick.handle(run.encode(false).as_bytes()).is_none()); // no reply requested
//! brick.advance(Duration::from_secs(1));
//! let reply = brick.handle(Request::GetOutputState { port: Port::B }.encode(true).as_bytes());
//! let Some(Ok(Reply::OutputState { state, .. })) = reply.map(|t| Reply::decode(t.as_bytes())) else {
//!     panic!("expected an output state");
//! };
//! assert_eq!(state.run_state, RunState::Idle);
//! assert!((246..260).contains(&state.tacho_count));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod motor;

use std::time::Duration;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use motor::Motor;
pub use motor::MotorView;

use crate::nxt::{
    DecodeError, DeviceInfo, Opcode, OutputState, Port, Reply, Request, Status, Telegram, Version,
    telegram_type,
};

/// The largest `speed_noise`: a relative standard deviation of the steady speed.
pub const MAX_SPEED_NOISE: f64 = 0.5;

/// The longest brick `name`, in ASCII characters (the name field of GETDEVICEINFO).
pub const BRICK_NAME_MAX: usize = 14;

/// Physics and identity of the simulated brick (the `[brick]` table of the bridge config;
/// serial transports ignore it). Each field's doc is its key's entry in the launch file's
/// reference (`tes launch --print-config`), as for
/// [`BridgeSettings`](crate::config::BridgeSettings).
///
/// The bridge process drives the brick by a [`ScaledClock`](crate::clock::ScaledClock) of
/// `time_scale` and converts its waits back to wall time.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimBrickConfig {
    /// Steady speed per unit of power (an unloaded NXT motor: about 9 to 10).
    ///
    /// Values: °/s per unit of power, above 0.
    pub speed_per_power: f64,
    /// Steady speed of an unregulated motor relative to a regulated one (load, battery sag).
    ///
    /// Values: factor, above 0.
    pub unregulated_speed_factor: f64,
    /// Time constant of the speed's response to power.
    ///
    /// Values: s, above 0.
    pub time_constant_s: f64,
    /// Time constant of a coasting (floating) motor's slow-down.
    ///
    /// Values: s, above 0.
    pub coast_time_constant_s: f64,
    /// Time constant of a braking motor's slow-down.
    ///
    /// Values: s, above 0.
    pub brake_time_constant_s: f64,
    /// Below this speed an undriven motor is at rest.
    ///
    /// Values: °/s, above 0.
    pub stop_speed_dps: f64,
    /// Relative standard deviation of a command's steady speed (0 = noiseless).
    ///
    /// Values: 0 to [`MAX_SPEED_NOISE`].
    pub speed_noise: f64,
    /// Fresh battery voltage.
    ///
    /// Values: mV.
    pub battery_mv: u16,
    /// Half-width of the uniform noise on a battery reading (0 = noiseless).
    ///
    /// Values: mV.
    pub battery_noise_mv: u16,
    /// Battery drain per powered motor per second.
    ///
    /// Values: mV/s, at least 0.
    pub battery_drain_mv_per_s: f64,
    /// The sleep timeout KEEPALIVE reports.
    ///
    /// Values: minutes.
    pub sleep_timeout_min: u32,
    /// The brick name GETDEVICEINFO reports.
    ///
    /// Values: at most [`BRICK_NAME_MAX`] ASCII characters.
    pub name: String,
    /// The Bluetooth address GETDEVICEINFO reports.
    ///
    /// Values: 6 bytes.
    pub address: [u8; 6],
    /// The free user flash GETDEVICEINFO reports.
    ///
    /// Values: bytes.
    pub free_flash: u32,
    /// How many times faster than the wall clock the simulated physics runs (1 = physical
    /// time). The watchdog deadline and the poll periods are in brick time, so they scale
    /// with it.
    ///
    /// Values: factor, [`TIME_SCALE_RANGE`](crate::config::TIME_SCALE_RANGE).
    pub time_scale: f64,
}

impl Default for SimBrickConfig {
    fn default() -> Self {
        Self {
            speed_per_power: 9.5,
            unregulated_speed_factor: 0.9,
            time_constant_s: 0.03,
            coast_time_constant_s: 0.04,
            brake_time_constant_s: 0.006,
            stop_speed_dps: 5.0,
            speed_noise: 0.02,
            battery_mv: 8200,
            battery_noise_mv: 15,
            battery_drain_mv_per_s: 0.2,
            sleep_timeout_min: 10,
            name: "NXT".to_owned(),
            address: [0x00, 0x16, 0x53, 0x0E, 0x5B, 0x01],
            free_flash: 98_304,
            time_scale: 1.0,
        }
    }
}

/// A [`SimBrickConfig`] value that cannot be simulated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("brick.{key}: {reason}")]
pub struct BrickConfigError {
    /// The offending key, relative to the `[brick]` table.
    pub key: &'static str,
    /// What is wrong with it.
    pub reason: String,
}

impl SimBrickConfig {
    /// Checks every value once; the simulation then never meets a NaN or a zero divisor.
    pub fn check(&self) -> Result<(), BrickConfigError> {
        let positive = [
            ("speed_per_power", self.speed_per_power),
            ("unregulated_speed_factor", self.unregulated_speed_factor),
            ("time_constant_s", self.time_constant_s),
            ("coast_time_constant_s", self.coast_time_constant_s),
            ("brake_time_constant_s", self.brake_time_constant_s),
            ("stop_speed_dps", self.stop_speed_dps),
            ("time_scale", self.time_scale),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(BrickConfigError {
                    key,
                    reason: format!("must be finite and > 0, got {v}"),
                });
            }
        }
        let non_negative = [
            ("speed_noise", self.speed_noise),
            ("battery_drain_mv_per_s", self.battery_drain_mv_per_s),
        ];
        for (key, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(BrickConfigError {
                    key,
                    reason: format!("must be finite and >= 0, got {v}"),
                });
            }
        }
        if self.speed_noise > MAX_SPEED_NOISE {
            return Err(BrickConfigError {
                key: "speed_noise",
                reason: format!(
                    "must be at most {MAX_SPEED_NOISE}, got {}",
                    self.speed_noise
                ),
            });
        }
        if self.name.len() > BRICK_NAME_MAX || !self.name.is_ascii() {
            return Err(BrickConfigError {
                key: "name",
                reason: format!(
                    "must be at most {BRICK_NAME_MAX} ASCII characters, got {:?}",
                    self.name
                ),
            });
        }
        Ok(())
    }
}

/// Counters of what the brick has seen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BrickStats {
    /// Telegrams handled.
    pub telegrams: u64,
    /// Telegrams answered with an error status or ignored as undecodable.
    pub errors: u64,
    /// PLAYTONE commands accepted.
    pub tones: u64,
    /// KEEPALIVE commands accepted.
    pub keep_alives: u64,
}

impl std::fmt::Display for BrickStats {
    /// In words, for the log.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} telegrams handled, {} errors, {} tones, {} keep-alives",
            self.telegrams, self.errors, self.tones, self.keep_alives
        )
    }
}

const TICK_NS: u64 = 1_000_000;

/// The simulated brick.
#[derive(Debug, Clone)]
pub struct SimBrick {
    cfg: SimBrickConfig,
    motors: [Motor; 3],
    rng: ChaCha8Rng,
    seed: u64,
    now_ns: u64,
    drained_mv: f64,
    stats: BrickStats,
}

impl SimBrick {
    /// A brick at rest at time 0, with all counts 0.
    pub fn new(cfg: SimBrickConfig, seed: u64) -> Result<Self, BrickConfigError> {
        cfg.check()?;
        Ok(Self {
            cfg,
            motors: [
                Motor::new(Port::A),
                Motor::new(Port::B),
                Motor::new(Port::C),
            ],
            rng: ChaCha8Rng::seed_from_u64(seed),
            seed,
            now_ns: 0,
            drained_mv: 0.0,
            stats: BrickStats::default(),
        })
    }

    /// The seed the brick was built with.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The configuration.
    pub fn config(&self) -> &SimBrickConfig {
        &self.cfg
    }

    /// The brick's simulated time.
    pub fn now(&self) -> Duration {
        Duration::from_nanos(self.now_ns)
    }

    /// Counters.
    pub fn stats(&self) -> BrickStats {
        self.stats
    }

    /// A motor's physics.
    pub fn motor(&self, port: Port) -> MotorView {
        self.motors[port.index()].view()
    }

    /// What GETOUTPUTSTATE would report for `port` now.
    pub fn output_state(&self, port: Port) -> OutputState {
        self.motors[port.index()].output_state()
    }

    /// Whether any motor is driven or still turning.
    pub fn is_active(&self) -> bool {
        self.motors.iter().any(Motor::is_active)
    }

    /// Advances the simulation by `dt`.
    pub fn advance(&mut self, dt: Duration) {
        let t = self.now().saturating_add(dt);
        self.advance_to(t);
    }

    /// Advances the simulation to time `t` (no-op if `t` is in the past).
    pub fn advance_to(&mut self, t: Duration) {
        let target_ns = u64::try_from(t.as_nanos()).unwrap_or(u64::MAX);
        let dt = TICK_NS as f64 * 1e-9;
        while self.now_ns.saturating_add(TICK_NS) <= target_ns {
            if !self.is_active() {
                // Nothing moves: jump, keeping the 1 ms grid.
                self.now_ns += (target_ns - self.now_ns) / TICK_NS * TICK_NS;
                break;
            }
            let powered = self.motors.iter().filter(|m| m.is_active()).count();
            self.drained_mv += self.cfg.battery_drain_mv_per_s * dt * powered as f64;
            for m in &mut self.motors {
                m.step(dt, &self.cfg);
            }
            self.now_ns += TICK_NS;
        }
    }

    /// Handles one telegram like the firmware does and returns the reply, if one is due.
    ///
    /// Reply telegrams and telegrams with an unknown type byte are ignored (no reply), as the
    /// firmware does. A request that fails to decode is answered, when a reply is required,
    /// with the status [`DecodeError::reply_status`] gives (GETOUTPUTSTATE for a bad port
    /// also carries the firmware's 22 zero bytes). Never panics, whatever the bytes.
    pub fn handle(&mut self, telegram: &[u8]) -> Option<Telegram> {
        self.stats.telegrams += 1;
        let (ty, opcode) = match telegram {
            [ty, op, ..] => (*ty, *op),
            _ => {
                self.stats.errors += 1;
                return None;
            }
        };
        let base = ty & !telegram_type::NO_REPLY;
        if base != telegram_type::DIRECT && base != telegram_type::SYSTEM {
            if ty != telegram_type::REPLY {
                self.stats.errors += 1;
            }
            return None;
        }
        let reply_required = ty & telegram_type::NO_REPLY == 0;
        let reply = match Request::decode(telegram) {
            Ok((req, _)) => self.execute(&req),
            Err(e) => {
                self.stats.errors += 1;
                error_reply(opcode, e)
            }
        };
        reply_required.then(|| reply.encode())
    }

    /// Executes a decoded request and returns its reply.
    pub fn execute(&mut self, req: &Request) -> Reply {
        let ok = Status::Success;
        match *req {
            Request::PlayTone { .. } => {
                self.stats.tones += 1;
                Reply::Status {
                    opcode: Opcode::PlayTone as u8,
                    status: ok,
                }
            }
            Request::SetOutputState(s) => {
                let factor = self.speed_factor();
                for m in Port::ALL {
                    if s.port.contains(m) {
                        self.motors[m.index()].set_output_state(&s, &self.cfg, factor);
                    }
                }
                Reply::Status {
                    opcode: Opcode::SetOutputState as u8,
                    status: ok,
                }
            }
            Request::GetOutputState { port } => Reply::OutputState {
                status: ok,
                state: self.output_state(port),
            },
            Request::ResetMotorPosition { port, relative } => {
                self.motors[port.index()].reset_position(relative);
                Reply::Status {
                    opcode: Opcode::ResetMotorPosition as u8,
                    status: ok,
                }
            }
            Request::GetBatteryLevel => Reply::BatteryLevel {
                status: ok,
                millivolts: self.battery_mv(),
            },
            Request::KeepAlive => {
                self.stats.keep_alives += 1;
                Reply::KeepAlive {
                    status: ok,
                    sleep_timeout_ms: self.cfg.sleep_timeout_min.saturating_mul(60_000),
                }
            }
            Request::GetFirmwareVersion => Reply::FirmwareVersion {
                status: ok,
                protocol: Version {
                    major: 1,
                    minor: 124,
                },
                firmware: Version {
                    major: 1,
                    minor: 28,
                },
            },
            Request::GetDeviceInfo => {
                let a = self.cfg.address;
                Reply::DeviceInfo {
                    status: ok,
                    info: DeviceInfo {
                        name: DeviceInfo::name_field(&self.cfg.name),
                        address: [a[0], a[1], a[2], a[3], a[4], a[5], 0],
                        signal_strength: [0; 4],
                        free_flash: self.cfg.free_flash,
                    },
                }
            }
        }
    }

    fn speed_factor(&mut self) -> f64 {
        if self.cfg.speed_noise == 0.0 {
            return 1.0;
        }
        // Box–Muller; 1 - u keeps the logarithm finite.
        let u1: f64 = 1.0 - self.rng.random::<f64>();
        let u2: f64 = self.rng.random::<f64>();
        let z = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
        (1.0 + self.cfg.speed_noise * z).clamp(0.5, 1.5)
    }

    fn battery_mv(&mut self) -> u16 {
        let n = i32::from(self.cfg.battery_noise_mv);
        let noise = if n == 0 {
            0
        } else {
            self.rng.random_range(-n..=n)
        };
        let mv = f64::from(self.cfg.battery_mv) - self.drained_mv + f64::from(noise);
        mv.clamp(0.0, f64::from(u16::MAX)) as u16
    }
}

/// The firmware-like answer to a request that did not decode.
fn error_reply(opcode: u8, e: DecodeError) -> Reply {
    let status = e.reply_status();
    if opcode == Opcode::GetOutputState as u8 && matches!(e, DecodeError::BadPort(_)) {
        // c_cmd.c: "Return error and all zeros if illegal port specification is made".
        return Reply::OutputState {
            status,
            state: OutputState::default(),
        };
    }
    Reply::Status { opcode, status }
}

#[cfg(test)]
mod tests;
