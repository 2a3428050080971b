//! `tes launch --ros2` and `--rosbag` (docs/ros2.md). Built without the `ros2` feature, `tes`
//! refuses them before anything starts. Built with it, a whole launched group is heard by an
//! independent ROS 2 peer — Eclipse Cyclone DDS (PyPI `cyclonedds`, run by the Python
//! `build.rs` probed), knowing only ROS 2's names and types — on every topic, and what it
//! hears is what the launch itself reports. (The ROS 2 side alone is tested against Cyclone
//! DDS and rosbags in `ros2/tests/it`.)

/// A `tes` without the feature says how to build it in, and starts nothing: no process, no
/// bag directory.
#[cfg(not(feature = "ros2"))]
#[test]
fn ros2_is_refused_by_a_tes_built_without_it() {
    use crate::common::{Group, launch_file};
    use std::time::Duration;

    let dir = tempfile::tempdir().expect("temp dir");
    let bag = dir.path().join("bag");
    let bag_arg = bag.display().to_string();
    for args in [vec!["--ros2"], vec!["--rosbag", bag_arg.as_str()]] {
        let toml = launch_file(dir.path(), "");
        let mut group = Group::start_in(dir.path(), &toml, 1, &args, &[]);
        let (ok, _, stderr) = group.finish(Duration::from_secs(120));
        assert!(!ok, "{args:?} was accepted: {stderr:?}");
        let said = stderr.join("\n");
        assert!(
            said.contains("built without ROS 2")
                && said.contains("--features ros2")
                && said.contains("nothing was started"),
            "{said}"
        );
        assert!(!said.contains("started controller"), "{said}");
        assert!(!bag.exists());
    }
}

#[cfg(feature = "ros2")]
mod on_ros2 {
    use std::io::{BufRead, BufReader, Write};
    use std::path::PathBuf;
    use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
    use std::time::Duration;

    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    use serde_json::Value;
    use tes_controller::summary::EpisodeLine;

    use crate::common::{Group, launch_file};

    /// The UDP sockets among `pid`'s open files (DDS speaks RTPS over UDP).
    fn udp_sockets_of(pid: u32) -> usize {
        let mut udp = std::collections::HashSet::new();
        for table in ["/proc/net/udp", "/proc/net/udp6"] {
            let text = std::fs::read_to_string(table).unwrap_or_default();
            udp.extend(
                text.lines()
                    .skip(1)
                    .filter_map(|l| l.split_whitespace().nth(9).map(str::to_owned)),
            );
        }
        let Ok(fds) = std::fs::read_dir(format!("/proc/{pid}/fd")) else {
            return 0;
        };
        fds.filter_map(Result::ok)
            .filter_map(|fd| std::fs::read_link(fd.path()).ok())
            .filter_map(|target| {
                let t = target.to_string_lossy().into_owned();
                Some(t.strip_prefix("socket:[")?.strip_suffix(']')?.to_owned())
            })
            .filter(|inode| udp.contains(inode))
            .count()
    }

