//! What Zenoh refuses, said by the link: a connection that failed the group's TLS, a sample
//! or a member token a peer's certificate does not allow.
//!
//! Zenoh reports neither to the application: a failed handshake only in its log (as a
//! warning of its QUIC listener), an access-control denial only as a trace event of its
//! interceptor. [`layer`] is a `tracing` layer that picks those events out (and nothing else:
//! it enables no other target) and queues them; the open [`Link`](crate::Link) hands them on
//! as [`LinkEvent::Denied`](crate::LinkEvent::Denied), which the launcher prints. Install it
//! once per process, before the link opens.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fmt::Write as _;
use std::sync::{Mutex, RwLock};
use std::time::{Duration, Instant};

use tracing::callsite::Identifier;
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::Layer;
use tracing_subscriber::filter::{FilterFn, Filtered};
use tracing_subscriber::layer::Context;

/// Denials kept until the link takes them; beyond this the oldest go (a flood of strangers
/// must not grow the launcher's memory).
pub const KEPT: usize = 256;

/// The target of Zenoh's QUIC listener and connector.
const QUIC_TARGET: &str = "zenoh_link_commons::quic";
/// The target of Zenoh's access control.
const ACL_TARGET: &str = "zenoh::net::routing::interceptor::access_control";

static DENIED: Mutex<VecDeque<Denial>> = Mutex::new(VecDeque::new());

/// One subject's refusals of a message, until another subject's allowance of the same
/// message clears them or [`PENDING_FOR`] makes them final.
static PENDING: Mutex<BTreeMap<Denial, Instant>> = Mutex::new(BTreeMap::new());

/// The message denials told so far, by (peer, what, key): each is told once.
static TOLD: Mutex<BTreeSet<(String, String, String)>> = Mutex::new(BTreeSet::new());

/// Distinct message denials remembered for telling each once; beyond, they are not told.
pub const TOLD_MAX: usize = 1024;

/// The access-control callsites found to say nothing this layer wants (they allow): their
/// events are not even built for it again.
static QUIET: RwLock<Vec<Identifier>> = RwLock::new(Vec::new());

/// Something Zenoh refused.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub enum Denial {
    /// A connection that did not pass the group's TLS (no certificate, another authority's,
    /// an expired one), with Zenoh's reason.
    Connection(String),
    /// A peer's message its certificate does not allow (told once per peer, kind and key).
    Message {
        /// The peer's Zenoh id.
        peer: String,
        /// What it tried: `Put (ingress)`, `Declare/Undeclare Liveliness Token (ingress)`.
        what: String,
        /// On which key.
        key: String,
    },
    /// Payloads of a service dropped because the session that announced the role writing it
    /// did not send them: a stranger on an unauthenticated link (told the first time, then
    /// every 100th).
    NotTheWriter {
        /// The service's key within the group.
        key: String,
        /// The role that writes it.
        writer: String,
        /// How many were dropped so far.
        count: u64,
    },
}

impl std::fmt::Display for Denial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Denial::Connection(why) => write!(f, "refused a connection: {why}"),
            Denial::Message { peer, what, key } => write!(
                f,
                "refused peer {peer}'s {what} on {key}: its certificate does not name the role \
                 that writes it (told once per peer and key)"
            ),
            Denial::NotTheWriter { key, writer, count } => write!(
                f,
                "dropped {count} sample(s) of {key} not sent by the launch that plays the \
                 {writer}: a stranger on the link (told the first time, then every 100th)"
            ),
        }
    }
}

/// The layer to add to the process's `tracing` subscriber (see the [module docs](self)).
pub fn layer<S>() -> Filtered<DenialLayer, FilterFn, S>
where
    S: Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    DenialLayer.with_filter(FilterFn::new(|meta| {
        let target = meta.target();
        if target.starts_with(QUIC_TARGET) {
            return *meta.level() <= Level::WARN;
        }
        target.starts_with(ACL_TARGET)
            && QUIET
                .read()
                .map(|quiet| !quiet.contains(&meta.callsite()))
                .unwrap_or(true)
    }))
}

/// The denials since the last call, oldest first.
pub fn take() -> Vec<Denial> {
    settle_pending();
    DENIED
        .lock()
        .map(|mut d| d.drain(..).collect())
        .unwrap_or_default()
}

/// Picks Zenoh's refusals out of its events (see [`layer`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct DenialLayer;

