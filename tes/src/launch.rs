//! `tes launch`: perception-sim, controller and bridge as one process group.
//!
//! The three are separate OS processes (this executable re-run in each role, so one build
//! serves all) sharing fixed-size buffers through iceoryx2. The launcher:
//!
//! * reads an optional TOML file (`[launch]`, `[perception]`, `[controller]`, `[bridge]`),
//!   checks every child's settings *before* starting anything (a bad key is reported with its
//!   name and the reason), and writes each child's settings to the run directory;
//! * removes iceoryx2 resources left by crashed runs, then starts the children with a
//!   parent-death signal (SIGTERM), so they die with the launcher even if it is killed;
//! * relays the controller's per-episode lines and final summary;
//! * when a child dies, says which and why, and either stops the others
//!   (`restart = "never"`, the default) or respawns it (`restart = "on-failure"`, at most
//!   `max_restarts` times, cleaning its stale resources first);
//! * on Ctrl-C or SIGTERM — or when perception has run its episodes — stops the children as
//!   ROS 2 launch does: SIGINT, then SIGTERM after `grace_ms`, then SIGKILL after another
//!   `grace_ms`. The controller saves the library on the way out.
//!
//! It exits non-zero if a child failed.

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, ExitStatus, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde::Deserialize;
use tes_bridge::config::BridgeConfig;
use tes_controller::config::{ControllerConfig, default_data_dir};
use tes_perception_sim::process::PerceptionConfig;
use tes_runtime::channel::{self, WaitStrategy};

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
}

/// What to do when a child dies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Restart {
    /// Stop the others and exit non-zero.
    #[default]
    Never,
    /// Respawn it (up to `max_restarts` times).
    OnFailure,
}

/// The `[launch]` table.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LaunchSection {
    /// Episodes perception runs before the group stops (default 20).
    pub episodes: u32,
    /// The arena: 1, 2 or 3 (default 3, the paper's test arena).
    pub arena: u8,
    /// Real-time factor: 1.0 = physical time (the paper's 200 ms settle), 0 = as fast as
    /// possible (default).
    pub real_time_factor: f64,
    /// How every process waits: `block` (default), `spin`, `spin-then-block[:<µs>]`.
    pub wait: String,
    /// `never` (default) or `on-failure`.
    pub restart: Restart,
    /// Respawns allowed per child with `on-failure` (default 3).
    pub max_restarts: u32,
    /// Grace period of each shutdown step, ms (default 3000).
    pub grace_ms: u64,
    /// Prefix of every iceoryx2 service (default none; set one per group to run several
    /// groups side by side).
    pub service_prefix: String,
    /// Where each child's settings are written (default: `run` in the data directory).
    pub run_dir: Option<PathBuf>,
    /// Seed of the world and the agent (default 1).
    pub seed: u64,
}

impl Default for LaunchSection {
    fn default() -> Self {
        Self {
            episodes: 20,
            arena: 3,
            real_time_factor: 0.0,
            wait: "block".into(),
            restart: Restart::Never,
            max_restarts: 3,
            grace_ms: 3000,
            service_prefix: String::new(),
            run_dir: None,
            seed: 1,
        }
    }
}

/// A whole launch file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct LaunchFile {
    pub(crate) launch: LaunchSection,
    pub(crate) perception: toml::Table,
    pub(crate) controller: toml::Table,
    pub(crate) bridge: toml::Table,
}

/// The simulated brick's speed-up at real-time factor 0 ("as fast as possible"): motor
/// motion runs this many times faster than physical time.
const FASTEST_TIME_SCALE: f64 = 200.0;

/// The roles this executable plays as a child.
pub const ROLES: [&str; 3] = ["bridge", "controller", "perception-sim"];

/// One child's launch recipe.
pub(crate) struct ChildSpec {
    pub(crate) role: &'static str,
    pub(crate) config: PathBuf,
}

/// A running (or finished) child.
pub(crate) struct Running {
    pub(crate) spec: ChildSpec,
    pub(crate) child: Child,
    pub(crate) restarts: u32,
    pub(crate) status: Option<ExitStatus>,
}

/// How a group run went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct GroupOutcome {
    /// Episodes the controller reported.
    pub(crate) episodes: u32,
}

