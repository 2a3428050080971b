//! The group split across two "hosts" on this machine: two launches, each in an iceoryx2
//! domain of its own (`TES_IPC_DOMAIN`, so shared memory cannot connect them) and a data
//! directory of its own, linked by Zenoh over loopback TCP only — perception-sim and the
//! bridge on one, the controller on the other.
//!
//! Every launch is killed (its children follow by their parent-death signal) and its domain's
//! stale resources removed when a test ends, failed or not.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

use crate::common::*;

/// A TCP port that was free a moment ago (the link listens on it).
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// One "host": its directory, its iceoryx2 domain, and its launch once started.
struct Host {
    dir: tempfile::TempDir,
    domain: String,
    /// Environment variables of its launch besides its domain.
    env: Vec<(&'static str, &'static str)>,
    group: Option<Group>,
}

impl Host {
    fn new(name: &str) -> Self {
        static HOSTS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let dir = tempfile::tempdir().expect("temp dir");
        // Short and unique (tests run side by side): iceoryx2 names files after it.
        let n = HOSTS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let domain = format!("t{}-{n}{name}", std::process::id());
        Self {
            dir,
            domain,
            env: Vec::new(),
            group: None,
        }
    }

    /// Starts `tes launch` with `[launch]` keys `launch` and `[launch.link]` keys `link`.
    fn start(&mut self, launch: &str, link: &str, episodes: u32, args: &[&str]) -> &mut Group {
        self.start_with(launch, link, "", episodes, args)
    }

    /// [`start`](Self::start) with the tables `tables` after `[launch.link]`.
    fn start_with(
        &mut self,
        launch: &str,
        link: &str,
        tables: &str,
        episodes: u32,
        args: &[&str],
    ) -> &mut Group {
        let text = format!(
            "{}{launch}\n[launch.link]\nmulticast_scouting = false\nrestamp = false\n\
             {link}\n{tables}\n",
            launch_file(self.dir.path(), "")
        );
        let mut env = vec![("TES_IPC_DOMAIN", self.domain.as_str())];
        env.extend(self.env.iter().copied());
        let group = Group::start_in(self.dir.path(), &text, episodes, args, &env);
        self.group.insert(group)
    }

    fn group(&mut self) -> &mut Group {
        self.group.as_mut().expect("started")
    }

