//! `tes launch` against the faults a robot user meets on day one: a dead link to the brick,
//! several groups at once, lost messages at start and after a respawn, a stalled process, a
//! launcher that dies (or whose output is closed) mid-run, and hostile library files.
//!
//! Each test gives its groups their own data directories; a guard kills every launcher (its
//! children follow by their parent-death signal) and removes dead processes' iceoryx2
//! resources even when the test fails.

use std::io::BufRead;
use std::os::fd::AsRawFd as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

use crate::common::*;

/// The library at `path`: its tasks seen (each saved run adds one).
fn tasks_of(path: &Path) -> u32 {
    load_library(path)
        .unwrap_or_else(|e| panic!("the library does not load: {e}"))
        .library
        .tasks_seen()
}

/// How many observations perception re-published (no motion report in time) in `lines`.
fn republished(lines: &[String]) -> usize {
    lines.iter().filter(|l| l.contains("re-publishing")).count()
}

/// The library a good two-episode run in `dir` saved: its path and its bytes.
fn library_from_a_good_run(dir: &Path) -> (PathBuf, Vec<u8>) {
    let mut first = Group::start(dir, &launch_file(dir, ""), 2);
    let (ok, out, err) = first.finish(Duration::from_secs(60));
    assert!(ok, "{out:?}\n{err:?}");
    let library = dir.join("data/library.tesl");
    let before = std::fs::read(&library).expect("a library was saved");
    (library, before)
}

/// Launches in `dir` with `[bridge]` keys `bridge` over a link that must fail: the launch
/// fails, runs no episode, leaves the library at `library` as `before` and no child behind.
/// Returns what it said on stderr.
fn a_failed_link_launch(dir: &Path, bridge: &str, library: &Path, before: &[u8]) -> String {
    let extra = format!("[bridge]\n{bridge}link_timeout_ms = 800\n");
    let mut group = Group::start(dir, &launch_file(dir, &extra), 3);
    let (ok, out, err) = group.finish(Duration::from_secs(60));
    assert!(!ok, "{bridge}: the launch must fail: {out:?}");
    assert!(
        !out.iter().any(|l| l.starts_with("episode ")),
        "no episode ran: {out:?}"
    );
    assert_eq!(
        std::fs::read(library).expect("the library is still there"),
        before,
        "{bridge}: the library changed"
    );
    assert!(!group.children_alive());
    // Everything the launch said, on either stream.
    out.iter()
        .chain(&err)
        .cloned()
        .collect::<Vec<_>>()
        .join("\n")
}

/// A link to the brick that never comes up stops the launch with an error naming the
/// transport, exits non-zero, and leaves the library byte for byte as it was.
#[test]
fn a_dead_link_stops_the_launch_and_leaves_the_library_as_it_was() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (library, before) = library_from_a_good_run(dir.path());
    // A terminal that is there but no brick answers on: a pseudo-terminal whose other end
    // nobody reads (a path that is not there, or is no terminal, is refused before anything
    // starts: see `run_folder::a_refused_launch_leaves_…` and `hostile_files::`).
    let pty = nix::pty::openpty(None, None).expect("a pseudo-terminal");
    let device = std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd()))
        .expect("the pseudo-terminal's path");
    let transport = format!("transport = \"serial:{}\"\n", device.display());
    let said = a_failed_link_launch(dir.path(), &transport, &library, &before);
    assert!(
        said.contains(&format!(
            "the link to the brick (serial:{}) did not come up",
            device.display()
        )),
        "{said}"
    );
    drop(pty);
}

