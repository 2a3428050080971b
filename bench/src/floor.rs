//! The floors a latency run is compared with: the loop's two hops with no work, on the
//! measured run's transport, at its cadence.
//!
//! * [`relay_floor`] — shared memory: [`crate::relay`]'s three processes (source, hop, sink)
//!   relaying the loop's payloads over iceoryx2;
//! * [`zenoh_floor`] — the split run's Zenoh link: the two hops through the very link a split
//!   launch uses ([`tes_link::Link`] on loopback TCP). The robot's side runs in this process,
//!   the controller's ([`zenoh_hop`]) in a process of its own with an iceoryx2 domain of its
//!   own, as the controller's launch is in the measured run.
//!
//! Each returns the round trip, and its first hop alone (observation stamped → the hop's
//! command published).

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use tes_launch::children::{self, ChildCommand, Process};
use tes_link::{Link, LinkSection};
use tes_runtime::channel::{self, Inbox, LatestInbox, LatestOutbox, Outbox, WaitStrategy};
use tes_runtime::clock::monotonic_ns;
use tes_runtime::latency::{LatencyRecorder, LatencyReport};
use tes_topics::{Command, Observation, Role, ServiceNames, StateAttributes, WorldMap};

use crate::error::{BenchError, Result};
use crate::group::{Carrier, remove_domain_of, wait_or_kill};
use crate::harness::{Floor, LatencySettings};
use crate::relay::{self, RelayConfig};

/// The scheduling help the floor gets because the group got it: the acting thread's CPU
/// for the hop, and a helper thread in the planner thread's place, polling as long after
/// each message as the planner polls after each plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Helps {
    /// The hop's CPU (the controller's acting thread's).
    pub hop_cpu: Option<usize>,
    /// The helper's CPU (the planner thread's).
    pub helper_cpu: Option<usize>,
    /// How long the helper polls after each message, µs (0: no helper).
    pub helper_idle_spin_us: u64,
}

/// Runs the three relay processes (`relay`, to which each role and `--config FILE` are
/// added) with the loop's services under `prefix`, one round trip every `cycle_us`, with
/// `helps`; returns the sink's reports (the round trip, and its first hop alone) and each
/// role's CPU.
pub fn relay_floor(
    dir: &Path,
    prefix: &str,
    cycle_us: u64,
    settings: &LatencySettings,
    helps: Helps,
    relay: &ChildCommand,
) -> Result<Floor> {
    let report = dir.join("floor.json");
    let hop_report = dir.join("floor-first-hop.json");
    let second_hop_report = dir.join("floor-second-hop.json");
    let cfg = RelayConfig {
        service_prefix: format!("{prefix}floor/"),
        wait: settings.acting_wait(),
        messages: settings.actions() + settings.warmup(),
        warmup: settings.warmup(),
        budget_us: settings.budget_us,
        report: Some(report.clone()),
        hop_report: Some(hop_report.clone()),
        second_hop_report: Some(second_hop_report.clone()),
        // The source's own round trip is part of the cycle.
        gap_us: cycle_us.saturating_sub(50),
        hop_cpu: helps.hop_cpu,
        helper_cpu: helps.helper_cpu,
        helper_idle_spin_us: helps.helper_idle_spin_us,
        cpu_dir: Some(dir.to_owned()),
        announce: settings.pace == crate::harness::Pace::Real,
        ..RelayConfig::default()
    };
    cfg.check()?;
    let config = dir.join("relay.toml");
    std::fs::write(&config, toml::to_string(&cfg)?)
        .map_err(BenchError::io(format!("cannot write {}", config.display())))?;
    let mut processes: Vec<Process> = Vec::new();
    // The receivers first, so the source's first observations find them sooner.
    for role in [relay::ROLES[2], relay::ROLES[1], relay::ROLES[0]] {
        let child = children::spawn_as(relay, role, &config)?;
        processes.push(Process::new(role, child));
    }
    let limit = Duration::from_millis(cfg.idle_timeout_ms)
        + Duration::from_micros(cfg.gap_us + 500)
            .saturating_mul(u32::try_from(cfg.messages).unwrap_or(u32::MAX));
    await_relays(&mut processes, limit)?;
    let mut cpu = std::collections::BTreeMap::new();
    for role in relay::ROLES {
        let path = relay::cpu_file(dir, role);
        let text = std::fs::read_to_string(&path).map_err(BenchError::io(format!(
            "no floor CPU report at {}",
            path.display()
        )))?;
        let used = serde_json::from_str(&text).map_err(BenchError::Malformed)?;
        cpu.insert(role.trim_start_matches("relay-").to_owned(), used);
    }
    let hop_catches = match std::fs::read_to_string(relay::catches_file(dir)) {
        Ok(text) => Some(serde_json::from_str(&text).map_err(BenchError::Malformed)?),
        // A hop that does not anticipate keeps no score.
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => {
            return Err(BenchError::io("cannot read the floor hop's catches".into())(e));
        }
    };
    Ok(Floor {
        round_trip: load(&report)?,
        first_hop: load(&hop_report)?,
        second_hop: load(&second_hop_report)?,
        cpu,
        hop_catches,
    })
}

