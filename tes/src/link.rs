//! The link: a launch that starts only some of the group's processes (`tes launch --roles`,
//! `[launch] roles`) reaches the others, on other hosts, through one Zenoh session.
//!
//! The link runs in the launcher. It forwards each local service a remote process reads —
//! a process's payload as the fixed-size bytes of its `#[repr(C)]` struct
//! ([`tes_topics::wire`]), one Zenoh key per service under `[launch.link] group` — and, on
//! receipt, checks each payload ([`tes_topics::wire::Checker`]), republishes what passes into
//! the local iceoryx2 service and notifies its event, so the processes themselves are
//! unchanged and never see a raw network sample. What it refuses it counts and reports.
//!
//! Each launch declares a Zenoh liveliness token per local role (`GROUP/member/ROLE/ZID`):
//! that is how a launch knows its peers are there, that a role is played twice, and that a
//! peer's host is gone (its session ended). A launch that stops tells its peers why
//! (`GROUP/stop`), so they stop too.
//!
//! Which services cross, by who writes and who reads them:
//!
//! | service | writer → readers | key |
//! |---|---|---|
//! | observation (publish–subscribe) | perception → controller | `GROUP/observation` |
//! | world map (publish–subscribe, history 1) | perception → controller (and every host, to check commands) | `GROUP/world-map` |
//! | command (blackboard) | controller → bridge | `GROUP/command` |
//! | motor state (publish–subscribe) | bridge → perception | `GROUP/motor-state` |
//! | progress of each role (publish–subscribe, history 1) | the role → everyone | `GROUP/progress/ROLE` |

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use serde::{Deserialize, Serialize};
use tes_runtime::channel::{self, Inbox, LatestInbox, LatestOutbox, Outbox, WaitStrategy};
use tes_topics::wire::{Checker, Refusal, as_bytes, from_bytes};
use tes_topics::{Command, MotorState, Observation, Progress, Role, ServiceNames, WorldMap};
use zenoh::Wait;

/// Zenoh's session mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Every launch a peer: they connect to each other directly.
    #[default]
    Peer,
    /// This launch reaches the others through a Zenoh router it connects to.
    Client,
}

/// The `[launch.link]` table: how a launch with roles reaches its peers.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LinkSection {
    /// The group's name on Zenoh: the first part of every key (default `tes`). Launches of
    /// one group give the same; two groups on one network give different ones.
    pub group: String,
    /// `peer` (default) or `client`.
    pub mode: Mode,
    /// Endpoints this launch listens on (default `tcp/127.0.0.1:7447`, loopback only).
    pub listen: Vec<String>,
    /// Endpoints of peers (or the router) to connect to (default none).
    pub connect: Vec<String>,
    /// Find peers by UDP multicast scouting: on by default when `connect` is empty.
    pub multicast_scouting: Option<bool>,
    /// How long to wait for the other roles' launches before giving up, ms (default 30000).
    pub peer_timeout_ms: u64,
    /// Stamp arriving observations and commands with this host's clock at arrival, keeping
    /// the differences between their stamps (default true: hosts' monotonic clocks differ).
    /// `false` keeps the sender's stamps, for hosts that share a clock (one machine).
    pub restamp: bool,
}

impl Default for LinkSection {
    fn default() -> Self {
        Self {
            group: "tes".into(),
            mode: Mode::Peer,
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: Vec::new(),
            multicast_scouting: None,
            peer_timeout_ms: 30_000,
            restamp: true,
        }
    }
}

impl LinkSection {
    /// Why the table cannot be used, as `(key, reason)`.
    pub fn check(&self) -> std::result::Result<(), (&'static str, String)> {
        let chunk_ok = |c: &str| {
            !c.is_empty()
                && c.bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_' || b == b'.')
        };
        if self.group.len() > 64 || !self.group.split('/').all(chunk_ok) {
            return Err((
                "link.group",
                format!(
                    "{:?} is not a group name: at most 64 bytes of ASCII letters, digits, '-', \
                     '_', '.', in parts separated by '/'",
                    self.group
                ),
            ));
        }
        for (key, endpoints) in [
            ("link.listen", &self.listen),
            ("link.connect", &self.connect),
        ] {
            if let Some(bad) = endpoints
                .iter()
                .find(|e| e.parse::<zenoh::config::EndPoint>().is_err() || !e.starts_with("tcp/"))
            {
                return Err((
                    key,
                    format!("{bad:?} is not a TCP endpoint such as \"tcp/192.168.1.20:7447\""),
                ));
            }
        }
        if self.listen.is_empty()
            && self.connect.is_empty()
            && self.multicast_scouting == Some(false)
        {
            return Err((
                "link.connect",
                "with nothing to listen on, nothing to connect to and no scouting, no peer can \
                 be reached"
                    .into(),
            ));
        }
        if self.peer_timeout_ms < 100 {
            return Err((
                "link.peer_timeout_ms",
                format!("must be at least 100, got {}", self.peer_timeout_ms),
            ));
        }
        Ok(())
    }

