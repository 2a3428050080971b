//! The bridge's logic, free of IPC: commands in, NXT telegrams out, motor states back.
//!
//! [`Bridge`] owns a [`Transport`], the [`ActionMap`] and the [`Watchdog`]. The process loop
//! ([`crate::ipc`]) hands it each [`Command`] ([`Bridge::on_command`]), calls
//! [`Bridge::tick`] whenever it wakes, publishes the [`MotorState`]s these return, and sleeps
//! at most [`Bridge::next_wakeup`]. Time is passed in, so tests drive it with a manual clock.
//!
//! While the wheels move the bridge polls their GETOUTPUTSTATE every `poll.moving_period_ms`
//! and publishes each reading; once both wheels are idle and their counts stopped changing
//! for `poll.settle_polls` polls it reads every port and the battery and publishes a state
//! flagged [`SETTLED`](tes_topics::motor_flags::SETTLED). At rest it publishes a heartbeat
//! every `poll.idle_period_ms`.
//!
//! ```
//! use std::time::Duration;
//! use tes_bridge::{brick::SimBrick, bridge::Bridge, clock::{Clock, ManualClock}};
//! use tes_bridge::config::BridgeConfig;
//! use tes_bridge::transport::SimTransport;
//! use tes_topics::{Command, motor_flags};
//!
//! let cfg = BridgeConfig::default();
//! let clock = ManualClock::new();
//! let brick = SimBrick::new(cfg.brick.clone(), cfg.seed)?;
//! let mut bridge = Bridge::new(SimTransport::new(brick, clock.clone()), &cfg);
//! bridge.on_command(&Command { seq: 1, action: 0, ..Command::default() }, clock.now())?;
//! let settled = loop {
//!     clock.advance(Duration::from_millis(20));
//!     if let Some(s) = bridge.tick(clock.now()) {
//!         if s.flags & motor_flags::SETTLED != 0 { break s; }
//!     }
//! };
//! assert_eq!(settled.after_command, 1);
//! assert!((246..270).contains(&settled.tacho_count[1])); // left wheel on port B
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::time::Duration;

use tes_topics::{Command, KEEP_ALIVE_ACTION, MotorState, motor_flags};

use crate::actions::{ActionMap, UnknownAction};
use crate::config::{BridgeConfig, PollConfig};
use crate::nxt::{Port, Reply, Request, RunState, SetOutputState};
use crate::transport::{Transport, TransportError};
use crate::watchdog::{Verdict, Watchdog};

/// Why a command was not executed.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// The action id is not in the table.
    #[error(transparent)]
    UnknownAction(#[from] UnknownAction),
    /// The transport failed.
    #[error("transport: {0}")]
    Transport(#[from] TransportError),
}

/// Counters of a [`Bridge`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BridgeStats {
    /// Commands received (keep-alives included).
    pub commands: u64,
    /// Commands refused for an unknown action id.
    pub unknown_actions: u64,
    /// Transport failures.
    pub transport_errors: u64,
    /// Watchdog brakes.
    pub watchdog_trips: u64,
    /// Motor states produced.
    pub states: u64,
}

impl std::fmt::Display for BridgeStats {
    /// In words, for the log.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} commands carried out, {} unknown actions, {} transport errors, {} watchdog \
             trips, {} motor states read",
            self.commands,
            self.unknown_actions,
            self.transport_errors,
            self.watchdog_trips,
            self.states
        )
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// At rest: heartbeats only.
    Idle,
    /// A move is under way: poll the wheels.
    Moving { stable_polls: u32 },
}

/// The bridge.
#[derive(Debug)]
pub struct Bridge<T: Transport> {
    transport: T,
    actions: ActionMap,
    use_command_degrees: bool,
    poll: PollConfig,
    watchdog: Watchdog,
    state: MotorState,
    power: [i8; 3],
    phase: Phase,
    next_poll: Duration,
    next_heartbeat: Duration,
    next_keepalive: Duration,
    stats: BridgeStats,
    /// Whether any exchange with the brick has succeeded since the bridge started.
    link_ever_up: bool,
    /// The last link failure says no retry can help.
    link_impossible: bool,
    /// The last link failure, for the error that stops a bridge whose link stays down.
    last_link_error: Option<String>,
    /// A command the link failed to deliver, tried again when the link is back (unless a
    /// newer command comes first): the controller still waits for its outcome.
    undelivered: Option<Command>,
    next_retry: Duration,
}

