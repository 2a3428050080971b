//! What the tests share: running `tes`, a launched group that is killed (with its children)
//! and cleaned up on drop, a process killed on drop, waiting for lines and for an exit, each
//! test's own service prefix, reading what a launch printed, and keeping other tests' groups
//! away from the tests that must be alone on the machine.

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt as _;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::{Condvar, Mutex, PoisonError, mpsc};
use std::thread::ThreadId;
use std::time::{Duration, Instant};

use nix::unistd::Pid;
use tes_controller::summary::EpisodeLine;
use tes_learning::library::store::{self, StoreError, StoredLibrary};

/// The built `tes` binary, as a command to add arguments to.
pub fn tes_command() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tes"))
}

/// Runs `tes ARGS` to its end; its output.
pub fn tes(args: &[&str]) -> Output {
    tes_command()
        .args(args)
        .output()
        .expect("the tes binary runs")
}

/// `tes replay FILE ARGS`: its success, stdout and stderr.
pub fn replay(file: &Path, args: &[&str]) -> (bool, String, String) {
    let out = tes_command()
        .arg("replay")
        .arg(file)
        .args(args)
        .output()
        .expect("tes replay runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A process killed (and reaped) on drop, so that a failing test leaves none behind; the
/// children of a `tes` process follow it by their parent-death signal.
pub struct Killed(pub Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Waits for `child` to exit, at most `limit` (else the test fails naming `what`).
pub fn wait_exit(child: &mut Child, limit: Duration, what: &str) -> ExitStatus {
    let deadline = Instant::now() + limit;
    loop {
        if let Some(status) = child.try_wait().expect("poll") {
            return status;
        }
        assert!(
            Instant::now() < deadline,
            "{what} did not finish within {limit:?}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Who uses the machine: how many groups run, and which test, if any, has it to itself.
struct Machine {
    groups: usize,
    alone: Option<ThreadId>,
}

static MACHINE: Mutex<Machine> = Mutex::new(Machine {
    groups: 0,
    alone: None,
});
static MACHINE_CHANGED: Condvar = Condvar::new();

/// Held while a test runs a group of processes: no other test that must be alone on the
/// machine ([`Alone`]) runs then.
pub struct Sharing(());

/// Waits until no other test is alone on the machine; it is then shared until the guard
/// drops. (The test that is alone may start groups of its own.)
pub fn sharing_the_machine() -> Sharing {
    let me = std::thread::current().id();
    let mut m = MACHINE.lock().unwrap_or_else(PoisonError::into_inner);
    while m.alone.is_some_and(|t| t != me) {
        m = MACHINE_CHANGED
            .wait(m)
            .unwrap_or_else(PoisonError::into_inner);
    }
    m.groups += 1;
    Sharing(())
}

impl Drop for Sharing {
    fn drop(&mut self) {
        MACHINE
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .groups -= 1;
        MACHINE_CHANGED.notify_all();
    }
}

/// Held by a test that no other test's group may run beside. As test binaries of their own
/// they never met; in one binary, libtest runs them side by side:
///
/// * a test that loads every core (an experiment on all threads): a group's background
///   threads (planning, saving) run under `SCHED_IDLE`, get no time beside it, and the
///   controller does not stop within the launcher's grace periods;
/// * a test that runs `tes status`, which opens the progress services of every group of the
///   machine for a moment: a group launched again on a prefix just stopped would find it in
///   use and be refused.
pub struct Alone(());

/// Waits until no group runs and no other test is alone; the machine is then this test's
/// (and its own groups') until the guard drops. Take it before starting a group.
pub fn alone_on_the_machine() -> Alone {
    let me = std::thread::current().id();
    let mut m = MACHINE.lock().unwrap_or_else(PoisonError::into_inner);
    while m.alone.is_some() || m.groups > 0 {
        m = MACHINE_CHANGED
            .wait(m)
            .unwrap_or_else(PoisonError::into_inner);
    }
    m.alone = Some(me);
    Alone(())
}

impl Drop for Alone {
    fn drop(&mut self) {
        MACHINE.lock().unwrap_or_else(PoisonError::into_inner).alone = None;
        MACHINE_CHANGED.notify_all();
    }
}

/// A launched group, killed on drop.
pub struct Group {
    /// The `tes launch` process.
    pub launcher: Child,
    /// Its standard output, line by line.
    pub stdout: mpsc::Receiver<String>,
    /// Its standard error, line by line.
    pub stderr: mpsc::Receiver<String>,
    /// Released once the group is killed and cleaned up (fields drop after `drop`).
    _sharing: Sharing,
}

impl Group {
    pub fn start(dir: &Path, launch_toml: &str, episodes: u32) -> Self {
        let config = dir.join("launch.toml");
        std::fs::write(&config, launch_toml).expect("launch file");
        Self::start_with(dir, &config, episodes)
    }

    /// Launches with the launch file `config` (which need not exist), data in `dir/data`.
    pub fn start_with(dir: &Path, config: &Path, episodes: u32) -> Self {
        Self::launch(dir, Some(config), episodes)
    }

    /// Launches with the embedded defaults (its own service prefix included), data in
    /// `dir/data`.
    pub fn start_default(dir: &Path, episodes: u32) -> Self {
        Self::launch(dir, None, episodes)
    }

    fn launch(dir: &Path, config: Option<&Path>, episodes: u32) -> Self {
        Self::launch_with(dir, config, episodes, &[], &[])
    }

    /// [`start`](Self::start), the launcher leading a process group of its own (its
    /// children in it), as a shell starts a command: a signal to the group is a Ctrl-C in
    /// its terminal.
    pub fn start_own_process_group(dir: &Path, launch_toml: &str, episodes: u32) -> Self {
        let config = dir.join("launch.toml");
        std::fs::write(&config, launch_toml).expect("launch file");
        let mut command = tes_command();
        command.process_group(0);
        Self::spawn(command, dir, Some(&config), episodes, &[], &[])
    }

    /// Launches `launch_toml` (written to `dir/launch.toml`) with `args` after the launch's
    /// own and the environment variables `env` set (an iceoryx2 domain of its own, say).
    pub fn start_in(
        dir: &Path,
        launch_toml: &str,
        episodes: u32,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let config = dir.join("launch.toml");
        std::fs::write(&config, launch_toml).expect("launch file");
        Self::launch_with(dir, Some(&config), episodes, args, env)
    }

    /// Launches the launch file `config` with `args` and `env`, its data directory
    /// `dir/data` (which launches given the same `dir` share).
    pub fn start_with_config(
        dir: &Path,
        config: &Path,
        episodes: u32,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        Self::launch_with(dir, Some(config), episodes, args, env)
    }

    fn launch_with(
        dir: &Path,
        config: Option<&Path>,
        episodes: u32,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        Self::spawn(tes_command(), dir, config, episodes, args, env)
    }

    fn spawn(
        mut command: Command,
        dir: &Path,
        config: Option<&Path>,
        episodes: u32,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let sharing = sharing_the_machine();
        command.arg("launch");
        if let Some(config) = config {
            command.arg("--config").arg(config);
        }
        command.args(args);
        command.envs(env.iter().copied());
        let mut launcher = command
            .arg("--episodes")
            .arg(episodes.to_string())
            .env("TES_DATA_DIR", dir.join("data"))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("tes launch starts");
        let lines = |r: Box<dyn std::io::Read + Send>| {
            let (tx, rx) = mpsc::channel();
            std::thread::spawn(move || {
                for line in BufReader::new(r).lines().map_while(Result::ok) {
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            });
            rx
        };
        let stdout = lines(Box::new(launcher.stdout.take().expect("stdout")));
        let stderr = lines(Box::new(launcher.stderr.take().expect("stderr")));
        Self {
            launcher,
            stdout,
            stderr,
            _sharing: sharing,
        }
    }

    /// Waits for the launcher to exit (at most `limit`); returns whether it ended cleanly
    /// and its output. Clean: status 0, or 128 + the signal that stopped it (130 after
    /// SIGINT, 143 after SIGTERM), as `tes launch` exits when a test stops it.
    pub fn finish(&mut self, limit: Duration) -> (bool, Vec<String>, Vec<String>) {
        let status = wait_exit(&mut self.launcher, limit, "tes launch");
        std::thread::sleep(Duration::from_millis(100));
        (
            status.success() || matches!(status.code(), Some(130 | 143)),
            self.stdout.try_iter().collect(),
            self.stderr.try_iter().collect(),
        )
    }

    /// Waits until stdout shows `n` episode lines; returns the lines seen.
    pub fn wait_for_episodes(&self, n: usize, limit: Duration) -> Vec<String> {
        wait_for_lines(
            &self.stdout,
            limit,
            &format!("{n} episodes on stdout"),
            |seen| seen.iter().filter(|l| l.starts_with("episode ")).count() >= n,
        )
    }

    /// The pid of the child playing `role`, if there is one.
    pub fn find_child(&self, role: &str) -> Option<Pid> {
        let parent = self.launcher.id();
        for entry in std::fs::read_dir("/proc").expect("procfs") {
            let Ok(entry) = entry else { continue };
            let Ok(pid) = entry.file_name().to_string_lossy().parse::<i32>() else {
                continue;
            };
            let ppid = parent_of(pid);
            let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
            let args: Vec<&[u8]> = cmdline.split(|&b| b == 0).collect();
            if ppid == Some(parent)
                && args.len() > 2
                && args[1] == b"child"
                && args[2] == role.as_bytes()
            {
                return Some(Pid::from_raw(pid));
            }
        }
        None
    }

    /// The pids of the launcher's children.
    pub fn children(&self) -> Vec<Pid> {
        ["bridge", "controller", "perception-sim"]
            .into_iter()
            .filter_map(|role| self.find_child(role))
            .collect()
    }

    /// The pid of the child playing `role`.
    pub fn child(&self, role: &str) -> Pid {
        self.find_child(role)
            .unwrap_or_else(|| panic!("no {role} child of the launcher"))
    }

    /// Waits until a stderr line contains `text`; returns the lines seen.
    pub fn wait_for_stderr(&self, text: &str, limit: Duration) -> Vec<String> {
        wait_for_lines(
            &self.stderr,
            limit,
            &format!("{text:?} on stderr"),
            |seen| seen.iter().any(|l| l.contains(text)),
        )
    }

    /// Whether any child of the launcher is still alive.
    pub fn children_alive(&self) -> bool {
        let parent = self.launcher.id();
        std::fs::read_dir("/proc")
            .expect("procfs")
            .filter_map(Result::ok)
            .filter_map(|e| e.file_name().to_string_lossy().parse::<i32>().ok())
            .any(|pid| parent_of(pid) == Some(parent))
    }
}

impl Drop for Group {
    fn drop(&mut self) {
        if self.launcher.try_wait().ok().flatten().is_none() {
            // The children follow by their parent-death signal. A node's resources can be
            // removed only once its process is gone, which on a loaded machine takes longer
            // than any fixed pause: wait for each child (bounded, and without a panic in a
            // drop), then clean.
            let children = self.children();
            let _ = self.launcher.kill();
            let _ = self.launcher.wait();
            let deadline = Instant::now() + Duration::from_secs(30);
            while children
                .iter()
                .any(|&p| nix::sys::signal::kill(p, None).is_ok())
                && Instant::now() < deadline
            {
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        let _ = tes_runtime::channel::clean_stale_resources();
    }
}

/// Waits until none of `pids` is alive (they were children of a launcher that died): a
/// SIGKILLed process is gone only once each of its threads has run to its end, which its
/// background threads (under `SCHED_IDLE`) do late on a loaded machine.
pub fn wait_gone(pids: &[Pid], limit: Duration) {
    let deadline = Instant::now() + limit;
    while pids
        .iter()
        .any(|&p| nix::sys::signal::kill(p, None).is_ok())
    {
        assert!(Instant::now() < deadline, "children still alive: {pids:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// The parent's pid of process `pid`, if it is alive.
fn parent_of(pid: i32) -> Option<u32> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // `pid (comm) state ppid …`; comm may hold spaces, so split after the last ')'.
    stat.rsplit_once(')')
        .and_then(|(_, rest)| rest.split_whitespace().nth(1))
        .and_then(|p| p.parse().ok())
}

/// Collects lines from `lines` until `done` holds for those seen (at most `limit`, else the
/// test fails naming `what`); returns them.
pub fn wait_for_lines(
    lines: &mpsc::Receiver<String>,
    limit: Duration,
    what: &str,
    done: impl Fn(&[String]) -> bool,
) -> Vec<String> {
    let deadline = Instant::now() + limit;
    let mut seen = Vec::new();
    while !done(&seen) {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(!left.is_zero(), "no {what} in {limit:?}: {seen:?}");
        if let Ok(line) = lines.recv_timeout(left.min(Duration::from_millis(100))) {
            seen.push(line);
        }
    }
    seen
}

/// The iceoryx2 service prefix of the group a test launches in `dir`: its own, by this test
/// process and the directory's name.
pub fn service_prefix(dir: &Path) -> String {
    format!(
        "tes-test/{}/{}/",
        std::process::id(),
        dir.file_name().and_then(|n| n.to_str()).unwrap_or("x")
    )
}

/// A launch file for a group in `dir`: its own service prefix, its run folder `dir/run`, and
/// `extra` after the `[launch]` table's first keys.
pub fn launch_file(dir: &Path, extra: &str) -> String {
    format!(
        "[launch]\nservice_prefix = \"{}\"\nrun_dir = \"{}\"\n{extra}",
        service_prefix(dir),
        dir.join("run").display()
    )
}

/// `[[bridge.actions]]` tables making every action a long move: 20 000° a wheel, about 30 s
/// at the default power in physical time.
pub fn long_move_actions() -> String {
    (0..3)
        .map(|id| {
            format!(
                "[[bridge.actions]]\nid = {id}\nname = \"long-{id}\"\nleft_deg = 20000\nright_deg = 20000\n"
            )
        })
        .collect()
}

/// The library at `path`, loaded for the arena's shape (3 actions, 20 effects, 312 features).
pub fn load_library(path: &Path) -> Result<StoredLibrary, StoreError> {
    store::load_for(path, 3, 20, 312)
}

/// Mean reward of episodes `from..to` in a launch's episode lines.
pub fn mean_reward(lines: &[String], from: usize, to: usize) -> f64 {
    let rewards: Vec<f64> = lines
        .iter()
        .filter_map(|l| EpisodeLine::parse(l))
        .map(|e| e.reward)
        .collect();
    assert!(rewards.len() >= to, "{} episodes: {lines:?}", rewards.len());
    rewards[from..to].iter().sum::<f64>() / (to - from) as f64
}

/// The actions the controller's summary line reports (`controller: 3 episodes, 89 actions, …`).
pub fn reported_actions(out: &[String]) -> u64 {
    out.iter()
        .find_map(|l| {
            let rest = l.strip_prefix("controller: ")?;
            // "89 actions", "1 action", "0 actions: no decision was made".
            let actions = rest.split(", ").nth(1)?.split(' ').next()?;
            actions.parse().ok()
        })
        .unwrap_or_else(|| panic!("no controller summary in {out:?}"))
}

/// Asserts that `lines` hold the bridge's watchdog line and that it braked 1000–1200 ms (the
/// 1 s deadline, some slack for a loaded machine) after the last command or keep-alive.
pub fn assert_braked_at_the_deadline(lines: &[String]) {
    let line = lines
        .iter()
        .find(|l| l.contains("watchdog: no command within the deadline"))
        .expect("the watchdog's line");
    let silence_ms: u64 = line
        .split("silence_ms=")
        .nth(1)
        .and_then(|r| r.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no silence_ms in {line:?}"));
    assert!(
        (1000..=1200).contains(&silence_ms),
        "braked after {silence_ms} ms of silence: {line}"
    );
}

pub use tes_runtime::test_support::CpuHogs;
