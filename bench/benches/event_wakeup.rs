//! Which iceoryx2 event implementation, and which way of waiting on it, wakes a blocked
//! *process* fastest on this machine — the question behind the controller's `block` mode.
//!
//! Three processes relay a stamp source → hop → sink → source, in the roles (and at the
//! cadence) of perception, controller and bridge: each payload is an iceoryx2
//! publish–subscribe sample, each receiver is woken by an iceoryx2 event, and only the way of
//! waking changes from row to row:
//!
//! | events | wait | how it sleeps |
//! |---|---|---|
//! | `socket` (`ipc::Service`'s `UnixDatagramShmCountingBitSet`) | `blocking` | `Listener::blocking_wait`: `recvfrom` on the socket |
//! | `socket` | `timed` | `Listener::timed_wait(50 ms)`: a socket receive timeout |
//! | `socket` | `ppoll` | `ppoll` on the listener's descriptor, then drain (what `tes_runtime::channel` does) |
//! | `socket` | `waitset` | a `WaitSet` with the listener attached (epoll), then drain |
//! | `semaphore` (`SemaphoreShmCountingBitSet`, a process-shared POSIX semaphore: a futex) | `blocking` | `Listener::blocking_wait`: `sem_wait` |
//! | `semaphore` | `timed` | `Listener::timed_wait(50 ms)`: iceoryx2's adaptive wait (yield, then sleeps of 0.1–10 ms) |
//!
//! The semaphore events are reached through a service type of our own (`ipc::Service` with
//! only its `Event` swapped); a semaphore has no descriptor, so `ppoll` and `WaitSet` do not
//! apply to it. For each row the sink reports the first hop (source stamped → hop awake and
//! holding the sample) and the two hops (→ sink awake), and the parent the CPU time the three
//! processes used. Rows are interleaved round by round, so each round shares the machine's
//! state.
//!
//! ```sh
//! cargo bench -p tes-bench --bench event_wakeup -- --round-trips 10000 --gap-us 2000
//! cargo bench -p tes-bench --bench event_wakeup -- --hop-cpu 1   # hop pinned, as the controller's acting thread
//! ```
//!
//! A measuring program rather than a criterion benchmark (`harness = false`): a bench target,
//! so that `cargo test` does not build it.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::{Parser, ValueEnum};
use iceoryx2::node::NodeBuilder;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::{CallbackProgression, Config, ZeroCopySend, ipc};
use iceoryx2::service::Service;
use iceoryx2::service::service_name::ServiceName;
use serde::{Deserialize, Serialize};
use tes_runtime::clock::monotonic_ns;
use tes_runtime::latency::{LatencyRecorder, LatencyReport};

/// `ipc::Service` with semaphore events instead of Unix datagrams (every other concept as in
/// iceoryx2 0.10's `ipc::Service`).
mod semaphore {
    use core::fmt::Debug;

    use iceoryx2_bb_elementary_traits::testing::abandonable::Abandonable;
    use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
    use iceoryx2_cal::shm_allocator::bump_allocator::BumpAllocator;
    use iceoryx2_cal::shm_allocator::pool_allocator::PoolAllocator;
    use iceoryx2_cal::*;

    #[derive(Debug, Clone)]
    pub struct Service {}

    impl iceoryx2::service::Service for Service {
        type StaticStorage = static_storage::recommended::Ipc;
        type ConfigSerializer = serialize::recommended::Recommended;
        type PersistentDynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
            dynamic_storage::recommended::PersistentIpc<T>;
        type Bag = bag::recommended::Recommended;
        type DynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
            dynamic_storage::recommended::Ipc<T>;
        type ServiceNameHasher = hash::recommended::Recommended;
        type SharedMemory = shared_memory::recommended::Ipc<PoolAllocator>;
        type ResizableSharedMemory = resizable_shared_memory::recommended::Ipc<PoolAllocator>;
        type Connection = zero_copy_connection::recommended::Ipc;
        type Event = event::SemaphoreShmCountingBitSet;
        type Monitoring = monitoring::recommended::Ipc;
        type Reactor = reactor::recommended::Ipc;
        type ArcThreadSafetyPolicy<T: Send + Debug + Abandonable> =
            arc_sync_policy::single_threaded::SingleThreaded<T>;
        type BlackboardMgmt<KeyType: Send + Sync + Debug + ZeroCopySend + 'static> =
            dynamic_storage::recommended::Ipc<KeyType>;
        type BlackboardPayload = shared_memory::recommended::Ipc<BumpAllocator>;
        type UniqueId = iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
    }