    /// The names of `pid`'s threads.
    fn thread_names_of(pid: u32) -> Vec<String> {
        let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
            return Vec::new();
        };
        tasks
            .filter_map(Result::ok)
            .filter_map(|t| std::fs::read_to_string(t.path().join("comm")).ok())
            .map(|n| n.trim().to_owned())
            .collect()
    }

    /// Built with the feature, a launch that does not ask for ROS 2 has no ROS 2 thread and
    /// no UDP socket while its group runs (the same look finds both in a launch that asks:
    /// the Cyclone DDS test below).
    #[test]
    fn a_launch_without_ros2_has_no_ros2_thread_and_no_udp_socket() {
        let dir = tempfile::tempdir().expect("temp dir");
        let toml = launch_file(dir.path(), "");
        let mut group = Group::start_in(dir.path(), &toml, 3, &[], &[]);
        let mut out = group.wait_for_episodes(1, Duration::from_secs(300));
        let launcher = group.launcher.id();
        let (threads, sockets) = (thread_names_of(launcher), udp_sockets_of(launcher));
        let (ok, rest, err) = group.finish(Duration::from_secs(300));
        out.extend(rest);
        assert!(ok, "the launch failed: {out:?} {err:?}");
        assert!(!threads.is_empty(), "the launcher's threads are readable");
        assert!(!threads.iter().any(|t| t == "ros2"), "{threads:?}");
        assert_eq!(sockets, 0, "UDP sockets of a launch without ROS 2");
        assert!(err.iter().all(|l| !l.contains("ROS 2")), "{err:?}");
    }

    /// Episodes the launch is given: more than it runs before the test stops it.
    const EPISODES: u32 = 1_000_000;
    /// Episodes the launch runs after DDS discovery is done, before the test stops it.
    const HEARD_EPISODES: usize = 20;
    /// The longest the peer listens (a bound on a hung test, not a timing claim).
    const LISTEN_S: u32 = 600;

    /// The Cyclone DDS listener of `ros2/tests/peers`, killed when dropped.
    pub(super) struct Listener {
        child: Child,
        stdin: Option<ChildStdin>,
        out: BufReader<ChildStdout>,
    }

    impl Listener {
        pub(super) fn start(domain: u16) -> Self {
            let peers = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../ros2/tests/peers");
            let mut child = Command::new(env!("TES_ROS2_PYTHON"))
                .arg(peers.join("listen.py"))
                .args([domain.to_string(), LISTEN_S.to_string()])
                .arg("--until-stdin-closes")
                .current_dir(&peers)
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .stderr(Stdio::inherit())
                .spawn()
                .expect("the Cyclone DDS listener starts");
            let stdin = child.stdin.take();
            let out = BufReader::new(child.stdout.take().expect("its output"));
            Self { child, stdin, out }
        }

        pub(super) fn line(&mut self) -> String {
            let mut line = String::new();
            self.out
                .read_line(&mut line)
                .expect("the listener's output");
            line.trim().to_owned()
        }

        /// Closes its input (the run is over) and reads its report.
        pub(super) fn report(&mut self) -> Value {
            if let Some(mut stdin) = self.stdin.take() {
                let _ = stdin.flush();
            }
            let line = self.line();
            serde_json::from_str(&line).unwrap_or_else(|e| panic!("the report {line:?}: {e}"))
        }
    }

    impl Drop for Listener {
        fn drop(&mut self) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }

    /// An episode end as `/tes/episode/end` says it: `episode N: reward R, A actions, OUTCOME`.
    fn episode_and_reward(text: &str) -> (u32, f64) {
        let parsed = text.strip_prefix("episode ").and_then(|rest| {
            let (n, rest) = rest.split_once(": reward ")?;
            let (reward, _) = rest.split_once(", ")?;
            Some((n.parse().ok()?, reward.parse().ok()?))
        });
        parsed.unwrap_or_else(|| panic!("not an episode end: {text:?}"))
    }

    /// A launched group with `--ros2`, in a DDS domain of the test's own, heard by Cyclone
    /// DDS. Discovery between RustDDS and Cyclone DDS takes seconds here, and volatile topics
    /// reach only a matched subscriber, so the group runs until the peer has matched every
    /// topic and then [`HEARD_EPISODES`] episodes more, and is stopped by Ctrl-C. Every topic
    /// of docs/ros2.md arrives and decodes with ROS 2's types (`/rosout`'s lines, transient
    /// local, from the start of the run); the episode ends heard are the launch's last ones,
    /// none missing, each naming an episode of the launch with that episode's reward (the
    /// launch's own line, to its two printed decimals), and `/tes/episode/reward` says the
    /// same rewards in the same order; the launch's end says how many messages it published.
    #[test]
    #[cfg_attr(
        not(tes_cyclonedds),
        ignore = "PyPI's cyclonedds is not installed: python3 -m venv target/ros2-venv && target/ros2-venv/bin/pip install cyclonedds rosbags"
    )]
    fn a_cyclone_dds_peer_hears_a_launched_group_on_every_topic() {
        let dir = tempfile::tempdir().expect("temp dir");
        let domain = 1 + (std::process::id() % 200) as u16;
        let mut listener = Listener::start(domain);
        assert_eq!(listener.line(), "ready");
        let toml = launch_file(dir.path(), "");
        let domain_text = domain.to_string();
        // At info the processes log lines for /rosout; RustDDS's own are left out.
        let mut group = Group::start_in(
            dir.path(),
            &toml,
            EPISODES,
            &["--ros2"],
            &[
                ("ROS_DOMAIN_ID", domain_text.as_str()),
                ("RUST_LOG", "info,rustdds=warn,ros2_client=warn"),
            ],
        );
        let matched = listener.line();
        assert_eq!(matched, "matched", "the peer never matched every topic");
        // The episodes so far went out before discovery was done; count those after.
        let mut out: Vec<String> = group.stdout.try_iter().collect();
        out.extend(group.wait_for_episodes(HEARD_EPISODES, Duration::from_secs(300)));
        let launcher = group.launcher.id();
        let (threads, sockets) = (thread_names_of(launcher), udp_sockets_of(launcher));
        kill(Pid::from_raw(launcher as i32), Signal::SIGINT).expect("Ctrl-C to the launcher");
        let (ok, rest, err) = group.finish(Duration::from_secs(120));
        out.extend(rest);
        assert!(ok, "the launch failed: {out:?} {err:?}");
        assert!(threads.iter().any(|t| t == "ros2"), "{threads:?}");
        assert!(sockets > 0, "the DDS node's UDP sockets: {threads:?}");
        let said = err.join("\n");
        assert!(
            said.contains(&format!(
                "on ROS 2 as node /tes/group, ROS 2 domain {domain}"
            )),
            "{said}"
        );
        assert!(said.contains("launch: published "), "{said}");
        let episodes: Vec<EpisodeLine> = out.iter().filter_map(|l| EpisodeLine::parse(l)).collect();

        let report = listener.report();
        every_topic_was_heard(&report);
        assert_eq!(report["/tes/path"]["last"]["frame"], "arena");
        assert!(
            report["/tes/decision/action"]["last"]["data"].as_u64() < Some(3),
            "one of the arena's three actions: {report}"
        );
        let roles = ["perception-sim", "controller", "bridge"];
        let rosout = report["/rosout"]["last"]["name"].as_str().unwrap_or("");
        assert!(roles.contains(&rosout), "{report}");
        the_episodes_heard_are_the_launchs(&report, &episodes);
    }

    /// Every topic of docs/ros2.md had a message, the arena (or grid) drawn in frame `arena`
    /// with the robot's body in `robot`, and the robot's pose on `/tf` from `arena`.
    pub(super) fn every_topic_was_heard(report: &Value) {
        for topic in [
            "/tf",
            "/tes/arena",
            "/tes/path",
            "/tes/decision/action",
            "/tes/decision/latency_us",
            "/tes/episode/reward",
            "/tes/episode/end",
            "/rosout",
        ] {
            assert!(
                report[topic]["count"].as_u64() > Some(0),
                "nothing on {topic}: {report}"
            );
        }
        assert_eq!(
            report["/tes/arena"]["last"]["frames"],
            serde_json::json!(["arena", "robot"])
        );
        assert_eq!(report["/tf"]["last"]["parent"], "arena");
    }

    /// The episode ends and rewards the peer heard against the launch's episode lines.
    fn the_episodes_heard_are_the_launchs(report: &Value, episodes: &[EpisodeLine]) {
        let ends: Vec<(u32, f64)> = report["/tes/episode/end"]["all"]
            .as_array()
            .expect("the episode ends")
            .iter()
            .map(|t| episode_and_reward(t.as_str().expect("a string")))
            .collect();
        let rewards: Vec<f64> = report["/tes/episode/reward"]["all"]
            .as_array()
            .expect("the rewards")
            .iter()
            .map(|r| r.as_f64().expect("a number"))
            .collect();
        let first = ends.first().expect("at least one episode end heard").0;
        let heard: Vec<u32> = ends.iter().map(|(n, _)| *n).collect();
        // The launch prints an episode once its controller has it; the ROS 2 side may have
        // published one more, ended as the group stopped.
        let printed: Vec<u32> = episodes
            .iter()
            .map(|e| e.episode)
            .filter(|n| *n >= first)
            .collect();
        assert!(
            heard.len() >= HEARD_EPISODES
                && heard.starts_with(&printed[..heard.len().min(printed.len())]),
            "episodes heard {heard:?}, the launch's from {first} on {printed:?}"
        );
        assert!(
            heard.len() <= printed.len() + 1,
            "heard {heard:?}, printed {printed:?}"
        );
        // The rewards topic matched at its own moment: its last ones are the ends' last ones.
        let tail = rewards.len().min(ends.len());
        let pairs = ends[ends.len() - tail..]
            .iter()
            .zip(&rewards[rewards.len() - tail..]);
        assert!(tail >= HEARD_EPISODES, "{rewards:?}");
        for ((n, said_reward), reward) in pairs {
            assert!(
                (said_reward - reward).abs() < 1e-3,
                "episode {n}: {said_reward} vs {reward}"
            );
            if let Some(line) = episodes.iter().find(|e| e.episode == *n) {
                assert!(
                    (line.reward - reward).abs() <= 0.005 + 1e-9,
                    "episode {n}: the launch printed {}, ROS 2 said {reward}",
                    line.reward
                );
            }
        }
    }
}

