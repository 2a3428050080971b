//! What the launch tests share: a launched group that is killed (with its children) and
//! cleaned up on drop, and line waiting.

// Each test binary uses its own part of this module.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use nix::unistd::Pid;

/// A launched group, killed on drop.
pub struct Group {
    pub launcher: Child,
    pub stdout: mpsc::Receiver<String>,
    pub stderr: mpsc::Receiver<String>,
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

    fn launch_with(
        dir: &Path,
        config: Option<&Path>,
        episodes: u32,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let mut command = Command::new(env!("CARGO_BIN_EXE_tes"));
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
        }
    }

    /// Waits for the launcher to exit (at most `limit`); returns its success and output.
    pub fn finish(&mut self, limit: Duration) -> (bool, Vec<String>, Vec<String>) {
        let deadline = Instant::now() + limit;
        let status = loop {
            if let Some(s) = self.launcher.try_wait().expect("poll") {
                break s;
            }
            assert!(
                Instant::now() < deadline,
                "tes launch did not finish in {limit:?}"
            );
            std::thread::sleep(Duration::from_millis(20));
        };
        std::thread::sleep(Duration::from_millis(100));
        (
            status.success(),
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
            let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
                continue;
            };
            // `pid (comm) state ppid …`; comm may hold spaces, so split after the last ')'.
            let ppid = stat
                .rsplit_once(')')
                .and_then(|(_, rest)| rest.split_whitespace().nth(1))
                .and_then(|p| p.parse::<u32>().ok());
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

    pub fn children_alive(&self) -> bool {
        let parent = self.launcher.id();
        std::fs::read_dir("/proc")
            .expect("procfs")
            .filter_map(Result::ok)
            .filter_map(|e| e.file_name().to_string_lossy().parse::<i32>().ok())
            .any(|pid| {
                std::fs::read_to_string(format!("/proc/{pid}/stat"))
                    .ok()
                    .and_then(|s| {
                        s.rsplit_once(')')
                            .and_then(|(_, r)| r.split_whitespace().nth(1))
                            .and_then(|p| p.parse::<u32>().ok())
                    })
                    == Some(parent)
            })
    }
}

impl Drop for Group {
    fn drop(&mut self) {
        if self.launcher.try_wait().ok().flatten().is_none() {
            // The children follow by their parent-death signal.
            let _ = self.launcher.kill();
            let _ = self.launcher.wait();
            std::thread::sleep(Duration::from_millis(300));
        }
        let _ = tes_runtime::channel::clean_stale_resources();
    }
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

pub fn launch_file(dir: &Path, extra: &str) -> String {
    format!(
        "[launch]\nservice_prefix = \"tes-test/{}/{}/\"\nrun_dir = \"{}\"\n{extra}",
        std::process::id(),
        dir.file_name().and_then(|n| n.to_str()).unwrap_or("x"),
        dir.join("run").display()
    )
}

/// The actions the controller's summary line reports (`controller: 3 episodes, 89 actions, …`).
pub fn reported_actions(out: &[String]) -> u64 {
    out.iter()
        .find_map(|l| {
            let rest = l.strip_prefix("controller: ")?;
            let actions = rest.split(", ").nth(1)?.strip_suffix(" actions")?;
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