    /// The Zenoh configuration: mode, endpoints, scouting.
    pub fn zenoh_config(&self) -> Result<zenoh::Config> {
        let mut config = zenoh::Config::default();
        let json = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
        let mode = match self.mode {
            Mode::Peer => "\"peer\"",
            Mode::Client => "\"client\"",
        };
        let multicast = self.multicast_scouting.unwrap_or(self.connect.is_empty());
        for (key, value) in [
            ("mode", mode.to_owned()),
            ("listen/endpoints", json(&self.listen)),
            ("connect/endpoints", json(&self.connect)),
            ("scouting/multicast/enabled", multicast.to_string()),
            // Peers a peer learns of from another are connected to as well.
            ("scouting/gossip/enabled", "true".into()),
        ] {
            config
                .insert_json5(key, &value)
                .map_err(|e| anyhow!("zenoh config {key} = {value}: {e}"))?;
        }
        Ok(config)
    }
}

/// A role's name as `[launch] roles` and `--roles` take it.
pub fn parse_role(name: &str) -> Option<Role> {
    Role::ALL.into_iter().find(|r| r.name() == name)
}

/// Something the link saw that the launcher acts on.
#[derive(Debug, Clone, PartialEq)]
pub enum LinkEvent {
    /// A peer launch playing `role` is there.
    Joined(Role),
    /// The peer playing `role` is gone: its session ended (stopped, killed, or unreachable).
    Left(Role),
    /// Two launches play `role`.
    Twice(Role),
    /// A peer stopped the group; `clean` when it stopped as planned (episodes done, Ctrl-C).
    Stop {
        /// Whether the peer stopped cleanly.
        clean: bool,
        /// What it said.
        reason: String,
    },
    /// A payload from a peer was refused (the first of its kind, then every 100th).
    Refused {
        /// The service.
        topic: &'static str,
        /// Why.
        why: Refusal,
        /// Payloads of this service refused so far.
        count: u64,
    },
}

/// What the link's threads share.
#[derive(Default)]
struct Shared {
    events: Mutex<VecDeque<LinkEvent>>,
    /// Remote sessions seen per role.
    peers: Mutex<BTreeMap<Role, BTreeSet<String>>>,
    /// Payloads refused, per topic index.
    refused: [AtomicU64; TOPICS.len()],
    /// Payloads forwarded to this host, per topic index.
    received: [AtomicU64; TOPICS.len()],
}

impl Shared {
    fn push(&self, event: LinkEvent) {
        if let Ok(mut e) = self.events.lock() {
            e.push_back(event);
        }
    }
}

/// The services that cross, in the order of [`Shared::refused`].
const TOPICS: [&str; 7] = [
    "observation",
    "world-map",
    "command",
    "motor-state",
    "progress/perception-sim",
    "progress/controller",
    "progress/bridge",
];

/// The role that writes a topic.
fn writer(topic: usize) -> Role {
    match topic {
        0 | 1 | 4 => Role::Perception,
        2 | 5 => Role::Controller,
        _ => Role::Bridge,
    }
}

/// Whether a topic is read on a host playing `local` (every host checks commands against
/// the world map, and the launcher watches every role's progress).
fn read_by(topic: usize, local: &[Role]) -> bool {
    let has = |r| local.contains(&r);
    match topic {
        0 => has(Role::Controller),
        1 => true,
        2 => has(Role::Bridge),
        3 => has(Role::Perception),
        _ => true,
    }
}

/// How the link counts what passed and what it refused, at the end.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkCounts {
    /// Per service name: (received and passed on, refused).
    pub by_topic: Vec<(&'static str, u64, u64)>,
}

impl std::fmt::Display for LinkCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts: Vec<String> = self
            .by_topic
            .iter()
            .filter(|(_, r, x)| r + x > 0)
            .map(|(t, r, x)| format!("{t} {r} taken, {x} refused"))
            .collect();
        if parts.is_empty() {
            f.write_str("nothing received")
        } else {
            f.write_str(&parts.join("; "))
        }
    }
}