/// A ROS 2 robot as the world (`[ros2_world]`, docs/ros2.md): an independent robot node on
/// Eclipse Cyclone DDS (`ros2/tests/peers/grid_robot.py`, no TES package: standard messages
/// only) plays one of the paper's §5.1 grid tasks, and `tes launch` learns it over ROS 2.
#[cfg(feature = "ros2")]
mod ros2_world {
    use std::io::{BufRead, BufReader};
    use std::path::{Path, PathBuf};
    use std::process::{Child, Command, Stdio};
    use std::time::Duration;

    use serde_json::{Value, json};
    use tes_controller::summary::EpisodeLine;
    use tes_experiments::episode::{AgentSettings, run_agent};
    use tes_experiments::grid::GridEnv;
    use tes_experiments::method::Method;
    use tes_perception_sim::grid::{GridSuite, GridTask};

    use super::on_ros2::Listener;
    use crate::common::{Group, launch_file};

    /// The grid task played: the suite's task 1 (20 × 20, 160 actions at most an episode),
    /// with the paper's 200 irrelevant features.
    const TASK: usize = 1;
    /// The suite's seed.
    const WORLD_SEED: u64 = 2017;
    /// Episodes the robot plays and the launch runs.
    const EPISODES: u32 = 20;
    /// In-process runs of the same task that make the spread.
    const RUNS: u64 = 20;

