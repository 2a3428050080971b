//! What local processes write and a peer reads: one thread per service, forwarding each
//! payload's bytes to its Zenoh key.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Instant;

use tes_runtime::channel::{self, Inbox, IpcError, LatestInbox, WaitStrategy};
use tes_topics::wire::{Wire, as_bytes};
use tes_topics::{Command, MotorState, Observation, Progress, Role, ServiceNames, WorldMap};
use zenoh::Wait;

use crate::Topic;
use crate::shared::{IDLE, MAP_AGAIN};

/// The node of the forwarding threads.
type Node = iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>;

/// Where a forwarding thread says whether it has its ports: `Ok` once it has them, the
/// error if it could not open them (or stopped later).
pub(crate) type Ready = mpsc::Sender<Result<(), IpcError>>;

/// Forwards the local service `topic` to the peers through `publisher` until `stop`,
/// telling `ready` when its ports are open. Each payload carries, as its attachment, the
/// Zenoh id `zid` of this launch's session: a peer takes a service only from the session that
/// announced the role writing it.
pub(crate) fn outbound(
    topic: Topic,
    names: &ServiceNames,
    publisher: &zenoh::pubsub::Publisher<'static>,
    zid: &str,
    stop: &AtomicBool,
    ready: &Ready,
) {
    let sender = zenoh::bytes::ZBytes::from(zid.to_owned());
    let put = |bytes: &[u8]| {
        if let Err(e) = publisher.put(bytes).attachment(sender.clone()).wait() {
            eprintln!("launch: link: warning: cannot send {topic}: {e}");
        }
    };
    let opened = || {
        let _ = ready.send(Ok(()));
    };
    let result = channel::node(false).and_then(|node| {
        let forward = Forward { stop, put, opened };
        match topic {
            Topic::Observation => {
                forward.each::<Observation>(&node, &names.observation, &names.observation_event, 0)
            }
            Topic::MotorState => {
                forward.each::<MotorState>(&node, &names.motor_state, &names.motor_state_event, 0)
            }
            Topic::WorldMap => forward.world_map(&node, names),
            Topic::Command => forward.commands(&node, names),
            Topic::Progress(role) => forward.progress(&node, names, role),
        }
    });
    if let Err(e) = result {
        eprintln!("launch: link: warning: forwarding {topic} stopped: {e}");
        let _ = ready.send(Err(e));
    }
}

/// One forwarding thread's loop: `put` sends a payload's bytes, `opened` says the ports are
/// open, `stop` ends it.
struct Forward<'a, P, O> {
    stop: &'a AtomicBool,
    put: P,
    opened: O,
}

impl<P: Fn(&[u8]), O: Fn()> Forward<'_, P, O> {
    fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// Every payload of a publish–subscribe service with an event, as it comes.
    fn each<T: Wire + iceoryx2::prelude::ZeroCopySend + Copy + std::fmt::Debug + 'static>(
        &self,
        node: &Node,
        service: &str,
        event: &str,
        history: usize,
    ) -> Result<(), IpcError> {
        let inbox: Inbox<T> = Inbox::open(node, service, event, history, WaitStrategy::Block)?;
        (self.opened)();
        while !self.stopped() {
            if let Ok(v) = inbox.next(IDLE, self.stop)? {
                (self.put)(as_bytes(&v));
            }
        }
        Ok(())
    }

    /// The world map: each new one at once, then again every [`MAP_AGAIN`] (a peer that
    /// joins later, or whose subscription was not yet known, gets it then).
    fn world_map(&self, node: &Node, names: &ServiceNames) -> Result<(), IpcError> {
        let inbox: Inbox<WorldMap> = Inbox::open(
            node,
            &names.world_map,
            &names.world_map_event,
            1,
            WaitStrategy::Block,
        )?;
        (self.opened)();
        let mut map: Option<Box<WorldMap>> = None;
        let mut sent = Instant::now();
        while !self.stopped() {
            if let Ok(m) = inbox.next(IDLE, self.stop)? {
                **map.get_or_insert_with(|| Box::new(WorldMap::EMPTY)) = m;
                sent = Instant::now() - MAP_AGAIN;
            }
            if let Some(m) = &map
                && sent.elapsed() >= MAP_AGAIN
            {
                (self.put)(as_bytes(&**m));
                sent = Instant::now();
            }
        }
        Ok(())
    }

    /// Each new command on the board; a board its writer abandoned is opened afresh.
    fn commands(&self, node: &Node, names: &ServiceNames) -> Result<(), IpcError> {
        let mut inbox: LatestInbox<Command> = LatestInbox::open(
            node,
            &names.command,
            &names.command_event,
            WaitStrategy::Block,
        )?;
        (self.opened)();
        while !self.stopped() {
            match inbox.next(IDLE, self.stop)? {
                Ok(c) => (self.put)(as_bytes(&c)),
                Err(_) => {
                    inbox.renew_if_abandoned(node)?;
                }
            }
        }
        Ok(())
    }

    /// The latest progress report of `role`, looked for every [`IDLE`]: progress has no
    /// event, a report is due a few times a second at most.
    fn progress(&self, node: &Node, names: &ServiceNames, role: Role) -> Result<(), IpcError> {
        let service = channel::pubsub::<Progress, _>(node, names.progress_of(role), 1)?;
        let subscriber = service
            .subscriber_builder()
            .create()
            .map_err(channel::ipc_err("create a progress subscriber"))?;
        (self.opened)();
        while !self.stopped() {
            let mut latest = None;
            while let Some(s) = subscriber
                .receive()
                .map_err(channel::ipc_err("receive a progress report"))?
            {
                latest = Some(*s);
            }
            if let Some(p) = latest {
                (self.put)(as_bytes(&p));
            }
            std::thread::sleep(IDLE);
        }
        Ok(())
    }
}