impl<T: Transport> Bridge<T> {
    /// A bridge over `transport`, configured by `cfg` (actions, poll periods, watchdog).
    pub fn new(transport: T, cfg: &BridgeConfig) -> Self {
        Self {
            transport,
            actions: cfg.actions.clone(),
            use_command_degrees: cfg.use_command_degrees,
            poll: cfg.poll,
            watchdog: Watchdog::new(cfg.watchdog_deadline),
            // At rest until the first command: nothing is in motion.
            state: MotorState {
                flags: motor_flags::SETTLED,
                ..MotorState::default()
            },
            power: [0; 3],
            phase: Phase::Idle,
            next_poll: Duration::ZERO,
            next_heartbeat: Duration::ZERO,
            next_keepalive: cfg.poll.keepalive_period(),
            stats: BridgeStats::default(),
            link_ever_up: false,
            link_impossible: false,
            last_link_error: None,
            undelivered: None,
            next_retry: Duration::ZERO,
        }
    }

    /// Whether the link to the brick is down (the last exchange failed).
    pub fn link_down(&self) -> bool {
        self.state.flags & motor_flags::LINK_DOWN != 0
    }

    /// Whether the link cannot exist on this machine (no Bluetooth, no USB bus): no retry
    /// will bring it up.
    pub fn link_impossible(&self) -> bool {
        self.link_impossible
    }

    /// Whether any exchange with the brick has succeeded since the bridge started.
    pub fn link_ever_up(&self) -> bool {
        self.link_ever_up
    }

    /// The last link failure, if any.
    pub fn last_link_error(&self) -> Option<&str> {
        self.last_link_error.as_deref()
    }

    /// The newest command executed (its SETOUTPUTSTATE telegrams delivered), 0 before any.
    pub fn executed(&self) -> u64 {
        self.state.after_command
    }

    /// The transport.
    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    /// Counters.
    pub fn stats(&self) -> BridgeStats {
        self.stats
    }

    /// The watchdog.
    pub fn watchdog(&self) -> &Watchdog {
        &self.watchdog
    }

    /// The last motor state produced.
    pub fn last_state(&self) -> &MotorState {
        &self.state
    }

    /// Whether a move is under way.
    pub fn is_moving(&self) -> bool {
        matches!(self.phase, Phase::Moving { .. })
    }

    /// Executes a command received at `now`: feeds the watchdog and, unless it is a
    /// keep-alive ([`KEEP_ALIVE_ACTION`]), sends its SETOUTPUTSTATE telegrams. A command the
    /// link fails to deliver is tried again by [`tick`](Self::tick) once the link is back,
    /// unless a newer one comes first; its motion is reported only once delivered.
    pub fn on_command(&mut self, cmd: &Command, now: Duration) -> Result<(), BridgeError> {
        self.stats.commands += 1;
        self.watchdog.feed(now);
        self.state.flags &= !motor_flags::WATCHDOG_BRAKED;
        if cmd.action == KEEP_ALIVE_ACTION {
            return Ok(());
        }
        self.undelivered = None;
        let delivered = self.execute(cmd, now);
        if let Err(BridgeError::Transport(e)) = &delivered
            && e.is_link_failure()
        {
            self.undelivered = Some(*cmd);
            self.next_retry = now + self.poll.idle_period();
        }
        delivered
    }

