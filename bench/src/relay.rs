//! The latency floor: a raw iceoryx2 two-hop relay with the controller loop's payloads and
//! wait strategy and no work, run as three processes in the roles of the real ones.
//!
//! * **source** (perception's place) stamps and publishes an [`Observation`], then waits for
//!   the sink's [`MotorState`] and `gap_us` more (the real loop's robot motion) before the
//!   next one — the same closed loop, at the same cadence, as the real group. The cadence
//!   matters: a receiver woken after a long idle gap pays the CPU's (and, in a VM, the
//!   hypervisor's) idle-exit latency, one woken back to back does not;
//! * **hop** (the controller's place) answers each observation at once with a [`Command`]
//!   carrying the observation's stamp;
//! * **sink** (the bridge's place) records `now − stamp` for each command, exactly where the
//!   real bridge records it, and acknowledges with a [`MotorState`]. It also records the
//!   first hop alone (stamp → the hop's command published, from the command's own stamp):
//!   the floor's counterpart of the controller's decision latency, so a gap between the two
//!   paths can be placed at the controller's hop or the bridge's.
//!
//! What the sink measures is therefore the cost of two iceoryx2 hops and two wake-ups by the
//! chosen strategy on this machine: the floor any controller on this transport pays. The
//! source always blocks for the acknowledgement (the return path is not measured, and on a
//! 2-core machine three busy-polling processes starve each other).

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use tes_runtime::channel::{
    self, Catches, Idle, Inbox, IpcError, LatestInbox, LatestOutbox, Loan, Outbox, WaitStrategy,
};
use tes_runtime::clock::monotonic_ns;
use tes_runtime::cpu::CpuMeter;
use tes_runtime::latency::{LatencyRecorder, LatencyReport};
use tes_runtime::settings::{self, SettingError};
use tes_topics::{
    Command, FeatureBits, HeadsUp, MotorState, Observation, ServiceNames, observation_flags,
};

/// The roles, as `tes child` names them.
pub const ROLES: [&str; 3] = ["relay-source", "relay-hop", "relay-sink"];

/// Settings shared by the three relay processes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RelayConfig {
    /// Prefixed to the services (each run its own).
    pub service_prefix: String,
    /// `block`, `spin` or `spin-then-block[:µs]`.
    pub wait: WaitStrategy,
    /// Round trips in all, warm-up included.
    pub messages: u64,
    /// Round trips left out of the report.
    pub warmup: u64,
    /// The budget overruns are counted against, µs.
    pub budget_us: u64,
    /// Where the sink writes its [`LatencyReport`].
    pub report: Option<PathBuf>,
    /// Where the sink writes the first hop's [`LatencyReport`]: observation stamped → the
    /// hop's command published, the floor's counterpart of the controller's decision latency.
    pub hop_report: Option<PathBuf>,
    /// Where the sink writes the second hop's latencies alone (the hop's command published →
    /// received at the sink), if anywhere.
    pub second_hop_report: Option<PathBuf>,
    /// Give up after this long without a message, ms.
    pub idle_timeout_ms: u64,
    /// Pause between an acknowledgement and the next observation, µs (the loop's cadence).
    pub gap_us: u64,
    /// Pin the hop to this CPU, as the controller's `acting_cpu` pins its acting thread
    /// (default: unpinned).
    pub hop_cpu: Option<usize>,
    /// The controller planner thread's counterpart: after each observation the hop wakes a
    /// helper thread that polls for the next one this long, under SCHED_IDLE, as the
    /// planner thread polls for its next job after a plan (0: no helper).
    pub helper_idle_spin_us: u64,
    /// The helper's CPU, as the planner thread's (default: unpinned).
    pub helper_cpu: Option<usize>,
    /// Each role writes its CPU over the round trips after the warm-up here, as
    /// `<role>-cpu.json` (default: nowhere).
    pub cpu_dir: Option<PathBuf>,
    /// The source announces each observation before its pause, keeps the time and lets the
    /// receivers run after sending, as perception does at the robot's pace (default: a plain
    /// pause, as perception's at the fastest pace, where it announces nothing).
    pub announce: bool,
}

impl Default for RelayConfig {
    fn default() -> Self {
        Self {
            service_prefix: "relay/".into(),
            wait: WaitStrategy::Block,
            messages: 10_000,
            warmup: 1_000,
            budget_us: tes_runtime::settings::DEFAULT_BUDGET_US,
            report: None,
            hop_report: None,
            second_hop_report: None,
            idle_timeout_ms: 10_000,
            gap_us: 0,
            hop_cpu: None,
            helper_idle_spin_us: 0,
            helper_cpu: None,
            cpu_dir: None,
            announce: false,
        }
    }
}