    fn task() -> GridTask {
        GridSuite::paper(WORLD_SEED, 200).swap_remove(TASK)
    }

    /// The task as the robot node reads it: its map (with the unreachable out state the
    /// group's map numbers after the cells), its true dynamics and its starts.
    fn task_json(task: &GridTask) -> Value {
        let n = task.n_states();
        let (e, a) = (task.n_effects(), task.n_actions());
        let mut next: Vec<Vec<usize>> = (0..n)
            .map(|s| (0..e).map(|k| task.apply_effect(s, k)).collect())
            .collect();
        next.push(vec![n; e]);
        let mut reward: Vec<f64> = (0..n).map(|s| task.reward(s)).collect();
        reward.push(0.0);
        let mut terminal: Vec<bool> = (0..n).map(|s| task.is_terminal(s)).collect();
        terminal.push(true);
        let mut features: Vec<Vec<u32>> = (0..n).map(|s| task.features(s).to_vec()).collect();
        features.push(Vec::new());
        let mut probs: Vec<Vec<Vec<f64>>> = (0..n)
            .map(|s| {
                (0..a)
                    .map(|k| task.true_effect_probs(s, k).to_vec())
                    .collect()
            })
            .collect();
        probs.push(vec![[1.0, 0.0, 0.0, 0.0, 0.0][..e].to_vec(); a]);
        let starts: Vec<usize> = (0..n).filter(|&s| !task.is_terminal(s)).collect();
        json!({
            "width": task.width(), "height": task.height(), "n_states": n + 1,
            "n_actions": a, "n_effects": e, "n_features": task.n_features(),
            "next_state": next, "reward": reward, "terminal": terminal,
            "features": features, "effect_probs": probs, "starts": starts,
            "step_cap": task.step_cap(),
        })
    }