/// A brick's own links on a machine that lacks them (this build machine has no Bluetooth in
/// its kernel and no USB bus): each launch is refused before anything starts, saying the
/// cause and the fix once, with no warning about settings the launch file did not write
/// (`brick.time_scale`, which the launcher fills in), runs no episode and leaves the library
/// byte for byte. A machine that has the bus but no brick retries until the link's timeout.
#[test]
fn bluetooth_and_usb_launches_say_why_they_cannot_run_and_leave_the_library() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (library, before) = library_from_a_good_run(dir.path());
    let no_usb_bus = !Path::new("/sys/bus/usb/devices").exists();
    for (transport, described, causes) in [
        (
            "bluetooth:00:16:53:01:02:03",
            "bluetooth:00:16:53:01:02:03@1",
            &[
                "this machine has no Bluetooth",
                "no Bluetooth adapter",
                "did not answer",
            ][..],
        ),
        (
            "usb",
            "usb",
            &["this machine shows no USB bus", "no NXT on USB"][..],
        ),
    ] {
        let keys = format!("transport = \"{transport}\"\n");
        let said = a_failed_link_launch(dir.path(), &keys, &library, &before);
        assert!(
            said.contains(&format!("the link to the brick ({described})")),
            "{said}"
        );
        assert!(
            causes.iter().any(|c| said.contains(c)),
            "{transport}: no cause named: {said}"
        );
        assert!(!said.contains("time_scale"), "{transport}: {said}");
        let impossible = [
            "this machine has no Bluetooth",
            "this machine shows no USB bus",
        ];
        if let Some(cause) = impossible.iter().find(|c| said.contains(*c)) {
            assert_eq!(
                said.matches(cause).count(),
                1,
                "{transport}: said again: {said}"
            );
            assert!(said.contains("nothing was started"), "{said}");
            assert!(!said.contains(" WARN "), "{transport}: {said}");
        }
        if transport == "usb" && no_usb_bus {
            assert!(said.contains("this machine shows no USB bus"), "{said}");
        }
    }
}

/// Default launches own their services: three at once, each with its own data directory,
/// all finish their own episodes; a second launch on a data directory in use is refused,
/// naming the holder's pid.
#[test]
fn default_launches_run_side_by_side_and_one_data_directory_has_one_group() {
    for n in [2usize, 3] {
        let dirs: Vec<tempfile::TempDir> = (0..n).map(|_| tempfile::tempdir().unwrap()).collect();
        let mut groups: Vec<Group> = dirs
            .iter()
            .enumerate()
            .map(|(i, d)| Group::start_default(d.path(), 6 + i as u32))
            .collect();
        if n == 2 {
            // While the first runs, a second launch on its data directory is refused.
            groups[0].wait_for_episodes(1, Duration::from_secs(60));
            let mut second = Group::start_default(dirs[0].path(), 2);
            let (ok, out, err) = second.finish(Duration::from_secs(30));
            assert!(!ok, "{out:?}");
            let said = err.join("\n");
            assert!(
                said.contains("is in use by another tes launch (pid ")
                    && said.contains(&format!("(pid {})", groups[0].launcher.id())),
                "{said}"
            );
        }
        for (i, group) in groups.iter_mut().enumerate() {
            let (ok, out, err) = group.finish(Duration::from_secs(120));
            assert!(ok, "group {i} of {n}: {out:?}\n{err:?}");
            // Its own counts (the first episode lines may have been read while waiting).
            let episodes = 6 + i;
            assert!(
                out.iter()
                    .any(|l| l.starts_with(&format!("controller: {episodes} episodes"))),
                "group {i} of {n}: {out:?}"
            );
            assert!(
                out.iter()
                    .any(|l| l.starts_with(&format!("launch: {episodes} episodes;"))),
                "group {i} of {n}: {out:?}"
            );
            assert_eq!(republished(&err), 0, "{err:?}");
        }
    }
}

/// No message is lost at the start of a launch: 100 short launches (with a library from the
/// first on) re-publish no observation, i.e. the first motion report always arrives.
#[test]
fn a_hundred_short_launches_lose_no_message() {
    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(dir.path(), "");
    for i in 0..100 {
        let mut group = Group::start(dir.path(), &toml, 2);
        let (ok, out, err) = group.finish(Duration::from_secs(60));
        assert!(ok, "launch {i}: {out:?}\n{err:?}");
        assert_eq!(republished(&err), 0, "launch {i}: {err:?}");
        assert_eq!(
            out.iter().filter(|l| l.starts_with("episode ")).count(),
            2,
            "launch {i}: {out:?}"
        );
    }
}