/// Runs `tes launch`.
pub fn run(args: &LaunchArgs) -> Result<()> {
    let mut file = match &args.config {
        Some(path) => read_launch_file(path)?,
        None => LaunchFile::default(),
    };
    if let Some(n) = args.episodes {
        file.launch.episodes = n;
    }
    let specs = match &args.config {
        Some(path) => prepare(&file).map_err(|e| LaunchFileError {
            path: path.clone(),
            problem: LaunchFileProblem::Settings(e),
        })?,
        None => prepare(&file).context(NOTHING_STARTED)?,
    };
    run_group(&file, specs, true).map(|_| ())
}

const NOTHING_STARTED: &str = "the launch settings are invalid; nothing was started";

/// A launch file that cannot be used; when one is refused, nothing is started.
#[derive(Debug)]
pub(crate) struct LaunchFileError {
    /// The file.
    pub(crate) path: PathBuf,
    /// What is wrong with it.
    pub(crate) problem: LaunchFileProblem,
}

/// What is wrong with a launch file.
#[derive(Debug)]
pub(crate) enum LaunchFileProblem {
    /// It cannot be read: missing, unreadable, or not UTF-8 text.
    Read(std::io::Error),
    /// It does not parse: not TOML, or a key that is unknown, repeated or of the wrong type.
    Parse {
        /// 1-based line of the offending text in the file.
        line: usize,
        /// 1-based column (in characters).
        column: usize,
        /// The key the error is about (`[launch] episodes`), when the parser got that far.
        key: Option<String>,
        /// The parser's reason.
        reason: String,
    },
    /// It parses, but a value is out of range, the settings contradict each other, or the
    /// children's settings cannot be written to the run directory.
    Settings(anyhow::Error),
}

impl std::fmt::Display for LaunchFileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let path = self.path.display();
        match &self.problem {
            LaunchFileProblem::Read(error) => {
                write!(f, "cannot read the launch file {path}: {error}")?;
            }
            LaunchFileProblem::Parse {
                line,
                column,
                key: Some(key),
                reason,
            } => write!(f, "launch file {path}:{line}:{column}: {key}: {reason}")?,
            LaunchFileProblem::Parse {
                line,
                column,
                key: None,
                reason,
            } => write!(
                f,
                "launch file {path}:{line}:{column}: not valid TOML: {reason}"
            )?,
            LaunchFileProblem::Settings(error) => write!(f, "launch file {path}: {error:#}")?,
        }
        f.write_str("; nothing was started")
    }
}

impl std::error::Error for LaunchFileError {}

/// The `[controller]` and `[perception]` tables as those processes read them: checked
/// against the launch file's own text, so that an unknown or mistyped key is reported at its
/// line. ([`prepare`] checks them again, merged with the launch-wide settings, with their
/// ranges.) The bridge's table is checked only by [`prepare`].
#[derive(Deserialize)]
struct ChildTables {
    #[serde(default, rename = "controller")]
    _controller: Option<ControllerConfig>,
    #[serde(default, rename = "perception")]
    _perception: Option<PerceptionConfig>,
}

/// Reads and parses a launch file; a problem is reported with the file, the line and the key.
pub(crate) fn read_launch_file(path: &Path) -> Result<LaunchFile, LaunchFileError> {
    let refuse = |problem| LaunchFileError {
        path: path.to_owned(),
        problem,
    };
    let text = std::fs::read_to_string(path).map_err(|e| refuse(LaunchFileProblem::Read(e)))?;
    let parse_error = |e: toml::de::Error| refuse(parse_problem(&text, &e));
    let file: LaunchFile = toml::from_str(&text).map_err(parse_error)?;
    toml::from_str::<ChildTables>(&text).map_err(parse_error)?;
    Ok(file)
}

/// Where in `text` the parser's `error` is, and which key it is about.
fn parse_problem(text: &str, error: &toml::de::Error) -> LaunchFileProblem {
    let at = error.span().map_or(0, |s| s.start);
    let before = text.get(..at).unwrap_or("");
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    let key = toml::de::DeTable::parse(text).ok().and_then(|doc| {
        let mut path = Vec::new();
        key_at(doc.get_ref(), at, &mut path).then(|| match path.split_first() {
            Some((table, rest)) if !rest.is_empty() => format!("[{table}] {}", rest.join(".")),
            _ => path.join("."),
        })
    });
    LaunchFileProblem::Parse {
        line,
        column,
        key,
        reason: error.message().to_owned(),
    }
}