/// The link of one launch: its Zenoh session, its tokens and its forwarding threads.
pub struct Link {
    session: zenoh::Session,
    group: String,
    zid: String,
    local: Vec<Role>,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    tokens: Vec<zenoh::liveliness::LivelinessToken>,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    stop_publisher: zenoh::pubsub::Publisher<'static>,
}

/// How long an idle forwarding thread sleeps between looks at the stop flag.
const IDLE: Duration = Duration::from_millis(50);

/// How often a host that writes the world map sends it again (a peer that joins later, or
/// whose subscription was not yet known, gets it then).
const MAP_AGAIN: Duration = Duration::from_secs(1);

impl Link {
    /// Opens the Zenoh session of `settings`, says which roles this launch plays (refusing a
    /// role another launch of the group already plays) and starts forwarding the services
    /// of the group `names` between this host and the others.
    pub fn open(settings: &LinkSection, local: &[Role], names: &ServiceNames) -> Result<Self> {
        let config = settings.zenoh_config()?;
        let session = zenoh::open(config).wait().map_err(|e| {
            anyhow!(
                "cannot open the Zenoh link (listen {:?}, connect {:?}): {e}",
                settings.listen,
                settings.connect
            )
        })?;
        let group = settings.group.clone();
        let zid = session.zid().to_string();
        let shared = Arc::new(Shared::default());
        let stop = Arc::new(AtomicBool::new(false));
        let mut subscribers = Vec::new();

        // Members: who plays what.
        let members = {
            let shared = shared.clone();
            let own = zid.clone();
            let local = local.to_vec();
            let prefix = format!("{group}/member/");
            session
                .liveliness()
                .declare_subscriber(format!("{group}/member/*/*"))
                .history(true)
                .callback(move |sample| {
                    let key = sample.key_expr().as_str();
                    let Some((role, who)) = key
                        .strip_prefix(&prefix)
                        .and_then(|rest| rest.split_once('/'))
                    else {
                        return;
                    };
                    let (Some(role), true) = (parse_role(role), who != own) else {
                        return;
                    };
                    let Ok(mut peers) = shared.peers.lock() else {
                        return;
                    };
                    let sessions = peers.entry(role).or_default();
                    match sample.kind() {
                        zenoh::sample::SampleKind::Put => {
                            if sessions.insert(who.to_owned()) {
                                let twice = local.contains(&role) || sessions.len() > 1;
                                drop(peers);
                                shared.push(if twice {
                                    LinkEvent::Twice(role)
                                } else {
                                    LinkEvent::Joined(role)
                                });
                            }
                        }
                        zenoh::sample::SampleKind::Delete => {
                            if sessions.remove(who) && sessions.is_empty() {
                                drop(peers);
                                shared.push(LinkEvent::Left(role));
                            }
                        }
                    }
                })
                .wait()
                .map_err(|e| anyhow!("cannot watch the group's members on Zenoh: {e}"))?
        };
        subscribers.push(members);

        // A peer's stop: "ZID clean|failed reason".
        let stops = {
            let shared = shared.clone();
            let own = zid.clone();
            session
                .declare_subscriber(format!("{group}/stop"))
                .callback(move |sample| {
                    let text = String::from_utf8_lossy(&sample.payload().to_bytes()).into_owned();
                    let mut parts = text.splitn(3, ' ');
                    let (Some(who), Some(how)) = (parts.next(), parts.next()) else {
                        return;
                    };
                    if who == own {
                        return;
                    }
                    let reason: String = parts.next().unwrap_or("").chars().take(500).collect();
                    shared.push(LinkEvent::Stop {
                        clean: how == "clean",
                        reason,
                    });
                })
                .wait()
                .map_err(|e| anyhow!("cannot subscribe on Zenoh: {e}"))?
        };
        subscribers.push(stops);
        let stop_publisher = session
            .declare_publisher(format!("{group}/stop"))
            .wait()
            .map_err(|e| anyhow!("cannot publish on Zenoh: {e}"))?;

        // What comes from peers is checked and republished on Zenoh's own receiving thread,
        // straight from its callback: no hand-over to another thread and its wake-up.
        let inbound = Arc::new(Mutex::new(
            Inbound::open(names, local, settings.restamp)
                .context("the link cannot open the local services")?,
        ));
        for (i, topic) in TOPICS.iter().enumerate() {
            if local.contains(&writer(i)) || !read_by(i, local) {
                continue;
            }
            let inbound = inbound.clone();
            let shared = shared.clone();
            let subscriber = session
                .declare_subscriber(format!("{group}/{topic}"))
                .callback(move |sample| {
                    let bytes = sample.payload().to_bytes();
                    if let Ok(mut inbound) = inbound.lock() {
                        inbound.take_counted(i, &bytes, &shared);
                    }
                })
                .wait()
                .map_err(|e| anyhow!("cannot subscribe to {group}/{topic} on Zenoh: {e}"))?;
            subscribers.push(subscriber);
        }

        let mut threads = Vec::new();
        let (ready_tx, ready_rx) = mpsc::channel::<Result<()>>();
        {
            let stop = stop.clone();
            threads.push(
                std::thread::Builder::new()
                    .name("link-in".into())
                    .spawn(move || tend(&inbound, &stop))
                    .context("cannot start the link's thread")?,
            );
        }
        // What local processes write and a peer reads: one thread per service.
        let remote_reads = |topic: usize| {
            let others: Vec<Role> = Role::ALL
                .into_iter()
                .filter(|r| !local.contains(r))
                .collect();
            local.contains(&writer(topic)) && (topic == 1 || topic >= 4 || read_by(topic, &others))
        };
        for (i, topic) in TOPICS.iter().enumerate() {
            if !remote_reads(i) {
                continue;
            }
            let publisher = session
                .declare_publisher(format!("{group}/{topic}"))
                .congestion_control(zenoh::qos::CongestionControl::Block)
                .express(true)
                .wait()
                .map_err(|e| anyhow!("cannot publish {group}/{topic} on Zenoh: {e}"))?;
            let names = names.clone();
            let stop = stop.clone();
            let ready = ready_tx.clone();
            threads.push(
                std::thread::Builder::new()
                    .name(format!("link-out-{i}"))
                    .spawn(move || outbound(i, &names, &publisher, &stop, ready))
                    .context("cannot start the link's thread")?,
            );
        }
        drop(ready_tx);
        let mut link = Self {
            session,
            group,
            zid,
            local: local.to_vec(),
            shared,
            stop,
            threads,
            tokens: Vec::new(),
            _subscribers: subscribers,
            stop_publisher,
        };
        // Every forwarding thread has its ports before anyone is told this launch is there
        // (the first thread, `tend`, opens none).
        let forwarding = link.threads.len() - 1;
        for _ in 0..forwarding {
            match ready_rx.recv_timeout(Duration::from_secs(30)) {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    link.close();
                    return Err(e.context("the link cannot open the local services"));
                }
                Err(_) => {
                    link.close();
                    bail!("the link's threads did not open the local services");
                }
            }
        }
        for role in local {
            let token = link
                .session
                .liveliness()
                .declare_token(format!(
                    "{}/member/{}/{}",
                    link.group,
                    role.name(),
                    link.zid
                ))
                .wait()
                .map_err(|e| anyhow!("cannot announce this launch on Zenoh: {e}"));
            match token {
                Ok(t) => link.tokens.push(t),
                Err(e) => {
                    link.close();
                    return Err(e);
                }
            }
        }
        Ok(link)
    }

    /// This launch's Zenoh session id.
    pub fn zid(&self) -> &str {
        &self.zid
    }

    /// The roles no launch of the group plays yet (neither this one nor a peer).
    pub fn missing(&self) -> Vec<Role> {
        let peers = self
            .shared
            .peers
            .lock()
            .map(|p| p.clone())
            .unwrap_or_default();
        Role::ALL
            .into_iter()
            .filter(|r| !self.local.contains(r) && peers.get(r).is_none_or(BTreeSet::is_empty))
            .collect()
    }

    /// The events since the last call.
    pub fn events(&self) -> Vec<LinkEvent> {
        self.shared
            .events
            .lock()
            .map(|mut e| e.drain(..).collect())
            .unwrap_or_default()
    }

    /// Tells the peers the group stops, and why.
    pub fn send_stop(&self, clean: bool, reason: &str) {
        let how = if clean { "clean" } else { "failed" };
        let _ = self
            .stop_publisher
            .put(format!("{} {how} {reason}", self.zid))
            .wait();
    }

    /// What passed and what was refused so far.
    pub fn counts(&self) -> LinkCounts {
        LinkCounts {
            by_topic: TOPICS
                .iter()
                .enumerate()
                .map(|(i, t)| {
                    (
                        *t,
                        self.shared.received[i].load(Ordering::Relaxed),
                        self.shared.refused[i].load(Ordering::Relaxed),
                    )
                })
                .collect(),
        }
    }

    /// Stops forwarding, withdraws this launch from the group and closes the session.
    pub fn close(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.tokens.clear();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        let _ = self.session.close().wait();
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.close();
    }
}

