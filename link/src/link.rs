//! The link of one launch: its Zenoh session, its members' tokens, the stop protocol and the
//! threads that forward the services.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::thread::JoinHandle;
use std::time::Duration;

use tes_runtime::channel::IpcError;
use tes_topics::{Role, ServiceNames};
use zenoh::Wait;

use crate::inbound::{Inbound, tend};
use crate::outbound::{Ready, outbound};
use crate::shared::{LinkEvent, Shared};
use crate::{LinkError, LinkSection, Topic};

/// How long [`Link::open`] waits for each forwarding thread to open its ports.
const READY_TIMEOUT: Duration = Duration::from_secs(30);

/// How a stop message says the group stopped as planned, and otherwise.
const CLEAN: &str = "clean";
const FAILED: &str = "failed";

/// The longest reason of a peer's stop kept, in characters.
const REASON_MAX: usize = 500;

/// How the link counts what passed and what it refused, at the end.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkCounts {
    /// Per service: (received and passed on, refused), in the order of [`Topic::ALL`].
    pub by_topic: Vec<(Topic, u64, u64)>,
    /// Per service, in the same order: payloads dropped because the session playing their
    /// writer's role did not send them (a stranger's).
    pub foreign: Vec<u64>,
}

/// `observation 10 taken, 0 refused; command 3 taken, 1 refused, 6 from strangers`, the
/// services with nothing left out; `nothing received` when none has anything.
impl std::fmt::Display for LinkCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts: Vec<String> = self
            .by_topic
            .iter()
            .zip(self.foreign.iter().chain(std::iter::repeat(&0)))
            .filter(|((_, r, x), s)| r + x + **s > 0)
            .map(|((t, r, x), s)| match s {
                0 => format!("{t} {r} taken, {x} refused"),
                s => format!("{t} {r} taken, {x} refused, {s} from strangers"),
            })
            .collect();
        if parts.is_empty() {
            f.write_str("nothing received")
        } else {
            f.write_str(&parts.join("; "))
        }
    }
}

/// The link of one launch: its Zenoh session, its tokens and its forwarding threads.
///
/// Dropping it [closes](Link::close) it.
pub struct Link {
    session: zenoh::Session,
    endpoints: Endpoints,
    group: String,
    zid: String,
    local: Vec<Role>,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    tokens: Vec<zenoh::liveliness::LivelinessToken>,
    subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    stop_publisher: zenoh::pubsub::Publisher<'static>,
}

impl Link {
    /// Opens the Zenoh session of `settings`, says which roles this launch plays (refusing a
    /// role another launch of the group already plays) and starts forwarding the services
    /// of the group `names` between this host and the others.
    ///
    /// Every forwarding thread has its ports before this launch's roles are announced to
    /// the peers. On an error, whatever was started is stopped again.
    pub fn open(
        settings: &LinkSection,
        local: &[Role],
        names: &ServiceNames,
    ) -> Result<Self, LinkError> {
        let (session, endpoints) = open_session(settings)?;
        let group = settings.group.clone();
        let zid = session.zid().to_string();
        let shared = Arc::new(Shared::default());
        let subscribers = vec![
            watch_members(&session, &group, &zid, local, &shared)?,
            watch_stops(&session, &group, &zid, &shared)?,
        ];
        let stop_publisher = session
            .declare_publisher(format!("{group}/stop"))
            .wait()
            .map_err(LinkError::StopPublisher)?;
        // From here on, dropping the link on an error closes what was started.
        let mut link = Self {
            session,
            endpoints,
            group,
            zid,
            local: local.to_vec(),
            shared,
            stop: Arc::new(AtomicBool::new(false)),
            threads: Vec::new(),
            tokens: Vec::new(),
            subscribers,
            stop_publisher,
        };
        let inbound =
            Inbound::open(names, local, settings.restamp).map_err(LinkError::LocalServices)?;
        let inbound = Arc::new(Mutex::new(inbound));
        link.subscribe_inbound(&inbound)?;
        link.spawn("link-in".into(), move |stop| tend(&inbound, &stop))?;
        let (ready, forwarding) = link.start_outbound(names)?;
        wait_until_ready(&ready, forwarding)?;
        link.announce_roles()?;
        Ok(link)
    }

