//! Stopping a launch on a machine whose every core is busy: the library the run learned is
//! saved whenever the stop comes. The controller's planner and saver run under `SCHED_IDLE`,
//! which on such a machine gets almost no CPU; at shutdown they are raised back to normal
//! priority, and the launcher waits (bounded) for a controller still saving instead of
//! killing it.

use std::time::{Duration, Instant};

use nix::sys::signal::Signal;
use nix::unistd::Pid;

use crate::common::*;

/// When, and how, a launch is stopped.
#[derive(Debug, Clone, Copy)]
enum Stop {
    /// Ctrl-C in the launch's terminal (SIGINT to its whole process group) once this many
    /// episodes were reported (0: as soon as the group has started).
    CtrlCAfter(usize),
    /// SIGTERM to the launcher alone once this many episodes were reported.
    SigtermAfter(usize),
}

/// The tasks of the library at `path` (0 when there is none yet).
fn tasks_in(path: &std::path::Path) -> u32 {
    if !path.exists() {
        return 0;
    }
    load_library(path)
        .expect("the library loads")
        .library
        .tasks_seen()
}

/// Launches in `dir` (in a process group of its own, as a terminal starts a command), stops
/// it as `stop` says; returns the launcher's exit code, the episodes it reported and its
/// lines.
fn launch_and_stop(dir: &std::path::Path, stop: Stop) -> (Option<i32>, usize, Vec<String>) {
    let mut group = Group::start_own_process_group(dir, &launch_file(dir, ""), 100_000);
    let (episodes, signal) = match stop {
        Stop::CtrlCAfter(n) => (n, Signal::SIGINT),
        Stop::SigtermAfter(n) => (n, Signal::SIGTERM),
    };
    let mut out = if episodes == 0 {
        std::thread::sleep(Duration::from_secs(3));
        Vec::new()
    } else {
        group.wait_for_episodes(episodes, Duration::from_secs(600))
    };
    let launcher = Pid::from_raw(group.launcher.id() as i32);
    match stop {
        Stop::CtrlCAfter(_) => nix::sys::signal::killpg(launcher, signal),
        Stop::SigtermAfter(_) => nix::sys::signal::kill(launcher, signal),
    }
    .expect("the launch is signalled");
    let status = wait_exit(&mut group.launcher, Duration::from_secs(300), "tes launch");
    std::thread::sleep(Duration::from_millis(100));
    out.extend(group.stdout.try_iter());
    let err: Vec<String> = group.stderr.try_iter().collect();
    let reported = out.iter().filter(|l| l.starts_with("episode ")).count();
    out.extend(err);
    (status.code(), reported, out)
}

/// The actions of an unfinished episode the launch's verdict counts (`launch: 2 episodes
/// and 5 actions of an unfinished one; …`), 0 when it counts none.
fn unfinished_actions(lines: &[String]) -> u64 {
    lines
        .iter()
        .filter_map(|l| l.strip_prefix("launch: "))
        .find_map(|l| {
            let (_, rest) = l
                .split_once(" episodes and ")
                .or(l.split_once(" episode and "))?;
            let (n, _) = rest.split_once(" action")?;
            n.parse().ok()
        })
        .unwrap_or(0)
}

/// Under full load, a launch stopped by Ctrl-C or SIGTERM — right after it started, after its
/// first episode, after a few — leaves a library holding the run's task whenever the run
/// reported an episode (and never a damaged one), exits with 128 + the signal, and never
/// needs SIGKILL for the controller.
#[test]
fn the_final_save_lands_under_full_load_whenever_the_launch_is_stopped() {
    let _alone = alone_on_the_machine();
    let _hogs = CpuHogs::two_per_core();
    let dir = tempfile::tempdir().expect("temp dir");
    let library = dir.path().join("data").join("library.tesl");
    let started = Instant::now();
    for stop in [
        Stop::SigtermAfter(1),
        Stop::CtrlCAfter(3),
        Stop::CtrlCAfter(0),
        Stop::SigtermAfter(2),
    ] {
        let before = tasks_in(&library);
        let (code, episodes, lines) = launch_and_stop(dir.path(), stop);
        let after = tasks_in(&library);
        let expected_code = match stop {
            Stop::CtrlCAfter(_) => 130,
            Stop::SigtermAfter(_) => 143,
        };
        assert_eq!(code, Some(expected_code), "{stop:?}: {lines:#?}");
        assert!(
            !lines.iter().any(|l| l.contains("escalating")),
            "{stop:?}: a process needed a harder signal: {lines:#?}"
        );
        // What the launch reported learning: episodes, or the actions of an unfinished one.
        let unfinished = unfinished_actions(&lines);
        if episodes > 0 || unfinished > 0 {
            assert_eq!(
                after,
                before + 1,
                "{stop:?}: {episodes} episodes and {unfinished} actions of an unfinished one \
                 reported, the run's task is in the library: {lines:#?}"
            );
            assert!(
                lines.iter().any(|l| l.contains("(saved)")),
                "{stop:?}: {lines:#?}"
            );
        } else {
            assert_eq!(
                after, before,
                "{stop:?}: nothing reported learned, no task added: {lines:#?}"
            );
        }
    }
    eprintln!("four stops under load in {:?}", started.elapsed());
}
