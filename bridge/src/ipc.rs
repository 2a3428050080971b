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
use std::time::{Duration, Instant};
use tes_runtime::channel::Catches;
use tes_runtime::cpu::{CpuMeter, CpuUse};

use iceoryx2::prelude::*;
use tes_runtime::channel::{Idle, LatestInbox, Outbox, WaitStrategy};
use tes_runtime::latency::{LatencyRecorder, LatencyReport};
use tes_runtime::progress::{ProgressOutbox, ProgressWatch};
use tes_runtime::wait::IDLE_TICK;
use tes_topics::{Command, MotorState, Role, motor_flags, progress_flags};

use crate::bridge::{Bridge, BridgeError};
use crate::clock::Clock;
use crate::transport::{LinkReport, Transport};

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
    /// Options for the `tes-bridge run` process: stop on SIGINT/SIGTERM.
    pub fn process() -> Self {
        Self {
            handle_signals: true,
            stop: None,
        }
    }
}

/// What a finished [`run`] did.
#[derive(Debug, Clone, Default, PartialEq)]
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
    /// Its last hop alone: command published → received here (the controller's wake-up of
    /// the bridge), with the same budget and warm-up.
    pub command_hop: LatencyReport,
    /// Set when the loop stopped because the link to the brick stayed down (or never came
    /// up) for longer than the link timeout.
    pub link_down: Option<LinkDown>,
    /// The link's round trips (filled in by [`crate::process::run`]).
    pub link: LinkReport,
    /// The process's CPU over the commands after the warm-up.
    pub cpu: Option<CpuUse>,
    /// Waiting by `anticipate`: how commands came against their poll windows.
    pub catches: Option<Catches>,
}

impl std::fmt::Display for RunSummary {
    /// In words, for the log: the commands, the states published, the latency, how it ended.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let l = &self.latency;
        write!(
            f,
            "{} commands received ({} refused, last sequence number {}), {} motor states \
             published; command latency p50 {} us p99 {} us max {} us over {} commands",
            self.commands,
            self.refused,
            self.last_seq,
            self.published,
            l.p50_us,
            l.p99_us,
            l.max_us,
            l.count
        )?;
        if self.interrupted {
            f.write_str("; stopped by a signal")?;
        }
        if let Some(down) = &self.link_down {
            if down.never_up {
                write!(
                    f,
                    "; the link to the brick never came up ({:?})",
                    down.down_for
                )?;
            } else {
                write!(
                    f,
                    "; the link to the brick was down for {:?}",
                    down.down_for
                )?;
            }
        }
        if !self.link.transport.is_empty() {
            write!(f, "; {}", self.link)?;
        }
        Ok(())
    }
}

/// The link to the brick stayed down too long.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkDown {
    /// How long it had been down (or, if it never came up, how long since the start).
    pub down_for: Duration,
    /// Whether it never came up at all.
    pub never_up: bool,
    /// Whether it cannot come up on this machine (no Bluetooth, no USB bus): given up at once.
    pub impossible: bool,
}

/// Watches the link to the brick against the link timeout (wall time).
#[derive(Debug)]
struct LinkWatch {
    timeout: Duration,
    started: Instant,
    down_since: Option<Instant>,
}

impl LinkWatch {
    fn new(timeout: Duration) -> Self {
        Self {
            timeout,
            started: Instant::now(),
            down_since: None,
        }
    }

    /// The verdict after the bridge's latest exchanges.
    fn check<T: Transport>(&mut self, bridge: &Bridge<T>) -> Option<LinkDown> {
        let now = Instant::now();
        if !bridge.link_ever_up() {
            let waited = now.duration_since(self.started);
            let impossible = bridge.link_impossible();
            return (waited > self.timeout || impossible).then_some(LinkDown {
                down_for: waited,
                never_up: true,
                impossible,
            });
        }
        if !bridge.link_down() {
            self.down_since = None;
            return None;
        }
        let down_for = now.duration_since(*self.down_since.get_or_insert(now));
        (down_for > self.timeout).then_some(LinkDown {
            down_for,
            never_up: false,
            impossible: false,
        })
    }
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
        Duration::from_millis(crate::config::DEFAULT_LINK_TIMEOUT_MS),
    )
}