    impl iceoryx2::service::internal::ServiceInternal<Service> for Service {}
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Events {
    Socket,
    Semaphore,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Wait {
    Blocking,
    Timed,
    Ppoll,
    Waitset,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Role {
    Source,
    Hop,
    Sink,
}

/// Every combination measured, in table order.
const VARIANTS: [(Events, Wait); 6] = [
    (Events::Socket, Wait::Blocking),
    (Events::Socket, Wait::Timed),
    (Events::Socket, Wait::Ppoll),
    (Events::Socket, Wait::Waitset),
    (Events::Semaphore, Wait::Blocking),
    (Events::Semaphore, Wait::Timed),
];

/// The timeout of the timed waits: the stop-flag poll of `tes_runtime::channel`.
const TIMED: Duration = Duration::from_millis(50);

#[derive(Parser, Debug)]
#[command(about = "iceoryx2 event wake-up latency across processes, by implementation and wait")]
struct Args {
    /// Measured round trips per row (1 000 more are run first as warm-up).
    #[arg(long, default_value_t = 10_000)]
    round_trips: u64,
    /// Pause between an acknowledgement and the next stamp, µs (the control loop's cadence).
    #[arg(long, default_value_t = 2_000)]
    gap_us: u64,
    /// Rounds over all rows.
    #[arg(long, default_value_t = 2)]
    rounds: u32,
    /// Pin the hop process to this CPU.
    #[arg(long)]
    hop_cpu: Option<usize>,
    /// Only these event implementations (default: both).
    #[arg(long, value_enum)]
    events: Option<Events>,
    /// Print one JSON object per row instead of the table.
    #[arg(long)]
    json: bool,
    // A child's part (set by the parent).
    #[arg(long, value_enum, hide = true)]
    role: Option<Role>,
    #[arg(long, value_enum, hide = true)]
    wait: Option<Wait>,
    #[arg(long, hide = true)]
    prefix: Option<String>,
    /// Passed by `cargo bench`; nothing to do with it.
    #[arg(long, hide = true)]
    bench: bool,
}

/// What travels each hop.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("tes::bench::WakeupStamp")]
#[repr(C)]
struct Stamp {
    seq: u64,
    sent_ns: u64,
    hop_awake_ns: u64,
}

/// The sink's answer to the parent, one JSON line on stdout.
#[derive(Debug, Serialize, Deserialize)]
struct SinkReport {
    first_hop: LatencyReport,
    two_hops: LatencyReport,
}

/// One measured row, as `--json` prints it.
#[derive(Debug, Serialize)]
struct Row {
    events: String,
    wait: String,
    round: u32,
    first_hop: LatencyReport,
    two_hops: LatencyReport,
    /// User + system CPU time of the three processes, ms per 1 000 round trips (warm-up
    /// included).
    cpu_ms_per_1k: f64,
}

fn main() -> Result<()> {
    let args = Args::parse();
    match (args.role, args.wait, &args.prefix) {
        (Some(role), Some(wait), Some(prefix)) => {
            let events = args.events.context("a child needs --events")?;
            child(&args, role, events, wait, prefix)
        }
        (None, None, None) => parent(&args),
        _ => bail!("--role, --wait and --prefix are set together, by the parent"),
    }
}

// ---------------------------------------------------------------------------------------------
// The parent: runs each row's three processes and prints the table.

/// The three children of one row; killed if still running when dropped (an error path).
struct Trio(Vec<Child>);

impl Drop for Trio {
    fn drop(&mut self) {
        for c in &mut self.0 {
            if matches!(c.try_wait(), Ok(None)) {
                let _ = c.kill();
                let _ = c.wait();
            }
        }
    }
}

fn parent(args: &Args) -> Result<()> {
    if args.round_trips == 0 {
        bail!("--round-trips must be at least 1");
    }
    let cleaned = tes_runtime::channel::clean_stale_resources()?;
    if cleaned > 0 {
        eprintln!("removed the resources of {cleaned} dead iceoryx2 nodes");
    }
    let variants: Vec<_> = VARIANTS
        .into_iter()
        .filter(|(e, _)| args.events.is_none_or(|only| only == *e))
        .collect();
    if !args.json {
        println!(
            "{:<10} {:<9} {:>5} {:>26} {:>34} {:>14}",
            "events",
            "wait",
            "round",
            "first hop p50/p90/p99 µs",
            "two hops p50/p90/p99/p99.9/max µs",
            "CPU ms per 1k"
        );
    }
    for round in 1..=args.rounds {
        for &(events, wait) in &variants {
            let row = run_row(args, events, wait, round)
                .with_context(|| format!("{events:?} events, {wait:?} wait, round {round}"))?;
            if args.json {
                println!("{}", serde_json::to_string(&row)?);
            } else {
                let (f, b) = (&row.first_hop, &row.two_hops);
                println!(
                    "{:<10} {:<9} {:>5} {:>26} {:>34} {:>14.1}",
                    row.events,
                    row.wait,
                    round,
                    format!("{}/{}/{}", f.p50_us, f.p90_us, f.p99_us),
                    format!(
                        "{}/{}/{}/{}/{}",
                        b.p50_us, b.p90_us, b.p99_us, b.p999_us, b.max_us
                    ),
                    row.cpu_ms_per_1k
                );
            }
        }
    }
    Ok(())
}

fn children_cpu() -> Result<Duration> {
    use nix::sys::resource::{UsageWho, getrusage};
    let u = getrusage(UsageWho::RUSAGE_CHILDREN).context("getrusage")?;
    let us = |t: nix::sys::time::TimeVal| {
        Duration::from_secs(t.tv_sec() as u64) + Duration::from_micros(t.tv_usec() as u64)
    };
    Ok(us(u.user_time()) + us(u.system_time()))
}

fn run_row(args: &Args, events: Events, wait: Wait, round: u32) -> Result<Row> {
    let exe = std::env::current_exe().context("own path")?;
    let prefix = format!(
        "tes-event-wakeup-{}/{round}/{events:?}/{wait:?}/",
        std::process::id()
    );
    let label = |v: &dyn std::fmt::Debug| format!("{v:?}").to_lowercase();
    let spawn = |role: &str, cpu: Option<usize>| -> Result<Child> {
        let mut cmd = Command::new(&exe);
        cmd.args(["--role", role, "--prefix", &prefix])
            .args(["--events", &label(&events), "--wait", &label(&wait)])
            .args(["--round-trips", &args.round_trips.to_string()])
            .args(["--gap-us", &args.gap_us.to_string()])
            .stdout(if role == "sink" {
                Stdio::piped()
            } else {
                Stdio::null()
            });
        if let Some(cpu) = cpu {
            cmd.args(["--hop-cpu", &cpu.to_string()]);
        }
        cmd.spawn().with_context(|| format!("start the {role}"))
    };
    let before = children_cpu()?;
    // Receivers first: the source's probes find them sooner.
    let mut trio = Trio(vec![spawn("sink", None)?, spawn("hop", args.hop_cpu)?]);
    trio.0.push(spawn("source", None)?);
    let trips = args.round_trips + WARMUP;
    let deadline = Instant::now()
        + Duration::from_secs(60)
        + Duration::from_micros(trips * (args.gap_us + 5_000));
    let stdout = trio.0[0].stdout.take().context("the sink's output")?;
    let reader = std::thread::spawn(move || -> Result<String> {
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line)?;
        Ok(line)
    });
    for (child, role) in trio.0.iter_mut().zip(["sink", "hop", "source"]) {
        loop {
            if let Some(status) = child.try_wait()? {
                if !status.success() {
                    bail!("the {role} failed: {status}");
                }
                break;
            }
            if Instant::now() > deadline {
                bail!("the {role} did not finish in time");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let line = reader
        .join()
        .map_err(|_| anyhow!("the reader thread panicked"))??;
    let report: SinkReport =
        serde_json::from_str(&line).with_context(|| format!("the sink's report {line:?}"))?;
    let cpu = children_cpu()?.saturating_sub(before);
    Ok(Row {
        events: label(&events),
        wait: label(&wait),
        round,
        first_hop: report.first_hop,
        two_hops: report.two_hops,
        cpu_ms_per_1k: cpu.as_secs_f64() * 1e3 / (trips as f64 / 1e3),
    })
}

// ---------------------------------------------------------------------------------------------
// A child: one role of the relay.

/// Round trips run before the measured ones.
const WARMUP: u64 = 1_000;

fn child(args: &Args, role: Role, events: Events, wait: Wait, prefix: &str) -> Result<()> {
    // Die with the parent (a killed benchmark leaves no relay behind).
    nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGKILL).context("pdeathsig")?;
    if let Some(cpu) = args.hop_cpu {
        tes_runtime::affinity::pin_this_thread(cpu)?;
    }
    let run = Relay {
        role,
        wait,
        prefix,
        trips: args.round_trips + WARMUP,
        gap: Duration::from_micros(args.gap_us),
    };
    match events {
        Events::Socket => run.run::<ipc::Service>(),
        Events::Semaphore => run.run::<semaphore::Service>(),
    }
}

/// How a service type's listener can be waited on.
trait Wakeable: Service {
    /// Calls `body` with a function that blocks, by `how`, until `listener` has been notified
    /// (and drains it); spurious returns are allowed.
    fn with_waiter<R>(
        listener: &Listener<Self>,
        how: Wait,
        body: impl FnOnce(&mut dyn FnMut() -> Result<()>) -> Result<R>,
    ) -> Result<R>;
}

fn blocking_or_timed<S: Service>(listener: &Listener<S>, how: Wait) -> Result<()> {
    match how {
        Wait::Blocking => listener
            .blocking_wait(|_| {})
            .map(|_| ())
            .map_err(|e| anyhow!("blocking_wait: {e:?}")),
        Wait::Timed => listener
            .timed_wait(|_| {}, TIMED)
            .map(|_| ())
            .map_err(|e| anyhow!("timed_wait: {e:?}")),
        other => bail!("{other:?} needs a listener with a file descriptor"),
    }
}

impl Wakeable for ipc::Service {
    fn with_waiter<R>(
        listener: &Listener<Self>,
        how: Wait,
        body: impl FnOnce(&mut dyn FnMut() -> Result<()>) -> Result<R>,
    ) -> Result<R> {
        use iceoryx2::prelude::{FileDescriptorBased, WaitSetBuilder};
        let drain = || {
            listener
                .try_wait(|_| {})
                .map(|_| ())
                .map_err(|e| anyhow!("try_wait: {e:?}"))
        };
        match how {
            Wait::Blocking | Wait::Timed => body(&mut || blocking_or_timed(listener, how)),
            Wait::Ppoll => body(&mut || {
                use nix::poll::{PollFd, PollFlags, ppoll};
                use std::os::fd::BorrowedFd;
                // SAFETY: the descriptor belongs to `listener`, which outlives this call.
                let fd =
                    unsafe { BorrowedFd::borrow_raw(listener.file_descriptor().native_handle()) };
                let mut fds = [PollFd::new(fd, PollFlags::POLLIN)];
                match ppoll(&mut fds, Some(TIMED.into()), None) {
                    Ok(_) | Err(nix::errno::Errno::EINTR) => drain(),
                    Err(e) => Err(anyhow!("ppoll: {e}")),
                }
            }),
            Wait::Waitset => {
                let waitset = WaitSetBuilder::new()
                    .create::<ipc::Service>()
                    .map_err(|e| anyhow!("waitset: {e:?}"))?;
                let _guard = waitset
                    .attach_notification(listener)
                    .map_err(|e| anyhow!("attach: {e:?}"))?;
                body(&mut || {
                    waitset
                        .wait_and_process_once_with_timeout(|_| CallbackProgression::Stop, TIMED)
                        .map_err(|e| anyhow!("waitset wait: {e:?}"))?;
                    drain()
                })
            }
        }
    }
}

impl Wakeable for semaphore::Service {
    fn with_waiter<R>(
        listener: &Listener<Self>,
        how: Wait,
        body: impl FnOnce(&mut dyn FnMut() -> Result<()>) -> Result<R>,
    ) -> Result<R> {
        if matches!(how, Wait::Ppoll | Wait::Waitset) {
            bail!("a semaphore listener has no file descriptor: {how:?} does not apply");
        }
        body(&mut || blocking_or_timed(listener, how))
    }
}

/// One role's settings.
struct Relay<'a> {
    role: Role,
    wait: Wait,
    prefix: &'a str,
    trips: u64,
    gap: Duration,
}

/// A receiving end (subscriber + listener) and a sending end (publisher + notifier).
struct Ports<S: Service> {
    subscriber: Subscriber<S, Stamp, ()>,
    listener: Listener<S>,
    publisher: Publisher<S, Stamp, ()>,
    notifier: Notifier<S>,
}

impl<S: Service> Ports<S> {
    fn open(node: &iceoryx2::node::Node<S>, prefix: &str, from: &str, to: &str) -> Result<Self> {
        let name = |s: &str| -> Result<ServiceName> {
            let full = format!("{prefix}{s}");
            ServiceName::new(&full).map_err(|e| anyhow!("{full}: {e:?}"))
        };
        let pubsub = |s: &str| {
            node.service_builder(&name(s)?)
                .publish_subscribe::<Stamp>()
                .open_or_create()
                .map_err(|e| anyhow!("service {s}: {e:?}"))
        };
        let event = |s: &str| {
            node.service_builder(&name(&format!("{s}/event"))?)
                .event()
                .open_or_create()
                .map_err(|e| anyhow!("event {s}: {e:?}"))
        };
        Ok(Self {
            subscriber: pubsub(from)?
                .subscriber_builder()
                .create()
                .map_err(|e| anyhow!("subscriber: {e:?}"))?,
            listener: event(from)?
                .listener_builder()
                .create()
                .map_err(|e| anyhow!("listener: {e:?}"))?,
            publisher: pubsub(to)?
                .publisher_builder()
                .create()
                .map_err(|e| anyhow!("publisher: {e:?}"))?,
            notifier: event(to)?
                .notifier_builder()
                .create()
                .map_err(|e| anyhow!("notifier: {e:?}"))?,
        })
    }

    fn send(&self, stamp: Stamp) -> Result<()> {
        self.publisher
            .update_connections()
            .map_err(|e| anyhow!("connect: {e:?}"))?;
        self.publisher
            .send_copy(stamp)
            .map_err(|e| anyhow!("send: {e:?}"))?;
        self.notifier
            .notify()
            .map_err(|e| anyhow!("notify: {e:?}"))?;
        Ok(())
    }

    fn try_receive(&self) -> Result<Option<Stamp>> {
        Ok(self
            .subscriber
            .receive()
            .map_err(|e| anyhow!("receive: {e:?}"))?
            .map(|s| *s))
    }

    /// The next stamp, sleeping by `wait` between looks.
    fn receive(&self, wait: &mut dyn FnMut() -> Result<()>) -> Result<Stamp> {
        loop {
            if let Some(s) = self.try_receive()? {
                return Ok(s);
            }
            wait()?;
        }
    }
}

impl Relay<'_> {
    fn run<S: Wakeable>(&self) -> Result<()> {
        let node = NodeBuilder::new()
            .config(&Config::default())
            .create::<S>()
            .map_err(|e| anyhow!("node: {e:?}"))?;
        let (from, to) = match self.role {
            Role::Source => ("ack", "stamp"),
            Role::Hop => ("stamp", "relayed"),
            Role::Sink => ("relayed", "ack"),
        };
        let ports = Ports::<S>::open(&node, self.prefix, from, to)?;
        S::with_waiter(&ports.listener, self.wait, |wait| match self.role {
            Role::Source => self.source(&ports, wait),
            Role::Hop => self.hop(&ports, wait),
            Role::Sink => self.sink(&ports, wait),
        })
    }

    fn source<S: Service>(&self, p: &Ports<S>, wait: &mut dyn FnMut() -> Result<()>) -> Result<()> {
        // Until the path is connected a stamp may reach nobody: probe (seq 0) by polling until
        // one comes back; only then wait by the row's way.
        let give_up = Instant::now() + Duration::from_secs(20);
        'connected: loop {
            p.send(Stamp::default())?;
            let resend = Instant::now() + Duration::from_millis(10);
            while Instant::now() < resend {
                if p.try_receive()?.is_some_and(|s| s.seq == 0) {
                    break 'connected;
                }
                std::thread::sleep(Duration::from_micros(200));
            }
            if Instant::now() > give_up {
                bail!("source: no answer to the probes in 20 s");
            }
        }
        // Late answers to extra probes.
        while p.try_receive()?.is_some() {}
        for seq in 1..=self.trips {
            std::thread::sleep(self.gap);
            p.send(Stamp {
                seq,
                sent_ns: monotonic_ns(),
                hop_awake_ns: 0,
            })?;
            while p.receive(wait)?.seq != seq {}
        }
        Ok(())
    }

    fn hop<S: Service>(&self, p: &Ports<S>, wait: &mut dyn FnMut() -> Result<()>) -> Result<()> {
        loop {
            let mut s = p.receive(wait)?;
            s.hop_awake_ns = monotonic_ns();
            p.send(s)?;
            if s.seq == self.trips {
                return Ok(());
            }
        }
    }

    fn sink<S: Service>(&self, p: &Ports<S>, wait: &mut dyn FnMut() -> Result<()>) -> Result<()> {
        let mut first = LatencyRecorder::new(1000, WARMUP);
        let mut both = LatencyRecorder::new(1000, WARMUP);
        loop {
            let s = p.receive(wait)?;
            let now = monotonic_ns();
            if s.seq > 0 {
                first.record_ns(s.hop_awake_ns.saturating_sub(s.sent_ns));
                both.record_ns(now.saturating_sub(s.sent_ns));
            }
            p.send(s)?;
            if s.seq == self.trips {
                break;
            }
        }
        let report = SinkReport {
            first_hop: first.report(),
            two_hops: both.report(),
        };
        println!("{}", serde_json::to_string(&report)?);
        Ok(())
    }
}
