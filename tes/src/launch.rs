//! `tes launch`: perception-sim, controller and bridge as one process group.
//!
//! The group is [`tes_launch`]'s: this module reads the arguments, installs the signal
//! handlers, and observes the supervisor's events — printed as lines ([`mod@print`]) or drawn
//! in the live view ([`tui`]). Each child is this executable again, `tes child ROLE`.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use anyhow::{Context, Result, bail};
use clap::Args;
use tes_launch::event::Verdict;
use tes_launch::{ChildCommand, LaunchFile, Options};
use tes_topics::Role;

mod live;
mod print;
mod tui;

pub(crate) use print::Printer;

/// What `tes launch --print-config` prints.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Format {
    /// A launch file with every key at its default, commented.
    Toml,
    /// The reference page (`docs/config.md`).
    Markdown,
}

/// Arguments of `tes launch`.
#[derive(Debug, Args)]
pub struct LaunchArgs {
    /// Launch file (TOML with `[launch]`, `[perception]`, `[controller]`, `[bridge]` tables);
    /// without one, embedded defaults: arena Env 3, simulated brick, fastest real-time factor,
    /// library in the default data directory.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Episodes to run (overrides `[launch] episodes`).
    #[arg(long)]
    episodes: Option<u32>,
    /// Show the group live in the terminal (processes, episodes, rewards, decision latency,
    /// the robot on the arena map, the last log lines) instead of printing its lines; `q`
    /// stops it.
    #[arg(long)]
    tui: bool,
    /// Print every key of the launch file with its default, meaning and allowed values, and
    /// exit: `toml` (the default) is a launch file `--config` reads back; `markdown` is the
    /// reference page, docs/config.md.
    #[arg(
        long,
        value_name = "FORMAT",
        value_enum,
        num_args = 0..=1,
        require_equals = true,
        default_missing_value = "toml",
        conflicts_with_all = ["config", "episodes", "tui", "record", "foxglove", "ros2", "rosbag", "roles"]
    )]
    print_config: Option<Format>,
    /// Record the run to this MCAP file (overrides `[launch] record`): every observation,
    /// command and motor state, for `tes replay` and viewers such as Foxglove.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Serve the run live to Foxglove over its WebSocket protocol (overrides `[launch]
    /// foxglove`): the arena, the robot moving, its decisions, rewards and logs. ADDR
    /// defaults to 127.0.0.1:8765 (loopback only); another address is said at start.
    #[arg(
        long,
        value_name = "ADDR",
        num_args = 0..=1,
        default_missing_value = tes_viewer::live::DEFAULT_ADDR
    )]
    foxglove: Option<String>,
    /// Publish the run on ROS 2 (sets `[launch] ros2`): /tf, the arena's markers, the path,
    /// decisions, rewards and /rosout, in the domain of ROS_DOMAIN_ID (docs/ros2.md). Needs a
    /// tes built with `--features ros2`.
    #[arg(long)]
    ros2: bool,
    /// Write the run's ROS 2 topics to a rosbag2 bag in this new directory (overrides
    /// `[launch] rosbag`). Needs a tes built with `--features ros2`.
    #[arg(long, value_name = "DIR")]
    rosbag: Option<PathBuf>,
    /// Start only these processes (comma-separated: perception-sim, controller, bridge;
    /// overrides `[launch] roles`); the others run on other hosts, reached over Zenoh
    /// (`[launch.link]`, docs/multi-host.md).
    #[arg(long, value_delimiter = ',', value_name = "ROLE,...")]
    roles: Option<Vec<String>>,
}

/// Runs `tes launch`.
pub fn run(args: &LaunchArgs) -> Result<()> {
    if let Some(format) = args.print_config {
        return print_reference(format);
    }
    let file = launch_file(args)?;
    // Zenoh tells refused connections and messages only in its log: the link's layer picks
    // them out. Log lines themselves only with RUST_LOG (the launcher says what it does),
    // but for the live view's warnings (full, or out of file descriptors).
    tes_runtime::logging::init_with("off,tes_viewer::live=warn", tes_link::refusals::layer());
    let stop = stop_on_signals()?;
    let signalled = signal_received()?;
    let options = Options::new(this_executable()?, stop);
    let verdict = if args.tui {
        live::run(&file, options)?
    } else {
        let mut printer = Printer {
            echo: true,
            ..Printer::default()
        };
        tes_launch::run(&file, options, &mut printer)?
    };
    verdict_to_result(&verdict)?;
    exit_as_signalled(&signalled);
    Ok(())
}