    /// The launch file's `[ros2_world]` for the task, and the controller's mDAGL at the
    /// paper's §5.1 settings (λ = 0.05, α = 1.5), as loreRL has them in process.
    fn world_table(task: &GridTask) -> String {
        format!(
            "\n[controller]\nlambda = 0.05\nalpha = 1.5\n\n[ros2_world]\ncells = [{}, {}]\nactions = [\"north\", \"east\", \"south\", \
             \"west\"]\neffects = [\"north\", \"east\", \"south\", \"west\", \"stay\"]\n\
             features = {}\nmap_timeout_s = 120\n",
            task.width(),
            task.height(),
            task.n_features()
        )
    }

    /// The robot node (its output kept open: it says `done` at the end), killed when dropped.
    struct Robot {
        child: Child,
        _out: BufReader<std::process::ChildStdout>,
    }

    impl Robot {
        fn start(task_file: &Path, result: &Path, domain: u16) -> Self {
            let peers = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../ros2/tests/peers");
            let mut child = Command::new(env!("TES_ROS2_PYTHON"))
                .arg(peers.join("grid_robot.py"))
                .arg(task_file)
                .args(["--domain", &domain.to_string()])
                .args(["--episodes", &EPISODES.to_string(), "--seed", "7"])
                .arg("--out")
                .arg(result)
                .args(["--timeout", "300", "--send-malformed"])
                .current_dir(&peers)
                .stdout(Stdio::piped())
                .stderr(Stdio::inherit())
                .spawn()
                .expect("the Cyclone DDS robot starts");
            let mut out = BufReader::new(child.stdout.take().expect("its output"));
            let mut line = String::new();
            out.read_line(&mut line).expect("the robot's output");
            assert_eq!(line.trim(), "ready");
            Self { child, _out: out }
        }

        fn wait(mut self) -> bool {
            // Dropped after: killing an ended child does nothing.
            self.child.wait().is_ok_and(|s| s.success())
        }
    }

    impl Drop for Robot {
        fn drop(&mut self) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }

    /// The spread of `RUNS` in-process runs of loreRL (what the controller's TES is with an
    /// empty library) on the task over [`EPISODES`] episodes: the mean and standard deviation
    /// of the reward accumulated over them.
    fn in_process_spread(task: GridTask) -> (f64, f64) {
        let env = GridEnv::new(task).expect("the task forms a CMDP");
        let totals: Vec<f64> = (0..RUNS)
            .map(|seed| {
                run_agent(
                    Method::LoreRl,
                    &env,
                    EPISODES as usize,
                    seed,
                    AgentSettings::default(),
                    |_| {},
                )
                .expect("loreRL runs")
                .iter()
                .map(|e| e.reward)
                .sum()
            })
            .collect();
        let mean = totals.iter().sum::<f64>() / totals.len() as f64;
        let var =
            totals.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / (totals.len() - 1) as f64;
        (mean, var.sqrt())
    }

    /// Every topic of the group on ROS 2 was heard, the grid drawn and the robot on it, and
    /// the episode ends and rewards heard are the robot's.
    fn every_topic_is_heard(report: &Value, played: &[f64]) {
        super::on_ros2::every_topic_was_heard(report);
        assert!(
            report["/tes/decision/action"]["last"]["data"].as_u64() < Some(4),
            "one of the task's four actions: {report}"
        );
        let rewards: Vec<f64> = report["/tes/episode/reward"]["all"]
            .as_array()
            .expect("the rewards")
            .iter()
            .map(|r| r.as_f64().expect("a number"))
            .collect();
        assert_eq!(rewards.len(), played.len(), "{report}");
        for (heard, p) in rewards.iter().zip(played) {
            assert!((heard - p).abs() < 1e-4, "heard {heard}, played {p}");
        }
    }

