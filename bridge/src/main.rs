//! `bridge`: the TES actuation process, and a simulated NXT brick server.
//!
//! ```text
//! tes-bridge run [--config FILE] [--time-scale K]      commands in over iceoryx2, NXT telegrams out
//! tes-bridge brick --pty PATH [--seed N] [--config FILE] [--link-delay]
//!                                                   serve the simulated brick on a pseudo-terminal
//! tes-bridge scan [--json]                          the bricks on USB and Bluetooth, or why none
//! ```

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use tes_bridge::brick::SimBrick;
use tes_bridge::clock::{Clock, ScaledClock};
use tes_bridge::config::BridgeConfig;
use tes_bridge::ipc::RunOptions;
use tes_bridge::pty::PtyServer;
use tes_bridge::transport::LinkDelay;

#[derive(Debug, Parser)]
#[command(
    name = "tes-bridge",
    version,
    about = "TES bridge: controller commands to LEGO NXT direct commands"
)]
struct Cli {
    /// On an error, print where it arose (a backtrace) as well as the message.
    #[arg(long, global = true)]
    backtrace: bool,
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Run the bridge process: subscribe to commands, drive the brick, publish motor states.
    Run {
        /// Bridge configuration (TOML); defaults to the simulated brick and the paper's actions.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Run the simulated brick K times faster than the wall clock (overrides the config's
        /// `[brick] time_scale`; ignored by serial transports).
        #[arg(long, value_name = "K")]
        time_scale: Option<f64>,
    },
    /// Serve the simulated brick on a new pseudo-terminal linked at PATH, until SIGINT/SIGTERM.
    Brick {
        /// Where to link the pseudo-terminal's slave device (clients open this path).
        #[arg(long, value_name = "PATH")]
        pty: PathBuf,
        /// Seed of the simulated brick (overrides the config's `seed`).
        #[arg(long)]
        seed: Option<u64>,
        /// Bridge configuration: its `[brick]` table and `[link_delay]` are used.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Delay each reply like a Bluetooth link (≈ 30 ms ± 10 ms unless configured).
        #[arg(long)]
        link_delay: bool,
    },
    /// List the NXTs this machine can reach — on USB, and paired over Bluetooth — with the
    /// `transport` line for each, or say plainly why there is none (no adapter, adapter off,
    /// no permission); exits 1 when no brick is found.
    Scan {
        /// Print the findings as JSON.
        #[arg(long)]
        json: bool,
    },
}

fn load(config: Option<&Path>) -> anyhow::Result<BridgeConfig> {
    match config {
        Some(p) => BridgeConfig::load(p).with_context(|| format!("loading {}", p.display())),
        None => Ok(BridgeConfig::default()),
    }
}

/// Errors are said as `tes` says them: one line, `error: what: why: …`, exit status 1; a
/// backtrace only with `--backtrace` (not whenever `RUST_BACKTRACE` happens to be set).
fn main() -> ExitCode {
    let cli = Cli::parse();
    if cli.backtrace {
        // SAFETY: no other thread exists yet; anyhow reads the variable when an error is
        // made.
        unsafe { std::env::set_var("RUST_LIB_BACKTRACE", "1") };
    } else {
        // SAFETY: as above.
        unsafe { std::env::set_var("RUST_LIB_BACKTRACE", "0") };
    }
    tes_runtime::logging::init("info");
    match execute(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) if cli.backtrace => {
            eprintln!("error: {err:#}\n\n{}", err.backtrace());
            ExitCode::FAILURE
        }
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}

fn execute(command: Cmd) -> anyhow::Result<()> {
    match command {
        Cmd::Run { config, time_scale } => {
            let mut cfg = load(config.as_deref())?;
            if let Some(k) = time_scale {
                cfg = cfg.with_time_scale(k).context("--time-scale")?;
            }
            run(cfg)
        }
        Cmd::Brick {
            pty,
            seed,
            config,
            link_delay,
        } => {
            let mut cfg = load(config.as_deref())?;
            if let Some(s) = seed {
                cfg.seed = s;
            }
            if link_delay && cfg.link_delay.is_none() {
                let d = tes_bridge::config::LinkDelayConfig::default();
                cfg.link_delay = Some((
                    Duration::from_millis(d.mean_ms),
                    Duration::from_millis(d.jitter_ms),
                ));
            }
            brick(&pty, &cfg)
        }
        Cmd::Scan { json } => scan(json),
    }
}

fn scan(json: bool) -> anyhow::Result<()> {
    let found = tes_bridge::scan::scan();
    if json {
        println!("{}", serde_json::to_string_pretty(&found)?);
    } else {
        print!("{found}");
    }
    if found.bricks() == 0 {
        std::process::exit(1);
    }
    Ok(())
}

fn run(cfg: BridgeConfig) -> anyhow::Result<()> {
    match tes_bridge::process::run(&cfg, &RunOptions::process()) {
        Err(e @ tes_bridge::process::ProcessError::LinkDown { .. }) => {
            eprintln!("error: {e}");
            std::process::exit(tes_bridge::process::LINK_DOWN_EXIT_STATUS);
        }
        done => {
            done.context("running the bridge")?;
            Ok(())
        }
    }
}

fn brick(link: &Path, cfg: &BridgeConfig) -> anyhow::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .context("installing the signal handlers")?;
    }
    let mut brick =
        SimBrick::new(cfg.brick.clone(), cfg.seed).context("building the simulated brick")?;
    let server = PtyServer::open(link)
        .with_context(|| format!("serving the brick at {}", link.display()))?;
    // The brick (and its simulated link) run at `[brick] time_scale`, like under `tes-bridge run`.
    let clock = ScaledClock::new(cfg.brick.time_scale);
    let delay = cfg.link_delay.map(|(mean, jitter)| {
        LinkDelay::new(
            clock.real_duration(mean),
            clock.real_duration(jitter),
            cfg.seed,
        )
    });
    tracing::info!(
        link = %link.display(),
        device = %server.slave_path().display(),
        seed = cfg.seed,
        link_delay = %match cfg.link_delay {
            Some((mean, jitter)) => format!("{mean:?} ± {jitter:?}"),
            None => "none".to_owned(),
        },
        time_scale = clock.scale(),
        "simulated NXT brick serving; stop with SIGINT or SIGTERM"
    );
    let stats = server
        .serve(&mut brick, &clock, delay, &stop)
        .context("serving the brick")?;
    tracing::info!(%stats, brick = %brick.stats(), "simulated brick stopped");
    Ok(())
}