/// The signal (SIGINT, SIGTERM) that stopped the command, once one has: 0 until then.
pub(crate) fn signal_received() -> Result<Arc<AtomicUsize>> {
    let received = Arc::new(AtomicUsize::new(0));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register_usize(signal, received.clone(), signal as usize)
            .context("cannot install the signal handlers")?;
    }
    Ok(received)
}

/// A command that a signal stopped, cleanly, exits as shells expect of one: with status
/// 128 + the signal (130 after Ctrl-C, 143 after SIGTERM), as `tes experiment` does; it
/// returns if no signal came.
pub(crate) fn exit_as_signalled(received: &AtomicUsize) {
    let signal = received.load(Ordering::Relaxed);
    if signal != 0 {
        std::process::exit(128 + i32::try_from(signal).unwrap_or(0));
    }
}

/// The launch file of `args`: the file or the embedded defaults, with the flags applied.
fn launch_file(args: &LaunchArgs) -> Result<LaunchFile> {
    let mut file = match &args.config {
        Some(path) => tes_launch::read_launch_file(path)?,
        None => LaunchFile::default(),
    };
    if let Some(n) = args.episodes {
        if n == 0 {
            bail!("--episodes: must be at least 1; nothing was started");
        }
        file.launch.episodes = n;
    }
    if let Some(path) = &args.record {
        file.launch.record = Some(path.clone());
    }
    if args.ros2 {
        file.launch.ros2 = true;
    }
    if let Some(dir) = &args.rosbag {
        file.launch.rosbag = Some(dir.clone());
    }
    if let Some(addr) = &args.foxglove {
        file.launch.foxglove = Some(addr.clone());
        if let Err(e) = file.launch.foxglove_addr() {
            bail!("--foxglove: {}; nothing was started", e.reason());
        }
    }
    if let Some(names) = &args.roles {
        // Parsed here rather than by clap, so that a bad role is said as every refusal of a
        // launch is: with the flag, and that nothing was started.
        let roles: Result<Vec<Role>, _> = names.iter().map(|n| n.parse::<Role>()).collect();
        file.launch.roles = match roles {
            Ok(roles) => roles,
            Err(e) => bail!("--roles: {e}; nothing was started"),
        };
        // Said by the user, so placed as theirs: a bad role is named with the flag; what the
        // roles bring in (the link's keys) with its key.
        if let Err(e) = tes_launch::file::check_launch(&file.launch) {
            if e.key == "roles" {
                bail!("--roles: {}; nothing was started", e.reason);
            }
            bail!("[launch] {}: {}; nothing was started", e.key, e.reason);
        }
    }
    Ok(file)
}

/// The children are this executable in their role: `tes child ROLE --config FILE`.
pub(crate) fn this_executable() -> Result<ChildCommand> {
    let exe = std::env::current_exe().context("cannot find the tes executable")?;
    Ok(ChildCommand::new(exe).arg("child"))
}

/// A flag raised by Ctrl-C or SIGTERM.
pub(crate) fn stop_on_signals() -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone())
            .context("cannot install the signal handlers")?;
    }
    Ok(stop)
}

/// A failed launch is an error of the command (exit status 1), after its lines were said.
fn verdict_to_result(verdict: &Verdict) -> Result<()> {
    if verdict.success() {
        Ok(())
    } else {
        bail!("a process failed: {}", verdict.failures.join("; "))
    }
}

/// Prints the launch file's reference (`--print-config`).
fn print_reference(format: Format) -> Result<()> {
    use std::io::Write as _;
    let text = match format {
        Format::Toml => tes_launch::reference::render_toml(false)?,
        Format::Markdown => tes_launch::reference::render_markdown()?,
    };
    let mut stdout = std::io::stdout().lock();
    match stdout
        .write_all(text.as_bytes())
        .and_then(|()| stdout.flush())
    {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(e).context("cannot write the reference to stdout")
        }
        _ => Ok(()),
    }
}