    /// Subscribes to each service a peer writes and this host reads. What comes is checked
    /// and republished on Zenoh's own receiving thread, straight from its callback: no
    /// hand-over to another thread and its wake-up.
    fn subscribe_inbound(&mut self, inbound: &Arc<Mutex<Inbound>>) -> Result<(), LinkError> {
        for topic in Topic::ALL {
            if !topic.comes_in(&self.local) {
                continue;
            }
            let inbound = inbound.clone();
            let shared = self.shared.clone();
            let key = format!("{}/{topic}", self.group);
            let subscriber = self
                .session
                .declare_subscriber(key.clone())
                .callback(move |sample| {
                    let sender = sample.attachment().map(|a| a.to_bytes());
                    if !shared.sent_by_writer(topic, sender.as_deref()) {
                        return;
                    }
                    let bytes = sample.payload().to_bytes();
                    if let Ok(mut inbound) = inbound.lock() {
                        inbound.take_counted(topic, &bytes, &shared);
                    }
                })
                .wait()
                .map_err(|error| LinkError::Subscribe { key, error })?;
            self.subscribers.push(subscriber);
        }
        Ok(())
    }

    /// Starts a thread per service this host writes and a peer reads; returns where they
    /// say they have their ports, and how many they are.
    fn start_outbound(
        &mut self,
        names: &ServiceNames,
    ) -> Result<(mpsc::Receiver<Result<(), IpcError>>, usize), LinkError> {
        let (ready_tx, ready_rx) = mpsc::channel();
        let mut forwarding = 0;
        for topic in Topic::ALL {
            if !topic.goes_out(&self.local) {
                continue;
            }
            let key = format!("{}/{topic}", self.group);
            let publisher = self
                .session
                .declare_publisher(key.clone())
                .congestion_control(zenoh::qos::CongestionControl::Block)
                .express(true)
                .wait()
                .map_err(|error| LinkError::Publish { key, error })?;
            let names = names.clone();
            let ready: Ready = ready_tx.clone();
            let zid = self.zid.clone();
            self.spawn(format!("link-out-{}", topic.index()), move |stop| {
                outbound(topic, &names, &publisher, &zid, &stop, &ready)
            })?;
            forwarding += 1;
        }
        Ok((ready_rx, forwarding))
    }

    /// Starts a thread of the link named `name`, running `body` with the stop flag.
    fn spawn(
        &mut self,
        name: String,
        body: impl FnOnce(Arc<AtomicBool>) + Send + 'static,
    ) -> Result<(), LinkError> {
        let stop = self.stop.clone();
        let thread = std::thread::Builder::new()
            .name(name)
            .spawn(move || body(stop))
            .map_err(LinkError::Thread)?;
        self.threads.push(thread);
        Ok(())
    }

    /// Declares a liveliness token `GROUP/member/ROLE/ZID` per local role.
    fn announce_roles(&mut self) -> Result<(), LinkError> {
        for role in &self.local {
            let token = self
                .session
                .liveliness()
                .declare_token(format!(
                    "{}/member/{}/{}",
                    self.group,
                    role.name(),
                    self.zid
                ))
                .wait()
                .map_err(LinkError::Announce)?;
            self.tokens.push(token);
        }
        Ok(())
    }

    /// Where this launch's link listens and connects (the private socket's, when the table
    /// names none; a loopback endpoint another launch of the group listens on is connected
    /// to).
    pub fn endpoints(&self) -> &Endpoints {
        &self.endpoints
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
        let mut events: Vec<LinkEvent> = self
            .shared
            .events
            .lock()
            .map(|mut e| e.drain(..).collect())
            .unwrap_or_default();
        events.extend(crate::refusals::take().into_iter().map(LinkEvent::Denied));
        events
    }

    /// Tells the peers the group stops, and why (`GROUP/stop`: `ZID clean|failed REASON`).
    pub fn send_stop(&self, clean: bool, reason: &str) {
        let how = if clean { CLEAN } else { FAILED };
        let _ = self
            .stop_publisher
            .put(format!("{} {how} {reason}", self.zid))
            .wait();
    }

