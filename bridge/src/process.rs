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

use tes_runtime::latency::LatencyRecorder;
use thiserror::Error;

use crate::brick::{BrickConfigError, SimBrick};
use crate::bridge::Bridge;
use crate::clock::{Clock, ScaledClock};
use crate::config::{BridgeConfig, TransportKind};
use crate::ipc::{self, IpcError, RunOptions, RunSummary, ServiceNames};
use crate::transport::{DelayedTransport, LinkDelay, SerialTransport, SimTransport, Transport};

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
        "the link to the brick ({transport}) {}: {last_error}",
        if *never_up { format!("did not come up within {:.1} s", down_for.as_secs_f64()) }
        else { format!("has been down for {:.1} s", down_for.as_secs_f64()) }
    )]
    LinkDown {
        /// The transport, as configured.
        transport: String,
        /// Whether it never came up.
        never_up: bool,
        /// How long it was down.
        down_for: std::time::Duration,
        /// The last failure.
        last_error: String,
    },
    /// The latency report could not be written.
    #[error("cannot write the latency report {}: {error}", path.display())]
    Report {
        /// The report file.
        path: std::path::PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

/// The exit status of a bridge process stopped by [`ProcessError::LinkDown`]: the launcher
/// takes it as the end of the launch, never as a crash to respawn.
pub const LINK_DOWN_EXIT_STATUS: i32 = 3;

/// Runs the bridge with `cfg` until a signal (if `opts` handles them) or `opts.stop`; brakes
/// the motors on the way out. Fails with [`ProcessError::LinkDown`] when the link to the brick
/// does not come up, or stays down, for longer than `cfg.link_timeout`.
///
/// With `transport = "sim"` the brick runs at `cfg.brick.time_scale`; with a serial transport
/// the time scale is ignored (with a warning) and everything runs in wall time. Fails if the
/// simulated brick's settings are invalid (a `time_scale` that is not finite and > 0 set in
/// code included) or iceoryx2 fails; a serial device that cannot be opened is retried, not
/// an error.
pub fn run(cfg: &BridgeConfig, opts: &RunOptions) -> Result<RunSummary, ProcessError> {
    let sim = matches!(cfg.transport, TransportKind::Sim);
    let clock = ScaledClock::new(if sim { cfg.brick.time_scale } else { 1.0 });
    if !sim && cfg.brick.time_scale != 1.0 {
        tracing::warn!(
            time_scale = cfg.brick.time_scale,
            "brick.time_scale is for the simulated brick; ignored with a serial transport"
        );
    }
    let transport: Box<dyn Transport> = match &cfg.transport {
        TransportKind::Sim => {
            let brick = SimBrick::new(cfg.brick.clone(), cfg.seed)?;
            let sim = SimTransport::new(brick, clock);
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
        TransportKind::Serial(path) => {
            if cfg.link_delay.is_some() {
                tracing::warn!(
                    "link_delay is for the simulated brick; ignored with a serial transport"
                );
            }
            Box::new(SerialTransport::new(cfg.serial_config(path)))
        }
    };
    tracing::info!(
        transport = %transport.describe(),
        seed = cfg.seed,
        time_scale = clock.scale(),
        "bridge starting"
    );
    let mut bridge = Bridge::new(transport, cfg);
    let names = ServiceNames::with_prefix(&cfg.ipc.service_prefix);
    let mut latency = LatencyRecorder::new(cfg.ipc.budget_us, cfg.ipc.warmup_commands);
    if cfg.ipc.latency_windows.is_some() {
        latency = latency.with_windows(cfg.ipc.latency_window);
    }
    let summary = ipc::run_with(
        &mut bridge,
        &clock,
        &names,
        opts,
        cfg.ipc.wait_strategy()?,
        &mut latency,
        cfg.link_timeout,
    )?;
    tracing::info!(%summary, stats = %bridge.stats(), "bridge stopped");
    if let Some(down) = summary.link_down {
        return Err(ProcessError::LinkDown {
            transport: bridge.transport_mut().describe(),
            never_up: down.never_up,
            down_for: down.down_for,
            last_error: bridge
                .last_link_error()
                .unwrap_or("no reply from the brick")
                .to_owned(),
        });
    }
    if let Some(path) = &cfg.ipc.latency_report {
        summary
            .latency
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
