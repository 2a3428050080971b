//! The bridge process's entry point, for the `tes-bridge run` binary and for launchers: builds
//! the transport the config names — the simulated brick (running at `[brick] time_scale`) or a
//! serial link — and runs the iceoryx2 loop until a signal or the stop flag.
//!
//! Time: the [`Bridge`] (poll periods, settling, watchdog, keep-alive) runs on one clock, a
//! [`ScaledClock`] at `time_scale` for the simulated brick and the wall clock (scale 1) for a
//! serial link. So at `time_scale = k` every period and deadline of the config is *brick*
//! time and lasts 1/k of it in wall time; the simulated link delay is brick time too.
//!
//! ```no_run
//! use std::sync::Arc;
//! use std::sync::atomic::AtomicBool;
//! use tes_bridge::config::BridgeConfig;
//! use tes_bridge::ipc::RunOptions;
//!
//! // What a launcher does: settings without a file, its own stop flag.
//! let cfg = BridgeConfig::default()
//!     .with_seed(7)
//!     .with_service_prefix("run-42/")?
//!     .with_time_scale(200.0)?;
//! let stop = Arc::new(AtomicBool::new(false));
//! let opts = RunOptions { handle_signals: false, stop: Some(Arc::clone(&stop)) };
//! let summary = tes_bridge::process::run(&cfg, &opts)?;
//! println!("{} commands", summary.commands);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use tes_runtime::latency::{LatencyRecorder, LatencyReport};
use thiserror::Error;

use crate::brick::{BrickConfigError, SimBrick};
use crate::bridge::Bridge;
use crate::clock::{Clock, ScaledClock};
use crate::config::{BridgeConfig, TransportKind};
use crate::ipc::{self, IpcError, RunOptions, RunSummary, ServiceNames};
use crate::transport::{
    BluetoothTransport, DelayedTransport, LinkDelay, LinkReport, SerialTransport, SimTransport,
    TimedTransport, Transport, TransportError, UsbTransport,
};

/// What to check when a link never came up (its possible causes are outside the program).
const NEVER_UP_FIX: &str =
    "; is the brick switched on, and is this its link? (docs/bridge.md, section 4: failures)";