    /// The robot plays [`EPISODES`] episodes of the grid task over ROS 2 and the launch runs
    /// as many: every episode's reward is the same on both sides (the robot's count, the ROS
    /// 2 world's report, the launch's episode lines, what a ROS 2 listener hears of the group
    /// on every topic), the one malformed step the robot sends is counted and dropped saying
    /// why, nothing else is refused, and the reward accumulated lies within three standard
    /// deviations of the same task run in-process.
    #[test]
    #[cfg_attr(
        not(tes_cyclonedds),
        ignore = "PyPI's cyclonedds is not installed: python3 -m venv target/ros2-venv && target/ros2-venv/bin/pip install cyclonedds rosbags"
    )]
    fn tes_learns_a_grid_task_a_cyclone_dds_robot_plays_over_ros2() {
        let dir = tempfile::tempdir().expect("temp dir");
        let task = task();
        let task_features = task.n_features();
        let task_file = dir.path().join("task.json");
        std::fs::write(&task_file, task_json(&task).to_string()).expect("the task file");
        let result = dir.path().join("robot.json");
        let domain = 1 + (std::process::id() % 200) as u16 + 17;
        // The group is also published on ROS 2 (`--ros2`) and heard by a listener that has
        // matched every topic before the robot starts (the world waits for its map).
        let mut listener = Listener::start(domain);
        assert_eq!(listener.line(), "ready");
        let toml = launch_file(dir.path(), &world_table(&task));
        let domain_text = domain.to_string();
        let mut group = Group::start_in(
            dir.path(),
            &toml,
            EPISODES,
            &["--ros2"],
            &[("ROS_DOMAIN_ID", domain_text.as_str())],
        );
        assert_eq!(
            listener.line(),
            "matched",
            "the listener never matched every topic"
        );
        let robot = Robot::start(&task_file, &result, domain);
        let (ok, out, err) = group.finish(Duration::from_secs(600));
        assert!(ok, "the launch failed: {out:?} {err:?}");
        assert!(robot.wait(), "the robot node failed");
        let heard = listener.report();

        let robot: Value = serde_json::from_slice(&std::fs::read(&result).expect("its result"))
            .expect("the robot's JSON");
        let played: Vec<f64> = robot["episodes"]
            .as_array()
            .expect("episodes")
            .iter()
            .map(|e| e["reward"].as_f64().expect("a reward"))
            .collect();
        assert_eq!(played.len(), EPISODES as usize);
        assert_eq!(robot["malformed_actions"], 0);
        let world: Value = serde_json::from_slice(
            &std::fs::read(dir.path().join("run/ros2-world.json")).expect("the world's report"),
        )
        .expect("its JSON");
        // The one step of the wrong size the robot sent: counted, dropped, said once.
        assert_eq!(world["malformed"], 1, "{world}");
        assert_eq!(world["stale"], 0, "{world}");
        let taken: Vec<f64> = world["episode_rewards"]
            .as_array()
            .expect("episode rewards")
            .iter()
            .map(|r| r.as_f64().expect("a number"))
            .collect();
        let lines: Vec<EpisodeLine> = out.iter().filter_map(|l| EpisodeLine::parse(l)).collect();
        assert_eq!(lines.len(), EPISODES as usize, "{out:?}");
        for (i, p) in played.iter().enumerate() {
            // The rewards travel as f32 once (the group's observations).
            assert!(
                (taken[i] - p).abs() < 1e-4,
                "episode {i}: {} vs {p}",
                taken[i]
            );
            assert!(
                (lines[i].reward - p).abs() <= 0.005 + 1e-6,
                "episode {i}: the launch printed {}, the robot had {p}",
                lines[i].reward
            );
        }
        every_topic_is_heard(&heard, &played);
        let total: f64 = played.iter().sum();
        let (mean, sd) = in_process_spread(task);
        assert!(
            (total - mean).abs() <= 3.0 * sd,
            "over ROS 2: {total:.3}; in process: {mean:.3} ± {sd:.3} (sd of {RUNS} runs)"
        );
        eprintln!("over ROS 2: {total:.3}; in process: {mean:.3} ± {sd:.3} ({RUNS} runs)");
        let said = err.join("\n");
        assert!(said.contains("the world of a ROS 2 robot"), "{said}");
        let features = task_features;
        let dropped = format!(
            "dropped a step on /tes/world/step: 3 numbers where the declared 7 step numbers + \
             {features} features make {}",
            7 + features
        );
        assert_eq!(said.matches(&dropped).count(), 1, "{said}");
        assert!(!said.contains("rustdds"), "DDS's own lines: {said}");
    }
}
