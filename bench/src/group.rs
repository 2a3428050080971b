//! The measured group of a latency run: its launch file and files, run on one host through
//! shared memory, or split in two launches linked by Zenoh.

use std::path::{Path, PathBuf};
use std::process::{Child, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use tes_controller::config::ThreadPlacement;
use tes_controller::process::ControllerSummary;
use tes_launch::children::{self, ChildCommand};
use tes_launch::{LaunchFile, LaunchSection, Options};
use tes_learning::library::store::{self, StoredLibrary};
use tes_runtime::affinity::Placement;
use tes_runtime::channel::WaitStrategy;
use tes_runtime::latency::LatencyReport;
use tes_topics::Role;

use crate::error::{BenchError, GroupFailure, Result};
use crate::harness::{CheckedLatency, Harness, Pace, REAL_LINK_DELAY_MS, Via};
use std::collections::BTreeMap;
use tes_bridge::config::LinkDelayConfig;
use tes_bridge::process::BridgeReport;
use tes_link::LinkSection;
use tes_link::keys::{self, KeySet};
use tes_perception_sim::process::PerceptionSummary;
use tes_runtime::channel::Catches;
use tes_runtime::cpu::CpuUse;

/// The files of one latency run, in its directory.
#[derive(Debug, Clone)]
pub(crate) struct RunFiles {
    /// The controller's view library.
    pub(crate) library: PathBuf,
    /// The controller's summary (`report`).
    pub(crate) controller_report: PathBuf,
    /// The bridge's latency report (observation → command at the bridge).
    pub(crate) bridge_report: PathBuf,
    /// Perception's summary (its CPU).
    pub(crate) perception_report: PathBuf,
}

impl RunFiles {
    fn in_dir(dir: &Path) -> Self {
        Self {
            library: dir.join("library.tesl"),
            controller_report: dir.join("controller.json"),
            bridge_report: dir.join("bridge.json"),
            perception_report: dir.join("perception.json"),
        }
    }
}

/// The measured group: its launch file, its starting library, its files.
pub(crate) struct Group {
    /// The launch file of the whole group.
    pub(crate) file: LaunchFile,
    /// The library every run starts from.
    stored: StoredLibrary,
    /// Where the run's files are.
    files: RunFiles,
    /// The run's directory.
    pub(crate) dir: PathBuf,
}

impl Group {
    /// The group of `latency`'s run in `dir`, its services under `prefix`, from `stored`.
    pub(crate) fn new(
        dir: &Path,
        prefix: &str,
        latency: &CheckedLatency,
        stored: StoredLibrary,
    ) -> Self {
        let files = RunFiles::in_dir(dir);
        Self {
            file: group_file(dir, prefix, latency, &files),
            stored,
            files,
            dir: dir.to_owned(),
        }
    }

    /// Runs `file` (the group's, or a variant of it) from the starting library, and reads
    /// the bridge's latency report and the controller's summary.
    pub(crate) fn run(
        &self,
        file: &LaunchFile,
        harness: &mut Harness<'_>,
    ) -> Result<(LatencyReport, ControllerSummary)> {
        // Every run starts from the same library (the previous one saved what it learned).
        store::save(&self.files.library, &self.stored)?;
        launch(file, "the process group failed", harness)?;
        read_reports(&self.files)
    }

    /// [`Group::run`] split in two launches linked by Zenoh over loopback TCP: perception-sim
    /// and the bridge in this process's launch, the controller in a launch of its own
    /// ([`crate::latency::Programs::launch`]) with an iceoryx2 domain of its own (so only the
    /// link connects them).
    pub(crate) fn run_split(
        &self,
        carrier: &Carrier,
        harness: &mut Harness<'_>,
    ) -> Result<(LatencyReport, ControllerSummary)> {
        store::save(&self.files.library, &self.stored)?;
        let port = carrier.free_port()?;
        let (robot, workstation) = split(&self.file, port, &self.dir, carrier);
        let text = tes_launch::reference::render_resolved(&workstation)?;
        let path = self.dir.join("controller-launch.toml");
        std::fs::write(&path, text)
            .map_err(BenchError::io(format!("cannot write {}", path.display())))?;
        let log = self.dir.join("controller-launch.log");
        let mut other = spawn_launch(&harness.programs.launch, &path, &log)?;
        let ran = launch(&robot, "the robot's launch failed", harness);
        let status = wait_or_kill(
            &mut other,
            Duration::from_secs(60),
            false,
            "cannot poll the controller's launch",
        );
        remove_domain_of(&split_domain());
        let status = status?;
        ran?;
        match status {
            Some(s) if s.success() => {}
            Some(s) => {
                return Err(BenchError::Run(format!(
                    "the controller's launch {} (see {})",
                    children::describe(s),
                    log.display()
                )));
            }
            None => {
                return Err(BenchError::Run(
                    "the controller's launch did not stop".into(),
                ));
            }
        }
        read_reports(&self.files)
    }
}

/// Each process's CPU, the anticipating receivers' catches, the bridge's command hop.
type RunExtras = (
    BTreeMap<String, CpuUse>,
    BTreeMap<String, Catches>,
    LatencyReport,
);

impl Group {
    /// Each process's CPU over the measured actions, from the reports of the last run and the
    /// controller's `summary`; the anticipating receivers' catches; and the bridge's command
    /// hop (command published → received).
    pub(crate) fn bridge_and_perception(&self, summary: &ControllerSummary) -> Result<RunExtras> {
        let bridge = BridgeReport::load(&self.files.bridge_report).map_err(BenchError::io(
            format!("no bridge report at {}", self.files.bridge_report.display()),
        ))?;
        let path = &self.files.perception_report;
        let text = std::fs::read_to_string(path).map_err(BenchError::io(format!(
            "no perception report at {}",
            path.display()
        )))?;
        let perception: PerceptionSummary =
            serde_json::from_str(&text).map_err(BenchError::Malformed)?;
        let cpu = [
            ("perception-sim", perception.cpu),
            ("controller", summary.cpu),
            ("controller/acting", summary.acting_thread_cpu),
            ("bridge", bridge.cpu),
        ]
        .into_iter()
        .filter_map(|(name, used)| used.map(|u| (name.to_owned(), u)))
        .collect();
        let catches = [("controller", summary.catches), ("bridge", bridge.catches)]
            .into_iter()
            .filter_map(|(name, c)| c.map(|c| (name.to_owned(), c)))
            .collect();
        Ok((cpu, catches, bridge.command_hop))
    }
}

/// Runs the group `file` describes until it stops, its events told to the harness's
/// observer; a failed verdict is an error, said as `what` with what failed.
fn launch(file: &LaunchFile, what: &'static str, harness: &mut Harness<'_>) -> Result<()> {
    let options = Options::new(harness.programs.child.clone(), harness.stop.clone());
    let verdict =
        tes_launch::run(file, options, &mut *harness.observer).map_err(|e| BenchError::Group {
            what,
            cause: Box::new(e.into()),
        })?;
    if verdict.success() {
        Ok(())
    } else {
        Err(BenchError::Group {
            what,
            cause: Box::new(GroupFailure::Failed(verdict.failures)),
        })
    }
}

/// The bridge's latency report and the controller's summary.
fn read_reports(files: &RunFiles) -> Result<(LatencyReport, ControllerSummary)> {
    let report = LatencyReport::load(&files.bridge_report).map_err(BenchError::io(format!(
        "no bridge report at {}",
        files.bridge_report.display()
    )))?;
    let path = &files.controller_report;
    let text = std::fs::read_to_string(path).map_err(BenchError::io(format!(
        "no controller report at {}",
        path.display()
    )))?;
    let summary: ControllerSummary = serde_json::from_str(&text).map_err(BenchError::Malformed)?;
    Ok((report, summary))
}

/// The launch file of the measured group.
fn group_file(dir: &Path, prefix: &str, latency: &CheckedLatency, files: &RunFiles) -> LaunchFile {
    let s = latency.settings();
    let mut file = LaunchFile {
        launch: LaunchSection {
            episodes: u32::MAX,
            arena: 3,
            real_time_factor: 0.0,
            wait: s.wait,
            service_prefix: prefix.to_owned(),
            run_dir: Some(dir.join("run")),
            seed: s.seed,
            ..LaunchSection::default()
        },
        ..LaunchFile::default()
    };
    file.perception.actions = latency.total();
    file.perception.report = Some(files.perception_report.clone());
    file.perception.warmup_actions = s.warmup();
    if s.pace == Pace::Real {
        // The robot's pace: the paper's settle time, the brick in real time, and every
        // reply of the brick as late as over Bluetooth.
        file.launch.real_time_factor = 1.0;
        let (mean_ms, jitter_ms) = REAL_LINK_DELAY_MS;
        file.bridge.link_delay = LinkDelayConfig {
            enabled: true,
            mean_ms,
            jitter_ms,
        };
    }
    // The return path (robot motion) is not measured: block, as the floor's source does.
    file.perception.wait = WaitStrategy::Block;
    file.keep("perception", "wait");
    let c = &mut file.controller;
    c.library = Some(files.library.clone());
    c.budget_us = s.budget_us;
    c.warmup_actions = s.warmup();
    c.report = Some(files.controller_report.clone());
    // Resolved CPUs or "none", never "auto": the floor's hop was given the same CPU.
    let ThreadPlacement { acting, planner } = latency.placement();
    c.acting_cpu = acting.map_or(Placement::Unpinned, Placement::Cpu);
    c.planner_cpu = planner.map_or(Placement::Unpinned, Placement::Cpu);
    c.planning = s.planning;
    c.order = s.order;
    if let Some(us) = s.planner_idle_spin_us {
        c.planner_idle_spin_us = Some(us);
    }
    // The bridge's [ipc] table as the bench writes it: the launch-wide prefix and wait go in.
    let ipc = &mut file.bridge.ipc;
    ipc.budget_us = s.budget_us;
    ipc.warmup_commands = s.warmup();
    ipc.latency_report = Some(files.bridge_report.clone());
    file
}

/// The group split in two: the robot's launch (perception-sim and the bridge, listening on
/// `port`) and the workstation's (the controller, connecting to it, its run folder apart),
/// linked by `carrier`.
fn split(file: &LaunchFile, port: u16, dir: &Path, carrier: &Carrier) -> (LaunchFile, LaunchFile) {
    let group = format!("tes-bench/{}", std::process::id());
    let mut robot = file.clone();
    robot.launch.roles = vec![Role::Perception, Role::Bridge];
    let link = &mut robot.launch.link;
    link.group.clone_from(&group);
    link.listen = vec![carrier.endpoint(port)];
    link.connect = Vec::new();
    link.multicast_scouting = Some(false);
    // Plain TCP is what `--via zenoh` measures: unauthenticated, so said as such.
    link.insecure = matches!(carrier, Carrier::Tcp);
    // One machine, one clock: the latency is measured across the link.
    link.restamp = false;
    carrier.keys_into(link, Carrier::ROBOT);
    let mut workstation = robot.clone();
    workstation.launch.roles = vec![Role::Controller];
    workstation.launch.run_dir = Some(dir.join("run-controller"));
    let link = &mut workstation.launch.link;
    link.listen = Vec::new();
    link.connect = vec![carrier.endpoint(port)];
    carrier.keys_into(link, Carrier::CONTROLLER);
    (robot, workstation)
}

/// How a split run's two launches (or the floor's two sides) are linked: plain TCP on
/// loopback, or QUIC with keys of the run's own authority (`tes link keygen`'s).
#[derive(Debug, Clone)]
pub enum Carrier {
    /// Plain TCP on loopback.
    Tcp,
    /// QUIC: TLS 1.3, both sides' certificates checked, access control by role.
    Quic(KeySet),
}

impl Carrier {
    /// The robot's host in the key set.
    pub const ROBOT: usize = 0;
    /// The controller's host in the key set.
    pub const CONTROLLER: usize = 1;

    /// The carrier `via` asks for; a QUIC run's keys are made in `dir/keys`.
    pub fn for_via(via: Via, dir: &Path) -> Result<Self> {
        if via != Via::ZenohTls {
            return Ok(Carrier::Tcp);
        }
        let keys = keys::keygen(
            &dir.join("keys"),
            &keys::default_hosts(),
            keys::DEFAULT_PORT,
        )
        .map_err(|e| BenchError::Run(format!("cannot make the run's keys: {e}")))?;
        Ok(Carrier::Quic(keys))
    }

    /// A port free a moment ago on loopback: TCP, or UDP for QUIC.
    pub fn free_port(&self) -> Result<u16> {
        match self {
            Carrier::Tcp => free_port(),
            Carrier::Quic(_) => std::net::UdpSocket::bind("127.0.0.1:0")
                .and_then(|s| s.local_addr())
                .map(|a| a.port())
                .map_err(BenchError::io("no free UDP port on loopback".into())),
        }
    }

    /// The loopback endpoint on `port`.
    pub fn endpoint(&self, port: u16) -> String {
        match self {
            Carrier::Tcp => format!("tcp/127.0.0.1:{port}"),
            Carrier::Quic(_) => format!("quic/127.0.0.1:{port}"),
        }
    }

    /// Host `host`'s files ([`Carrier::ROBOT`] or [`Carrier::CONTROLLER`]): the authority,
    /// its certificate and its key; none over TCP.
    pub fn files(&self, host: usize) -> Option<[PathBuf; 3]> {
        let Carrier::Quic(keys) = self else {
            return None;
        };
        let files = keys.hosts.get(host)?;
        Some([
            keys.authority.clone(),
            files.cert.clone(),
            files.key.clone(),
        ])
    }

    /// Gives `link` host `host`'s files, if any.
    pub fn keys_into(&self, link: &mut LinkSection, host: usize) {
        if let Some(files) = self.files(host) {
            link.set_keys(files);
        }
    }
}

/// Starts `launch --config CONFIG` in an iceoryx2 domain of its own, its output in `log`.
fn spawn_launch(launch: &ChildCommand, config: &Path, log: &Path) -> Result<Child> {
    let file = std::fs::File::create(log).map_err(BenchError::io(
        "cannot create the controller launch's log".into(),
    ))?;
    let shared = file
        .try_clone()
        .map_err(BenchError::io("cannot share the log".into()))?;
    std::process::Command::new(&launch.program)
        .args(&launch.args)
        .arg("--config")
        .arg(config)
        .env(tes_runtime::channel::DOMAIN_VAR, split_domain())
        .stdin(Stdio::null())
        .stdout(shared)
        .stderr(file)
        .spawn()
        .map_err(BenchError::io(
            "cannot start the controller's launch".into(),
        ))
}

/// The iceoryx2 domain of the split run's controller launch: this process's own.
fn split_domain() -> String {
    format!("bench{}", std::process::id())
}

/// Removes what iceoryx2 keeps of `domain` once its processes have ended (the segment it keeps
/// per domain included), so a bench leaves nothing in shared memory. A process of it still
/// alive (a killed launch's children are stopping) leaves the domain to `tes status --clean`.
pub(crate) fn remove_domain_of(domain: &str) {
    for _ in 0..50 {
        match tes_runtime::channel::remove_domain(domain) {
            Ok(true) => return,
            Ok(false) => std::thread::sleep(Duration::from_millis(100)),
            Err(e) => {
                eprintln!("warning: cannot remove the iceoryx2 domain {domain}: {e}");
                return;
            }
        }
    }
    eprintln!(
        "warning: the iceoryx2 domain {domain} still has a live process; tes status --clean removes it later"
    );
}

/// A free TCP port on loopback.
pub(crate) fn free_port() -> Result<u16> {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .map_err(BenchError::io("no free TCP port on loopback".into()))
}

/// Waits up to `limit` for `child` to end (at once with `now`); kills it if it has not.
/// Returns how it ended, or `None` if it was killed. `poll` says a failed poll.
pub(crate) fn wait_or_kill(
    child: &mut Child,
    limit: Duration,
    now: bool,
    poll: &str,
) -> Result<Option<ExitStatus>> {
    let deadline = Instant::now() + limit;
    loop {
        if let Some(s) = child.try_wait().map_err(BenchError::io(poll.to_owned()))? {
            return Ok(Some(s));
        }
        if now || Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}