impl<S: Subscriber> Layer<S> for DenialLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        let mut message = Message(String::new());
        event.record(&mut message);
        let text = message.0;
        if event.metadata().target().starts_with(QUIC_TARGET) {
            if let Some(denial) = quic_refusal(&text) {
                remember(denial);
            }
            return;
        }
        let Some(decision) = acl_decision(&text) else {
            return;
        };
        match (decision.cached, decision.allowed) {
            // The hot path of every allowed message: not even built for this layer again.
            (true, true) => {
                if let Ok(mut quiet) = QUIET.write() {
                    quiet.push(event.metadata().callsite());
                }
            }
            (true, false) => {
                if let Some(denial) = decision.denial()
                    && first_telling(&denial)
                {
                    remember(denial);
                }
            }
            // Zenoh weighs each subject a peer matches in turn and logs each verdict; the
            // message passes if any allows it. A subject's refusal is only pending until
            // the next subject's verdict on the same message. A sample's uncached verdicts
            // read the same as those Zenoh weighs in advance for a declared key (no sample
            // came): only its cached, final verdict is told.
            (false, false) => {
                if !decision.what.starts_with("Put")
                    && let Some(denial) = decision.denial()
                    && let Ok(mut pending) = PENDING.lock()
                    && pending.len() < TOLD_MAX
                {
                    pending.entry(denial).or_insert_with(Instant::now);
                }
            }
            (false, true) => {
                if let Some(denial) = decision.denial()
                    && let Ok(mut pending) = PENDING.lock()
                {
                    pending.remove(&denial);
                }
            }
        }
    }
}

/// A QUIC listener's or connector's failed handshake: its cause in words a person acts on,
/// then Zenoh's reason (without its hint about open files, which fits only its other
/// errors, and the places in its sources).
fn quic_refusal(text: &str) -> Option<Denial> {
    let failed = text.contains("QUIC acceptor failed")
        || text.contains("Cannot accept QUIC connection")
        || text.contains("handshake");
    failed.then(|| {
        let reason = text.split(" Hint:").next().unwrap_or(text).trim();
        let reason = without_source_places(reason);
        Denial::Connection(match handshake_cause(&reason) {
            Some(cause) => format!("{cause} ({reason})"),
            None => reason,
        })
    })
}

/// Why a TLS handshake failed, from rustls's words in Zenoh's reason: the side that checks
/// a certificate names the fault; the side whose certificate it was hears only an alert.
fn handshake_cause(reason: &str) -> Option<&'static str> {
    let has = |words: &[&str]| words.iter().any(|w| reason.contains(w));
    if has(&["not valid yet", "NotValidYet"]) {
        Some(
            "its certificate is not valid yet: one host's clock is wrong, or the keys were \
             made on a host whose clock was ahead",
        )
    } else if has(&["certificate expired", "Expired"]) && !has(&["alert"]) {
        Some("its certificate has expired: make new keys with `tes link keygen`")
    } else if has(&["CertificateExpired"]) {
        Some(
            "the other side finds this host's certificate out of its dates (expired, or \
             not yet valid by its clock)",
        )
    } else if has(&["UnknownIssuer", "unknown issuer"]) {
        Some(
            "its certificate was not issued by the group's authority (link.tls_ca): it is \
             not a member, or its keys are of another keygen",
        )
    } else if has(&["UnknownCA", "UnknownCa"]) {
        Some(
            "the other side does not know the authority of this host's certificate: the two \
             hosts have keys of different keygens",
        )
    } else if has(&["NoCertificatesPresented", "CertificateRequired"]) {
        Some("it showed no certificate: it is not a member of the group")
    } else {
        None
    }
}

/// One access-control verdict Zenoh logged: `[Using cached result: ]ZID[ on SUBJECT] is
/// [un]authorized to WHAT on KEY`.
struct AclDecision {
    /// A cached verdict: the message's final one. Otherwise one subject's.
    cached: bool,
    allowed: bool,
    peer: String,
    what: String,
    key: String,
}

impl AclDecision {
    /// The denial to tell, if the message is one that came in (a sample or a member
    /// token): what this host would not send (egress) is left out, and so are the verdicts
    /// Zenoh weighs in advance for every kind of message on each key a peer declares
    /// (`Declare/Undeclare …`: no such message came).
    fn denial(&self) -> Option<Denial> {
        let came_in = self.what.ends_with("(ingress)")
            && !self.what.starts_with("Declare/Undeclare")
            && (self.what.starts_with("Put") || self.what.contains("Liveliness Token"));
        came_in.then(|| Denial::Message {
            peer: self.peer.clone(),
            what: self.what.clone(),
            key: self.key.clone(),
        })
    }
}