/// The path of the innermost key of `table` whose name or value holds byte `at`.
fn key_at(table: &toml::de::DeTable<'_>, at: usize, path: &mut Vec<String>) -> bool {
    for (key, value) in table.iter() {
        path.push(key.get_ref().to_string());
        if let toml::de::DeValue::Table(inner) = value.get_ref()
            && key_at(inner, at, path)
        {
            return true;
        }
        if key.span().contains(&at) || value.span().contains(&at) {
            return true;
        }
        path.pop();
    }
    false
}

/// Runs the group `file` describes until perception finishes, a child fails (or exhausts its
/// restarts) or a signal; `echo` prints the controller's lines and the launcher's notes.
pub(crate) fn run_file(file: &LaunchFile, echo: bool) -> Result<GroupOutcome> {
    let specs = prepare(file).context(NOTHING_STARTED)?;
    run_group(file, specs, echo)
}

/// [`run_file`] with the children already prepared.
fn run_group(file: &LaunchFile, specs: Vec<ChildSpec>, echo: bool) -> Result<GroupOutcome> {
    let launch = &file.launch;
    let note = |text: String| {
        if echo {
            eprintln!("{text}");
        }
    };

    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone())
            .context("cannot install the signal handlers")?;
    }
    match channel::clean_stale_resources() {
        Ok(0) => {}
        Ok(n) => note(format!(
            "launch: removed the stale iceoryx2 resources of {n} dead processes"
        )),
        Err(e) => eprintln!("launch: warning: {e}"),
    }
    note(format!(
        "launch: arena Env {}, {} episodes, real-time factor {}, wait {}, restart {:?}",
        launch.arena, launch.episodes, launch.real_time_factor, launch.wait, launch.restart
    ));
    let (lines_tx, lines) = mpsc::channel::<String>();
    let mut children = Vec::new();
    for spec in specs {
        let child = spawn(&spec, &lines_tx)?;
        children.push(Running {
            spec,
            child,
            restarts: 0,
            status: None,
        });
    }
    let grace = Duration::from_millis(launch.grace_ms);
    let mut failure: Option<String> = None;
    let mut episodes = 0u32;
    'supervise: loop {
        for line in lines.try_iter() {
            if line.starts_with("episode ") {
                episodes += 1;
            }
            if echo {
                println!("{line}");
            }
        }
        if stop.load(Ordering::Relaxed) {
            eprintln!("launch: stop requested; stopping the group");
            break;
        }
        for i in 0..children.len() {
            let Some(status) = children[i]
                .child
                .try_wait()
                .context("cannot poll a child")?
            else {
                continue;
            };
            let role = children[i].spec.role;
            if role == "perception-sim" && status.success() {
                note("launch: perception-sim finished its episodes; stopping the group".into());
                children[i].status = Some(status);
                break 'supervise;
            }
            let why = describe(status);
            let may_restart = launch.restart == Restart::OnFailure
                && !status.success()
                && children[i].restarts < launch.max_restarts;
            if !may_restart {
                eprintln!("launch: {role} {why}; stopping the others");
                children[i].status = Some(status);
                failure = Some(format!("{role} {why}"));
                break 'supervise;
            }
            children[i].restarts += 1;
            eprintln!(
                "launch: {role} {why}; respawning it (restart {}/{})",
                children[i].restarts, launch.max_restarts
            );
            if let Err(e) = channel::clean_stale_resources() {
                eprintln!("launch: warning: {e}");
            }
            children[i].child = spawn(&children[i].spec, &lines_tx)?;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    shutdown(&mut children, grace);
    // Every child has exited; take what they printed last (the controller reports its last
    // episode and its summary on the way out) until each one's output is closed, or 2 s.
    drop(lines_tx);
    let deadline = Instant::now() + Duration::from_secs(2);
    while let Ok(line) = lines.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        if line.starts_with("episode ") {
            episodes += 1;
        }
        if echo {
            println!("{line}");
        }
    }
    let mut failed: Vec<String> = failure.into_iter().collect();
    for c in &children {
        match c.status {
            Some(s) if !s.success() && !stopped_by_us(s) => {
                failed.push(format!("{} {}", c.spec.role, describe(s)));
            }
            _ => {}
        }
    }
    failed.dedup();
    if echo {
        println!(
            "launch: {episodes} episodes; {}",
            if failed.is_empty() {
                "all processes stopped cleanly".to_owned()
            } else {
                format!("failed: {}", failed.join("; "))
            }
        );
    }
    if !failed.is_empty() {
        bail!("a process failed: {}", failed.join("; "));
    }
    Ok(GroupOutcome { episodes })
}