    fn execute(&mut self, cmd: &Command, now: Duration) -> Result<(), BridgeError> {
        let cmds = if self.use_command_degrees {
            self.actions.for_rotation(cmd.left_deg, cmd.right_deg)
        } else {
            self.actions
                .for_action(cmd.action)
                .inspect_err(|_| self.stats.unknown_actions += 1)?
        };
        for sos in cmds.iter() {
            let req = Request::SetOutputState(*sos);
            let sent = if cmds.acknowledge {
                self.transport.request(&req).map(|_| ())
            } else {
                self.transport.send(&req)
            };
            if let Err(e) = sent {
                self.link_error(&e);
                return Err(e.into());
            }
            self.link_ok();
            for p in Port::ALL {
                if sos.port.contains(p) {
                    self.power[p.index()] = sos.power;
                    self.state.run_state[p.index()] = RunState::Running as u8;
                }
            }
        }
        // Only a delivered command's motion is reported as following it.
        self.state.after_command = cmd.seq;
        self.state.action = u16::try_from(cmd.action).unwrap_or(tes_topics::NO_ACTION);
        self.state.flags &= !motor_flags::SETTLED;
        self.phase = Phase::Moving { stable_polls: 0 };
        self.next_poll = now + self.poll.moving_period();
        Ok(())
    }

    /// Does whatever is due at `now` — poll a move, brake on the watchdog, heartbeat,
    /// keep the brick awake — and returns the motor state to publish, if any.
    pub fn tick(&mut self, now: Duration) -> Option<MotorState> {
        let mut out = None;
        if now >= self.next_retry
            && let Some(cmd) = self.undelivered.take()
        {
            // Tried again at the heartbeat cadence while the link is down.
            self.next_retry = now + self.poll.idle_period();
            match self.execute(&cmd, now) {
                Ok(()) => {
                    tracing::info!(seq = cmd.seq, "link back: the undelivered command went out");
                }
                Err(BridgeError::Transport(e)) if e.is_link_failure() => {
                    self.undelivered = Some(cmd);
                }
                Err(e) => tracing::warn!(seq = cmd.seq, error = %e, "undelivered command refused"),
            }
        }
        if now >= self.next_keepalive {
            self.next_keepalive = now + self.poll.keepalive_period();
            match self.transport.request(&Request::KeepAlive) {
                Ok(_) => self.link_ok(),
                Err(e) => self.link_error(&e),
            }
        }
        match self.phase {
            Phase::Moving { stable_polls } => {
                if self.watchdog.check(now, self.motor_running()) == Verdict::Brake {
                    self.stats.watchdog_trips += 1;
                    tracing::warn!(
                        deadline_ms = self.watchdog.deadline().as_millis() as u64,
                        silence_ms = self.watchdog.silence(now).as_millis() as u64,
                        after_command = self.state.after_command,
                        "watchdog: no command within the deadline while a motor runs; braking all motors"
                    );
                    self.brake_all();
                    self.state.flags |= motor_flags::WATCHDOG_BRAKED;
                    self.phase = Phase::Moving { stable_polls: 0 };
                    self.next_poll = now;
                }
                if now >= self.next_poll {
                    self.next_poll = now + self.poll.moving_period();
                    out = Some(self.poll_move(now, stable_polls));
                }
            }
            Phase::Idle => {
                if now >= self.next_heartbeat {
                    self.next_heartbeat = now + self.poll.idle_period();
                    self.read_all();
                    out = Some(self.emit(now));
                }
            }
        }
        out
    }

    /// How long the process loop may sleep before [`tick`](Self::tick) has something to do.
    pub fn next_wakeup(&self, now: Duration) -> Duration {
        let mut due = match self.phase {
            Phase::Moving { .. } => self.next_poll.min(now + self.watchdog.remaining(now)),
            Phase::Idle => self.next_heartbeat,
        };
        if self.undelivered.is_some() {
            due = due.min(self.next_retry);
        }
        due.min(self.next_keepalive).saturating_sub(now)
    }

    /// Stops any motion (brake) — for shutdown.
    pub fn stop(&mut self) {
        if self.is_moving() || self.motor_running() {
            self.brake_all();
        }
    }