/// The verdict of an access-control event's text, if it is one.
fn acl_decision(text: &str) -> Option<AclDecision> {
    let (who, rest, allowed) = match text.split_once(" is unauthorized to ") {
        Some((who, rest)) => (who, rest, false),
        None => {
            let (who, rest) = text.split_once(" is authorized to ")?;
            (who, rest, true)
        }
    };
    let (what, key) = rest.split_once(" on ")?;
    let cached = who.trim_start().starts_with("Using cached result:");
    let peer = who
        .trim()
        .trim_start_matches("Using cached result:")
        .split_whitespace()
        .next()?
        .to_owned();
    Some(AclDecision {
        cached,
        allowed,
        peer,
        what: what.to_owned(),
        key: key.trim().to_owned(),
    })
}

/// A denial of something a peer sent, final or not (see [`acl_decision`]).
#[cfg(test)]
fn acl_refusal(text: &str) -> Option<Denial> {
    acl_decision(text).filter(|d| !d.allowed)?.denial()
}

/// How long a subject's refusal stays pending before it is the message's verdict: Zenoh
/// weighs a message's subjects one after the other at once, so a later subject's allowance
/// comes within microseconds.
const PENDING_FOR: Duration = Duration::from_millis(200);

/// Moves the pending refusals old enough to be final to the told ones.
fn settle_pending() {
    let settled: Vec<Denial> = match PENDING.lock() {
        Ok(mut pending) => {
            let old: Vec<Denial> = pending
                .iter()
                .filter(|(_, at)| at.elapsed() >= PENDING_FOR)
                .map(|(d, _)| d.clone())
                .collect();
            for d in &old {
                pending.remove(d);
            }
            old
        }
        Err(_) => Vec::new(),
    };
    for denial in settled {
        if first_telling(&denial) {
            remember(denial);
        }
    }
}

/// Whether a message denial is told for the first time (each is told once).
fn first_telling(denial: &Denial) -> bool {
    let Denial::Message { peer, what, key } = denial else {
        return true;
    };
    let Ok(mut told) = TOLD.lock() else {
        return false;
    };
    if told.len() >= TOLD_MAX {
        return false;
    }
    told.insert((peer.clone(), what.clone(), key.clone()))
}

fn remember(denial: Denial) {
    if let Ok(mut denied) = DENIED.lock() {
        if denied.len() >= KEPT {
            denied.pop_front();
        }
        denied.push_back(denial);
    }
}

/// An event's text: its message and its other fields.
struct Message(String);

impl Visit for Message {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            let _ = write!(self.0, "{value:?}");
        } else {
            let _ = write!(self.0, " {}={value:?}", field.name());
        }
    }
}

