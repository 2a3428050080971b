//! The bridge process loop over iceoryx2.
//!
//! Subscribes to [`Command`]s, wakes on the controller's command event (a `WaitSet` with the
//! listener attached as a deadline, and a timeout from [`Bridge::next_wakeup`]), drives the
//! [`Bridge`], and publishes each [`MotorState`] it produces, notifying the motor-state event
//! after each. Ports stay on the calling thread (`ipc::Service` ports are not `Send`).
//!
//! The bridge runs on the clock passed in, and so do its poll periods, settling and watchdog
//! deadline; only the waits are wall time. Each wait is the clock time until
//! [`Bridge::next_wakeup`] converted by [`Clock::real_duration`], and the listener's deadline
//! is the watchdog deadline converted the same way, so with a
//! [`ScaledClock`](crate::clock::ScaledClock) at `k` everything happens `k` times sooner in
//! wall time. [`process::run`](crate::process::run) builds the bridge and its clock from a
//! config.
//!
//! ```no_run
//! use tes_bridge::{brick::SimBrick, bridge::Bridge, clock::MonotonicClock, config::BridgeConfig};
//! use tes_bridge::ipc::{self, RunOptions, ServiceNames};
//! use tes_bridge::transport::SimTransport;
//!
//! let cfg = BridgeConfig::default();
//! let clock = MonotonicClock::new();
//! let brick = SimBrick::new(cfg.brick.clone(), cfg.seed)?;
//! let mut bridge = Bridge::new(SimTransport::new(brick, clock), &cfg);
//! let summary = ipc::run(&mut bridge, &clock, &ServiceNames::default(), &RunOptions::default())?;
//! println!("{summary:?}");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use tes_runtime::channel::{Idle, LatestInbox, Outbox, WaitStrategy};
use tes_runtime::latency::{LatencyRecorder, LatencyReport};
use tes_topics::{Command, MotorState};

use crate::bridge::{Bridge, BridgeError};
use crate::clock::Clock;
use crate::transport::Transport;

pub use tes_topics::ServiceNames;

/// How [`run`] ends.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Let iceoryx2 catch SIGINT/SIGTERM and end the loop on them (the `bridge` binary).
    pub handle_signals: bool,
    /// End the loop when this becomes true (checked at least every 100 ms).
    pub stop: Option<Arc<AtomicBool>>,
}

impl RunOptions {
    /// Options for the `bridge run` process: stop on SIGINT/SIGTERM.
    pub fn process() -> Self {
        Self {
            handle_signals: true,
            stop: None,
        }
    }
}

/// What a finished [`run`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RunSummary {
    /// Commands received.
    pub commands: u64,
    /// Motor states published.
    pub published: u64,
    /// Commands refused (stale or duplicate sequence number, unknown action, transport
    /// failure).
    pub refused: u64,
    /// The newest command sequence number executed.
    pub last_seq: u64,
    /// Whether a signal ended the loop.
    pub interrupted: bool,
    /// Observation → command latency of the commands received (keep-alives left out).
    pub latency: LatencyReport,
}

pub use tes_runtime::channel::IpcError;
use tes_runtime::channel::ipc_err;
pub use tes_runtime::clock::monotonic_ns;

/// Runs the bridge until a signal (if handled) or the stop flag; brakes any motion on exit.
///
/// Waits for commands by `wait` (see [`WaitStrategy`]) and at most until the bridge's next
/// timed duty (poll, keep-alive, watchdog). Each command's observation → command latency is
/// recorded into `latency` on arrival, before any work.
pub fn run<T: Transport, C: Clock>(
    bridge: &mut Bridge<T>,
    clock: &C,
    names: &ServiceNames,
    opts: &RunOptions,
) -> Result<RunSummary, IpcError> {
    run_with(
        bridge,
        clock,
        names,
        opts,
        WaitStrategy::Block,
        &mut LatencyRecorder::new(1000, 0),
    )
}

/// [`run`] with a wait strategy, recording latencies into `latency`.
pub fn run_with<T: Transport, C: Clock>(
    bridge: &mut Bridge<T>,
    clock: &C,
    names: &ServiceNames,
    opts: &RunOptions,
    wait: WaitStrategy,
    latency: &mut LatencyRecorder,
) -> Result<RunSummary, IpcError> {
    let stop: Arc<AtomicBool> = opts.stop.clone().unwrap_or_default();
    if opts.handle_signals {
        for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            signal_hook::flag::register(signal, stop.clone()).map_err(ipc_err("handle signals"))?;
        }
    }
    let node = tes_runtime::channel::node(false)?;
    let mut commands: LatestInbox<Command> =
        LatestInbox::open(&node, &names.command, &names.command_event, wait)?;
    let states: Outbox<MotorState> =
        Outbox::open(&node, &names.motor_state, &names.motor_state_event, 0)?;
    tracing::info!(command = %names.command, motor_state = %names.motor_state, %wait, "bridge loop running");

    let mut summary = RunSummary::default();
    loop {
        // Brick time to wall time (the simulated brick may run faster than the wall clock);
        // at most 100 ms, so the stop flag is seen.
        let timeout = clock
            .real_duration(bridge.next_wakeup(clock.now()))
            .clamp(Duration::from_micros(20), Duration::from_millis(100));
        match commands.next(timeout, &stop)? {
            Ok(cmd) => {
                on_command(bridge, clock, latency, cmd, &mut summary);
                // Take every other pending command too.
                while let Some(cmd) = commands.try_next()? {
                    on_command(bridge, clock, latency, cmd, &mut summary);
                }
            }
            Err(Idle::Timeout) => {
                // A controller killed mid-run leaves its command board unusable to its
                // successor; let it go while idle (see LatestInbox::renew_if_abandoned).
                commands.renew_if_abandoned(&node)?;
            }
            Err(Idle::Stopped) => {
                summary.interrupted = opts.handle_signals;
                break;
            }
        }
        if let Some(state) = bridge.tick(clock.now()) {
            states.send(MotorState {
                stamp_ns: monotonic_ns(),
                ..state
            })?;
            summary.published += 1;
        }
    }
    bridge.stop();
    summary.latency = latency.report();
    tracing::info!(?summary, "bridge loop stopped");
    Ok(summary)
}

/// One received command: its latency recorded first, then handed to the brick.
fn on_command<T: Transport, C: Clock>(
    bridge: &mut Bridge<T>,
    clock: &C,
    latency: &mut LatencyRecorder,
    cmd: Command,
    summary: &mut RunSummary,
) {
    if cmd.observed_ns != 0 {
        latency.record_ns(monotonic_ns().saturating_sub(cmd.observed_ns));
    }
    summary.commands += 1;
    if cmd.action != tes_topics::KEEP_ALIVE_ACTION {
        if cmd.seq <= summary.last_seq {
            summary.refused += 1;
            tracing::warn!(
                seq = cmd.seq,
                last = summary.last_seq,
                "stale or duplicate command refused"
            );
            return;
        }
        summary.last_seq = cmd.seq;
    }
    match bridge.on_command(&cmd, clock.now()) {
        Ok(()) => tracing::debug!(
            seq = cmd.seq,
            action = cmd.action,
            "command sent to the brick"
        ),
        Err(e @ BridgeError::UnknownAction(_)) => {
            summary.refused += 1;
            tracing::warn!(seq = cmd.seq, error = %e, "command refused");
        }
        Err(e) => {
            summary.refused += 1;
            tracing::warn!(seq = cmd.seq, error = %e, "command not delivered to the brick");
        }
    }
}