    /// What passed and what was refused so far.
    pub fn counts(&self) -> LinkCounts {
        LinkCounts {
            by_topic: Topic::ALL
                .into_iter()
                .map(|t| {
                    let i = t.index();
                    (
                        t,
                        self.shared.received[i].load(Ordering::Relaxed),
                        self.shared.refused[i].load(Ordering::Relaxed),
                    )
                })
                .collect(),
            foreign: self
                .shared
                .foreign
                .iter()
                .map(|c| c.load(Ordering::Relaxed))
                .collect(),
        }
    }

    /// Stops forwarding, withdraws this launch from the group and closes the session. The
    /// forwarding stops first: nothing this launch sends arrives after its role is
    /// withdrawn (a peer would drop it as a stranger's).
    pub fn close(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        self.tokens.clear();
        let _ = self.session.close().wait();
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.close();
    }
}

/// The endpoints a link listens on and connects to.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Endpoints {
    /// Where it listens.
    pub listen: Vec<String>,
    /// Where it connects.
    pub connect: Vec<String>,
}

/// Opens the Zenoh session `settings` describe: on the private socket when the table names
/// no endpoints. When it cannot listen because another launch of this host listens there
/// (the private socket, or a loopback port), it connects to that launch instead.
fn open_session(settings: &LinkSection) -> Result<(zenoh::Session, Endpoints), LinkError> {
    let first = if settings.is_private() {
        let socket = settings
            .prepare_private_socket()
            .map_err(LinkError::PrivateSocket)?;
        Endpoints {
            listen: vec![socket],
            connect: Vec::new(),
        }
    } else {
        Endpoints {
            listen: settings.listen.clone(),
            connect: settings.connect.clone(),
        }
    };
    let text = match try_open(settings, &first)? {
        Ok(session) => return Ok((session, first)),
        Err(text) => text,
    };
    if listening_taken(&text) && first.listen.iter().all(|e| on_this_host(e)) {
        let instead = Endpoints {
            listen: Vec::new(),
            connect: first.listen.iter().chain(&first.connect).cloned().collect(),
        };
        if let Ok(session) = try_open(settings, &instead)? {
            return Ok((session, instead));
        }
    }
    Err(LinkError::Open {
        reason: zenoh_words(&text, &first),
        listen: first.listen,
        connect: first.connect,
    })
}

/// A Zenoh session on `endpoints`; the outer error for a configuration Zenoh refused, the
/// inner one Zenoh's reason it could not open.
fn try_open(
    settings: &LinkSection,
    endpoints: &Endpoints,
) -> Result<Result<zenoh::Session, String>, LinkError> {
    let config = settings.zenoh_config_for(&endpoints.listen, &endpoints.connect)?;
    Ok(zenoh::open(config).wait().map_err(|e| e.to_string()))
}

/// Whether Zenoh could not listen because something holds the address (a TCP port in use,
/// the lock of a Unix socket another launch listens on).
fn listening_taken(error: &str) -> bool {
    error.contains("Address already in use") || error.contains("Unable to acquire lock")
}

/// Whether only this host can be listening on `endpoint` (a Unix socket, loopback).
fn on_this_host(endpoint: &str) -> bool {
    endpoint.starts_with(crate::settings::UNIX_SCHEME) || crate::settings::is_loopback(endpoint)
}

/// Zenoh's error `text` for a link that tried `endpoints`, in the link's words: without the
/// places in Zenoh's sources it names, and with the fix where the cause is known.
fn zenoh_words(text: &str, endpoints: &Endpoints) -> String {
    let said = crate::refusals::without_source_places(text);
    if listening_taken(text) {
        return format!(
            "another program listens on {:?}, and no launch of the group answered there: stop \
             it, or choose another port (two launches of one group on one host need no \
             endpoints: leave link.listen and link.connect empty) ({said})",
            endpoints.listen
        );
    }
    said
}

