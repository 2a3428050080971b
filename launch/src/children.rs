//! The group's child processes: how one is started (the program and arguments are the
//! caller's), how the group is stopped, and how an exit is told.

use std::ffi::OsString;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use tes_topics::Role;

use crate::logs;

/// How to start a child: a program and the arguments before the role, to which the
/// supervisor adds `ROLE --config FILE`. `tes` itself is `ChildCommand::new(tes).arg("child")`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChildCommand {
    /// The program.
    pub program: PathBuf,
    /// Its arguments before the role.
    pub args: Vec<OsString>,
}

impl ChildCommand {
    /// `program` with no arguments before the role.
    pub fn new(program: impl Into<PathBuf>) -> Self {
        Self {
            program: program.into(),
            args: Vec::new(),
        }
    }

    /// Adds an argument before the role.
    pub fn arg(mut self, arg: impl Into<OsString>) -> Self {
        self.args.push(arg.into());
        self
    }

    /// The command line of one child: `PROGRAM ARGS… ROLE --config FILE`.
    fn command(&self, role: &str, config: &Path) -> Command {
        let mut cmd = Command::new(&self.program);
        cmd.args(&self.args).arg(role).arg("--config").arg(config);
        cmd
    }
}

/// One child's launch recipe: its role and its settings file (in the run directory).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChildSpec {
    /// The role it plays.
    pub role: Role,
    /// Its settings file.
    pub config: PathBuf,
}

impl ChildSpec {
    /// The run directory its settings are in (its output goes there too).
    pub fn run_dir(&self) -> PathBuf {
        self.config
            .parent()
            .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
    }
}

/// A started process and how it ended, once it has.
#[derive(Debug)]
pub struct Process {
    /// What it is, as messages name it (a role's name).
    pub name: String,
    /// The process.
    pub child: Child,
    /// How it ended, once it has.
    pub status: Option<ExitStatus>,
}

impl Process {
    /// The process `child`, called `name`, running.
    pub fn new(name: impl Into<String>, child: Child) -> Self {
        Self {
            name: name.into(),
            child,
            status: None,
        }
    }
}

/// A running (or finished) child of the group.
#[derive(Debug)]
pub struct Running {
    /// What it was started from.
    pub spec: ChildSpec,
    /// The process.
    pub process: Process,
    /// Respawns so far.
    pub restarts: u32,
}

/// A child that cannot be started.
#[derive(Debug, thiserror::Error)]
#[error("cannot start {what}: {cause}")]
pub struct SpawnError {
    /// What (a role's name).
    pub what: String,
    /// Why, in words ([`tes_runtime::cause::explain`]).
    pub cause: String,
}

/// Starts one child with `command` in the role of `spec`, dying with this process (a
/// parent-death signal, SIGTERM); its standard output and error go to its files in the run
/// directory (see [`logs`]).
pub fn spawn(command: &ChildCommand, spec: &ChildSpec) -> Result<Child, SpawnError> {
    spawn_as(command, spec.role.name(), &spec.config)
}

/// The environment variable a respawned child finds set to `1`: it goes on with the run
/// its predecessor started (perception continues the episode numbers and budget) instead
/// of starting one.
pub const RESUME_ENV: &str = "TES_RESUME";

/// Starts a child again in the role of `spec` after it died: [`spawn`] with [`RESUME_ENV`]
/// set.
pub fn respawn(command: &ChildCommand, spec: &ChildSpec) -> Result<Child, SpawnError> {
    spawn_with(command, spec.role.name(), &spec.config, true)
}

/// Starts `command` as `NAME --config CONFIG`, dying with this process, its output in
/// `NAME.out` and `NAME.log` beside `config`: a child of the group ([`spawn`]) or any other
/// process a harness starts the same way.
pub fn spawn_as(command: &ChildCommand, name: &str, config: &Path) -> Result<Child, SpawnError> {
    spawn_with(command, name, config, false)
}

fn spawn_with(
    command: &ChildCommand,
    name: &str,
    config: &Path,
    resume: bool,
) -> Result<Child, SpawnError> {
    let failed = |e: &std::io::Error| SpawnError {
        what: name.to_owned(),
        cause: tes_runtime::cause::explain(e),
    };
    let dir = config.parent().unwrap_or(Path::new("."));
    let (out, log) = logs::open(dir, name).map_err(|e| failed(&e.source))?;
    let mut cmd = command.command(name, config);
    cmd.stdin(Stdio::null())
        .stdout(Stdio::from(out))
        .stderr(Stdio::from(log));
    if resume {
        cmd.env(RESUME_ENV, "1");
    } else {
        cmd.env_remove(RESUME_ENV);
    }
    die_with_parent(&mut cmd);
    cmd.spawn().map_err(|e| failed(&e))
}

/// Has the child of `cmd` receive SIGTERM when this process dies, however it dies — also
/// when it dies between the fork and the child's `prctl`, which no signal would then tell the
/// child: the child checks that its parent is still this process and does not start if not.
pub fn die_with_parent(cmd: &mut Command) {
    let parent = nix::unistd::getpid();
    // SAFETY: `pre_exec` runs in the forked child before exec; prctl(PR_SET_PDEATHSIG) and
    // getppid are async-signal-safe and touch no memory of the parent.
    unsafe {
        cmd.pre_exec(move || {
            nix::sys::prctl::set_pdeathsig(Signal::SIGTERM).map_err(std::io::Error::from)?;
            if nix::unistd::getppid() != parent {
                return Err(std::io::Error::other(
                    "the launcher died while starting this process",
                ));
            }
            Ok(())
        });
    }
}