/// Checks every child's settings and writes them to the run directory.
fn prepare(file: &LaunchFile) -> Result<Vec<ChildSpec>> {
    let l = &file.launch;
    let wait: WaitStrategy = l
        .wait
        .parse()
        .map_err(|e| anyhow::anyhow!("[launch] wait: {e}"))?;
    if !(1..=3).contains(&l.arena) {
        bail!("[launch] arena: must be 1, 2 or 3, got {}", l.arena);
    }
    if !(l.real_time_factor.is_finite() && l.real_time_factor >= 0.0) {
        bail!("[launch] real_time_factor: must be a finite number >= 0");
    }
    if l.episodes == 0 {
        bail!("[launch] episodes: must be at least 1");
    }
    let prefix = l.service_prefix.clone();
    let run_dir = l
        .run_dir
        .clone()
        .unwrap_or_else(|| default_data_dir().join("run"));
    std::fs::create_dir_all(&run_dir)
        .with_context(|| format!("cannot create the run directory {}", run_dir.display()))?;

    // Launch-wide settings go into each table unless the table sets them itself.
    let with = |table: &toml::Table, extra: &[(&str, toml::Value)]| {
        let mut t = table.clone();
        for (k, v) in extra {
            t.entry((*k).to_owned()).or_insert_with(|| v.clone());
        }
        t
    };
    let s = |v: &str| toml::Value::String(v.to_owned());
    let seed = toml::Value::Integer(i64::try_from(l.seed).unwrap_or(i64::MAX));
    let perception = with(
        &file.perception,
        &[
            ("arena", toml::Value::Integer(i64::from(l.arena))),
            ("episodes", toml::Value::Integer(i64::from(l.episodes))),
            ("real_time_factor", toml::Value::Float(l.real_time_factor)),
            ("wait", s(&wait.to_string())),
            ("service_prefix", s(&prefix)),
            ("seed", seed.clone()),
        ],
    );
    let controller = with(
        &file.controller,
        &[
            ("wait", s(&wait.to_string())),
            ("service_prefix", s(&prefix)),
            ("seed", seed.clone()),
        ],
    );
    let mut bridge = file.bridge.clone();
    bridge
        .entry("seed".to_owned())
        .or_insert_with(|| seed.clone());
    bridge
        .entry("use_command_degrees".to_owned())
        .or_insert(toml::Value::Boolean(true));
    let ipc = bridge
        .entry("ipc".to_owned())
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(t) = ipc.as_table_mut() {
        t.entry("service_prefix".to_owned())
            .or_insert_with(|| s(&prefix));
        t.entry("wait".to_owned())
            .or_insert_with(|| s(&wait.to_string()));
    }
    let simulated = bridge
        .get("transport")
        .and_then(toml::Value::as_str)
        .is_none_or(|t| t == "sim");
    let time_scale = if l.real_time_factor == 0.0 {
        FASTEST_TIME_SCALE
    } else {
        1.0 / l.real_time_factor
    };
    let brick = bridge
        .entry("brick".to_owned())
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(t) = brick.as_table_mut() {
        t.entry("time_scale".to_owned())
            .or_insert(toml::Value::Float(time_scale));
    }
    // The watchdog deadline is in brick time: at a speed-up, give the wall clock the usual
    // second, so a descheduled bridge on a busy machine does not brake a healthy run.
    let watchdog = bridge
        .entry("watchdog".to_owned())
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(t) = watchdog.as_table_mut() {
        // A real brick (serial transport) runs in physical time whatever the scale.
        let scale = if simulated { time_scale.max(1.0) } else { 1.0 };
        let ms = (1000.0 * scale).round() as i64;
        t.entry("deadline_ms".to_owned())
            .or_insert(toml::Value::Integer(ms));
    }

    let texts = [
        ("bridge", toml::to_string(&bridge)?),
        ("controller", toml::to_string(&controller)?),
        ("perception-sim", toml::to_string(&perception)?),
    ];
    // Every child's settings are checked here, so a bad key stops the launch before any
    // process starts.
    let bridge_cfg =
        BridgeConfig::from_toml_str(&texts[0].1).map_err(|e| anyhow::anyhow!("[bridge] {e}"))?;
    let controller_cfg = ControllerConfig::from_toml(&texts[1].1)
        .map_err(|e| anyhow::anyhow!("[controller] {e}"))?;
    // The watchdog's deadline is brick time; the keep-alives are wall time.
    let wall_scale = if simulated {
        bridge_cfg.brick.time_scale
    } else {
        1.0
    };
    let deadline_wall_ms = bridge_cfg.watchdog_deadline.as_secs_f64() * 1000.0 / wall_scale;
    if controller_cfg.keepalive_ms as f64 * 2.0 > deadline_wall_ms {
        anyhow::bail!(
            "[controller] keepalive_ms = {} must be at most half the bridge's watchdog deadline \
             ({deadline_wall_ms:.0} ms of wall time: watchdog.deadline_ms / brick.time_scale), \
             or the watchdog brakes moves of a live controller",
            controller_cfg.keepalive_ms
        );
    }
    PerceptionConfig::from_toml(&texts[2].1).map_err(|e| anyhow::anyhow!("[perception] {e}"))?;
    let mut specs = Vec::new();
    for (role, text) in texts {
        let path = run_dir.join(format!("{role}.toml"));
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
        let role = ROLES
            .into_iter()
            .find(|r| *r == role)
            .unwrap_or("controller");
        specs.push(ChildSpec { role, config: path });
    }
    Ok(specs)
}

