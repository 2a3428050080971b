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
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use tes_topics::{Command, MotorState, service};

use crate::bridge::{Bridge, BridgeError};
use crate::clock::Clock;
use crate::transport::Transport;

/// The iceoryx2 service names the bridge uses.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    /// Commands from the controller.
    pub command: String,
    /// The controller's "command published" event.
    pub command_event: String,
    /// Motor states to perception.
    pub motor_state: String,
    /// The "motor state published" event.
    pub motor_state_event: String,
}

impl Default for ServiceNames {
    fn default() -> Self {
        Self::with_prefix("")
    }
}

impl ServiceNames {
    /// The shared names from [`tes_topics::service`], each prefixed by `prefix`.
    pub fn with_prefix(prefix: &str) -> Self {
        Self {
            command: format!("{prefix}{}", service::COMMAND),
            command_event: format!("{prefix}{}", service::COMMAND_EVENT),
            motor_state: format!("{prefix}{}", service::MOTOR_STATE),
            motor_state_event: format!("{prefix}{}", service::MOTOR_STATE_EVENT),
        }
    }
}

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
    /// Commands refused (unknown action or transport failure).
    pub refused: u64,
    /// Whether a signal ended the loop.
    pub interrupted: bool,
}

use tes_topics::channel::ipc_err;
pub use tes_topics::channel::{IpcError, monotonic_ns};

/// Runs the bridge until a signal (if handled) or the stop flag; brakes any motion on exit.
pub fn run<T: Transport, C: Clock>(
    bridge: &mut Bridge<T>,
    clock: &C,
    names: &ServiceNames,
    opts: &RunOptions,
) -> Result<RunSummary, IpcError> {
    let signals = if opts.handle_signals {
        SignalHandlingMode::HandleTerminationRequests
    } else {
        SignalHandlingMode::Disabled
    };
    let name = |s: &str| ServiceName::new(s).map_err(ipc_err("use the service name"));
    let node = NodeBuilder::new()
        .config(&Config::default())
        .signal_handling_mode(signals)
        .create::<ipc::Service>()
        .map_err(ipc_err("create the node"))?;
    let commands = tes_topics::channel::pubsub::<Command>(&node, &names.command, 0)?;
    let subscriber = commands
        .subscriber_builder()
        .create()
        .map_err(ipc_err("create the command subscriber"))?;
    let command_event = node
        .service_builder(&name(&names.command_event)?)
        .event()
        .open_or_create()
        .map_err(ipc_err("open the command event service"))?;
    let listener = command_event
        .listener_builder()
        .create()
        .map_err(ipc_err("create the command listener"))?;
    let states = tes_topics::channel::pubsub::<MotorState>(&node, &names.motor_state, 0)?;
    let publisher = states
        .publisher_builder()
        .create()
        .map_err(ipc_err("create the motor state publisher"))?;
    let state_event = node
        .service_builder(&name(&names.motor_state_event)?)
        .event()
        .open_or_create()
        .map_err(ipc_err("open the motor state event service"))?;
    let notifier = state_event
        .notifier_builder()
        .create()
        .map_err(ipc_err("create the motor state notifier"))?;
    subscriber
        .update_connections()
        .map_err(ipc_err("connect the command subscriber"))?;
    publisher
        .update_connections()
        .map_err(ipc_err("connect the motor state publisher"))?;

    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(signals)
        .create::<ipc::Service>()
        .map_err(ipc_err("create the wait set"))?;
    // The watchdog deadline is clock time, like everything the bridge decides; the wait set
    // only needs it in wall time to wake the loop when the controller falls silent.
    let _guard = waitset
        .attach_deadline(&listener, clock.real_duration(bridge.watchdog().deadline()))
        .map_err(ipc_err("attach the listener"))?;
    tracing::info!(command = %names.command, motor_state = %names.motor_state, "bridge loop running");

    let mut summary = RunSummary::default();
    let publish = |state: MotorState, summary: &mut RunSummary| -> Result<(), IpcError> {
        let sample = publisher
            .loan_uninit()
            .map_err(ipc_err("loan a motor state sample"))?;
        let sample = sample.write_payload(MotorState {
            stamp_ns: monotonic_ns(),
            ..state
        });
        sample.send().map_err(ipc_err("publish a motor state"))?;
        notifier
            .notify()
            .map_err(ipc_err("notify the motor state event"))?;
        summary.published += 1;
        Ok(())
    };
    loop {
        if opts.stop.as_ref().is_some_and(|s| s.load(Ordering::SeqCst)) {
            break;
        }
        // Brick time to wall time (the simulated brick may run faster than the wall clock).
        let mut timeout = clock
            .real_duration(bridge.next_wakeup(clock.now()))
            .max(Duration::from_micros(20));
        if opts.stop.is_some() {
            timeout = timeout.min(Duration::from_millis(100));
        }
        let result = waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, timeout)
            .map_err(ipc_err("wait"))?;
        if matches!(
            result,
            WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest
        ) {
            summary.interrupted = true;
            break;
        }
        // Drain the event so the wait set does not spin, then take every pending command.
        listener
            .try_wait(|_| {})
            .map_err(ipc_err("drain the command listener"))?;
        while let Some(sample) = subscriber.receive().map_err(ipc_err("receive a command"))? {
            let cmd = *sample;
            drop(sample);
            summary.commands += 1;
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
        if let Some(state) = bridge.tick(clock.now()) {
            publish(state, &mut summary)?;
        }
    }
    bridge.stop();
    tracing::info!(?summary, "bridge loop stopped");
    Ok(summary)
}
