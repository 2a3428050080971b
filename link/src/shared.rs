//! What the link's threads share: the events the launcher acts on, the peers seen, the
//! counts of payloads taken and refused, and how often the threads look again.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tes_topics::Role;
use tes_topics::wire::Refusal;

use crate::Topic;

/// How long an idle forwarding thread sleeps between looks at the stop flag.
pub(crate) const IDLE: Duration = Duration::from_millis(50);

/// How often a host that writes the world map sends it again (a peer that joins later, or
/// whose subscription was not yet known, gets it then).
pub(crate) const MAP_AGAIN: Duration = Duration::from_secs(1);

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
    /// Zenoh refused a connection or a peer's message ([`refusals`](crate::refusals)):
    /// seen only where the launcher installed [`refusals::layer`](crate::refusals::layer).
    Denied(crate::refusals::Denial),
    /// A payload from a peer was refused (the first of its kind, then every 100th).
    Refused {
        /// The service.
        topic: Topic,
        /// Why.
        why: Refusal,
        /// Payloads of this service refused so far.
        count: u64,
    },
}

/// What the link's threads share.
#[derive(Default)]
pub(crate) struct Shared {
    pub(crate) events: Mutex<VecDeque<LinkEvent>>,
    /// Remote sessions seen per role.
    pub(crate) peers: Mutex<BTreeMap<Role, BTreeSet<String>>>,
    /// Payloads refused, per [`Topic::index`].
    pub(crate) refused: [AtomicU64; Topic::ALL.len()],
    /// Payloads forwarded to this host, per [`Topic::index`].
    pub(crate) received: [AtomicU64; Topic::ALL.len()],
    /// Payloads dropped unchecked because the session that announced their writer's role
    /// did not send them, per [`Topic::index`].
    pub(crate) foreign: [AtomicU64; Topic::ALL.len()],
}

impl Shared {
    pub(crate) fn push(&self, event: LinkEvent) {
        if let Ok(mut e) = self.events.lock() {
            e.push_back(event);
        }
    }

    /// Whether a payload of `topic` that says it was sent by the session `sender` comes from
    /// the session that announced the role writing `topic`. One that does not — a stranger
    /// on the link, whatever its sequence numbers — is dropped before any check, so it
    /// cannot move the checker's state (the last sequence number taken) and shut the genuine
    /// writer out; it is counted and told (the first, then every 100th).
    pub(crate) fn sent_by_writer(&self, topic: Topic, sender: Option<&[u8]>) -> bool {
        let writer = topic.writer();
        let known = sender.is_some_and(|sender| {
            self.peers.lock().is_ok_and(|peers| {
                peers
                    .get(&writer)
                    .is_some_and(|sessions| sessions.iter().any(|s| s.as_bytes() == sender))
            })
        });
        if !known {
            let count = self.foreign[topic.index()].fetch_add(1, Ordering::Relaxed) + 1;
            if count == 1 || count.is_multiple_of(100) {
                self.push(LinkEvent::Denied(crate::refusals::Denial::NotTheWriter {
                    key: topic.key().to_owned(),
                    writer: writer.name().to_owned(),
                    count,
                }));
            }
        }
        known
    }

    /// A member token of `role` by the session `who` appeared (`put`) or went away.
    pub(crate) fn member(&self, role: Role, who: &str, put: bool, local: &[Role]) {
        let Ok(mut peers) = self.peers.lock() else {
            return;
        };
        let sessions = peers.entry(role).or_default();
        let event = if put {
            if !sessions.insert(who.to_owned()) {
                return;
            }
            let twice = local.contains(&role) || sessions.len() > 1;
            if twice {
                LinkEvent::Twice(role)
            } else {
                LinkEvent::Joined(role)
            }
        } else {
            if !(sessions.remove(who) && sessions.is_empty()) {
                return;
            }
            LinkEvent::Left(role)
        };
        drop(peers);
        self.push(event);
    }
}