/// Starts one child: this executable in the child's role, dying with the launcher.
pub(crate) fn spawn(spec: &ChildSpec, lines: &mpsc::Sender<String>) -> Result<Child> {
    let exe = std::env::current_exe().context("cannot find the tes executable")?;
    let mut cmd = Command::new(exe);
    cmd.arg("child")
        .arg(spec.role)
        .arg("--config")
        .arg(&spec.config)
        .stdin(Stdio::null())
        .stdout(Stdio::piped());
    // SAFETY: `pre_exec` runs in the forked child before exec; prctl(PR_SET_PDEATHSIG) is
    // async-signal-safe and touches no memory of the parent.
    unsafe {
        cmd.pre_exec(|| {
            nix::sys::prctl::set_pdeathsig(Signal::SIGTERM).map_err(std::io::Error::from)
        });
    }
    let mut child = cmd
        .spawn()
        .with_context(|| format!("cannot start {}", spec.role))?;
    if let Some(out) = child.stdout.take() {
        relay(out, lines.clone());
    }
    Ok(child)
}

/// Forwards a child's stdout, line by line, to the launcher.
fn relay(out: ChildStdout, lines: mpsc::Sender<String>) {
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines() {
            let Ok(line) = line else { break };
            if lines.send(line).is_err() {
                break;
            }
        }
    });
}

/// SIGINT, then SIGTERM after `grace`, then SIGKILL after `grace`; waits for every child.
pub(crate) fn shutdown(children: &mut [Running], grace: Duration) {
    for signal in [Signal::SIGINT, Signal::SIGTERM, Signal::SIGKILL] {
        let mut any = false;
        for c in children.iter_mut() {
            if c.status.is_none() {
                if let Ok(Some(s)) = c.child.try_wait() {
                    c.status = Some(s);
                    continue;
                }
                let pid = Pid::from_raw(c.child.id() as i32);
                if kill(pid, signal).is_ok() {
                    any = true;
                }
            }
        }
        if !any {
            break;
        }
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            let mut alive = false;
            for c in children.iter_mut() {
                if c.status.is_none() {
                    match c.child.try_wait() {
                        Ok(Some(s)) => c.status = Some(s),
                        _ => alive = true,
                    }
                }
            }
            if !alive {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        for c in children.iter() {
            if c.status.is_none() && signal != Signal::SIGKILL {
                eprintln!(
                    "launch: {} did not stop within {grace:?} of {signal}; escalating",
                    c.spec.role
                );
            }
        }
    }
    for c in children.iter_mut() {
        if c.status.is_none() {
            c.status = c.child.wait().ok();
        }
    }
}

/// Whether `status` is an exit the shutdown itself caused (SIGINT/SIGTERM handled by a
/// child that then exited by that signal).
fn stopped_by_us(status: ExitStatus) -> bool {
    use std::os::unix::process::ExitStatusExt;
    matches!(status.signal(), Some(s) if s == Signal::SIGINT as i32 || s == Signal::SIGTERM as i32)
}

/// "exited with status 3" / "was killed by SIGKILL".
pub(crate) fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(code), _) => format!("exited with status {code}"),
        (None, Some(sig)) => match Signal::try_from(sig) {
            Ok(s) => format!("was killed by {s}"),
            Err(_) => format!("was killed by signal {sig}"),
        },
        _ => "ended".to_owned(),
    }
}