/// Waits up to `limit` for the relay's processes, stops those still running, and checks they
/// all finished cleanly.
fn await_relays(processes: &mut [Process], limit: Duration) -> Result<()> {
    let started = Instant::now();
    while processes.iter().any(|c| c.status.is_none()) && started.elapsed() < limit {
        for c in processes.iter_mut().filter(|c| c.status.is_none()) {
            c.status = c
                .child
                .try_wait()
                .map_err(BenchError::io("cannot poll a relay process".into()))?;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut all: Vec<&mut Process> = processes.iter_mut().collect();
    children::shutdown(&mut all, Duration::from_secs(1));
    for c in processes.iter() {
        match c.status {
            Some(s) if s.success() => {}
            Some(s) => {
                return Err(BenchError::Run(format!(
                    "the floor's {} {}",
                    c.name,
                    children::describe(s)
                )));
            }
            None => {
                return Err(BenchError::Run(format!(
                    "the floor's {} did not finish",
                    c.name
                )));
            }
        }
    }
    Ok(())
}

/// A floor report the floor's processes wrote.
fn load(path: &Path) -> Result<LatencyReport> {
    LatencyReport::load(path).map_err(BenchError::io(format!(
        "no floor report at {}",
        path.display()
    )))
}

/// Marks the probes the floor sends until its link carries a first round trip: not measured.
const FLOOR_PROBE: u32 = u32::MAX;

/// The arena the floor's samples are checked against (the measured run's).
fn floor_map() -> Result<Box<WorldMap>> {
    use tes_perception_sim::arena::{Arena, ArenaId};
    Ok(tes_perception_sim::process::world_map(&Arena::new(
        ArenaId::Env3,
    ))?)
}

/// One end of the floor's link.
fn floor_link_settings(group: &str, listen: Vec<String>, connect: Vec<String>) -> LinkSection {
    LinkSection {
        group: group.to_owned(),
        // Plain TCP is what `--via zenoh` measures: unauthenticated, so said as such.
        insecure: listen.iter().chain(&connect).any(|e| e.starts_with("tcp/")),
        listen,
        connect,
        multicast_scouting: Some(false),
        // One machine, one clock, as in the measured run.
        restamp: false,
        ..LinkSection::default()
    }
}

/// Waits until `link` sees a peer for every role it does not play.
fn wait_for_peer(link: &Link, side: &str) -> Result<()> {
    let started = Instant::now();
    while !link.missing().is_empty() {
        if started.elapsed() > Duration::from_secs(20) {
            return Err(BenchError::Run(format!(
                "the floor's {side} side waited 20 s for {:?} on loopback",
                link.missing()
            )));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

/// The settings of the Zenoh floor's controller side ([`zenoh_hop`]), which its process
/// receives as flags ([`HopSettings::args`]).
#[derive(Debug, Clone, PartialEq)]
pub struct HopSettings {
    /// The robot side's endpoint.
    pub connect: String,
    /// The link's group.
    pub group: String,
    /// This side's service-name prefix.
    pub prefix: String,
    /// How the hop waits for an observation.
    pub wait: WaitStrategy,
    /// The CPU the hop runs on.
    pub hop_cpu: Option<usize>,
    /// Observations answered (warm-up included) before the hop stops.
    pub answer: u64,
    /// Of those, the first left out of the report.
    pub warmup: u64,
    /// The per-action budget, µs.
    pub budget_us: u64,
    /// Where the first hop's report goes.
    pub report: PathBuf,
    /// The group's authority, this side's certificate and key, over QUIC.
    pub tls: Option<[PathBuf; 3]>,
}

impl HopSettings {
    /// The flags `tes bench zenoh-floor-hop` reads these from.
    pub fn args(&self) -> Vec<OsString> {
        let mut args: Vec<OsString> = [
            ("--connect", self.connect.clone()),
            ("--group", self.group.clone()),
            ("--prefix", self.prefix.clone()),
            ("--wait", self.wait.to_string()),
            ("--answer", self.answer.to_string()),
            ("--warmup", self.warmup.to_string()),
            ("--budget-us", self.budget_us.to_string()),
        ]
        .into_iter()
        .flat_map(|(flag, value)| [OsString::from(flag), OsString::from(value)])
        .collect();
        args.push("--report".into());
        args.push(self.report.clone().into_os_string());
        if let Some(cpu) = self.hop_cpu {
            args.push("--hop-cpu".into());
            args.push(cpu.to_string().into());
        }
        if let Some(files) = &self.tls {
            args.push("--tls".into());
            args.extend(files.iter().map(|f| f.clone().into_os_string()));
        }
        args
    }
}

/// The floor of a split run: the loop's two hops through a [`Link`] on loopback (by
/// `carrier`: plain TCP, or QUIC with the run's keys) with no work at either end. The robot's side runs here, the controller's in a child process
/// (`floor_hop`, to which [`HopSettings::args`] are added) with an iceoryx2 domain of its
/// own: an observation published here is forwarded, checked and republished there, answered
/// at once with a command that comes back the same way. One round trip every `cycle_us`; the
/// round trip, and its first hop alone.
pub fn zenoh_floor(
    dir: &Path,
    cycle_us: u64,
    settings: &LatencySettings,
    hop_cpu: Option<usize>,
    floor_hop: &ChildCommand,
    carrier: &Carrier,
) -> Result<(LatencyReport, LatencyReport)> {
    let port = carrier.free_port()?;
    let pid = std::process::id();
    let group = format!("tes-bench-floor/{pid}");
    let endpoint = carrier.endpoint(port);
    let names = ServiceNames::with_prefix(&format!("tes-bench-{pid}/floor-robot/"));
    let mut robot_link = floor_link_settings(&group, vec![endpoint.clone()], Vec::new());
    carrier.keys_into(&mut robot_link, Carrier::ROBOT);
    let robot =
        Link::open(&robot_link, &[Role::Perception, Role::Bridge], &names).map_err(|cause| {
            BenchError::Link {
                side: "robot",
                cause,
            }
        })?;
    let total = settings.actions() + settings.warmup();
    let hop = HopSettings {
        connect: endpoint,
        group,
        prefix: format!("tes-bench-{pid}/floor-desk/"),
        wait: settings.acting_wait(),
        hop_cpu,
        answer: total,
        warmup: settings.warmup(),
        budget_us: settings.budget_us,
        report: dir.join("floor-first-hop.json"),
        tls: carrier.files(Carrier::CONTROLLER),
    };
    let log = dir.join("floor-hop.log");
    let mut child = spawn_hop(floor_hop, &hop, &log)?;
    let measured = round_trips(&robot, &names, settings, cycle_us);
    let status = wait_or_kill(
        &mut child,
        Duration::from_secs(10),
        measured.is_err(),
        "cannot poll the floor's controller side",
    );
    drop(robot);
    remove_domain_of(&floor_domain());
    let status = status?;
    let round = measured.map_err(|e| BenchError::SeeAlso {
        log: log.clone(),
        cause: Box::new(e),
    })?;
    match status {
        Some(s) if s.success() => {}
        Some(s) => {
            return Err(BenchError::Run(format!(
                "the floor's controller side {} (see {})",
                children::describe(s),
                log.display()
            )));
        }
        None => {
            return Err(BenchError::Run(format!(
                "the floor's controller side did not stop (see {})",
                log.display()
            )));
        }
    }
    Ok((round, load(&hop.report)?))
}

/// Starts the floor's controller side with `hop`'s flags, in an iceoryx2 domain of its own,
/// its output in `log`.
fn spawn_hop(floor_hop: &ChildCommand, hop: &HopSettings, log: &Path) -> Result<Child> {
    let file = std::fs::File::create(log)
        .map_err(BenchError::io(format!("cannot create {}", log.display())))?;
    let shared = file
        .try_clone()
        .map_err(BenchError::io("cannot share the log".into()))?;
    std::process::Command::new(&floor_hop.program)
        .args(&floor_hop.args)
        .args(hop.args())
        .env(tes_runtime::channel::DOMAIN_VAR, floor_domain())
        .stdin(Stdio::null())
        .stdout(shared)
        .stderr(file)
        .spawn()
        .map_err(BenchError::io(
            "cannot start the floor's controller side".into(),
        ))
}

/// The iceoryx2 domain of the floor's controller side: this process's own.
fn floor_domain() -> String {
    format!("benchfloor{}", std::process::id())
}

/// The robot's side of the Zenoh floor: the world map, observations out, commands in.
/// (Fields drop in order: the ports before their node.)
struct RobotSide {
    commands: LatestInbox<Command>,
    observations: Outbox<Observation>,
    _maps: Outbox<WorldMap>,
    _node: iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
    n_features: u32,
    seq: u64,
    stop: AtomicBool,
}

impl RobotSide {
    /// Opens the robot's services under `names` and publishes the arena's world map.
    fn open(names: &ServiceNames, wait: WaitStrategy) -> Result<Self> {
        let map: Box<WorldMap> = floor_map()?;
        let node = channel::node(false)?;
        let maps: Outbox<WorldMap> =
            Outbox::open(&node, &names.world_map, &names.world_map_event, 1)?;
        maps.send(*map)?;
        let observations: Outbox<Observation> =
            Outbox::open(&node, &names.observation, &names.observation_event, 0)?;
        let commands: LatestInbox<Command> =
            LatestInbox::open(&node, &names.command, &names.command_event, wait)?;
        Ok(Self {
            commands,
            observations,
            _maps: maps,
            _node: node,
            n_features: map.n_features,
            seq: 0,
            stop: AtomicBool::new(false),
        })
    }

    /// The next observation, stamped now.
    fn observation(&mut self, step: u32) -> Observation {
        self.seq += 1;
        Observation {
            seq: self.seq,
            stamp_ns: monotonic_ns(),
            step,
            state: StateAttributes::at(0, 0, 0),
            n_features: self.n_features,
            ..Observation::default()
        }
    }

    /// The world map crosses within a second, and until it has, the controller's side
    /// refuses observations: probes until a first round trip.
    fn probe(&mut self) -> Result<()> {
        let probing = Instant::now();
        loop {
            if probing.elapsed() > Duration::from_secs(20) {
                return Err(BenchError::Run(
                    "the floor's link never carried a round trip".into(),
                ));
            }
            self.observations.update_connections()?;
            let probe = self.observation(FLOOR_PROBE);
            self.observations.send(probe)?;
            if let Ok(c) = self.commands.next(Duration::from_millis(50), &self.stop)?
                && c.answers == probe.seq
            {
                return Ok(());
            }
        }
    }

    /// One measured round trip of step `step`: its latency, ns, from the observation's stamp.
    fn round_trip(&mut self, step: u64) -> Result<u64> {
        let o = self.observation(u32::try_from(step).unwrap_or(FLOOR_PROBE - 1));
        self.observations.send(o)?;
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(BenchError::Run(format!(
                    "the floor's link lost a round trip (observation {})",
                    o.seq
                )));
            }
            if let Ok(c) = self.commands.next(left, &self.stop)?
                && c.answers == o.seq
            {
                return Ok(monotonic_ns().saturating_sub(c.observed_ns));
            }
        }
    }
}

/// The robot side's measurement: waits for the controller's side, probes, then one round trip
/// every `cycle_us`.
fn round_trips(
    robot: &Link,
    names: &ServiceNames,
    settings: &LatencySettings,
    cycle_us: u64,
) -> Result<LatencyReport> {
    wait_for_peer(robot, "robot's")?;
    let mut side = RobotSide::open(names, settings.acting_wait())?;
    side.probe()?;
    let mut round = LatencyRecorder::new(settings.budget_us, settings.warmup());
    let gap = Duration::from_micros(cycle_us);
    for step in 0..settings.actions() + settings.warmup() {
        let next = Instant::now() + gap;
        round.record_ns(side.round_trip(step)?);
        let left = next.saturating_duration_since(Instant::now());
        if !left.is_zero() {
            std::thread::sleep(left);
        }
    }
    Ok(round.report())
}

/// The Zenoh floor's controller side (`tes bench zenoh-floor-hop`): answers each observation
/// that crosses at once, the first `answer` of them, then saves the first hop's latencies.
pub fn zenoh_hop(settings: &HopSettings) -> Result<()> {
    let names = ServiceNames::with_prefix(&settings.prefix);
    let wheels = floor_map()?.action_wheels[0];
    let mut hop_link =
        floor_link_settings(&settings.group, Vec::new(), vec![settings.connect.clone()]);
    if let Some(files) = &settings.tls {
        hop_link.set_keys(files.clone());
    }
    let link =
        Link::open(&hop_link, &[Role::Controller], &names).map_err(|cause| BenchError::Link {
            side: "controller",
            cause,
        })?;
    wait_for_peer(&link, "controller's")?;
    // Pinned only now, once Zenoh's threads exist: they follow the affinity of the thread
    // that starts them, and in the measured group the link runs in the launcher, off the
    // acting CPU.
    if let Some(cpu) = settings.hop_cpu {
        tes_runtime::affinity::pin_this_thread(cpu)?;
    }
    let first_hop = answer(settings, &names, wheels)?;
    first_hop
        .save(&settings.report)
        .map_err(BenchError::io(format!(
            "cannot write {}",
            settings.report.display()
        )))?;
    drop(link);
    Ok(())
}

/// Answers the first `answer` observations at once with a command driving `wheels`; the
/// first hop's latencies.
fn answer(settings: &HopSettings, names: &ServiceNames, wheels: [i32; 2]) -> Result<LatencyReport> {
    let node = channel::node(false)?;
    let observations: Inbox<Observation> = Inbox::open(
        &node,
        &names.observation,
        &names.observation_event,
        0,
        settings.wait,
    )?;
    let commands: LatestOutbox<Command> =
        LatestOutbox::open(&node, &names.command, &names.command_event)?;
    let mut first_hop = LatencyRecorder::new(settings.budget_us, settings.warmup);
    let stop = AtomicBool::new(false);
    let (mut seq, mut answered) = (0, 0);
    let mut idle_since = Instant::now();
    while answered < settings.answer {
        let Ok(o) = observations.next(Duration::from_millis(50), &stop)? else {
            if idle_since.elapsed() > Duration::from_secs(30) {
                return Err(BenchError::Run(
                    "no observation crossed the floor's link for 30 s".into(),
                ));
            }
            continue;
        };
        idle_since = Instant::now();
        let now = monotonic_ns();
        if o.step != FLOOR_PROBE {
            first_hop.record_ns(now.saturating_sub(o.stamp_ns));
            answered += 1;
        }
        seq += 1;
        commands.send(Command {
            seq,
            answers: o.seq,
            stamp_ns: now,
            observed_ns: o.stamp_ns,
            action: 0,
            left_deg: wheels[0],
            right_deg: wheels[1],
            ..Command::default()
        })?;
    }
    // The last command must cross before this side leaves.
    std::thread::sleep(Duration::from_millis(200));
    Ok(first_hop.report())
}
