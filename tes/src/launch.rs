//! `tes launch`: perception-sim, controller and bridge as one process group.
//!
//! The three are separate OS processes (this executable re-run in each role, so one build
//! serves all) sharing fixed-size buffers through iceoryx2. The launcher:
//!
//! * reads an optional TOML file (`[launch]`, `[perception]`, `[controller]`, `[bridge]`) once,
//!   into each process's typed settings; sets the launch-wide values (arena, episodes, wait,
//!   seed, service prefix, the brick's time scale, …) on them where a table does not set its
//!   own; checks every child's settings *before* starting anything (a bad key is reported with
//!   the file, its line, the table and key, and the reason); and writes each child's settings,
//!   serialised from those typed values, to the run directory;
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
//! * with `--roles` (`[launch] roles`), starts only those children and reaches the others,
//!   in launches on other hosts, through its link ([`crate::link`]): it waits for them before
//!   starting anything, stops with them, and stops (non-zero) when one is lost.
//!
//! It exits non-zero if a child failed.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde::{Deserialize, Serialize};
use tes_bridge::config::{BridgeConfig, BridgeSettings, TransportKind};
use tes_controller::config::{ControllerConfig, default_data_dir};
use tes_perception_sim::process::PerceptionConfig;
use tes_runtime::channel::{self, WaitStrategy};
use tes_runtime::lock::{Lock, LockError};
use tes_runtime::progress::{ProgressWatch, holdup};
use tes_runtime::settings::{self, Origin, SettingError};
use tes_topics::{Role, ServiceNames};

mod child;
mod file;
mod group;
mod logs;
mod reference;
mod run_folder;
mod run_record;
mod tui;

pub use child::run_child;
pub(crate) use file::*;
pub(crate) use group::*;
use logs::ChildLine;
pub(crate) use reference::render_resolved as render_launch_file;
use run_folder::RUNS;

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
        conflicts_with_all = ["config", "episodes", "tui", "record", "roles"]
    )]
    print_config: Option<reference::Format>,
    /// Record the run to this MCAP file (overrides `[launch] record`): every observation,
    /// command and motor state, for `tes replay` and viewers such as Foxglove.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Start only these processes (comma-separated: perception-sim, controller, bridge;
    /// overrides `[launch] roles`); the others run on other hosts, reached over Zenoh
    /// (`[launch.link]`, docs/multi-host.md).
    #[arg(long, value_delimiter = ',', value_name = "ROLE,...")]
    roles: Option<Vec<String>>,
}