/// `text` without the ` at PATH.rs:LINE` places Zenoh's errors end with.
pub(crate) fn without_source_places(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find(" at ") {
        let after = &rest[at + 4..];
        let end = after.find(char::is_whitespace).unwrap_or(after.len());
        if after[..end].contains(".rs:") {
            out.push_str(&rest[..at]);
            rest = &after[end..];
        } else {
            out.push_str(&rest[..at + 4]);
            rest = after;
        }
    }
    out.push_str(rest);
    out.trim_end().to_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refusals_are_told_from_other_events() {
        assert_eq!(
            quic_refusal(
                "QUIC acceptor failed: ConnectionError(TransportError(..)) Hint: increase the \
                 system open file limit."
            ),
            Some(Denial::Connection(
                "QUIC acceptor failed: ConnectionError(TransportError(..))".into()
            ))
        );
        assert_eq!(quic_refusal("Listener added"), None);
        assert_eq!(
            acl_refusal(
                "Using cached result: 4c29 is unauthorized to Put (ingress) on lab/command"
            ),
            Some(Denial::Message {
                peer: "4c29".into(),
                what: "Put (ingress)".into(),
                key: "lab/command".into()
            })
        );
        let token = acl_refusal(
            "6e38 on Interface(lo)+CertCommonName(bridge) is unauthorized to Liveliness Token \
             (ingress) on lab/member/controller/6e38",
        );
        assert!(matches!(token, Some(Denial::Message { peer, .. }) if peer == "6e38"));
        for quiet in [
            "6e38 on lo is unauthorized to Delete (ingress) on lab/command",
            "6e38 on lo is unauthorized to Declare/Undeclare Liveliness Token (ingress) on lab/stop",
            "6e38 on lo is unauthorized to Put (egress) on lab/command",
            "Using cached result: 4c29 is authorized to Put (ingress) on lab/stop",
        ] {
            assert_eq!(acl_refusal(quiet), None, "{quiet}");
        }
    }

    /// The tests that drain the process's queue, one at a time.
    static SERIAL: Mutex<()> = Mutex::new(());

    /// A failed handshake is said by its cause: each of rustls's reasons a certificate is
    /// refused for, then Zenoh's words (without the places in its sources).
    #[test]
    fn handshake_failures_name_their_cause() {
        for (reason, cause) in [
            (
                "QUIC acceptor failed: invalid peer certificate: UnknownIssuer at \
                 /root/.cargo/registry/src/x/zenoh-link-quic-1.10.2/src/unicast.rs:404.",
                "not issued by the group's authority",
            ),
            (
                "QUIC acceptor failed: invalid peer certificate: certificate expired: \
                 verification time 1800000000 (UNIX), but certificate is not valid after \
                 1700000000",
                "its certificate has expired",
            ),
            (
                "QUIC acceptor failed: invalid peer certificate: certificate not valid yet: \
                 verification time 1700000000 (UNIX), but certificate is not valid before \
                 1800000000",
                "not valid yet",
            ),
            (
                "Cannot accept QUIC connection: received fatal alert: CertificateExpired",
                "out of its dates",
            ),
            (
                "QUIC acceptor failed: peer sent no certificates (NoCertificatesPresented)",
                "showed no certificate",
            ),
        ] {
            let Some(Denial::Connection(said)) = quic_refusal(reason) else {
                panic!("not a refusal: {reason}");
            };
            assert!(said.contains(cause), "{said}");
            assert!(!said.contains(".cargo/registry"), "{said}");
        }
    }

    /// Zenoh logs each subject's verdict on a message in turn: a refusal another subject
    /// overrules is not told (a healthy peer's own member tokens), one that none overrules
    /// is, once.
    #[test]
    fn a_refusal_another_subject_overrules_is_not_told() {
        use tracing_subscriber::layer::SubscriberExt;
        let _serial = SERIAL.lock();
        let subscriber = tracing_subscriber::registry().with(layer());
        tracing::subscriber::with_default(subscriber, || {
            for _ in 0..3 {
                tracing::trace!(
                    target: ACL_TARGET,
                    "aa11 on Interface(lo)+CertCommonName(perception-sim+bridge) is \
                     unauthorized to Liveliness Token (ingress) on lab/member/bridge/aa11"
                );
                tracing::trace!(
                    target: ACL_TARGET,
                    "aa11 on Interface(lo)+CertCommonName(perception-sim+bridge) is \
                     authorized to Liveliness Token (ingress) on lab/member/bridge/aa11"
                );
            }
            for _ in 0..3 {
                // Weighed in advance for a declared key, or a sample: not told.
                tracing::trace!(
                    target: ACL_TARGET,
                    "bb22 on Interface(lo) is unauthorized to Put (ingress) on lab/command"
                );
                tracing::trace!(
                    target: ACL_TARGET,
                    "dd44 on Interface(lo) is unauthorized to Liveliness Token (ingress) on \
                     lab/member/controller/dd44"
                );
                tracing::trace!(
                    target: ACL_TARGET,
                    "Using cached result: cc33 is unauthorized to Put (ingress) on lab/command"
                );
            }
        });
        std::thread::sleep(PENDING_FOR + Duration::from_millis(50));
        let peers: Vec<String> = take()
            .into_iter()
            .filter_map(|d| match d {
                Denial::Message { peer, .. } if peer.len() == 4 => Some(peer),
                _ => None,
            })
            .collect();
        assert_eq!(peers, ["cc33", "dd44"]);
    }

    #[test]
    fn the_queue_keeps_the_latest() {
        let _serial = SERIAL.lock();
        for i in 0..KEPT + 10 {
            remember(Denial::Connection(format!("{i}")));
        }
        let taken = take();
        assert_eq!(taken.len(), KEPT);
        assert_eq!(taken[0], Denial::Connection("10".into()));
        assert!(take().is_empty());
    }
}