/// A respawned bridge carries out the command in flight that its predecessor did not: 20
/// bridge kills in one run re-publish no observation, and the run goes on.
#[test]
fn twenty_bridge_respawns_lose_no_message() {
    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(dir.path(), "restart = \"on-failure\"\nmax_restarts = 100\n");
    let mut group = Group::start(dir.path(), &toml, 1_000_000);
    group.wait_for_episodes(1, Duration::from_secs(60));
    let mut stderr = Vec::new();
    for kill_no in 1..=20 {
        std::thread::sleep(Duration::from_millis(150 + 37 * (kill_no % 5)));
        let deadline = Instant::now() + Duration::from_secs(30);
        let pid = loop {
            if let Some(pid) = group.find_child("bridge") {
                break pid;
            }
            assert!(Instant::now() < deadline, "kill {kill_no}: no bridge");
            std::thread::sleep(Duration::from_millis(10));
        };
        kill(pid, Signal::SIGKILL).expect("kill the bridge");
        stderr.extend(group.wait_for_stderr(
            &format!("bridge was killed by SIGKILL; respawning it (restart {kill_no}/100)"),
            Duration::from_secs(30),
        ));
        // The respawned bridge takes part: episodes go on.
        while group.stdout.try_recv().is_ok() {}
        group.wait_for_episodes(1, Duration::from_secs(30));
    }
    kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGINT).expect("Ctrl-C");
    let (ok, out, err) = group.finish(Duration::from_secs(60));
    stderr.extend(err);
    assert!(ok, "{out:?}\n{stderr:?}");
    assert_eq!(republished(&stderr), 0, "{stderr:?}");
}

/// A process that stops (SIGSTOP: alive, silent) stalls the group: the launcher names it
/// and stops the group (`restart = "never"`), or restarts it and goes on (`on-failure`).
#[test]
fn a_stalled_process_is_named_and_stopped_or_restarted() {
    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(dir.path(), "stall_timeout_ms = 1000\n");
    let mut group = Group::start(dir.path(), &toml, 1_000_000);
    group.wait_for_episodes(1, Duration::from_secs(60));
    let controller = group.child("controller");
    kill(controller, Signal::SIGSTOP).expect("stop the controller");
    let (ok, out, err) = group.finish(Duration::from_secs(60));
    let said = err.join("\n");
    assert!(!ok, "{out:?}");
    assert!(
        said.contains("the group made no progress for 1.0 s: controller stopped reporting"),
        "{said}"
    );
    // Stopped processes ignore everything but SIGKILL, which the shutdown ends with.
    assert!(!group.children_alive());

    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(
        dir.path(),
        "stall_timeout_ms = 1000\nrestart = \"on-failure\"\n",
    );
    let mut group = Group::start(dir.path(), &toml, 1_000_000);
    group.wait_for_episodes(1, Duration::from_secs(60));
    kill(group.child("bridge"), Signal::SIGSTOP).expect("stop the bridge");
    let said = group.wait_for_stderr("restarting it", Duration::from_secs(60));
    assert!(
        said.iter()
            .any(|l| l.contains("no progress for 1.0 s: bridge stopped reporting")),
        "{said:?}"
    );
    while group.stdout.try_recv().is_ok() {}
    group.wait_for_episodes(2, Duration::from_secs(60));
    kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGINT).expect("Ctrl-C");
    let (ok, out, err) = group.finish(Duration::from_secs(60));
    assert!(ok, "{out:?}\n{err:?}");
}

/// The library survives the launcher's death: 20 times, the launcher is SIGKILLed mid-run;
/// each time its children shut down with their save (a task more in the library), leave no
/// temporary file, and the library loads.
#[test]
fn killing_the_launcher_twenty_times_never_loses_the_library() {
    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(dir.path(), "");
    let library = dir.path().join("data/library.tesl");
    for round in 1..=20u32 {
        let group = Group::start(dir.path(), &toml, 1_000_000);
        group.wait_for_episodes(1 + round as usize % 3, Duration::from_secs(60));
        let children = group.children();
        assert_eq!(children.len(), 3, "round {round}");
        kill(Pid::from_raw(group.launcher.id() as i32), Signal::SIGKILL).expect("kill");
        wait_gone(&children, Duration::from_secs(30));
        assert_eq!(tasks_of(&library), round, "round {round}");
        let leftovers: Vec<_> = std::fs::read_dir(dir.path().join("data"))
            .expect("data dir")
            .filter_map(Result::ok)
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp-"))
            .map(|e| e.file_name())
            .collect();
        assert!(leftovers.is_empty(), "round {round}: {leftovers:?}");
        drop(group);
    }
}