/// Forwards the local service `topic` to the peers until `stop`.
fn outbound(
    topic: usize,
    names: &ServiceNames,
    publisher: &zenoh::pubsub::Publisher<'static>,
    stop: &AtomicBool,
    ready: mpsc::Sender<Result<()>>,
) {
    let result = (|| -> Result<()> {
        let node = channel::node(false)?;
        let put = |bytes: &[u8]| {
            if let Err(e) = publisher.put(bytes).wait() {
                eprintln!("launch: link: warning: cannot send {}: {e}", TOPICS[topic]);
            }
        };
        match topic {
            0 => {
                let inbox: Inbox<Observation> = Inbox::open(
                    &node,
                    &names.observation,
                    &names.observation_event,
                    0,
                    WaitStrategy::Block,
                )?;
                let _ = ready.send(Ok(()));
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(o) = inbox.next(IDLE, stop)? {
                        put(as_bytes(&o));
                    }
                }
            }
            1 => {
                let inbox: Inbox<WorldMap> = Inbox::open(
                    &node,
                    &names.world_map,
                    &names.world_map_event,
                    1,
                    WaitStrategy::Block,
                )?;
                let _ = ready.send(Ok(()));
                let mut map: Option<Box<WorldMap>> = None;
                let mut sent = Instant::now();
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(m) = inbox.next(IDLE, stop)? {
                        **map.get_or_insert_with(|| Box::new(WorldMap::EMPTY)) = m;
                        sent = Instant::now() - MAP_AGAIN;
                    }
                    if let Some(m) = &map
                        && sent.elapsed() >= MAP_AGAIN
                    {
                        put(as_bytes(&**m));
                        sent = Instant::now();
                    }
                }
            }
            2 => {
                let mut inbox: LatestInbox<Command> = LatestInbox::open(
                    &node,
                    &names.command,
                    &names.command_event,
                    WaitStrategy::Block,
                )?;
                let _ = ready.send(Ok(()));
                while !stop.load(Ordering::Relaxed) {
                    match inbox.next(IDLE, stop)? {
                        Ok(c) => put(as_bytes(&c)),
                        Err(_) => {
                            inbox.renew_if_abandoned(&node)?;
                        }
                    }
                }
            }
            3 => {
                let inbox: Inbox<MotorState> = Inbox::open(
                    &node,
                    &names.motor_state,
                    &names.motor_state_event,
                    0,
                    WaitStrategy::Block,
                )?;
                let _ = ready.send(Ok(()));
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(m) = inbox.next(IDLE, stop)? {
                        put(as_bytes(&m));
                    }
                }
            }
            _ => {
                // Progress has no event: a report is due a few times a second at most.
                let role = writer(topic);
                let service = channel::pubsub::<Progress, _>(&node, names.progress_of(role), 1)?;
                let subscriber = service
                    .subscriber_builder()
                    .create()
                    .map_err(channel::ipc_err("create a progress subscriber"))?;
                let _ = ready.send(Ok(()));
                while !stop.load(Ordering::Relaxed) {
                    let mut latest = None;
                    while let Some(s) = subscriber
                        .receive()
                        .map_err(channel::ipc_err("receive a progress report"))?
                    {
                        latest = Some(*s);
                    }
                    if let Some(p) = latest {
                        put(as_bytes(&p));
                    }
                    std::thread::sleep(IDLE);
                }
            }
        }
        Ok(())
    })();
    if let Err(e) = result {
        eprintln!(
            "launch: link: warning: forwarding {} stopped: {e:#}",
            TOPICS[topic]
        );
        let _ = ready.send(Err(e));
    }
}