/// Watches the liveliness tokens `GROUP/member/ROLE/ZID` of the other sessions: who plays
/// what, who plays a role twice, who left.
fn watch_members(
    session: &zenoh::Session,
    group: &str,
    own: &str,
    local: &[Role],
    shared: &Arc<Shared>,
) -> Result<zenoh::pubsub::Subscriber<()>, LinkError> {
    let shared = shared.clone();
    let own = own.to_owned();
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
            let (Ok(role), true) = (role.parse::<Role>(), who != own) else {
                return;
            };
            let put = sample.kind() == zenoh::sample::SampleKind::Put;
            shared.member(role, who, put, &local);
        })
        .wait()
        .map_err(LinkError::WatchMembers)
}

/// Watches `GROUP/stop` for a peer's stop, `ZID clean|failed REASON` (this session's own
/// ignored).
fn watch_stops(
    session: &zenoh::Session,
    group: &str,
    own: &str,
    shared: &Arc<Shared>,
) -> Result<zenoh::pubsub::Subscriber<()>, LinkError> {
    let shared = shared.clone();
    let own = own.to_owned();
    session
        .declare_subscriber(format!("{group}/stop"))
        .callback(move |sample| {
            let text = String::from_utf8_lossy(&sample.payload().to_bytes()).into_owned();
            if let Some(event) = parse_stop(&text, &own) {
                shared.push(event);
            }
        })
        .wait()
        .map_err(LinkError::WatchStops)
}

/// The event of a stop message `ZID clean|failed REASON` from a session other than `own`
/// (anything but `clean` is a failure; the reason cut to [`REASON_MAX`] characters).
fn parse_stop(text: &str, own: &str) -> Option<LinkEvent> {
    let mut parts = text.splitn(3, ' ');
    let (who, how) = (parts.next()?, parts.next()?);
    if who == own {
        return None;
    }
    let reason: String = parts
        .next()
        .unwrap_or("")
        .chars()
        .take(REASON_MAX)
        .collect();
    Some(LinkEvent::Stop {
        clean: how == CLEAN,
        reason,
    })
}

