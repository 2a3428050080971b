//! One simulated NXT servo motor: a first-order speed response, a 1° encoder and the
//! firmware's tacho-limit bookkeeping.

use crate::nxt::{Mode, OutputState, Port, RegulationMode, RunState, SetOutputState};

use super::SimBrickConfig;

/// What drives the motor shaft this tick.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Drive {
    /// Powered towards a target speed (deg/s).
    Powered,
    /// Unpowered, windings open: friction slows it slowly.
    Coast,
    /// Windings shorted: it stops quickly and holds.
    Brake,
}

/// A snapshot of a simulated motor's physics, for tests and tools.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorView {
    /// Shaft angle, degrees since power-on (continuous).
    pub angle_deg: f64,
    /// Shaft speed, degrees per second.
    pub speed_dps: f64,
    /// The current run state.
    pub run_state: RunState,
    /// The encoder count (whole degrees since power-on).
    pub encoder: i64,
    /// The accumulated tacho target the firmware compares the count with.
    pub target: i64,
}

/// A simulated motor.
#[derive(Debug, Clone)]
pub(crate) struct Motor {
    port: Port,
    // Last SETOUTPUTSTATE fields, reported back verbatim by GETOUTPUTSTATE.
    power: i8,
    mode: Mode,
    regulation: RegulationMode,
    turn_ratio: i8,
    tacho_limit: u32,
    run_state: RunState,
    // Physics.
    drive: Drive,
    angle: f64,
    speed: f64,
    target_speed: f64,
    // Firmware counters (encoder counts at the last resets) and the tacho target.
    tacho_zero: i64,
    block_zero: i64,
    rotation_zero: i64,
    target: i64,
    run_forever: bool,
}

impl Motor {
    pub(crate) fn new(port: Port) -> Self {
        Self {
            port,
            power: 0,
            mode: Mode::IDLE,
            regulation: RegulationMode::Idle,
            turn_ratio: 0,
            tacho_limit: 0,
            run_state: RunState::Idle,
            drive: Drive::Coast,
            angle: 0.0,
            speed: 0.0,
            target_speed: 0.0,
            tacho_zero: 0,
            block_zero: 0,
            rotation_zero: 0,
            target: 0,
            run_forever: true,
        }
    }

    /// Whole degrees the encoder has counted (it resolves 1°).
    pub(crate) fn encoder(&self) -> i64 {
        self.angle.floor() as i64
    }

    /// Whether the shaft is turning or being driven.
    pub(crate) fn is_active(&self) -> bool {
        self.drive == Drive::Powered || self.speed != 0.0
    }

    pub(crate) fn view(&self) -> MotorView {
        MotorView {
            angle_deg: self.angle,
            speed_dps: self.speed,
            run_state: self.run_state,
            encoder: self.encoder(),
            target: self.target,
        }
    }

    pub(crate) fn output_state(&self) -> OutputState {
        let enc = self.encoder();
        OutputState {
            port: self.port,
            power: self.power,
            mode: self.mode,
            regulation: self.regulation,
            turn_ratio: self.turn_ratio,
            run_state: self.run_state,
            tacho_limit: self.tacho_limit,
            tacho_count: (enc - self.tacho_zero) as i32,
            block_tacho_count: (enc - self.block_zero) as i32,
            rotation_count: (enc - self.rotation_zero) as i32,
        }
    }

    /// RESETMOTORPOSITION: `relative` resets the block count, otherwise the rotation count.
    pub(crate) fn reset_position(&mut self, relative: bool) {
        if relative {
            self.block_zero = self.encoder();
        } else {
            self.rotation_zero = self.encoder();
        }
    }

    /// Applies SETOUTPUTSTATE the way `c_output.c`/`d_output.c` order it: speed and run
    /// state, then mode, then the tacho limit. `speed_factor` is this command's noise draw.
    pub(crate) fn set_output_state(
        &mut self,
        s: &SetOutputState,
        cfg: &SimBrickConfig,
        speed_factor: f64,
    ) {
        self.power = s.power;
        self.mode = s.mode;
        self.regulation = s.regulation;
        self.turn_ratio = s.turn_ratio;
        self.tacho_limit = s.tacho_limit;
        let power = f64::from(s.power.clamp(-100, 100));
        let on = s.mode.contains(Mode::MOTOR_ON);
        let brake = s.mode.contains(Mode::BRAKE);
        if !on || s.run_state == RunState::Idle {
            // Unpowered or idle: the firmware's idle control floats the output.
            self.run_state = RunState::Idle;
            self.drive = Drive::Coast;
            self.target_speed = 0.0;
        } else if s.power == 0 {
            // Power 0 while running: hold (braked) or float; the firmware reports RUNNING.
            self.run_state = RunState::Running;
            self.drive = if brake { Drive::Brake } else { Drive::Coast };
            self.target_speed = 0.0;
        } else {
            // RAMPUP/RAMPDOWN are accepted and modelled as an immediate RUNNING.
            self.run_state = RunState::Running;
            self.drive = Drive::Powered;
            let regulated =
                s.mode.contains(Mode::REGULATED) && s.regulation != RegulationMode::Idle;
            let k = if regulated {
                1.0
            } else {
                cfg.unregulated_speed_factor
            };
            self.target_speed = cfg.speed_per_power * power * k * speed_factor;
        }
        // Tacho limit: 0 runs forever; otherwise the target accumulates in the direction
        // of the power, so the next move absorbs the last one's overshoot.
        if s.tacho_limit == 0 {
            self.run_forever = true;
            self.target = self.encoder();
        } else {
            self.run_forever = false;
            let limit = i64::from(s.tacho_limit);
            if s.power > 0 {
                self.target += limit;
            } else {
                self.target -= limit;
            }
        }
    }

    /// Advances the physics by `dt` seconds (the brick steps 1 ms at a time, like the
    /// firmware's output control loop).
    pub(crate) fn step(&mut self, dt: f64, cfg: &SimBrickConfig) {
        match self.drive {
            Drive::Powered => {
                let a = (-dt / cfg.time_constant_s).exp();
                self.speed = self.target_speed + (self.speed - self.target_speed) * a;
            }
            Drive::Coast => {
                self.speed *= (-dt / cfg.coast_time_constant_s).exp();
            }
            Drive::Brake => {
                self.speed *= (-dt / cfg.brake_time_constant_s).exp();
            }
        }
        if self.drive != Drive::Powered && self.speed.abs() < cfg.stop_speed_dps {
            self.speed = 0.0;
        }
        self.angle += self.speed * dt;
        if self.drive == Drive::Powered {
            if self.run_forever {
                self.target = self.encoder();
            } else {
                let count = self.encoder();
                let reached = if self.power > 0 {
                    count >= self.target
                } else {
                    count <= self.target
                };
                if reached {
                    self.run_state = RunState::Idle;
                    self.drive = if self.mode.contains(Mode::BRAKE) {
                        Drive::Brake
                    } else {
                        Drive::Coast
                    };
                    self.target_speed = 0.0;
                }
            }
        }
    }
}