/// `tes launch | head -2`: the launcher's output closes after two lines; the group still
/// runs to its end and the library is saved.
#[test]
fn a_closed_output_pipe_does_not_lose_the_run() {
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::write(dir.path().join("launch.toml"), launch_file(dir.path(), "")).unwrap();
    let _sharing = sharing_the_machine();
    let launcher = tes_command()
        .args(["launch", "--episodes", "6", "--config"])
        .arg(dir.path().join("launch.toml"))
        .env("TES_DATA_DIR", dir.path().join("data"))
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("tes launch starts");
    let mut launcher = Killed(launcher);
    let out = launcher.0.stdout.take().expect("stdout");
    let mut lines = std::io::BufReader::new(out).lines();
    for _ in 0..2 {
        lines.next().expect("a line").expect("text");
    }
    drop(lines); // `head` exits: the pipe's reading end is closed
    let status = wait_exit(&mut launcher.0, Duration::from_secs(60), "the launcher");
    assert!(status.success(), "{status:?}");
    assert_eq!(tasks_of(&dir.path().join("data/library.tesl")), 1);
    let controller = std::fs::read_to_string(dir.path().join("run/controller.out")).unwrap();
    assert_eq!(
        controller
            .lines()
            .filter(|l| l.starts_with("episode "))
            .count(),
        6,
        "{controller}"
    );
}

/// A library path that is a FIFO, a dangling symbolic link, or a directory stops the launch
/// with a message naming the path and what it is; the dangling link is left in place.
#[test]
fn a_hostile_library_path_stops_the_launch_and_is_left_alone() {
    let dir = tempfile::tempdir().expect("temp dir");
    let fifo = dir.path().join("fifo.tesl");
    nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
    let dangling = dir.path().join("dangling.tesl");
    std::os::unix::fs::symlink(dir.path().join("gone.tesl"), &dangling).expect("symlink");
    let directory = dir.path().join("dir.tesl");
    std::fs::create_dir(&directory).expect("dir");
    for (path, what) in [
        (&fifo, "FIFO"),
        (&dangling, "does not exist"),
        (&directory, "directory"),
    ] {
        let extra = format!("[controller]\nlibrary = \"{}\"\n", path.display());
        let mut group = Group::start(dir.path(), &launch_file(dir.path(), &extra), 2);
        let (ok, out, err) = group.finish(Duration::from_secs(60));
        assert!(!ok, "{}: {out:?}", path.display());
        let said = err.join("\n");
        assert!(
            said.contains(&path.display().to_string()) && said.contains(what),
            "{}: {said}",
            path.display()
        );
    }
    assert!(
        std::fs::symlink_metadata(&dangling).is_ok_and(|m| m.file_type().is_symlink()),
        "the dangling link was replaced"
    );
}

/// The simulated brick served on a pseudo-terminal at `link` (50 times faster than the wall
/// clock) until `stop` is raised.
fn serve_brick(
    link: &Path,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<()> {
    use tes_bridge::brick::{SimBrick, SimBrickConfig};
    use tes_bridge::clock::ScaledClock;
    let server = tes_bridge::pty::PtyServer::open(link).expect("a pty for the brick");
    std::thread::spawn(move || {
        let mut brick = SimBrick::new(SimBrickConfig::default(), 7).expect("a brick");
        server
            .serve(&mut brick, &ScaledClock::new(50.0), None, &stop)
            .expect("the brick serves");
    })
}

/// A link to the brick that goes down and comes back within `link_timeout_ms` (the brick's
/// pseudo-terminal closed, then opened again at the same path) only pauses the run: the
/// bridge reports the link down, reconnects, carries out the command it could not deliver,
/// and the launch finishes its episodes.
#[test]
fn a_link_that_comes_back_within_the_timeout_resumes_the_run() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let dir = tempfile::tempdir().expect("temp dir");
    let link = dir.path().join("brick");
    let stop = Arc::new(AtomicBool::new(false));
    let brick = serve_brick(&link, stop.clone());
    let extra = format!(
        "[perception]\nstep_cap = 8\n\
         [bridge]\ntransport = \"serial:{}\"\nlink_timeout_ms = 5000\n\
         [bridge.serial]\nreconnect_backoff_ms = 100\n\
         [bridge.poll]\nidle_period_ms = 100\n",
        link.display()
    );
    let mut group = Group::start(dir.path(), &launch_file(dir.path(), &extra), 8);
    group.wait_for_episodes(2, Duration::from_secs(60));
    // The brick goes away...
    stop.store(true, Ordering::SeqCst);
    brick.join().expect("the brick thread");
    group.wait_for_stderr("link to the brick failed", Duration::from_secs(30));
    std::thread::sleep(Duration::from_millis(500));
    // ...and comes back at the same path.
    let stop = Arc::new(AtomicBool::new(false));
    let brick = serve_brick(&link, stop.clone());
    let (ok, out, err) = group.finish(Duration::from_secs(120));
    stop.store(true, Ordering::SeqCst);
    brick.join().expect("the brick thread");
    assert!(ok, "{out:?}\n{err:?}");
    assert!(
        out.iter().any(|l| l.starts_with("controller: 8 episodes")),
        "{out:?}"
    );
}

