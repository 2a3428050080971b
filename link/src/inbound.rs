//! What arrives from peers: checked, restamped and republished into the local services.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use tes_runtime::channel::{self, Inbox, IpcError, LatestOutbox, Outbox, WaitStrategy};
use tes_topics::wire::{Checker, Refusal, as_bytes, from_bytes};
use tes_topics::{Command, MotorState, Observation, Progress, Role, ServiceNames, WorldMap};

use crate::shared::{IDLE, Shared};
use crate::topic::role_index;
use crate::{LinkEvent, Topic};

/// The ports of iceoryx2's thread-safe flavour: written from Zenoh's callbacks.
type ThreadSafe = iceoryx2::service::ipc_threadsafe::Service;

/// A progress publisher of the thread-safe flavour.
type ProgressPublisher = iceoryx2::port::publisher::Publisher<ThreadSafe, Progress, ()>;

/// How often the ports look for local processes that started since.
const RECONNECT: Duration = Duration::from_millis(200);

/// The local ports what arrives from peers is republished on, each only where its service
/// crosses.
struct LocalPorts {
    observation: Option<Outbox<Observation, ThreadSafe>>,
    world_map: Option<Outbox<WorldMap, ThreadSafe>>,
    command: Option<LatestOutbox<Command, ThreadSafe>>,
    motor_state: Option<Outbox<MotorState, ThreadSafe>>,
    /// Per role, in the order of [`Role::ALL`].
    progress: [Option<ProgressPublisher>; 3],
    /// The world map published on this host, when its writer is local.
    local_map: Option<Inbox<WorldMap, ThreadSafe>>,
}

impl LocalPorts {
    fn open(
        node: &iceoryx2::prelude::Node<ThreadSafe>,
        names: &ServiceNames,
        local: &[Role],
    ) -> Result<Self, IpcError> {
        let crosses = |topic: Topic| topic.comes_in(local);
        let mut progress = [None, None, None];
        for (slot, role) in progress.iter_mut().zip(Role::ALL) {
            if crosses(Topic::Progress(role)) {
                let service = channel::pubsub::<Progress, _>(node, names.progress_of(role), 1)?;
                *slot = Some(
                    service
                        .publisher_builder()
                        .create()
                        .map_err(channel::ipc_err("create a progress publisher"))?,
                );
            }
        }
        Ok(Self {
            observation: crosses(Topic::Observation)
                .then(|| Outbox::open(node, &names.observation, &names.observation_event, 0))
                .transpose()?,
            world_map: crosses(Topic::WorldMap)
                .then(|| Outbox::open(node, &names.world_map, &names.world_map_event, 1))
                .transpose()?,
            command: crosses(Topic::Command)
                .then(|| LatestOutbox::open(node, &names.command, &names.command_event))
                .transpose()?,
            motor_state: crosses(Topic::MotorState)
                .then(|| Outbox::open(node, &names.motor_state, &names.motor_state_event, 0))
                .transpose()?,
            progress,
            local_map: (!crosses(Topic::WorldMap))
                .then(|| {
                    Inbox::open(
                        node,
                        &names.world_map,
                        &names.world_map_event,
                        1,
                        WaitStrategy::Block,
                    )
                })
                .transpose()?,
        })
    }
}

/// What arrives from peers: the checker that judges it and the ports that republish what
/// passes. Zenoh's callbacks take it under a lock, one sample at a time.
pub(crate) struct Inbound {
    ports: LocalPorts,
    checker: Checker,
    restamp: bool,
    /// When the ports last looked for processes that started since.
    connected: Instant,
    // Declared last: dropped after the ports.
    _node: iceoryx2::prelude::Node<ThreadSafe>,
}

impl Inbound {
    /// Opens the ports of the services that come in to a host playing `local`.
    pub(crate) fn open(
        names: &ServiceNames,
        local: &[Role],
        restamp: bool,
    ) -> Result<Self, IpcError> {
        let node = channel::shared_node(false)?;
        Ok(Self {
            ports: LocalPorts::open(&node, names, local)?,
            checker: Checker::default(),
            restamp,
            connected: Instant::now(),
            _node: node,
        })
    }

    /// Takes the world map published on this host, if a new one came: what arrives is
    /// checked against the latest.
    fn follow_local_map(&mut self) {
        if let Some(inbox) = &self.ports.local_map {
            match inbox.try_next() {
                Ok(Some(m)) => {
                    let _ = self.checker.world_map(&m);
                }
                Ok(None) => {}
                Err(e) => eprintln!("launch: link: warning: cannot read the world map: {e}"),
            }
        }
    }

    /// Checks one payload of `topic` from a peer, republishes it if it passes and counts it
    /// either way.
    pub(crate) fn take_counted(&mut self, topic: Topic, bytes: &[u8], shared: &Shared) {
        self.follow_local_map();
        let i = topic.index();
        match self.take(topic, bytes) {
            Ok(Taken::Passed) => {
                shared.received[i].fetch_add(1, Ordering::Relaxed);
            }
            Ok(Taken::Repeat) => {}
            Err(why) => {
                let count = shared.refused[i].fetch_add(1, Ordering::Relaxed) + 1;
                if count == 1 || count.is_multiple_of(100) {
                    shared.push(LinkEvent::Refused { topic, why, count });
                }
            }
        }
    }