/// The process name [`SettingError`]s of these settings carry.
pub const PROCESS: &str = "relay";

/// A [`RelayConfig`] that passed [`RelayConfig::check`].
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedRelay {
    config: RelayConfig,
}

impl CheckedRelay {
    /// The settings.
    pub fn config(&self) -> &RelayConfig {
        &self.config
    }

    /// How every relay process waits (`wait`).
    pub fn wait(&self) -> WaitStrategy {
        self.config.wait
    }
}

impl RelayConfig {
    /// Parses and checks a TOML document of these keys; an error names the key and its line.
    pub fn from_toml(text: &str) -> Result<Self, SettingError> {
        Self::from_toml_in(text, settings::Origin::Text)
    }

    /// [`from_toml`](Self::from_toml) for a document from `origin`, which an error names.
    pub fn from_toml_in(text: &str, origin: settings::Origin) -> Result<Self, SettingError> {
        let (cfg, _) = settings::parse_checked(PROCESS, text, origin, Self::check)?;
        Ok(cfg)
    }

    /// Checks every key; the first bad one is reported.
    pub fn check(&self) -> Result<CheckedRelay, SettingError> {
        if self.messages == 0 || self.warmup >= self.messages {
            return Err(SettingError::new(
                PROCESS,
                "messages",
                "must be more than warmup",
            ));
        }
        if self.budget_us == 0 || self.idle_timeout_ms == 0 {
            return Err(SettingError::new(
                PROCESS,
                "budget_us",
                "budget_us and idle_timeout_ms must be at least 1",
            ));
        }
        settings::cpu(PROCESS, "hop_cpu", self.hop_cpu)?;
        settings::cpu(PROCESS, "helper_cpu", self.helper_cpu)?;
        Ok(CheckedRelay {
            config: self.clone(),
        })
    }

    fn names(&self) -> ServiceNames {
        ServiceNames::with_prefix(&self.service_prefix)
    }

    /// Marks `meter` after round trip `seq` once the warm-up is over.
    fn mark(&self, meter: &mut CpuMeter, seq: u64) {
        if seq >= self.warmup {
            meter.mark();
        }
    }

    /// Writes the hop's catches to `cpu_dir`, if set and it anticipated.
    fn save_catches(&self, catches: Option<Catches>) -> Result<(), RelayError> {
        let (Some(dir), Some(catches)) = (&self.cpu_dir, catches) else {
            return Ok(());
        };
        let path = catches_file(dir);
        serde_json::to_string_pretty(&catches)
            .map_err(std::io::Error::other)
            .and_then(|text| std::fs::write(&path, text))
            .map_err(|error| RelayError::Report { path, error })
    }

    /// Writes `role`'s CPU to `cpu_dir`, if set.
    fn save_cpu(&self, role: &str, meter: &CpuMeter) -> Result<(), RelayError> {
        let (Some(dir), Some(used)) = (&self.cpu_dir, meter.report()) else {
            return Ok(());
        };
        let path = cpu_file(dir, role);
        serde_json::to_string_pretty(&used)
            .map_err(std::io::Error::other)
            .and_then(|text| std::fs::write(&path, text))
            .map_err(|error| RelayError::Report { path, error })
    }
}

