//! What Zenoh refuses, said by the link: a connection that failed the group's TLS, a sample
//! or a member token a peer's certificate does not allow.
//!
//! Zenoh reports neither to the application: a failed handshake only in its log (as a
//! warning of its QUIC listener), an access-control denial only as a trace event of its
//! interceptor. [`layer`] is a `tracing` layer that picks those events out (and nothing else:
//! it enables no other target) and queues them; the open [`Link`](crate::Link) hands them on
//! as [`LinkEvent::Denied`](crate::LinkEvent::Denied), which the launcher prints. Install it
//! once per process, before the link opens.

use std::collections::{BTreeSet, VecDeque};
use std::fmt::Write as _;
use std::sync::{Mutex, RwLock};

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

/// The message denials told so far, by (peer, what, key): each is told once.
static TOLD: Mutex<BTreeSet<(String, String, String)>> = Mutex::new(BTreeSet::new());

/// Distinct message denials remembered for telling each once; beyond, they are not told.
pub const TOLD_MAX: usize = 1024;

/// The access-control callsites found to say nothing this layer wants (they allow): their
/// events are not even built for it again.
static QUIET: RwLock<Vec<Identifier>> = RwLock::new(Vec::new());

/// Something Zenoh refused.
#[derive(Debug, Clone, PartialEq, Eq)]
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
        // Access control traces every decision; only its denials matter here. A callsite
        // that allows (one per decision kind) says so on its first event and is silenced.
        if !text.contains("is unauthorized to") {
            if let Ok(mut quiet) = QUIET.write() {
                quiet.push(event.metadata().callsite());
            }
            return;
        }
        if let Some(denial) = acl_refusal(&text)
            && first_telling(&denial)
        {
            remember(denial);
        }
    }
}

/// A QUIC listener's or connector's failed handshake, without Zenoh's hint about open files
/// (which fits only its other errors).
fn quic_refusal(text: &str) -> Option<Denial> {
    let failed = text.contains("QUIC acceptor failed")
        || text.contains("Cannot accept QUIC connection")
        || text.contains("handshake");
    failed.then(|| {
        let reason = text
            .split(" Hint:")
            .next()
            .unwrap_or(text)
            .trim()
            .to_owned();
        Denial::Connection(reason)
    })
}

/// A denial of something a peer sent: `[Using cached result: ]ZID[ on SUBJECT] is
/// unauthorized to WHAT (ingress) on KEY`. What this host would not send (egress) and the
/// kinds Zenoh weighs in advance for every declared key are left out: only a sample or a
/// member token that came in and was dropped is told.
fn acl_refusal(text: &str) -> Option<Denial> {
    let (who, rest) = text.split_once(" is unauthorized to ")?;
    let (what, key) = rest.split_once(" on ")?;
    let came_in = what.ends_with("(ingress)")
        && (what.starts_with("Put") || what.contains("Liveliness Token"));
    if !came_in {
        return None;
    }
    let peer = who
        .trim()
        .trim_start_matches("Using cached result:")
        .split_whitespace()
        .next()?
        .to_owned();
    Some(Denial::Message {
        peer,
        what: what.to_owned(),
        key: key.trim().to_owned(),
    })
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
            "6e38 on Interface(lo)+CertCommonName(bridge) is unauthorized to Declare/Undeclare \
             Liveliness Token (ingress) on lab/member/controller/6e38",
        );
        assert!(matches!(token, Some(Denial::Message { peer, .. }) if peer == "6e38"));
        for quiet in [
            "6e38 on lo is unauthorized to Delete (ingress) on lab/command",
            "6e38 on lo is unauthorized to Put (egress) on lab/command",
            "Using cached result: 4c29 is authorized to Put (ingress) on lab/stop",
        ] {
            assert_eq!(acl_refusal(quiet), None, "{quiet}");
        }
    }

    #[test]
    fn the_queue_keeps_the_latest() {
        for i in 0..KEPT + 10 {
            remember(Denial::Connection(format!("{i}")));
        }
        let taken = take();
        assert_eq!(taken.len(), KEPT);
        assert_eq!(taken[0], Denial::Connection("10".into()));
        assert!(take().is_empty());
    }
}