    fn motor_running(&self) -> bool {
        (0..3).any(|i| self.state.run_state[i] != RunState::Idle as u8 && self.power[i] != 0)
    }

    fn brake_all(&mut self) {
        match self
            .transport
            .send(&Request::SetOutputState(SetOutputState::BRAKE_ALL))
        {
            Ok(()) => {
                self.power = [0; 3];
                self.link_ok();
            }
            Err(e) => self.link_error(&e),
        }
    }

    fn poll_move(&mut self, now: Duration, stable_polls: u32) -> MotorState {
        let before = self.state.tacho_count;
        let mut ok = true;
        for p in self.actions.wheel_ports() {
            ok &= self.read_port(p);
        }
        if !ok {
            return self.emit(now);
        }
        let wheels_still = self.actions.wheel_ports().iter().all(|p| {
            let i = p.index();
            (self.state.run_state[i] == RunState::Idle as u8 || self.power[i] == 0)
                && self.state.tacho_count[i] == before[i]
        });
        let stable = if wheels_still { stable_polls + 1 } else { 0 };
        if stable >= self.poll.settle_polls {
            self.read_all();
            if self.state.flags & motor_flags::LINK_DOWN == 0 {
                self.phase = Phase::Idle;
                self.state.flags |= motor_flags::SETTLED;
                self.next_heartbeat = now + self.poll.idle_period();
            }
        } else {
            self.phase = Phase::Moving {
                stable_polls: stable,
            };
        }
        self.emit(now)
    }

    /// Reads one port's output state into the motor state; false on a transport failure.
    fn read_port(&mut self, port: Port) -> bool {
        match self.transport.request(&Request::GetOutputState { port }) {
            Ok(Reply::OutputState { state, .. }) => {
                let i = port.index();
                self.state.tacho_count[i] = state.tacho_count;
                self.state.rotation_count[i] = state.rotation_count;
                self.state.run_state[i] = state.run_state as u8;
                self.power[i] = state.power;
                self.link_ok();
                true
            }
            Ok(other) => {
                tracing::warn!(?other, "unexpected reply to GETOUTPUTSTATE");
                false
            }
            Err(e) => {
                self.link_error(&e);
                false
            }
        }
    }

    fn read_all(&mut self) {
        for p in Port::ALL {
            if !self.read_port(p) {
                return;
            }
        }
        match self.transport.request(&Request::GetBatteryLevel) {
            Ok(Reply::BatteryLevel { millivolts, .. }) => {
                self.state.battery_mv = millivolts;
                self.link_ok();
            }
            Ok(_) => {}
            Err(e) => self.link_error(&e),
        }
    }

    fn link_error(&mut self, e: &TransportError) {
        self.stats.transport_errors += 1;
        if self.state.flags & motor_flags::LINK_DOWN == 0 {
            if self.link_ever_up {
                tracing::warn!(error = %e, transport = %self.transport.describe(), "link to the brick failed");
            } else {
                // Still coming up: if it never does, the process's error says this cause, once.
                tracing::debug!(error = %e, transport = %self.transport.describe(), "link to the brick not up yet");
            }
        }
        if e.is_link_failure() {
            self.state.flags |= motor_flags::LINK_DOWN;
            // A back-off is the consequence of the failure before it, not a cause to report.
            if !matches!(e, TransportError::Backoff { .. }) || self.last_link_error.is_none() {
                self.last_link_error = Some(e.to_string());
            }
            self.link_impossible = e.is_impossible();
        }
    }

    fn link_ok(&mut self) {
        if self.state.flags & motor_flags::LINK_DOWN != 0 {
            tracing::info!(transport = %self.transport.describe(), "link to the brick is back");
        }
        self.state.flags &= !motor_flags::LINK_DOWN;
        self.link_ever_up = true;
    }

    fn emit(&mut self, now: Duration) -> MotorState {
        self.stats.states += 1;
        self.state.seq += 1;
        self.state.stamp_ns = u64::try_from(now.as_nanos()).unwrap_or(u64::MAX);
        self.state
    }
}

#[cfg(test)]
mod tests;