/// Why a relay process failed.
#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    /// Bad settings.
    #[error(transparent)]
    Setting(#[from] SettingError),
    /// iceoryx2 failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),
    /// The partner fell silent.
    #[error("{1}: nothing received for {0:?} (is the rest of the relay running?)")]
    Silent(Duration, &'static str),
    /// The report could not be written.
    #[error("cannot write the report {}: {error}", path.display())]
    Report {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// Not a relay role.
    #[error("unknown relay role {0:?} (expected one of {ROLES:?})")]
    Role(String),
    /// The hop could not be pinned to `hop_cpu`.
    #[error("relay-hop: {0}")]
    Affinity(#[from] tes_runtime::affinity::AffinityError),
}

/// Where the hop writes in `dir` how its observations came against its poll windows.
pub fn catches_file(dir: &std::path::Path) -> PathBuf {
    dir.join("relay-hop-catches.json")
}

/// Where `role` writes its CPU in `dir`.
pub fn cpu_file(dir: &std::path::Path, role: &str) -> PathBuf {
    dir.join(format!("{role}-cpu.json"))
}

/// Runs one relay role until its messages are done or `stop` is raised. The sink returns its
/// report.
pub fn run(
    role: &str,
    cfg: &RelayConfig,
    stop: &AtomicBool,
) -> Result<Option<LatencyReport>, RelayError> {
    let wait = cfg.check()?.wait();
    let node = channel::node(false)?;
    let idle = Duration::from_millis(cfg.idle_timeout_ms);
    match role {
        "relay-source" => source(cfg, &node, idle, stop).map(|()| None),
        "relay-hop" => hop(cfg, &node, wait, idle, stop).map(|()| None),
        "relay-sink" => sink(cfg, &node, wait, idle, stop).map(Some),
        other => Err(RelayError::Role(other.to_owned())),
    }
}

type Node = iceoryx2::node::Node<iceoryx2::service::ipc::Service>;

fn source(
    cfg: &RelayConfig,
    node: &Node,
    idle: Duration,
    stop: &AtomicBool,
) -> Result<(), RelayError> {
    let names = cfg.names();
    let out: Outbox<Observation> =
        Outbox::open(node, &names.observation, &names.observation_event, 0)?;
    let acks: Inbox<MotorState> = Inbox::open(
        node,
        &names.motor_state,
        &names.motor_state_event,
        0,
        WaitStrategy::Block,
    )?;
    let heads_up: Outbox<HeadsUp> = Outbox::open(
        node,
        &names.observation_due,
        &names.observation_due_event,
        0,
    )?;
    // Placed as perception: off the hop's CPU when it announces, else on it.
    tes_runtime::affinity::join_the_chain(cfg.announce, "the relay's source");
    let mut cpu = CpuMeter::process();
    let gap = Duration::from_micros(cfg.gap_us);
    // The arena's payload: a full feature vector's worth of bits.
    let mut features = FeatureBits::EMPTY;
    for i in (0..tes_topics::ARENA_FEATURES).step_by(21) {
        features.set(i);
    }
    for seq in 1..=cfg.messages {
        let mut loan = if !gap.is_zero() && seq > 1 {
            pause(cfg, &out, &heads_up, seq, gap)?
        } else {
            None
        };
        let last = seq == cfg.messages;
        let started = Instant::now();
        // Until the other two are up, an observation may reach nobody: send it again.
        'resend: loop {
            out.update_connections()?;
            out.send_in(
                loan.take(),
                Observation {
                    seq,
                    stamp_ns: monotonic_ns(),
                    n_features: tes_topics::ARENA_FEATURES as u32,
                    features,
                    flags: if last { observation_flags::TERMINAL } else { 0 },
                    ..Observation::default()
                },
            )?;
            // As perception does at the robot's pace: the receivers run first.
            if cfg.announce {
                std::thread::yield_now();
            }
            loop {
                match acks.next(Duration::from_millis(100), stop)? {
                    Ok(ack) if ack.after_command == seq => {
                        cfg.mark(&mut cpu, seq);
                        break 'resend;
                    }
                    Ok(_) => continue, // a late answer to a resent observation
                    Err(Idle::Stopped) => return cfg.save_cpu("relay-source", &cpu),
                    Err(Idle::Timeout) if started.elapsed() > idle => {
                        return Err(RelayError::Silent(idle, "relay-source"));
                    }
                    Err(Idle::Timeout) => continue 'resend,
                }
            }
        }
    }
    cfg.save_cpu("relay-source", &cpu)
}

/// The source's pause before observation `seq`, as perception's settle: announced and kept
/// with `announce` (the observation's sample loaned just before), a plain sleep without.
fn pause(
    cfg: &RelayConfig,
    out: &Outbox<Observation>,
    heads_up: &Outbox<HeadsUp>,
    seq: u64,
    gap: Duration,
) -> Result<Option<Loan<Observation>>, RelayError> {
    if !cfg.announce {
        std::thread::sleep(gap);
        return Ok(None);
    }
    let due_ns = monotonic_ns() + gap.as_nanos() as u64;
    heads_up.send(HeadsUp { seq, due_ns })?;
    Ok(Some(tes_runtime::channel::sleep_until_with_loan(
        due_ns, out,
    )?))
}

fn hop(
    cfg: &RelayConfig,
    node: &Node,
    wait: WaitStrategy,
    idle: Duration,
    stop: &AtomicBool,
) -> Result<(), RelayError> {
    let names = cfg.names();
    let mut observations: Inbox<Observation> =
        Inbox::open(node, &names.observation, &names.observation_event, 0, wait)?.with_heads_up(
            node,
            &names.observation_due,
            &names.observation_due_event,
        )?;
    let out: LatestOutbox<Command> =
        LatestOutbox::open(node, &names.command, &names.command_event)?;
    tes_runtime::memory::keep_resident("the relay's hop");
    if let Some(cpu) = cfg.hop_cpu {
        // As the controller's acting thread: polls without yielding when alone on its CPU.
        let alone =
            tes_runtime::affinity::pin_acting_thread(cpu, wait == WaitStrategy::Anticipate)?;
        observations.poll_alone(alone);
    }
    let helper = Helper::spawn(cfg);
    let mut cpu = CpuMeter::process();
    let done = |cpu: &CpuMeter| {
        cfg.save_catches(observations.catches())?;
        cfg.save_cpu("relay-hop", cpu)
    };
    loop {
        let obs = match observations.next(idle, stop)? {
            Ok(o) => o,
            Err(Idle::Stopped) => return done(&cpu),
            Err(Idle::Timeout) => return Err(RelayError::Silent(idle, "relay-hop")),
        };
        out.send(Command {
            seq: obs.seq,
            answers: obs.seq,
            stamp_ns: monotonic_ns(),
            observed_ns: obs.stamp_ns,
            ..Command::default()
        })?;
        helper.wake();
        cfg.mark(&mut cpu, obs.seq);
        if obs.flags & observation_flags::TERMINAL != 0 {
            return done(&cpu);
        }
    }
}

/// The hop's counterpart of the controller's planner thread: woken after each observation,
/// it polls for the next wake-up for `helper_idle_spin_us` under SCHED_IDLE, then sleeps —
/// so whatever the planner's idle poll does for the controller's CPUs, it does for the
/// floor's. Ends with the hop.
struct Helper {
    wakes: Option<std::sync::mpsc::SyncSender<()>>,
}

impl Helper {
    fn spawn(cfg: &RelayConfig) -> Self {
        if cfg.helper_idle_spin_us == 0 {
            return Self { wakes: None };
        }
        let (wakes, jobs) = std::sync::mpsc::sync_channel::<()>(1);
        let spin = Duration::from_micros(cfg.helper_idle_spin_us);
        let cpu = cfg.helper_cpu;
        let _ = std::thread::Builder::new()
            .name("floor-helper".into())
            .spawn(move || {
                if let Some(cpu) = cpu {
                    let _ = tes_runtime::affinity::pin_this_thread(cpu);
                }
                let spin = if tes_runtime::affinity::lower_this_threads_priority() {
                    spin
                } else {
                    Duration::ZERO
                };
                while jobs.recv().is_ok() {
                    let start = Instant::now();
                    while start.elapsed() < spin {
                        match jobs.try_recv() {
                            Ok(()) => continue,
                            Err(std::sync::mpsc::TryRecvError::Empty) => std::hint::spin_loop(),
                            Err(std::sync::mpsc::TryRecvError::Disconnected) => return,
                        }
                    }
                }
            });
        Self { wakes: Some(wakes) }
    }

    /// Hands the helper a job, as the acting loop hands the planner the model.
    fn wake(&self) {
        if let Some(w) = &self.wakes {
            let _ = w.try_send(());
        }
    }
}

fn sink(
    cfg: &RelayConfig,
    node: &Node,
    wait: WaitStrategy,
    idle: Duration,
    stop: &AtomicBool,
) -> Result<LatencyReport, RelayError> {
    let names = cfg.names();
    let commands: LatestInbox<Command> =
        LatestInbox::open(node, &names.command, &names.command_event, wait)?.with_heads_up(
            node,
            &names.observation_due,
            &names.observation_due_event,
        )?;
    let acks: Outbox<MotorState> =
        Outbox::open(node, &names.motor_state, &names.motor_state_event, 0)?;
    // Placed as the bridge: off the hop's CPU when it anticipates, else on it.
    tes_runtime::affinity::join_the_chain(wait == WaitStrategy::Anticipate, "the relay's sink");
    let mut cpu = CpuMeter::process();
    let mut latency = LatencyRecorder::new(cfg.budget_us, cfg.warmup);
    let mut first_hop = LatencyRecorder::new(cfg.budget_us, cfg.warmup);
    let mut second_hop = LatencyRecorder::new(cfg.budget_us, cfg.warmup);
    let mut last_seq = 0;
    loop {
        let cmd = match commands.next(idle, stop)? {
            Ok(c) => c,
            Err(Idle::Stopped) => break,
            Err(Idle::Timeout) => return Err(RelayError::Silent(idle, "relay-sink")),
        };
        // Recorded on arrival, as the bridge does; a resent observation's second answer is
        // not a new round trip.
        if cmd.seq > last_seq {
            let now = monotonic_ns();
            latency.record_ns(now.saturating_sub(cmd.observed_ns));
            first_hop.record_ns(cmd.stamp_ns.saturating_sub(cmd.observed_ns));
            second_hop.record_ns(now.saturating_sub(cmd.stamp_ns));
            last_seq = cmd.seq;
        }
        acks.send(MotorState {
            seq: cmd.seq,
            after_command: cmd.seq,
            stamp_ns: monotonic_ns(),
            ..MotorState::default()
        })?;
        cfg.mark(&mut cpu, cmd.seq);
        if cmd.seq == cfg.messages {
            break;
        }
    }
    cfg.save_cpu("relay-sink", &cpu)?;
    let report = latency.report();
    for (path, report) in [
        (&cfg.report, &report),
        (&cfg.hop_report, &first_hop.report()),
        (&cfg.second_hop_report, &second_hop.report()),
    ] {
        if let Some(path) = path {
            report.save(path).map_err(|error| RelayError::Report {
                path: path.clone(),
                error,
            })?;
        }
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_are_checked() {
        assert!(RelayConfig::default().check().is_ok());
        let err = RelayConfig::from_toml("messages = 5\nwarmup = 5").unwrap_err();
        assert_eq!(err.key, "messages");
        assert_eq!(
            RelayConfig::from_toml("wait = \"nap\"").unwrap_err().key,
            "wait"
        );
        assert_eq!(
            RelayConfig::from_toml("mesages = 5").unwrap_err().key,
            "mesages"
        );
        assert_eq!(
            RelayConfig::from_toml("hop_cpu = 100000").unwrap_err().key,
            "hop_cpu"
        );
    }

    #[test]
    fn the_wait_key_is_a_strategy() {
        let cfg = RelayConfig::from_toml("wait = \"spin-then-block:15\"").unwrap();
        assert_eq!(
            cfg.check().map(|c| c.wait()),
            Ok(WaitStrategy::SpinThenBlock(Duration::from_micros(15)))
        );
        let err = RelayConfig::from_toml("gap_us = 1\nwait = \"doze\"").unwrap_err();
        assert_eq!((err.key.as_str(), err.line()), ("wait", Some(2)));
    }

    #[test]
    fn three_threads_relay_every_message_and_report_it() {
        // The roles as threads of one process (ports are per thread), on a private prefix.
        let dir = tempfile::tempdir().unwrap();
        let cfg = RelayConfig {
            service_prefix: format!("relay-test-{}/", std::process::id()),
            report: Some(dir.path().join("floor.json")),
            hop_report: Some(dir.path().join("hop.json")),
            second_hop_report: Some(dir.path().join("second-hop.json")),
            messages: 300,
            warmup: 50,
            idle_timeout_ms: 20_000,
            ..RelayConfig::default()
        };
        let stop = AtomicBool::new(false);
        let report = std::thread::scope(|s| {
            let sink = s.spawn(|| run("relay-sink", &cfg, &stop));
            let hop = s.spawn(|| run("relay-hop", &cfg, &stop));
            let source = s.spawn(|| run("relay-source", &cfg, &stop));
            source.join().unwrap().unwrap();
            hop.join().unwrap().unwrap();
            sink.join().unwrap().unwrap()
        })
        .expect("the sink reports");
        assert_eq!(report.count, 250);
        assert_eq!(report.warmup, 50);
        assert!(report.p50_us >= 1 && report.p50_us <= report.p99_us);
        assert_eq!(
            LatencyReport::load(&dir.path().join("floor.json")).unwrap(),
            report
        );
        // The first hop is part of the round trip: never longer, message by message.
        let hop = LatencyReport::load(&dir.path().join("hop.json")).unwrap();
        assert_eq!((hop.count, hop.warmup), (250, 50));
        assert!(hop.p50_us <= report.p50_us && hop.max_us <= report.max_us);
        // So is the second.
        let second = LatencyReport::load(&dir.path().join("second-hop.json")).unwrap();
        assert_eq!((second.count, second.warmup), (250, 50));
        assert!(second.p50_us <= report.p50_us && second.max_us <= report.max_us);
        assert!(matches!(
            run("relay-nope", &cfg, &stop),
            Err(RelayError::Role(_))
        ));
    }
}
