//! `tes launch --tui` in a real terminal: tmux runs it in a detached session of its own (a
//! private tmux server), the test reads the screen with `capture-pane`, presses `q` with
//! `send-keys`, and checks that the group stopped cleanly and kept its library and run
//! folder. A guard kills the tmux server — and with it the launcher, whose children die with
//! it — even when the test fails.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use crate::common::*;

/// A private tmux server: its socket is a file in this test's own temporary directory
/// (`-S`), removed with it — not one under tmux's shared directory, which outlives the test.
struct Tmux {
    socket: PathBuf,
}

impl Tmux {
    fn run(&self, args: &[&str]) -> std::process::Output {
        Command::new("tmux")
            .arg("-S")
            .arg(&self.socket)
            .args(args)
            .output()
            .expect("tmux runs (install it: apt-get install tmux)")
    }

    fn screen(&self) -> String {
        String::from_utf8_lossy(&self.run(&["capture-pane", "-p", "-t", "tes"]).stdout).into_owned()
    }

    /// Waits until the screen satisfies `done`; returns it.
    fn wait_for(&self, what: &str, limit: Duration, done: impl Fn(&str) -> bool) -> String {
        let deadline = Instant::now() + limit;
        loop {
            let screen = self.screen();
            if done(&screen) {
                return screen;
            }
            assert!(
                Instant::now() < deadline,
                "no {what} on the screen in {limit:?}:\n{screen}"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = self.run(&["kill-server"]);
        // tmux leaves its socket behind when its server is killed.
        let _ = std::fs::remove_file(&self.socket);
    }
}

/// The number after `label` on the screen.
fn number_after(screen: &str, label: &str) -> Option<u64> {
    let rest = &screen[screen.find(label)? + label.len()..];
    rest.split(|c: char| !c.is_ascii_digit())
        .find(|w| !w.is_empty())?
        .parse()
        .ok()
}

fn shell_quote(path: &Path) -> String {
    format!("'{}'", path.display().to_string().replace('\'', r"'\''"))
}

#[test]
fn the_live_view_shows_the_group_and_q_stops_it_cleanly() {
    let dir = tempfile::tempdir().expect("temp dir");
    let config = dir.path().join("launch.toml");
    std::fs::write(&config, launch_file(dir.path(), "")).expect("launch file");
    let exit = dir.path().join("exit");
    let _sharing = sharing_the_machine();
    let tmux = Tmux {
        socket: dir.path().join("tmux.sock"),
    };
    let command = format!(
        "TES_DATA_DIR={} {} launch --config {} --episodes 100000 --tui; echo $? > {}; sleep 60",
        shell_quote(&dir.path().join("data")),
        shell_quote(Path::new(env!("CARGO_BIN_EXE_tes"))),
        shell_quote(&config),
        shell_quote(&exit),
    );
    let started = tmux.run(&[
        "new-session",
        "-d",
        "-s",
        "tes",
        "-x",
        "150",
        "-y",
        "50",
        &command,
    ]);
    assert!(started.status.success(), "{started:?}");

    // The processes, the episodes, the latency, the arena and the log, live.
    let screen = tmux.wait_for("three episodes", Duration::from_secs(90), |s| {
        number_after(s, "episodes ").is_some_and(|n| n >= 3)
    });
    for text in [
        "Processes",
        "perception-sim",
        "controller",
        "bridge",
        "running",
        "Reward per episode",
        "decision latency p50",
        "Env 3",
        "Log",
        "stop the group",
    ] {
        assert!(
            screen.contains(text),
            "{text:?} not on the screen:\n{screen}"
        );
    }
    // The robot stands on one cell at a time; Env 3 has four death spots.
    assert!(
        screen.contains("X "),
        "the death spots on the map:\n{screen}"
    );
    let first = number_after(&screen, "episodes ").unwrap_or(0);
    // It goes on: the count grows.
    tmux.wait_for("more episodes", Duration::from_secs(60), |s| {
        number_after(s, "episodes ").is_some_and(|n| n > first)
    });

    tmux.run(&["send-keys", "-t", "tes", "q"]);
    let deadline = Instant::now() + Duration::from_secs(60);
    while !exit.exists() {
        assert!(
            Instant::now() < deadline,
            "q did not stop the launch:\n{}",
            tmux.screen()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_millis(100));
    let status = std::fs::read_to_string(&exit).expect("exit status");
    let screen = tmux.screen();
    assert_eq!(status.trim(), "0", "{screen}");
    // Back on the normal screen: the summary as a launch without the view prints it.
    assert!(screen.contains("all processes stopped cleanly"), "{screen}");
    assert!(screen.contains("(saved)"), "{screen}");
    assert!(dir.path().join("data/library.tesl").is_file());
    assert!(dir.path().join("run/arena.svg").is_file());
}