/// Waits until each of the `forwarding` threads has opened its ports.
fn wait_until_ready(
    ready: &mpsc::Receiver<Result<(), IpcError>>,
    forwarding: usize,
) -> Result<(), LinkError> {
    for _ in 0..forwarding {
        match ready.recv_timeout(READY_TIMEOUT) {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(LinkError::LocalServices(e)),
            Err(_) => return Err(LinkError::NotReady),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::time::Instant;
    use tes_runtime::channel::{self, Inbox, LatestInbox, Outbox, WaitStrategy};
    use tes_topics::wire::as_bytes;
    use tes_topics::{Command, KEEP_ALIVE_ACTION, Observation, StateAttributes, WorldMap};

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

    #[test]
    fn stop_messages_parse_and_own_ones_are_ignored() {
        assert_eq!(
            parse_stop("peer clean episodes done", "me"),
            Some(LinkEvent::Stop {
                clean: true,
                reason: "episodes done".into()
            })
        );
        assert_eq!(
            parse_stop("peer failed ", "me"),
            Some(LinkEvent::Stop {
                clean: false,
                reason: String::new()
            })
        );
        assert_eq!(parse_stop("me clean done", "me"), None);
        assert_eq!(parse_stop("peer", "me"), None);
        let long = format!("peer failed {}", "x".repeat(2 * REASON_MAX));
        let Some(LinkEvent::Stop { reason, .. }) = parse_stop(&long, "me") else {
            panic!("no stop");
        };
        assert_eq!(reason.len(), REASON_MAX);
    }

    #[test]
    fn members_join_leave_and_play_twice() {
        let shared = Shared::default();
        let local = [Role::Perception, Role::Bridge];
        shared.member(Role::Controller, "a", true, &local);
        shared.member(Role::Controller, "a", true, &local);
        shared.member(Role::Controller, "b", true, &local);
        shared.member(Role::Bridge, "c", true, &local);
        shared.member(Role::Controller, "a", false, &local);
        shared.member(Role::Controller, "b", false, &local);
        let events: Vec<LinkEvent> = shared.events.lock().expect("events").drain(..).collect();
        assert_eq!(
            events,
            [
                LinkEvent::Joined(Role::Controller),
                LinkEvent::Twice(Role::Controller),
                LinkEvent::Twice(Role::Bridge),
                LinkEvent::Left(Role::Controller),
            ]
        );
    }

    #[test]
    fn counts_print_the_services_with_something() {
        let mut counts = LinkCounts {
            by_topic: Topic::ALL.into_iter().map(|t| (t, 0, 0)).collect(),
            foreign: vec![0; Topic::ALL.len()],
        };
        assert_eq!(counts.to_string(), "nothing received");
        counts.by_topic[2] = (Topic::Command, 3, 1);
        counts.by_topic[5] = (Topic::Progress(Role::Controller), 7, 0);
        assert_eq!(
            counts.to_string(),
            "command 3 taken, 1 refused; progress/controller 7 taken, 0 refused"
        );
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
            // Plain TCP: the peers below are bare Zenoh sessions, as a stranger's would be.
            insecure: true,
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
        let peer = bare_session(port);
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

    /// A bare Zenoh session connected to the link listening on loopback `port`.
    fn bare_session(port: u16) -> zenoh::Session {
        let settings = LinkSection {
            listen: Vec::new(),
            connect: vec![format!("tcp/127.0.0.1:{port}")],
            multicast_scouting: Some(false),
            insecure: true,
            ..LinkSection::default()
        };
        zenoh::open(settings.zenoh_config().expect("config"))
            .wait()
            .expect("peer session")
    }

    impl Rig {
        /// Sends `bytes` as a command from the peer, as the link's own forwarding does (its
        /// session's id attached), until the link has taken or refused one more (a first
        /// sample may race the subscription being known).
        fn send_command(&self, bytes: &[u8]) {
            let before = self.taken_or_refused();
            let start = Instant::now();
            while self.taken_or_refused() == before {
                self.peer
                    .put(format!("{}/command", self.group), bytes)
                    .attachment(self.peer.zid().to_string())
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
                .find(|(t, _, _)| *t == Topic::Command)
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
                    topic: Topic::Command,
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

    /// A stranger on an unauthenticated link — a session that announced no role — sends
    /// well-formed commands with a sequence number far ahead (2^62), bare or claiming
    /// another session's id: each is dropped before the checks, counted and told, and the
    /// genuine controller's commands after them still reach the board.
    #[test]
    fn a_stranger_far_ahead_in_sequence_cannot_shut_the_controller_out() {
        let rig = rig("stranger");
        let port = rig
            .link
            .endpoints()
            .listen
            .first()
            .and_then(|e| e.rsplit(':').next())
            .and_then(|p| p.parse().ok())
            .expect("a port");
        let stranger = bare_session(port);
        let ahead = Command {
            seq: 1 << 62,
            action: 1,
            left_deg: 90,
            right_deg: -90,
            ..Command::default()
        };
        let key = format!("{}/command", rig.group);
        let start = Instant::now();
        let foreign = |rig: &Rig| rig.link.counts().foreign[Topic::Command.index()];
        while foreign(&rig) < 6 {
            stranger.put(&key, as_bytes(&ahead)).wait().expect("put");
            stranger
                .put(&key, as_bytes(&ahead))
                .attachment("not-the-controller")
                .wait()
                .expect("put");
            assert!(start.elapsed() < Duration::from_secs(20), "nothing dropped");
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(rig.commands.try_next().expect("board"), None);
        for seq in 1..=3 {
            let genuine = Command {
                seq,
                action: 2,
                left_deg: -90,
                right_deg: 90,
                ..Command::default()
            };
            rig.send_command(as_bytes(&genuine));
            assert_eq!(rig.commands.try_next().expect("board"), Some(genuine));
        }
        assert_eq!(rig.refused(), 0, "{}", rig.link.counts());
        assert!(rig.link.counts().to_string().contains("from strangers"));
        let told = rig.link.events().into_iter().any(|e| {
            matches!(e, LinkEvent::Denied(crate::refusals::Denial::NotTheWriter { ref key, .. })
                if key == "command")
        });
        assert!(told, "the stranger's commands were not told");
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