    /// The iceoryx2 files of this host's domain still on the machine.
    fn leftovers(&self) -> Vec<PathBuf> {
        let prefix = format!("iox2_{}_", self.domain);
        let mut found = Vec::new();
        let mut dirs = vec![
            PathBuf::from("/dev/shm"),
            std::env::temp_dir().join("iceoryx2"),
        ];
        while let Some(dir) = dirs.pop() {
            let Ok(entries) = std::fs::read_dir(&dir) else {
                continue;
            };
            for e in entries.filter_map(Result::ok) {
                let path = e.path();
                if path.is_dir() {
                    dirs.push(path);
                } else {
                    let name = e.file_name().to_string_lossy().into_owned();
                    // iceoryx2 keeps one management segment per domain, by design, whoever
                    // ran in it: not a resource of the group.
                    if name.starts_with(&prefix) && !name.ends_with(".global_mgmt") {
                        found.push(path);
                    }
                }
            }
        }
        found
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        drop(self.group.take());
        // The guard of `Group` cleans the test's own domain; this host's is its own.
        let _ = tes_command()
            .args(["status", "--clean"])
            .env("TES_IPC_DOMAIN", &self.domain)
            .output();
        // The domain's management segment goes with the test's domain.
        if let Ok(entries) = std::fs::read_dir("/dev/shm") {
            let prefix = format!("iox2_{}_", self.domain);
            for e in entries.filter_map(Result::ok) {
                if e.file_name().to_string_lossy().starts_with(&prefix) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
    }
}

/// The `[launch]` lines of the two hosts of group `group`, the robot's host listening on
/// `port`.
fn split(group: &str, port: u16) -> (String, String) {
    let robot = format!(
        "group = \"{group}\"\nlisten = [\"tcp/127.0.0.1:{port}\"]\nconnect = []\n\
         peer_timeout_ms = 60000\n"
    );
    let workstation = format!(
        "group = \"{group}\"\nlisten = []\nconnect = [\"tcp/127.0.0.1:{port}\"]\n\
         peer_timeout_ms = 60000\n"
    );
    (robot, workstation)
}

fn group_name(test: &str) -> String {
    format!("tes-test/{}/{test}", std::process::id())
}

/// Split over Zenoh, the group runs its 80 episodes, learns (its last 40 beat a random
/// policy's over the same seeded budget, as on one host), and the library is saved on the
/// controller's side only; both launches stop cleanly and leave nothing in their domains.
#[test]
fn split_across_two_hosts_the_group_learns_and_saves_on_the_controllers_side() {
    let port = free_port();
    let (robot_link, workstation_link) = split(&group_name("learn"), port);
    let mut robot = Host::new("r");
    let mut workstation = Host::new("w");
    let library = workstation.dir.path().join("library.tesl");
    let controller = format!(
        "[controller]\nepsilon = 0.05\nlibrary = \"{}\"\n",
        library.display()
    );
    let recording = workstation.dir.path().join("run.mcap");
    let record = recording.to_str().expect("a UTF-8 temp path");
    // The controller's host first: it waits for the others. It records the run.
    workstation.start_with(
        "seed = 1",
        &workstation_link,
        &controller,
        80,
        &["--roles", "controller", "--record", record],
    );
    robot.start(
        "seed = 1\nroles = [\"perception-sim\", \"bridge\"]",
        &robot_link,
        80,
        &[],
    );
    let (ok_r, out_r, err_r) = robot.group().finish(Duration::from_secs(600));
    let (ok_w, out_w, err_w) = workstation.group().finish(Duration::from_secs(60));
    assert!(ok_r, "robot: stdout {out_r:?}\nstderr {err_r:?}");
    assert!(ok_w, "workstation: stdout {out_w:?}\nstderr {err_w:?}");
    let episodes = out_w.iter().filter(|l| l.starts_with("episode ")).count();
    assert_eq!(episodes, 80, "{out_w:?}");
    // The recording on the controller's side holds the map and observations that came over
    // the link and every command, and replays to the same decisions.
    let recorded = tes_recorder::reader::Recording::open(&recording).expect("the recording reads");
    assert_eq!(recorded.truncated, None);
    assert!(recorded.world_map.is_some());
    assert_eq!(recorded.commands.len() as u64, reported_actions(&out_w));
    assert!(recorded.observations.len() > recorded.commands.len());
    let (ok, said, stderr) = replay(&recording, &[]);
    assert!(ok, "{said} {stderr}");
    let n = recorded.commands.len();
    assert_eq!(
        said.trim(),
        format!("replay: {n} of {n} commands identical")
    );
    let learner_last = mean_reward(&out_w, 40, 80);

    // The random policy, on one host (the transport does not change what it does).
    let dir = tempfile::tempdir().expect("temp dir");
    let random = format!(
        "seed = 1\n[controller]\nepsilon = 1.0\nlibrary = \"{}\"\n",
        dir.path().join("library.tesl").display()
    );
    let mut single = Group::start(dir.path(), &launch_file(dir.path(), &random), 80);
    let (ok, out, err) = single.finish(Duration::from_secs(600));
    assert!(ok, "stdout {out:?}\nstderr {err:?}");
    let random_last = mean_reward(&out, 40, 80);
    assert!(
        learner_last > random_last + 1.0,
        "learner {learner_last:.2} vs random {random_last:.2} per episode (last 40)"
    );

    // The library is the workstation's; the robot's data directory has none.
    let stored = load_library(&library).expect("the saved library loads");
    assert!(!stored.library.is_empty());
    assert!(!robot.dir.path().join("data/library.tesl").exists());
    for host in [&robot, &workstation] {
        assert!(host.leftovers().is_empty(), "{:?}", host.leftovers());
    }
}

/// Ctrl-C on either host stops both launches cleanly (exit 0, the library saved).
#[test]
fn ctrl_c_on_either_host_stops_the_other_cleanly() {
    for interrupted in ["robot", "workstation"] {
        let port = free_port();
        let (robot_link, workstation_link) = split(&group_name(interrupted), port);
        let mut robot = Host::new("r");
        let mut workstation = Host::new("w");
        robot.start(
            "roles = [\"perception-sim\", \"bridge\"]\nreal_time_factor = 0.01",
            &robot_link,
            10_000,
            &[],
        );
        workstation.start("", &workstation_link, 10_000, &["--roles", "controller"]);
        workstation
            .group()
            .wait_for_episodes(1, Duration::from_secs(120));
        let target = if interrupted == "robot" {
            &mut robot
        } else {
            &mut workstation
        };
        let pid = Pid::from_raw(target.group().launcher.id() as i32);
        kill(pid, Signal::SIGINT).expect("SIGINT");
        let (ok_r, out_r, err_r) = robot.group().finish(Duration::from_secs(60));
        let (ok_w, out_w, err_w) = workstation.group().finish(Duration::from_secs(60));
        assert!(ok_r, "{interrupted}: robot: {out_r:?}\n{err_r:?}");
        assert!(ok_w, "{interrupted}: workstation: {out_w:?}\n{err_w:?}");
        assert!(
            out_w.iter().any(|l| l.contains("(saved)")),
            "{interrupted}: the controller saved its library: {out_w:?}"
        );
        let stopper = if interrupted == "robot" {
            &err_w
        } else {
            &err_r
        };
        assert!(
            stopper
                .iter()
                .any(|l| l.contains("a peer stopped the group")),
            "{interrupted}: {stopper:?}"
        );
        for host in [&robot, &workstation] {
            assert!(!host.group.as_ref().is_some_and(Group::children_alive));
            assert!(host.leftovers().is_empty(), "{:?}", host.leftovers());
        }
    }
}

/// Killing the controller's host mid-move (its launcher and, with it, its children): the
/// keep-alives that came over the link held the robot's watchdog off through the move until
/// then; the bridge brakes within its deadline of the last one, and the robot's launch ends
/// non-zero naming the lost peer, with no child left and no stale shared memory.
#[test]
fn losing_the_controllers_host_mid_move_brakes_and_stops_the_robot_non_zero() {
    let port = free_port();
    let (robot_link, workstation_link) = split(&group_name("loss"), port);
    let mut robot = Host::new("r");
    let mut workstation = Host::new("w");
    // Physical time (the watchdog's deadline is then 1 s of wall time) and every action a
    // long move, 20 000° a wheel (about 30 s); the bridge says when a command reaches the
    // brick.
    robot.env.push(("RUST_LOG", "warn,tes_bridge=debug"));
    robot.start_with(
        "roles = [\"perception-sim\", \"bridge\"]\nreal_time_factor = 1.0",
        &robot_link,
        &format!(
            "[bridge]\nuse_command_degrees = false\n{}",
            long_move_actions()
        ),
        10_000,
        &[],
    );
    workstation.start("", &workstation_link, 10_000, &["--roles", "controller"]);
    let mut seen = robot
        .group()
        .wait_for_stderr("command sent to the brick", Duration::from_secs(120));
    // Two and a half deadlines into the move, the watchdog has not tripped.
    std::thread::sleep(Duration::from_millis(2500));
    seen.extend(robot.group().stderr.try_iter());
    assert!(
        !seen.iter().any(|l| l.contains("watchdog:")),
        "braked while the controller lives: {seen:?}"
    );
    let killed = Instant::now();
    workstation
        .group()
        .launcher
        .kill()
        .expect("kill the workstation");
    let brake = "watchdog: no command within the deadline";
    let lines = robot
        .group()
        .wait_for_stderr(brake, Duration::from_secs(10));
    // Seen on the launcher's stderr (through the bridge's log file) within the deadline and
    // some slack for a loaded machine; braked `silence_ms` after the last keep-alive.
    let took = killed.elapsed();
    assert!(
        took <= Duration::from_millis(2500),
        "braked {took:?} after the kill"
    );
    assert_braked_at_the_deadline(&lines);

    let (ok, out, err) = robot.group().finish(Duration::from_secs(60));
    assert!(!ok, "the robot's launch must fail: {out:?}\n{err:?}");
    let err = lines.into_iter().chain(err).collect::<Vec<_>>().join("\n");
    assert!(
        err.contains("the controller's launch left the group"),
        "{err}"
    );
    assert!(
        killed.elapsed() < Duration::from_secs(60),
        "the robot's launch took {:?} to give up",
        killed.elapsed()
    );
    assert!(!robot.group().children_alive());
    assert!(robot.leftovers().is_empty(), "{:?}", robot.leftovers());
}

/// Bad settings are refused before anything runs: an unknown role; a role no host plays or an
/// unreachable peer (the launch says whom it waits for and gives up, non-zero); two launches
/// playing the controller.
#[test]
fn bad_roles_and_unreachable_peers_are_refused_and_start_nothing() {
    // An unknown role, by flag and in the file.
    let mut host = Host::new("u");
    let group = host.start("", "", 1, &["--roles", "controler"]);
    let (ok, _, err) = group.finish(Duration::from_secs(30));
    let err = err.join("\n");
    assert!(!ok && err.contains("unknown role \"controler\""), "{err}");
    assert!(err.trim_end().ends_with("nothing was started"), "{err}");
    let group = host.start("roles = [\"brige\"]", "", 1, &[]);
    let (ok, _, err) = group.finish(Duration::from_secs(30));
    let err = err.join("\n");
    assert!(
        !ok && err.contains("[launch] roles: unknown role \"brige\""),
        "{err}"
    );

    // Nobody there: the launch names the roles it waits for and gives up.
    let port = free_port();
    let group = host.start(
        "",
        &format!(
            "group = \"{}\"\nlisten = []\nconnect = [\"tcp/127.0.0.1:{port}\"]\n\
             peer_timeout_ms = 1500\n",
            group_name("nobody")
        ),
        1,
        &["--roles", "controller"],
    );
    let (ok, _, err) = group.finish(Duration::from_secs(60));
    let err = err.join("\n");
    assert!(!ok, "{err}");
    assert!(
        err.contains("playing the perception-sim, bridge was reached within 1.5 s"),
        "{err}"
    );
    assert!(!host.dir.path().join("run/controller.out").exists() || !err.contains("episode"));

    // Two controllers in one group.
    let port = free_port();
    let (a_link, b_link) = split(&group_name("twice"), port);
    let mut a = Host::new("a");
    let mut b = Host::new("b");
    a.start("", &a_link, 1, &["--roles", "controller"]);
    b.start("", &b_link, 1, &["--roles", "controller"]);
    for host in [&mut a, &mut b] {
        let (ok, _, err) = host.group().finish(Duration::from_secs(60));
        let err = err.join("\n");
        assert!(!ok, "{err}");
        assert!(err.contains("play the controller"), "{err}");
        assert!(!host.group().children_alive());
    }
}