/// [`run`] with a wait strategy, recording latencies into `latency`; stops (with
/// [`RunSummary::link_down`] set) when the link to the brick has been down, or not yet up
/// since the start, for longer than `link_timeout`.
pub fn run_with<T: Transport, C: Clock>(
    bridge: &mut Bridge<T>,
    clock: &C,
    names: &ServiceNames,
    opts: &RunOptions,
    wait: WaitStrategy,
    latency: &mut LatencyRecorder,
    link_timeout: Duration,
) -> Result<RunSummary, IpcError> {
    let stop = stop_flag(opts)?;
    let node = tes_runtime::channel::group_node(names, Role::Bridge, false)?;
    let mut commands: LatestInbox<Command> =
        LatestInbox::open(&node, &names.command, &names.command_event, wait)?
            // Waiting by `anticipate`: a command follows perception's observation by the
            // controller's decision, so perception's word of when it is due serves here too.
            .with_heads_up(&node, &names.observation_due, &names.observation_due_event)?;
    let mut cpu = CpuMeter::process();
    // Anticipating, off the acting thread's CPU (which then polls alone); blocking, on it.
    tes_runtime::affinity::join_the_chain(wait == WaitStrategy::Anticipate, "the bridge");
    let states: Outbox<MotorState> =
        Outbox::open(&node, &names.motor_state, &names.motor_state_event, 0)?;
    let mut progress = ProgressOutbox::open(&node, names, Role::Bridge)?;
    tracing::info!(command = %names.command, motor_state = %names.motor_state, %wait, "bridge loop running");

    let mut summary = RunSummary::default();
    let mut command_hop = latency.alike();
    // A command on the board that the predecessor of a respawned bridge did not carry out.
    if let Some(cmd) = in_flight_at_start(&node, names, &commands, &stop)? {
        tracing::info!(
            seq = cmd.seq,
            "taking over the command in flight (its motion was never reported)"
        );
        on_command(
            bridge,
            clock,
            (&mut *latency, &mut command_hop),
            cmd,
            &mut summary,
            &mut cpu,
        );
    }
    let mut link = LinkWatch::new(link_timeout);
    let mut was_down = false;
    loop {
        // Brick time to wall time (the simulated brick may run faster than the wall clock);
        // at most the idle tick, so the stop flag is seen.
        let timeout = clock
            .real_duration(bridge.next_wakeup(clock.now()))
            .clamp(Duration::from_micros(20), IDLE_TICK);
        match commands.next(timeout, &stop)? {
            Ok(first) => {
                // This command, then every other pending one.
                let mut next = Some(first);
                while let Some(cmd) = next {
                    on_command(
                        bridge,
                        clock,
                        (&mut *latency, &mut command_hop),
                        cmd,
                        &mut summary,
                        &mut cpu,
                    );
                    next = commands.try_next()?;
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
        publish_motor_state(bridge, clock, &states, &mut summary, &mut progress)?;
        report_progress(&mut progress, bridge, &summary, &mut was_down)?;
        if let Some(verdict) = link.check(bridge) {
            summary.link_down = Some(verdict);
            break;
        }
    }
    bridge.stop();
    summary.latency = latency.report();
    summary.command_hop = command_hop.report();
    summary.cpu = cpu.report();
    summary.catches = commands.catches();
    tracing::info!(%summary, "bridge loop stopped");
    Ok(summary)
}

/// The flag that stops the loop: the caller's, or a new one; raised by SIGINT and SIGTERM
/// when the loop handles signals.
fn stop_flag(opts: &RunOptions) -> Result<Arc<AtomicBool>, IpcError> {
    let stop: Arc<AtomicBool> = opts.stop.clone().unwrap_or_default();
    if opts.handle_signals {
        for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            signal_hook::flag::register(signal, stop.clone()).map_err(ipc_err("handle signals"))?;
        }
    }
    Ok(stop)
}

/// Advances the brick's timed duties and publishes the motor state they report, if any; a
/// settled motion over a live link is how far the bridge got.
fn publish_motor_state<T: Transport, C: Clock>(
    bridge: &mut Bridge<T>,
    clock: &C,
    states: &Outbox<MotorState>,
    summary: &mut RunSummary,
    progress: &mut ProgressOutbox,
) -> Result<(), IpcError> {
    let Some(state) = bridge.tick(clock.now()) else {
        return Ok(());
    };
    states.send(MotorState {
        stamp_ns: monotonic_ns(),
        ..state
    })?;
    summary.published += 1;
    if state.flags & motor_flags::SETTLED != 0 && state.flags & motor_flags::LINK_DOWN == 0 {
        progress.report_mut().out_seq = state.after_command;
    }
    Ok(())
}

/// Tells the launcher how far the bridge got and whether its link is down: at once when the
/// link's state changed, else when a report is due.
fn report_progress<T: Transport>(
    progress: &mut ProgressOutbox,
    bridge: &Bridge<T>,
    summary: &RunSummary,
    was_down: &mut bool,
) -> Result<(), IpcError> {
    let down = bridge.link_down() || !bridge.link_ever_up();
    let report = progress.report_mut();
    report.in_seq = bridge.executed();
    report.steps = summary.commands;
    report.flags = 0;
    if bridge.link_down() {
        report.flags |= progress_flags::LINK_DOWN;
    }
    if !bridge.link_ever_up() {
        report.flags |= progress_flags::LINK_NEVER_UP;
    }
    if down != *was_down {
        *was_down = down;
        progress.publish(monotonic_ns())
    } else {
        progress.publish_due(monotonic_ns()).map(|_| ())
    }
}

/// One received command: its latencies recorded first (from the observation, and from the
/// command's own publication), then handed to the brick; the CPU meter is marked once the
/// warm-up is over.
fn on_command<T: Transport, C: Clock>(
    bridge: &mut Bridge<T>,
    clock: &C,
    (latency, command_hop): (&mut LatencyRecorder, &mut LatencyRecorder),
    cmd: Command,
    summary: &mut RunSummary,
    cpu: &mut CpuMeter,
) {
    if cmd.observed_ns != 0 {
        let now = monotonic_ns();
        latency.record_ns(now.saturating_sub(cmd.observed_ns));
        command_hop.record_ns(now.saturating_sub(cmd.stamp_ns));
        if latency.warmed_up() {
            cpu.mark();
        }
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

/// How long a starting bridge waits for perception's progress report to judge the command
/// found on the board (perception reports at least every [`ProgressOutbox::PERIOD`]).
const PERCEPTION_REPORT_WAIT: Duration = Duration::from_millis(600);

/// The command a starting bridge must carry out itself: the one on the board (or the one in
/// flight that a keep-alive on the board carries), if perception has not used its motion yet
/// (its predecessor died before carrying it out or reporting it).
/// `None` at a group's start (the board is empty), or when perception's report says the
/// motion was used, or when perception does not report within [`PERCEPTION_REPORT_WAIT`].
fn in_flight_at_start(
    node: &Node<ipc::Service>,
    names: &ServiceNames,
    commands: &LatestInbox<Command>,
    stop: &AtomicBool,
) -> Result<Option<Command>, IpcError> {
    // A keep-alive stands for the command in flight it carries.
    let Some(cmd) = commands.current()?.and_then(|c| c.in_flight()) else {
        return Ok(None);
    };
    if cmd.seq == 0 {
        return Ok(None);
    }
    let mut watch = ProgressWatch::open(node, names)?;
    let deadline = Instant::now() + PERCEPTION_REPORT_WAIT;
    while Instant::now() < deadline && !stop.load(std::sync::atomic::Ordering::Relaxed) {
        watch.poll()?;
        if let Some(perception) = watch.latest(Role::Perception) {
            return Ok((perception.in_seq < cmd.seq).then_some(cmd));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    tracing::warn!(
        seq = cmd.seq,
        "perception did not report within {PERCEPTION_REPORT_WAIT:?}; not carrying out the \
         command found on the board (its motion may have been used)"
    );
    Ok(None)
}