/// Runs `tes launch`.
pub fn run(args: &LaunchArgs) -> Result<()> {
    if let Some(format) = args.print_config {
        return reference::print(format);
    }
    let mut file = match &args.config {
        Some(path) => read_launch_file(path)?,
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
    if let Some(roles) = &args.roles {
        file.launch.roles.clone_from(roles);
        // Said by the user, so placed as theirs: a bad role is named with the flag.
        if let Err(e) = check_launch(&file.launch) {
            bail!("--roles: {}; nothing was started", e.reason);
        }
    }
    let prepared = prepare(&file)?;
    run_group(&file, prepared, true, args.tui).map(|_| ())
}

/// Runs the group `file` describes until perception finishes, a child fails (or exhausts its
/// restarts) or a signal; `echo` prints the controller's lines and the launcher's notes.
pub(crate) fn run_file(file: &LaunchFile, echo: bool) -> Result<GroupOutcome> {
    let prepared = prepare(file)?;
    run_group(file, prepared, echo, false)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tes_controller::config::PlanningMode;

    /// A launch file `launch.toml` in a fresh directory, with `[launch] run_dir` in that
    /// directory followed by `extra`; the directory and the file, read.
    fn launch_file(
        extra: &str,
    ) -> (
        tempfile::TempDir,
        PathBuf,
        Result<LaunchFile, LaunchFileError>,
    ) {
        let dir = tempfile::tempdir().expect("temp dir");
        let text = format!(
            "[launch]\nrun_dir = \"{}\"\n{extra}",
            dir.path().join("run").display()
        );
        let path = dir.path().join("launch.toml");
        std::fs::write(&path, text).expect("launch file");
        let file = read_launch_file(&path);
        (dir, path, file)
    }

    /// Prepares the children of a launch file with `extra` after its `[launch]` table; the
    /// directory's `run` holds the children's settings files.
    fn prepared(extra: &str) -> (tempfile::TempDir, Result<Prepared, LaunchFileError>) {
        let (dir, _, file) = launch_file(extra);
        let specs = prepare(&file.expect("a launch file"));
        (dir, specs)
    }

    fn bridge_settings(dir: &tempfile::TempDir) -> BridgeConfig {
        let path = dir.path().join("run/bridge.toml");
        let text = std::fs::read_to_string(path).expect("bridge.toml");
        BridgeConfig::from_toml_str(&text).expect("valid bridge settings")
    }

    /// The setting error a launch file's problem is.
    fn setting(err: &LaunchFileError) -> &SettingError {
        match err {
            LaunchFileError::Setting(e) => e,
            other => panic!("not a setting error: {other}"),
        }
    }

    /// A run directory that cannot be written is named with its cause — never reported as
    /// invalid settings.
    #[test]
    fn an_unwritable_run_directory_is_named_with_its_cause() {
        for (code, cause) in [
            (28, "the disk is full"),
            (30, "the file system is read-only"),
        ] {
            let err = LaunchFileError::RunDir {
                path: PathBuf::from("/data/run"),
                error: std::io::Error::from_raw_os_error(code),
            };
            let shown = err.to_string();
            assert!(
                shown.starts_with("cannot write the run directory: /data/run: ")
                    && shown.contains(cause)
                    && shown.ends_with("; nothing was started"),
                "{shown}"
            );
        }
    }

    /// `roles` starts only the named children; an unknown or repeated role, and link settings
    /// that cannot work, are refused naming their key.
    #[test]
    fn roles_name_the_children_and_bad_roles_or_link_settings_are_refused() {
        let (_, ok) = prepared("roles = [\"controller\"]\n");
        let specs = ok.expect("prepared").specs;
        assert_eq!(
            specs.iter().map(|s| s.role).collect::<Vec<_>>(),
            ["controller"]
        );
        let (_, ok) = prepared("roles = [\"bridge\", \"perception-sim\"]\n");
        let specs = ok.expect("prepared").specs;
        assert_eq!(
            specs.iter().map(|s| s.role).collect::<Vec<_>>(),
            ["bridge", "perception-sim"]
        );
        for (extra, key, reason) in [
            ("roles = [\"brige\"]\n", "roles", "unknown role \"brige\""),
            (
                "roles = [\"bridge\", \"bridge\"]\n",
                "roles",
                "\"bridge\" is listed twice",
            ),
            (
                "roles = [\"bridge\"]\n[launch.link]\ngroup = \"a*b\"\n",
                "link.group",
                "is not a group name",
            ),
            (
                "roles = [\"bridge\"]\n[launch.link]\nconnect = [\"udp/10.0.0.1:7447\"]\n",
                "link.connect",
                "is not a TCP endpoint",
            ),
            (
                "roles = [\"bridge\"]\n[launch.link]\npeer_timeout_ms = 5\n",
                "link.peer_timeout_ms",
                "at least 100",
            ),
        ] {
            let (_, bad) = prepared(extra);
            let err = bad.expect_err(extra);
            let e = setting(&err);
            assert_eq!((e.process, e.key.as_str()), ("launch", key), "{extra}");
            assert!(e.reason.contains(reason), "{extra}: {}", e.reason);
        }
        // Link settings are not checked without roles: nothing uses them.
        let (_, ok) = prepared("[launch.link]\npeer_timeout_ms = 5\n");
        assert!(ok.is_ok());
    }

    #[test]
    fn keep_alives_must_come_well_within_the_watchdog_deadline() {
        let (_, ok) = prepared("");
        assert!(ok.is_ok());
        let (_, off) = prepared("[controller]\nkeepalive_ms = 0\n");
        assert!(off.is_ok());
        let (_, bad) = prepared("[controller]\nkeepalive_ms = 600\n");
        let err = bad.expect_err("refused");
        let e = setting(&err);
        assert_eq!((e.process, e.key.as_str()), ("controller", "keepalive_ms"));
        assert_eq!(e.line(), Some(4));
        let err = err.to_string();
        assert!(
            err.contains("[controller] keepalive_ms: 600 must be at most half")
                && err.contains("1000 ms of wall time"),
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

    /// A key the parser refuses in any table — unknown, of the wrong type, an enum's unknown
    /// word — is reported against the user's own file, at its line, with its table and key.
    #[test]
    fn a_bad_key_in_a_child_table_names_the_users_file_line_and_key() {
        // (text after the two-line [launch] table, process, key, line)
        let cases = [
            (
                "episodes = 2\n\n[bridge]\nseed = 3\n[bridge.watchdog]\ndeadline_ms = \"soon\"\n",
                "bridge",
                "watchdog.deadline_ms",
                8,
            ),
            ("[bridge]\nwatchdogg = 1\n", "bridge", "watchdogg", 4),
            ("[bridge]\ntransport = \"usb\"\n", "bridge", "transport", 4),
            (
                "[bridge.ipc]\nservice_prefix = \"x/\"\nwait = \"nap\"\n",
                "bridge",
                "ipc.wait",
                5,
            ),
            (
                "[[bridge.actions]]\nid = 0\nleft_deg = 1\nright_deg = 1\nspeed = 3\n",
                "bridge",
                "actions[0].speed",
                7,
            ),
            (
                "[controller]\nepsilon = 0.1\nbudjet_us = 5\n",
                "controller",
                "budjet_us",
                5,
            ),
            ("[controller]\nwait = \"nap\"\n", "controller", "wait", 4),
            (
                "[controller]\nplanning = \"later\"\n",
                "controller",
                "planning",
                4,
            ),
            (
                "[controller]\nacting_cpu = \"fast\"\n",
                "controller",
                "acting_cpu",
                4,
            ),
            (
                "[perception]\narena = \"three\"\n",
                "perception",
                "arena",
                4,
            ),
            ("[perception]\nwait = \"doze\"\n", "perception", "wait", 4),
            ("wait = \"nap\"\n", "launch", "wait", 3),
            ("restart = \"always\"\n", "launch", "restart", 3),
        ];
        for (extra, process, key, line) in cases {
            let (_, path, file) = launch_file(extra);
            let err = file.expect_err(extra);
            let e = setting(&err);
            assert_eq!(
                (e.process, e.key.as_str(), e.line()),
                (process, key, Some(line)),
                "{extra}"
            );
            let location = e.location.as_ref().expect("placed");
            assert_eq!(location.origin, Origin::File(path.clone()));
            let table = if process == "launch" {
                "launch"
            } else {
                process
            };
            let shown = err.to_string();
            let start = format!("launch file {}:{line}:", path.display());
            assert!(shown.starts_with(&start), "{shown}");
            assert!(shown.contains(&format!(": [{table}] {key}: ")), "{shown}");
            assert!(shown.ends_with("; nothing was started"), "{shown}");
        }
    }

    /// A value a child's `check` refuses is placed at its key's line in the user's file; a
    /// refused value the file does not set is said to be a default or a launch-wide value.
    /// Nothing is written to the run directory.
    #[test]
    fn a_range_error_of_a_child_names_the_users_file_line_and_key() {
        let cases = [
            (
                "seed = 2\n[bridge]\nuse_command_degrees = false\n\
                 [bridge.poll]\nsettle_polls = 0\n",
                "bridge",
                "poll.settle_polls",
                Some(7),
            ),
            (
                "[bridge.watchdog]\ndeadline_ms = 100\n[bridge.poll]\nmoving_period_ms = 100\n",
                "bridge",
                "poll.moving_period_ms",
                Some(6),
            ),
            (
                "[[bridge.actions]]\nid = 1\nleft_deg = 1\nright_deg = 1\n\
                 [[bridge.actions]]\nid = 1\nleft_deg = 2\nright_deg = 2\n",
                "bridge",
                "actions[1].id",
                Some(8),
            ),
            (
                "[controller]\n# the budget\nbudget_us = 0\n",
                "controller",
                "budget_us",
                Some(5),
            ),
            (
                "[controller]\nplanning = \"between-polls\"\n",
                "controller",
                "planning",
                Some(4),
            ),
            (
                "[perception]\nstep_cap = 0\n",
                "perception",
                "step_cap",
                Some(4),
            ),
            ("arena = 4\n", "launch", "arena", Some(3)),
            (
                &format!("service_prefix = \"{}\"\n", "x".repeat(65)),
                "launch",
                "service_prefix",
                Some(3),
            ),
            // The launch-wide real-time factor makes the brick 100 000 times faster.
            (
                "real_time_factor = 0.00001\n",
                "bridge",
                "brick.time_scale",
                None,
            ),
        ];
        for (extra, process, key, line) in cases {
            let (dir, path, file) = launch_file(extra);
            let err = prepare(&file.expect(extra)).expect_err(extra);
            let e = setting(&err);
            assert_eq!(
                (e.process, e.key.as_str(), e.line()),
                (process, key, line),
                "{extra}"
            );
            let shown = err.to_string();
            let table = format!("[{process}] {key}");
            match line {
                Some(line) => {
                    let start = format!("launch file {}:{line}:1: {table}: ", path.display());
                    assert!(shown.starts_with(&start), "{shown}");
                }
                None => {
                    let start = format!(
                        "launch file {}: {table} (not in the file: a default or a launch-wide \
                         value): ",
                        path.display()
                    );
                    assert!(shown.starts_with(&start), "{shown}");
                }
            }
            for role in ROLES {
                let written = dir.path().join(format!("run/{role}.toml"));
                assert!(!written.exists(), "{extra}: {role} was written");
            }
        }
    }

    /// The launch-wide values go into the typed tables unless a table sets the key itself
    /// (in the file, or in code with `keep`).
    #[test]
    fn launch_wide_values_go_where_a_table_does_not_set_its_own() {
        let (_, _, file) = launch_file(
            "arena = 1\nepisodes = 3\nreal_time_factor = 0.5\nwait = \"spin-then-block\"\n\
             seed = 5\nservice_prefix = \"g/\"\n\
             [perception]\nwait = \"block\"\nseed = 9\n\
             [controller]\nservice_prefix = \"c/\"\n\
             [bridge]\nuse_command_degrees = false\n[bridge.ipc]\nwait = \"spin\"\n",
        );
        let c = file.expect("valid").children().expect("valid");
        let stb = WaitStrategy::SpinThenBlock(WaitStrategy::DEFAULT_SPIN);
        let p = &c.perception;
        assert_eq!((p.arena, p.episodes, p.real_time_factor), (1, 3, 0.5));
        assert_eq!(
            (p.wait, p.seed, p.service_prefix.as_str()),
            (WaitStrategy::Block, 9, "g/")
        );
        let k = &c.controller;
        assert_eq!((k.wait, k.seed, k.service_prefix.as_str()), (stb, 5, "c/"));
        let b = &c.bridge;
        assert_eq!((b.seed, b.use_command_degrees), (5, false));
        assert_eq!(
            (b.ipc.wait, b.ipc.service_prefix.as_str()),
            (WaitStrategy::Spin, "g/")
        );
        // Twice as fast as physical time: the brick at 2x, its deadline 2 s of brick time.
        assert_eq!((b.brick.time_scale, b.watchdog.deadline_ms), (2.0, 2000));

        let mut file = LaunchFile::default();
        file.launch.wait = WaitStrategy::Spin;
        file.perception.wait = WaitStrategy::Block;
        file.keep("perception", "wait");
        let c = file.children().expect("valid");
        assert_eq!(c.perception.wait, WaitStrategy::Block);
        assert_eq!(c.controller.wait, WaitStrategy::Spin);
        assert_eq!(c.controller.planning, PlanningMode::Auto);
        assert_eq!(c.bridge.ipc.wait, WaitStrategy::Spin);
        assert!(c.bridge.use_command_degrees);
        // Without a file, an error names the embedded defaults.
        file.launch.episodes = 0;
        let err = LaunchFileError::Setting(file.children().expect_err("no episodes"));
        assert_eq!(
            err.to_string(),
            "launch settings (embedded defaults): [launch] episodes: must be at least 1; \
             nothing was started"
        );
    }

    /// What a child reads from the run directory is exactly the typed settings the launcher
    /// checked: typed → TOML → typed is the identity for each child.
    #[test]
    fn the_children_read_back_exactly_what_the_launcher_checked() {
        for extra in [
            "",
            "wait = \"spin\"\nseed = 77\nreal_time_factor = 1.0\narena = 2\n\
             [perception]\nsettle_ms = 150\nmotor_timeout_ms = 900\n\
             [controller]\nlibrary = \"/tmp/tes-lib.tesl\"\nreport = \"/tmp/r.json\"\n\
             planning = \"thread\"\nacting_cpu = \"none\"\nepsilon = 0.2\n\
             [bridge]\nseed = 3\n[bridge.link_delay]\nenabled = true\n[bridge.motors]\npower = 60\n\
             [[bridge.actions]]\nid = 0\nname = \"only\"\nleft_deg = 10\nright_deg = -10\n",
        ] {
            let (dir, _, file) = launch_file(extra);
            let mut file = file.expect("valid");
            let prepared = prepare(&file).expect("prepared");
            // Without a prefix of its own, the launch got a unique one.
            assert!(prepared.service_prefix.starts_with("tes-"), "{prepared:?}");
            file.launch
                .service_prefix
                .clone_from(&prepared.service_prefix);
            let mut children = file.children().expect("valid");
            children.write_into(&dir.path().join("run"));
            assert_eq!(
                prepared.specs.iter().map(|s| s.role).collect::<Vec<_>>(),
                ["bridge", "controller", "perception-sim"]
            );
            let read = |role: &str| {
                let path = dir.path().join(format!("run/{role}.toml"));
                (
                    std::fs::read_to_string(&path).expect("written"),
                    Origin::File(path),
                )
            };
            let (text, origin) = read("bridge");
            let bridge = BridgeSettings::from_toml_in(&text, origin.clone()).expect("bridge");
            assert_eq!(bridge, children.bridge, "{text}");
            assert_eq!(
                BridgeConfig::from_toml_in(&text, origin).ok(),
                children.bridge.check().ok()
            );
            let (text, origin) = read("controller");
            let controller = ControllerConfig::from_toml_in(&text, origin).expect("controller");
            assert_eq!(controller, children.controller, "{text}");
            let (text, origin) = read("perception-sim");
            let perception = PerceptionConfig::from_toml_in(&text, origin).expect("perception");
            assert_eq!(perception, children.perception, "{text}");
        }
    }
}