    /// Checks one payload of `topic` from a peer and republishes it locally.
    fn take(&mut self, topic: Topic, bytes: &[u8]) -> Result<Taken, Refusal> {
        let now = tes_runtime::clock::monotonic_ns();
        let (checker, ports, restamp) = (&mut self.checker, &self.ports, self.restamp);
        match topic {
            Topic::Observation => {
                let o = take_observation(bytes, checker, restamp.then_some(now))?;
                if let Some(out) = &ports.observation {
                    republished(out.send(o));
                }
            }
            Topic::WorldMap => {
                let Some(m) = take_world_map(bytes, checker)? else {
                    return Ok(Taken::Repeat);
                };
                if let Some(out) = &ports.world_map {
                    republished(out.send(*m));
                }
            }
            Topic::Command => {
                let c = take_command(bytes, checker, restamp.then_some(now))?;
                if let Some(out) = &ports.command {
                    republished(out.send(c));
                }
            }
            Topic::MotorState => {
                let m: MotorState = from_bytes(bytes)?;
                checker.motor_state(&m)?;
                if let Some(out) = &ports.motor_state {
                    republished(out.send(m));
                }
            }
            Topic::Progress(role) => {
                let p = take_progress(role, bytes, checker, now)?;
                if let Some(out) = &ports.progress[role_index(role)] {
                    republished(
                        out.send_copy(p)
                            .map(|_| ())
                            .map_err(channel::ipc_err("publish a progress report")),
                    );
                }
            }
        }
        Ok(Taken::Passed)
    }

    /// Connects the processes that started since the last look (a few times a second).
    fn reconnect(&mut self) {
        if self.connected.elapsed() < RECONNECT {
            return;
        }
        self.connected = Instant::now();
        let ports = &self.ports;
        let connected = [
            ports.observation.as_ref().map(Outbox::update_connections),
            ports.world_map.as_ref().map(Outbox::update_connections),
            ports.motor_state.as_ref().map(Outbox::update_connections),
        ];
        for e in connected.into_iter().flatten().filter_map(Result::err) {
            eprintln!("launch: link: warning: cannot connect a local port: {e}");
        }
    }
}

/// What became of a payload that passed the checks.
enum Taken {
    /// Republished locally.
    Passed,
    /// A repeat of the world map already taken: nothing to do.
    Repeat,
}

/// Warns of a payload that passed but could not be republished.
fn republished(result: Result<(), IpcError>) {
    if let Err(e) = result {
        eprintln!("launch: link: warning: cannot republish: {e}");
    }
}

/// An observation from a peer, checked; stamped `now` when given.
fn take_observation(
    bytes: &[u8],
    checker: &mut Checker,
    now: Option<u64>,
) -> Result<Observation, Refusal> {
    let mut o: Observation = from_bytes(bytes)?;
    checker.observation(&o)?;
    if let Some(now) = now {
        o.stamp_ns = now;
    }
    Ok(o)
}

/// A world map from a peer, checked and kept by `checker`; `None` for a repeat of the one
/// it already holds.
fn take_world_map(bytes: &[u8], checker: &mut Checker) -> Result<Option<Box<WorldMap>>, Refusal> {
    let m: Box<WorldMap> = boxed_from_bytes(bytes)?;
    if checker
        .map()
        .is_some_and(|kept| as_bytes(kept) == as_bytes(&*m))
    {
        return Ok(None);
    }
    checker.world_map(&m)?;
    Ok(Some(m))
}

/// A command from a peer, checked; when `now` is given, stamped `now` with the time it
/// waited since its observation kept.
fn take_command(bytes: &[u8], checker: &mut Checker, now: Option<u64>) -> Result<Command, Refusal> {
    let mut c: Command = from_bytes(bytes)?;
    checker.command(&c)?;
    if let Some(now) = now {
        let waited = c.stamp_ns.saturating_sub(c.observed_ns);
        c.stamp_ns = now;
        c.observed_ns = if c.observed_ns == 0 {
            0
        } else {
            now.saturating_sub(waited)
        };
    }
    Ok(c)
}

/// A progress report of `role` from a peer, checked and restamped to `now` (always: the
/// watcher compares report stamps with its own clock), keeping its age.
fn take_progress(
    role: Role,
    bytes: &[u8],
    checker: &mut Checker,
    now: u64,
) -> Result<Progress, Refusal> {
    let mut p: Progress = from_bytes(bytes)?;
    checker.progress(role, &p)?;
    let age = p.stamp_ns.saturating_sub(p.started_ns);
    p.stamp_ns = now;
    p.started_ns = now.saturating_sub(age);
    Ok(p)
}

/// A world map from bytes, on the heap (it is ~90 kB).
fn boxed_from_bytes(bytes: &[u8]) -> Result<Box<WorldMap>, Refusal> {
    let mut map = Box::new(WorldMap::EMPTY);
    *map = from_bytes::<WorldMap>(bytes)?;
    Ok(map)
}

/// Keeps the inbound ports current between samples until `stop`: the local world map
/// followed, processes that started since connected.
pub(crate) fn tend(inbound: &Mutex<Inbound>, stop: &AtomicBool) {
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(IDLE);
        let Ok(mut inbound) = inbound.lock() else {
            return;
        };
        inbound.follow_local_map();
        inbound.reconnect();
    }
}