/// Errors say the real cause: a process out of file descriptors (`ulimit -n 32`) and a run
/// directory that cannot be written are named as such, and the launch exits non-zero.
#[test]
fn errors_name_the_real_cause() {
    let dir = tempfile::tempdir().expect("temp dir");
    let _sharing = sharing_the_machine();
    let out = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -n 32 && exec '{}' launch --episodes 1",
            env!("CARGO_BIN_EXE_tes")
        ))
        .env("TES_DATA_DIR", dir.path().join("data"))
        .stdin(Stdio::null())
        .output()
        .expect("tes launch runs");
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{said}");
    assert!(said.contains("too many open files"), "{said}");
    let _ = tes_runtime::channel::clean_stale_resources();

    // A run directory under /sys cannot be created (not even by root).
    let toml = dir.path().join("launch.toml");
    std::fs::write(&toml, "[launch]\nrun_dir = \"/sys/tes-run\"\n").expect("launch file");
    let out = tes_command()
        .args(["launch", "--episodes", "1", "--config"])
        .arg(&toml)
        .env("TES_DATA_DIR", dir.path().join("data"))
        .output()
        .expect("tes launch runs");
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{said}");
    assert!(
        said.contains("cannot write the run directory: /sys/tes-run") && !said.contains("invalid"),
        "{said}"
    );
}

/// The episode numbers of `csv` (an `episodes.csv`), in order.
fn csv_episodes(csv: &str) -> Vec<u32> {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let at = header
        .iter()
        .position(|c| *c == "episode")
        .expect("an episode column");
    lines
        .map(|l| {
            l.split(',')
                .nth(at)
                .expect("the episode")
                .parse()
                .expect("a number")
        })
        .collect()
}

/// A respawned role goes on with the run: with `restart = "on-failure"`, perception-sim, the
/// controller and the bridge are each killed mid-run; the episode numbers carry on (no number
/// twice, in the output or in `episodes.csv`), and the run ends at the episode budget — not
/// the budget again after perception's restart. (Perception killed in the instant between
/// recording an episode's end and publishing it leaves that one number out: at most one gap.)
#[test]
fn a_respawned_role_continues_the_run_and_repeats_no_episode() {
    let dir = tempfile::tempdir().expect("temp dir");
    let toml = launch_file(dir.path(), "restart = \"on-failure\"\nmax_restarts = 10\n");
    let budget = 60;
    let mut group = Group::start(dir.path(), &toml, budget);
    let mut out = Vec::new();
    for role in ["perception-sim", "controller", "bridge"] {
        out.extend(group.wait_for_episodes(3, Duration::from_secs(120)));
        kill(group.child(role), Signal::SIGKILL).expect("kill a child");
        // Restarts are counted per process.
        group.wait_for_stderr(
            &format!("{role} was killed by SIGKILL; respawning it (restart 1/10)"),
            Duration::from_secs(60),
        );
    }
    let (ok, rest, err) = group.finish(Duration::from_secs(300));
    out.extend(rest);
    assert!(ok, "{out:#?}\n{err:#?}");
    let numbers: Vec<u32> = out
        .iter()
        .filter_map(|l| tes_controller::summary::EpisodeLine::parse(l))
        .map(|e| e.episode)
        .collect();
    let mut unique = numbers.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(unique.len(), numbers.len(), "an episode twice: {numbers:?}");
    assert!(numbers.iter().all(|&n| n < budget), "{numbers:?}");
    assert!(numbers.len() + 1 >= budget as usize, "{numbers:?}");
    let csv = std::fs::read_to_string(dir.path().join("run/episodes.csv")).expect("episodes.csv");
    let mut rows = csv_episodes(&csv);
    rows.sort_unstable();
    assert_eq!(rows, unique, "episodes.csv has each episode once:\n{csv}");
}