/// Why the bridge process could not run.
#[derive(Debug, Error)]
pub enum ProcessError {
    /// The simulated brick's settings are invalid.
    #[error("the simulated brick: {0}")]
    Brick(#[from] BrickConfigError),
    /// The iceoryx2 loop failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// `[ipc] wait` names no strategy.
    #[error("ipc.wait: {0}")]
    Wait(#[from] tes_runtime::channel::BadWaitStrategy),
    /// The link to the brick did not come up, or stayed down, for longer than
    /// `link_timeout_ms`.
    #[error(
        "the link to the brick ({transport}) {}: {last_error}{}",
        if *impossible { "cannot be used on this machine".to_owned() }
        else if *never_up { format!("did not come up within {:.1} s", down_for.as_secs_f64()) }
        else { format!("has been down for {:.1} s", down_for.as_secs_f64()) },
        if *never_up && !*impossible { NEVER_UP_FIX } else { "" }
    )]
    LinkDown {
        /// The transport, as configured.
        transport: String,
        /// Whether it never came up.
        never_up: bool,
        /// Whether it cannot come up on this machine (given up at once).
        impossible: bool,
        /// How long it was down.
        down_for: std::time::Duration,
        /// The last failure.
        last_error: String,
    },
    /// The link to a real brick could not be set up.
    #[error("the link to the brick: {0}")]
    Link(#[from] TransportError),
    /// `transport = "serial:PATH"` names no terminal device.
    #[error("transport: {0}")]
    Device(#[from] crate::config::DeviceError),
    /// The latency report could not be written.
    #[error("cannot write the latency report {}: {error}", path.display())]
    Report {
        /// The report file.
        path: std::path::PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

/// The transport `cfg` names: the simulated brick on `clock` (behind its simulated link
/// delay, if set), or a real brick's link.
fn transport(cfg: &BridgeConfig, clock: ScaledClock) -> Result<Box<dyn Transport>, ProcessError> {
    if cfg.transport.is_real() && cfg.link_delay.is_some() {
        tracing::warn!("link_delay is for the simulated brick; ignored with a real brick's link");
    }
    let timing = cfg.link_timing();
    Ok(match &cfg.transport {
        TransportKind::Sim => {
            let sim = SimTransport::new(SimBrick::new(cfg.brick.clone(), cfg.seed)?, clock);
            match cfg.link_delay {
                // The simulated link belongs to the simulated world: its delay is brick time.
                Some((mean, jitter)) => Box::new(DelayedTransport::new(
                    sim,
                    LinkDelay::new(
                        clock.real_duration(mean),
                        clock.real_duration(jitter),
                        cfg.seed,
                    ),
                )),
                None => Box::new(sim),
            }
        }
        TransportKind::Serial(path) => Box::new(SerialTransport::serial(cfg.serial_config(path))),
        TransportKind::Bluetooth(target) => {
            Box::new(BluetoothTransport::bluetooth(*target, timing)?)
        }
        TransportKind::Usb(serial) => Box::new(UsbTransport::usb(serial.clone(), timing)),
    })
}

/// The bridge's report at exit (`[ipc] latency_report`, a launch's `bridge-report.json`):
/// the observation-to-command latency's percentiles at the top level, and the link's round
/// trips under `link`.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BridgeReport {
    /// Observation → command latency of the commands received.
    #[serde(flatten)]
    pub latency: LatencyReport,
    /// The link's round trips.
    #[serde(default)]
    pub link: LinkReport,
    /// Commands carried out (keep-alives included).
    #[serde(default)]
    pub commands: u64,
    /// How long the bridge ran (wall time), ms.
    #[serde(default)]
    pub run_ms: u64,
    /// The process's CPU over the commands after the warm-up.
    #[serde(default)]
    pub cpu: Option<tes_runtime::cpu::CpuUse>,
    /// Waiting by `anticipate`: how commands came against their poll windows.
    #[serde(default)]
    pub catches: Option<tes_runtime::channel::Catches>,
    /// The last hop alone: command published → received by the bridge.
    #[serde(default)]
    pub command_hop: LatencyReport,
}

impl BridgeReport {
    /// The report of a run that ended with `summary` after `run_ms`.
    pub fn of(summary: &RunSummary, run_ms: u64) -> Self {
        Self {
            latency: summary.latency,
            link: summary.link.clone(),
            commands: summary.commands,
            run_ms,
            cpu: summary.cpu,
            catches: summary.catches,
            command_hop: summary.command_hop,
        }
    }

    /// Each command's share of the run, and of that the link's, µs: `(per command, on the
    /// link)`; `None` before any command.
    pub fn per_command_us(&self) -> Option<(u64, u64)> {
        (self.commands > 0).then(|| {
            (
                self.run_ms.saturating_mul(1000) / self.commands,
                self.link.busy_us / self.commands,
            )
        })
    }

    /// Reads a report [`BridgeReport::save`] wrote.
    pub fn load(path: &std::path::Path) -> std::io::Result<Self> {
        let text = std::fs::read_to_string(path)?;
        serde_json::from_str(&text).map_err(std::io::Error::other)
    }

    /// Writes the report as one JSON object.
    pub fn save(&self, path: &std::path::Path) -> std::io::Result<()> {
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        std::fs::write(path, text + "\n")
    }
}

/// The exit status of a bridge process stopped by [`ProcessError::LinkDown`]: the launcher
/// takes it as the end of the launch, never as a crash to respawn.
pub const LINK_DOWN_EXIT_STATUS: i32 = 3;

/// Runs the bridge with `cfg` until a signal (if `opts` handles them) or `opts.stop`; brakes
/// the motors on the way out. Fails with [`ProcessError::LinkDown`] when the link to the brick
/// does not come up, or stays down, for longer than `cfg.link_timeout`.
///
/// With `transport = "sim"` the brick runs at `cfg.brick.time_scale`; with a real brick's
/// link (serial, Bluetooth, USB) the time scale is ignored (with a warning) and everything
/// runs in wall time. Fails if the simulated brick's settings are invalid (a `time_scale` that
/// is not finite and > 0 set in code included) or iceoryx2 fails; a link that cannot be
/// opened is retried until `link_timeout_ms`, not an error at once.
pub fn run(cfg: &BridgeConfig, opts: &RunOptions) -> Result<RunSummary, ProcessError> {
    // A serial path that is no terminal can never carry the link: refused before anything
    // starts, not after the link's timeout.
    cfg.transport.check_device()?;
    let sim = matches!(cfg.transport, TransportKind::Sim);
    let clock = ScaledClock::new(if sim { cfg.brick.time_scale } else { 1.0 });
    if !sim && cfg.brick.time_scale != 1.0 {
        tracing::warn!(
            time_scale = cfg.brick.time_scale,
            "brick.time_scale is for the simulated brick; ignored with a real brick's link"
        );
    }
    let transport = transport(cfg, clock)?;
    tracing::info!(
        transport = %transport.describe(),
        seed = cfg.seed,
        time_scale = clock.scale(),
        "bridge starting"
    );
    let mut bridge = Bridge::new(TimedTransport::new(transport), cfg);
    let names = ServiceNames::with_prefix(&cfg.ipc.service_prefix);
    let started = std::time::Instant::now();
    let mut latency = LatencyRecorder::new(cfg.ipc.budget_us, cfg.ipc.warmup_commands);
    if cfg.ipc.latency_windows.is_some() {
        latency = latency.with_windows(cfg.ipc.latency_window);
    }
    let mut summary = ipc::run_with(
        &mut bridge,
        &clock,
        &names,
        opts,
        cfg.ipc.wait_strategy()?,
        &mut latency,
        cfg.link_timeout,
    )?;
    summary.link = bridge.transport_mut().report();
    tracing::info!(%summary, stats = %bridge.stats(), "bridge stopped");
    if let Some(down) = summary.link_down {
        return Err(ProcessError::LinkDown {
            transport: bridge.transport_mut().describe(),
            never_up: down.never_up,
            impossible: down.impossible,
            down_for: down.down_for,
            last_error: bridge
                .last_link_error()
                .unwrap_or("no reply from the brick")
                .to_owned(),
        });
    }
    if let Some(path) = &cfg.ipc.latency_report {
        BridgeReport::of(
            &summary,
            u64::try_from(started.elapsed().as_millis()).unwrap_or(u64::MAX),
        )
        .save(path)
        .map_err(|error| ProcessError::Report {
            path: path.clone(),
            error,
        })?;
    }
    if let Some(path) = &cfg.ipc.latency_windows {
        tes_runtime::latency::LatencyReport::save_windows_csv(latency.windows(), path).map_err(
            |error| ProcessError::Report {
                path: path.clone(),
                error,
            },
        )?;
    }
    Ok(summary)
}