/// A child that had to be sent a harder signal: it did not stop within `grace` of `signal`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Escalation {
    /// The process.
    pub process: String,
    /// The signal it ignored, by name.
    pub signal: &'static str,
    /// How long it had.
    pub grace: Duration,
}

/// How long the launcher waits, beyond its grace, for a child that is still saving what the
/// run learned (the controller's final library save) before it sends SIGKILL. A save takes
/// well under a second at normal priority; the bound only keeps a hung child from holding
/// the launcher forever.
pub const SAVE_PATIENCE: Duration = Duration::from_secs(60);

/// A child the shutdown waited for while it saved, before SIGKILL.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SaveWait {
    /// The process.
    pub process: String,
    /// How long it was waited for.
    pub waited: Duration,
    /// The most it would have been waited for ([`SAVE_PATIENCE`]).
    pub bound: Duration,
    /// Whether it was done saving within the bound (false: it was killed).
    pub done: bool,
}

/// What stopping the children took beyond SIGINT.
#[derive(Debug, Default)]
pub struct Shutdown {
    /// The children that needed a harder signal.
    pub escalations: Vec<Escalation>,
    /// The children waited for while they saved, before SIGKILL.
    pub save_waits: Vec<SaveWait>,
}

/// Stops `children` as ROS 2 launch does: SIGINT, then SIGTERM after `grace`, then SIGKILL
/// after `grace`; waits for every child. Returns the children that needed a harder signal.
pub fn shutdown(children: &mut [&mut Process], grace: Duration) -> Vec<Escalation> {
    shutdown_saving(children, grace, &|_| false).escalations
}

/// [`shutdown`], but a child that `saving` says is still saving is given up to
/// [`SAVE_PATIENCE`] more before SIGKILL (a kill then would lose what the run learned).
pub fn shutdown_saving(
    children: &mut [&mut Process],
    grace: Duration,
    saving: &dyn Fn(&Process) -> bool,
) -> Shutdown {
    let mut shutdown = Shutdown::default();
    for signal in [Signal::SIGINT, Signal::SIGTERM, Signal::SIGKILL] {
        if signal == Signal::SIGKILL {
            shutdown.save_waits = wait_for_saves(children, saving, SAVE_PATIENCE);
        }
        if !signal_the_living(children, signal) {
            break;
        }
        if wait_for_all(children, grace) {
            return shutdown;
        }
        if signal != Signal::SIGKILL {
            shutdown
                .escalations
                .extend(
                    children
                        .iter()
                        .filter(|c| c.status.is_none())
                        .map(|c| Escalation {
                            process: c.name.clone(),
                            signal: signal.as_str(),
                            grace,
                        }),
                );
        }
    }
    for c in children.iter_mut().filter(|c| c.status.is_none()) {
        c.status = c.child.wait().ok();
    }
    shutdown
}

/// Waits, up to `bound`, for the living children that `saving` says are saving to end (or
/// to stop saving); one [`SaveWait`] per child waited for.
fn wait_for_saves(
    children: &mut [&mut Process],
    saving: &dyn Fn(&Process) -> bool,
    bound: Duration,
) -> Vec<SaveWait> {
    let start = Instant::now();
    let mut waits = Vec::new();
    for c in children.iter_mut() {
        if c.status.is_some() || !saving(c) {
            continue;
        }
        let done = loop {
            if let Ok(Some(s)) = c.child.try_wait() {
                c.status = Some(s);
                break true;
            }
            if !saving(c) {
                break true;
            }
            if start.elapsed() >= bound {
                break false;
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        waits.push(SaveWait {
            process: c.name.clone(),
            waited: start.elapsed(),
            bound,
            done,
        });
    }
    waits
}

/// Sends `signal` to every child still running; whether any was.
fn signal_the_living(children: &mut [&mut Process], signal: Signal) -> bool {
    let mut any = false;
    for c in children.iter_mut().filter(|c| c.status.is_none()) {
        if let Ok(Some(s)) = c.child.try_wait() {
            c.status = Some(s);
            continue;
        }
        let pid = Pid::from_raw(c.child.id() as i32);
        any |= kill(pid, signal).is_ok();
    }
    any
}

/// Waits up to `grace` for every child to end; whether they all did.
fn wait_for_all(children: &mut [&mut Process], grace: Duration) -> bool {
    let deadline = Instant::now() + grace;
    while Instant::now() < deadline {
        let mut alive = false;
        for c in children.iter_mut().filter(|c| c.status.is_none()) {
            match c.child.try_wait() {
                Ok(Some(s)) => c.status = Some(s),
                _ => alive = true,
            }
        }
        if !alive {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    false
}

/// Whether `status` is an exit the shutdown itself caused (SIGINT/SIGTERM handled by a
/// child that then exited by that signal).
pub fn stopped_by_us(status: ExitStatus) -> bool {
    use std::os::unix::process::ExitStatusExt;
    matches!(status.signal(), Some(s) if s == Signal::SIGINT as i32 || s == Signal::SIGTERM as i32)
}

/// "exited with status 3" / "was killed by SIGKILL".
pub fn describe(status: ExitStatus) -> String {
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