/// The ports of iceoryx2's thread-safe flavour: written from Zenoh's callbacks.
type ThreadSafe = iceoryx2::service::ipc_threadsafe::Service;

/// The local ports what arrives from peers is republished on, each only where its service
/// crosses.
struct LocalPorts {
    observation: Option<Outbox<Observation, ThreadSafe>>,
    world_map: Option<Outbox<WorldMap, ThreadSafe>>,
    command: Option<LatestOutbox<Command, ThreadSafe>>,
    motor_state: Option<Outbox<MotorState, ThreadSafe>>,
    progress: [Option<iceoryx2::port::publisher::Publisher<ThreadSafe, Progress, ()>>; 3],
    /// The world map published on this host, when its writer is local.
    local_map: Option<Inbox<WorldMap, ThreadSafe>>,
}

/// What arrives from peers: the checker that judges it and the ports that republish what
/// passes. Zenoh's callbacks take it under a lock, one sample at a time.
struct Inbound {
    ports: LocalPorts,
    checker: Checker,
    restamp: bool,
    /// When the ports last looked for processes that started since.
    connected: Instant,
    // Declared last: dropped after the ports.
    _node: iceoryx2::prelude::Node<ThreadSafe>,
}

impl Inbound {
    fn open(names: &ServiceNames, local: &[Role], restamp: bool) -> Result<Self> {
        let node = channel::shared_node(false)?;
        let crosses = |topic: usize| !local.contains(&writer(topic)) && read_by(topic, local);
        let mut progress = [None, None, None];
        for (i, slot) in progress.iter_mut().enumerate() {
            let role = Role::ALL[i];
            if crosses(4 + i) {
                let service = channel::pubsub::<Progress, _>(&node, names.progress_of(role), 1)?;
                *slot = Some(
                    service
                        .publisher_builder()
                        .create()
                        .map_err(channel::ipc_err("create a progress publisher"))?,
                );
            }
        }
        let ports = LocalPorts {
            observation: crosses(0)
                .then(|| Outbox::open(&node, &names.observation, &names.observation_event, 0))
                .transpose()?,
            world_map: crosses(1)
                .then(|| Outbox::open(&node, &names.world_map, &names.world_map_event, 1))
                .transpose()?,
            command: crosses(2)
                .then(|| LatestOutbox::open(&node, &names.command, &names.command_event))
                .transpose()?,
            motor_state: crosses(3)
                .then(|| Outbox::open(&node, &names.motor_state, &names.motor_state_event, 0))
                .transpose()?,
            progress,
            local_map: (!crosses(1))
                .then(|| {
                    Inbox::open(
                        &node,
                        &names.world_map,
                        &names.world_map_event,
                        1,
                        WaitStrategy::Block,
                    )
                })
                .transpose()?,
        };
        Ok(Self {
            ports,
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
    fn take_counted(&mut self, topic: usize, bytes: &[u8], shared: &Shared) {
        self.follow_local_map();
        match take(topic, bytes, &mut self.checker, &self.ports, self.restamp) {
            Ok(true) => {
                shared.received[topic].fetch_add(1, Ordering::Relaxed);
            }
            Ok(false) => {}
            Err(why) => {
                let count = shared.refused[topic].fetch_add(1, Ordering::Relaxed) + 1;
                if count == 1 || count.is_multiple_of(100) {
                    shared.push(LinkEvent::Refused {
                        topic: TOPICS[topic],
                        why,
                        count,
                    });
                }
            }
        }
    }

    /// Connects the processes that started since the last look (a few times a second).
    fn reconnect(&mut self) {
        if self.connected.elapsed() < Duration::from_millis(200) {
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

/// Keeps the inbound ports current between samples until `stop`: the local world map
/// followed, processes that started since connected.
fn tend(inbound: &Mutex<Inbound>, stop: &AtomicBool) {
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(IDLE);
        let Ok(mut inbound) = inbound.lock() else {
            return;
        };
        inbound.follow_local_map();
        inbound.reconnect();
    }
}

/// Checks one payload of `topic` from a peer and republishes it locally; `Ok(false)` for a
/// payload that is a repeat of the world map already taken.
fn take(
    topic: usize,
    bytes: &[u8],
    checker: &mut Checker,
    ports: &LocalPorts,
    restamp: bool,
) -> std::result::Result<bool, Refusal> {
    let now = tes_runtime::clock::monotonic_ns();
    let sent = |r: Result<(), channel::IpcError>| {
        if let Err(e) = r {
            eprintln!("launch: link: warning: cannot republish: {e}");
        }
    };
    match topic {
        0 => {
            let mut o: Observation = from_bytes(bytes)?;
            checker.observation(&o)?;
            if restamp {
                o.stamp_ns = now;
            }
            if let Some(out) = &ports.observation {
                sent(out.send(o));
            }
        }
        1 => {
            let m: Box<WorldMap> = boxed_from_bytes(bytes)?;
            if checker
                .map()
                .is_some_and(|kept| as_bytes(kept) == as_bytes(&*m))
            {
                return Ok(false);
            }
            checker.world_map(&m)?;
            if let Some(out) = &ports.world_map {
                sent(out.send(*m));
            }
        }
        2 => {
            let mut c: Command = from_bytes(bytes)?;
            checker.command(&c)?;
            if restamp {
                let waited = c.stamp_ns.saturating_sub(c.observed_ns);
                c.stamp_ns = now;
                c.observed_ns = if c.observed_ns == 0 {
                    0
                } else {
                    now.saturating_sub(waited)
                };
            }
            if let Some(out) = &ports.command {
                sent(out.send(c));
            }
        }
        3 => {
            let m: MotorState = from_bytes(bytes)?;
            checker.motor_state(&m)?;
            if let Some(out) = &ports.motor_state {
                sent(out.send(m));
            }
        }
        _ => {
            let i = topic - 4;
            let role = Role::ALL[i];
            let mut p: Progress = from_bytes(bytes)?;
            checker.progress(role, &p)?;
            // The watcher compares report stamps with its own clock.
            let age = p.stamp_ns.saturating_sub(p.started_ns);
            p.stamp_ns = now;
            p.started_ns = now.saturating_sub(age);
            if let Some(out) = &ports.progress[i] {
                sent(
                    out.send_copy(p)
                        .map(|_| ())
                        .map_err(channel::ipc_err("publish a progress report")),
                );
            }
        }
    }
    Ok(true)
}

/// A world map from bytes, on the heap (it is ~90 kB).
fn boxed_from_bytes(bytes: &[u8]) -> std::result::Result<Box<WorldMap>, Refusal> {
    let mut map = Box::new(WorldMap::EMPTY);
    *map = from_bytes::<WorldMap>(bytes)?;
    Ok(map)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use tes_topics::{KEEP_ALIVE_ACTION, StateAttributes};

    fn free_port() -> u16 {
        std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("a free port")
    }

    fn map() -> WorldMap {
        let mut m = WorldMap::EMPTY;
        (m.width, m.height, m.orientations) = (3, 2, 8);
        m.n_states = 3 * 2 * 8 + 1;
        (m.n_actions, m.n_effects, m.n_features) = (3, 20, 312);
        m.action_wheels[..3].copy_from_slice(&[[246, 246], [90, -90], [-90, 90]]);
        m
    }

    /// A robot host's link (perception and bridge local, the controller remote) and a bare
    /// Zenoh session playing a malicious controller's host, over loopback.
    struct Rig {
        link: Link,
        peer: zenoh::Session,
        names: ServiceNames,
        group: String,
        node: iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
        _maps: Outbox<WorldMap>,
        commands: LatestInbox<Command>,
        observations: Inbox<Observation>,
    }

    fn rig(test: &str) -> Rig {
        let port = free_port();
        let group = format!("tes-test/{}/{test}", std::process::id());
        let settings = LinkSection {
            group: group.clone(),
            listen: vec![format!("tcp/127.0.0.1:{port}")],
            multicast_scouting: Some(false),
            restamp: false,
            ..LinkSection::default()
        };
        let names =
            ServiceNames::with_prefix(&format!("tes-test/link-{test}/{}/", std::process::id()));
        let node = channel::node(false).expect("node");
        // The world map, as perception on this host publishes it.
        // (The link opens before the processes start, as in a launch.)
        let link = Link::open(&settings, &[Role::Perception, Role::Bridge], &names).expect("link");
        let maps = Outbox::open(&node, &names.world_map, &names.world_map_event, 1).expect("map");
        maps.send(map()).expect("map sent");
        let commands = LatestInbox::open(
            &node,
            &names.command,
            &names.command_event,
            WaitStrategy::Block,
        )
        .expect("command board");
        let observations = Inbox::open(
            &node,
            &names.observation,
            &names.observation_event,
            0,
            WaitStrategy::Block,
        )
        .expect("observations");
        let peer = LinkSection {
            group: group.clone(),
            listen: Vec::new(),
            connect: vec![format!("tcp/127.0.0.1:{port}")],
            multicast_scouting: Some(false),
            ..LinkSection::default()
        };
        let peer = zenoh::open(peer.zenoh_config().expect("config"))
            .wait()
            .expect("peer session");
        // The peer plays the controller, so the link takes what it sends.
        let start = Instant::now();
        let token = peer
            .liveliness()
            .declare_token(format!("{group}/member/controller/{}", peer.zid()))
            .wait()
            .expect("token");
        std::mem::forget(token);
        while link.missing().contains(&Role::Controller) {
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "the peer never joined"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        Rig {
            link,
            peer,
            names,
            group,
            node,
            _maps: maps,
            commands,
            observations,
        }
    }

    impl Rig {
        /// Sends `bytes` as a command from the peer until the link has taken or refused one
        /// more (a first sample may race the subscription being known).
        fn send_command(&self, bytes: &[u8]) {
            let before = self.taken_or_refused();
            let start = Instant::now();
            while self.taken_or_refused() == before {
                self.peer
                    .put(format!("{}/command", self.group), bytes)
                    .wait()
                    .expect("put");
                assert!(
                    start.elapsed() < Duration::from_secs(20),
                    "the link saw nothing"
                );
                std::thread::sleep(Duration::from_millis(20));
            }
        }

        fn taken_or_refused(&self) -> u64 {
            let c = self.link.counts();
            c.by_topic
                .iter()
                .find(|(t, _, _)| *t == "command")
                .map_or(0, |(_, r, x)| r + x)
        }

        fn refused(&self) -> u64 {
            let c = self.link.counts();
            c.by_topic.iter().map(|(_, _, x)| x).sum()
        }
    }

    /// A valid command crosses and reaches the local board; each kind of bad one is refused,
    /// counted and reported, and the board never shows it. An observation sent to a host that
    /// plays perception itself is not taken at all.
    #[test]
    fn malformed_commands_never_reach_the_board_and_valid_ones_do() {
        let rig = rig("bad");
        let good = Command {
            seq: 10,
            action: 1,
            left_deg: 90,
            right_deg: -90,
            ..Command::default()
        };
        rig.send_command(as_bytes(&good));
        let start = Instant::now();
        let got = loop {
            if let Some(c) = rig.commands.try_next().expect("board") {
                break c;
            }
            assert!(
                start.elapsed() < Duration::from_secs(10),
                "nothing on the board: {} ({:?})",
                rig.link.counts(),
                rig.link.events()
            );
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_eq!(got, good);
        let bad = [
            Command {
                seq: 11,
                action: 3,
                ..good
            },
            Command {
                seq: 12,
                left_deg: 9000,
                ..good
            },
            Command { seq: 10, ..good },
            Command {
                seq: 13,
                action: KEEP_ALIVE_ACTION,
                in_flight_action: 7,
                answers: 10,
                ..good
            },
        ];
        for (i, c) in bad.iter().enumerate() {
            rig.send_command(as_bytes(c));
            assert!(rig.refused() > i as u64, "{c:?} was not refused");
        }
        rig.send_command(&as_bytes(&good)[..20]);
        assert!(rig.refused() >= 5);
        assert_eq!(rig.commands.try_next().expect("board"), None);
        let events = rig.link.events();
        assert!(
            events.iter().any(|e| matches!(
                e,
                LinkEvent::Refused {
                    topic: "command",
                    ..
                }
            )),
            "{events:?}"
        );
        // Not the peer's to send: this host's perception writes observations.
        let o = Observation {
            seq: 1,
            n_features: 312,
            state: StateAttributes::at(0, 0, 0),
            ..Observation::default()
        };
        rig.peer
            .put(format!("{}/observation", rig.group), as_bytes(&o))
            .wait()
            .expect("put");
        std::thread::sleep(Duration::from_millis(200));
        assert_eq!(rig.observations.try_next().expect("inbox"), None);
        let _ = (&rig.names, &rig.node);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

        /// Arbitrary bytes, and commands with arbitrary fields, sent across a loopback link:
        /// nothing panics, whatever reaches the bridge's board is a command of the map with
        /// that action's own wheel targets, and the link still carries a valid command after.
        #[test]
        fn whatever_a_peer_sends_only_valid_commands_reach_the_board(
            samples in proptest::collection::vec(
                prop_oneof![
                    proptest::collection::vec(any::<u8>(), 0..100),
                    (0u64..1 << 40, 0u32..6, -400i32..400, -400i32..400).prop_map(|(seq, action, l, r)| {
                        as_bytes(&Command { seq, action, left_deg: l, right_deg: r, ..Command::default() }).to_vec()
                    }),
                    // Valid but for chance: an action's own wheels, sometimes.
                    (0u64..1 << 40, 0u32..4).prop_map(|(seq, action)| {
                        let [l, r] = map().action_wheels[action as usize];
                        as_bytes(&Command { seq, action, left_deg: l, right_deg: r, ..Command::default() }).to_vec()
                    }),
                ],
                1..8,
            )
        ) {
            let rig = rig("prop");
            let m = map();
            for bytes in &samples {
                rig.send_command(bytes);
                if let Some(c) = rig.commands.try_next().expect("board") {
                    prop_assert!(c.action < m.n_actions);
                    prop_assert_eq!(m.action_wheels[c.action as usize], [c.left_deg, c.right_deg]);
                }
            }
            let last = Command { seq: 1 << 41, action: 0, left_deg: 246, right_deg: 246, ..Command::default() };
            rig.send_command(as_bytes(&last));
            prop_assert_eq!(rig.commands.try_next().expect("board"), Some(last));
        }
    }
}