/// The child roles' entry points (`tes child ROLE --config FILE`).
pub fn run_child(role: &str, config: &Path) -> Result<()> {
    let text = std::fs::read_to_string(config)
        .with_context(|| format!("cannot read {}", config.display()))?;
    match role {
        "controller" => {
            let cfg = ControllerConfig::from_toml(&text)?;
            let stop = tes_runtime::signals::stop_on_signals()?;
            let summary = tes_controller::process::run_to_end(&cfg, &stop)?;
            if summary.failed_saves > 0 {
                bail!("{} library saves failed", summary.failed_saves);
            }
            Ok(())
        }
        "perception-sim" => {
            let cfg = PerceptionConfig::from_toml(&text)?;
            let stop = tes_runtime::signals::stop_on_signals()?;
            tes_perception_sim::process::run(&cfg, &stop)?;
            Ok(())
        }
        "bridge" => {
            let cfg = BridgeConfig::from_toml_str(&text)?;
            let stop = tes_runtime::signals::stop_on_signals()?;
            let opts = tes_bridge::ipc::RunOptions {
                handle_signals: false,
                stop: Some(stop),
            };
            tes_bridge::process::run(&cfg, &opts)?;
            Ok(())
        }
        relay if tes_bench::relay::ROLES.contains(&relay) => {
            let cfg = tes_bench::relay::RelayConfig::from_toml(&text)?;
            let stop = tes_runtime::signals::stop_on_signals()?;
            tes_bench::relay::run(relay, &cfg, &stop)?;
            Ok(())
        }
        other => bail!("unknown role {other:?} (expected one of {ROLES:?})"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Prepares the children of a launch file with `extra` after its `[launch]` table; the
    /// directory holds the children's settings files.
    fn prepared(extra: &str) -> (tempfile::TempDir, Result<Vec<ChildSpec>>) {
        let dir = tempfile::tempdir().expect("temp dir");
        let text = format!("[launch]\nrun_dir = \"{}\"\n{extra}", dir.path().display());
        let file: LaunchFile = toml::from_str(&text).expect("a launch file");
        let specs = prepare(&file);
        (dir, specs)
    }

    fn bridge_settings(dir: &tempfile::TempDir) -> BridgeConfig {
        let text = std::fs::read_to_string(dir.path().join("bridge.toml")).expect("bridge.toml");
        BridgeConfig::from_toml_str(&text).expect("valid bridge settings")
    }

    #[test]
    fn keep_alives_must_come_well_within_the_watchdog_deadline() {
        let (_, ok) = prepared("");
        assert!(ok.is_ok());
        let (_, off) = prepared("[controller]\nkeepalive_ms = 0\n");
        assert!(off.is_ok());
        let (_, bad) = prepared("[controller]\nkeepalive_ms = 600\n");
        let err = bad.err().expect("refused").to_string();
        assert!(
            err.contains("keepalive_ms = 600") && err.contains("1000 ms of wall time"),
            "{err}"
        );
    }

    #[test]
    fn the_watchdog_deadline_follows_the_simulated_brick_but_not_a_real_one() {
        // As fast as possible: the simulated brick runs 200x, so its deadline is 200 s of brick
        // time, one second of wall time.
        let (dir, specs) = prepared("");
        assert!(specs.is_ok());
        let sim = bridge_settings(&dir);
        assert_eq!(sim.watchdog_deadline, Duration::from_secs(200));
        // A real NXT lives in physical time whatever the real-time factor.
        let (dir, specs) = prepared("[bridge]\ntransport = \"serial:/dev/rfcomm0\"\n");
        assert!(specs.is_ok());
        let real = bridge_settings(&dir);
        assert_eq!(real.watchdog_deadline, Duration::from_secs(1));
    }
}
