//! The live view: a Foxglove WebSocket server (the `foxglove` crate's) on threads of its own,
//! fed the same drawings as a recording.
//!
//! The server runs on a one-worker Tokio runtime whose threads are placed off the CPU the
//! controller's acting thread is pinned to and run at the lowest priority (`SCHED_IDLE`), so
//! serving a viewer never takes that CPU nor delays a waking group process. On a machine
//! whose cores are all busy at normal priority such threads would get almost no CPU and a
//! viewer's handshake would time out: a task on the runtime beats every [`BEAT_EVERY`], and a
//! watcher at normal priority ([`tes_runtime::background::Watcher`]) raises the threads back
//! to normal scheduling for the rest of the run once the beat is [`LAG_LIMIT`] (100 ms) late. Where
//! this process could not undo `SCHED_IDLE`, the threads keep normal priority.
//! [`LiveServer::draw`] only queues a message for each subscribed client (a bounded queue per
//! client, oldest dropped when full): a viewer that stops reading loses messages, never slows
//! the caller. Pictures of the robot's motion go out at a screen's pace ([`MotionPace`]), not
//! the loop's; decisions, episode ends and log lines all go out. Requests it cannot serve
//! (malformed, an unknown channel) are answered by the server with a status message.
//!
//! Viewers reach the crate's server through a front door of ours (`door`), which bounds
//! what they can make the launcher hold: [`CONNECTIONS_MAX`] connections, each with
//! [`HANDSHAKE_DEADLINE`] to finish its upgrade, a request head of at most
//! [`REQUEST_HEAD_MAX`] bytes and messages of at most [`CLIENT_MESSAGE_MAX`] bytes; it keeps
//! listening when the process runs out of file descriptors, and offers the protocol under
//! both its names ([`handshake`]). [`LiveServer::stop`] takes at most [`STOP_WAIT`] twice
//! (the crate's server, then the runtime), whatever the viewers do.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, WebSocketServer};

use tes_runtime::background::{Background, LAG_LIMIT, Watcher};

use crate::canvas::{Canvas, Channel, Drawing};

mod door;
mod frames;
pub mod handshake;

/// The address the live server binds unless told otherwise: loopback only.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// Messages queued per client before the oldest are dropped: about 50 actions' worth of
/// drawings. The crate's server keeps a second queue of this many for its own answers
/// (advertisements, statuses), and drops a client that fills it.
pub const BACKLOG: usize = 1024;

/// Connections the live server holds at once, handshaking or served; one more is answered
/// `503 Service Unavailable` and closed.
pub const CONNECTIONS_MAX: usize = 16;

/// The time a connection has to finish its WebSocket upgrade.
pub const HANDSHAKE_DEADLINE: Duration = Duration::from_secs(5);

/// The longest upgrade request (its HTTP head) a viewer may send.
pub const REQUEST_HEAD_MAX: usize = 8 * 1024;

/// The longest message (its fragments added up) a viewer may send; its requests are small
/// JSON objects.
pub const CLIENT_MESSAGE_MAX: usize = 64 * 1024;

/// The longest [`LiveServer::stop`] waits for the crate's server to close its connections,
/// and then for the runtime's threads.
pub const STOP_WAIT: Duration = Duration::from_secs(1);

/// How often the server's runtime says it runs (a timer task on its worker).
pub const BEAT_EVERY: Duration = Duration::from_millis(20);

/// The live view's pace for the robot's motion: at most this many pictures a second per
/// channel, about a screen's rate. The loop may decide 500 times a second; each picture sent
/// is a loopback TCP send whose kernel work no thread priority holds back.
pub const MOTION_PER_SECOND: u64 = 30;

/// Which pictures of motion the live view sends: on each channel, one at least
/// 1/[`MOTION_PER_SECOND`] s after the last one sent. A skipped picture is superseded by the
/// next on its channel, so a viewer is at most that far behind.
#[derive(Debug, Default, Clone)]
pub struct MotionPace {
    last_sent: BTreeMap<&'static str, u64>,
}

impl MotionPace {
    /// Whether a picture on `topic` at `wall_ns` is sent (and, if so, notes it).
    pub fn admits(&mut self, topic: &'static str, wall_ns: u64) -> bool {
        let frame = 1_000_000_000 / MOTION_PER_SECOND;
        match self.last_sent.get(topic) {
            Some(&last) if wall_ns < last.saturating_add(frame) => false,
            _ => {
                self.last_sent.insert(topic, wall_ns);
                true
            }
        }
    }
}

/// Why the live server cannot start.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// Its runtime cannot start.
    #[error("cannot start the Foxglove server's threads: {0}")]
    Runtime(#[source] std::io::Error),
    /// A channel cannot be created.
    #[error("cannot create the Foxglove channel {topic}: {source}")]
    Channel {
        /// The topic.
        topic: &'static str,
        /// Why.
        #[source]
        source: foxglove::FoxgloveError,
    },
    /// The server cannot listen.
    #[error("cannot serve Foxglove on {addr}: {reason}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why, as the server says it (its own error already names its cause).
        reason: String,
    },
}

/// Notes that a client subscribed, so what is drawn once is drawn again for it.
#[derive(Debug, Default)]
struct Joins(AtomicBool);

impl ServerListener for Joins {
    fn on_subscribe(&self, _client: Client, _channel: ChannelView<'_>) {
        self.0.store(true, Ordering::Release);
    }
}

/// A running Foxglove WebSocket server serving a scene's channels.
pub struct LiveServer {
    addr: SocketAddr,
    channels: BTreeMap<&'static str, Arc<RawChannel>>,
    motion: MotionPace,
    joins: Arc<Joins>,
    inner: Option<Arc<door::Inner>>,
    door: Option<tokio::task::JoinHandle<()>>,
    // Kept for its channels' lifetime; dropped last.
    _context: Arc<Context>,
    /// Raises the runtime's threads once their beat is late; stopped before the runtime.
    watcher: Option<Watcher>,
    runtime: Option<tokio::runtime::Runtime>,
}

impl std::fmt::Debug for LiveServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveServer")
            .field("addr", &self.addr)
            .field("channels", &self.channels.keys())
            .finish_non_exhaustive()
    }
}

impl LiveServer {
    /// Starts serving `channels` on `addr` (port 0: any free port; see [`addr`](Self::addr)).
    pub fn start<'a>(
        addr: SocketAddr,
        channels: impl IntoIterator<Item = &'a Channel>,
    ) -> Result<Self, LiveError> {
        let background = Arc::new(Background::new());
        let lowered = background.clone();
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .max_blocking_threads(1)
            .thread_name("foxglove")
            .on_thread_start(move || {
                if let Err(e) = tes_runtime::affinity::pin_off_the_acting_cpu() {
                    tracing::debug!("a Foxglove server thread stays unpinned: {e}");
                }
                lowered.lower_if_restorable();
            })
            .enable_all()
            .build()
            .map_err(LiveError::Runtime)?;
        let beating = background.clone();
        runtime.spawn(async move {
            let mut every = tokio::time::interval(BEAT_EVERY);
            every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                every.tick().await;
                beating.beat();
            }
        });
        let watcher = Watcher::start(background, LAG_LIMIT, "the Foxglove server")
            .map_err(LiveError::Runtime)?;
        let context = Context::new();
        let channels = channels
            .into_iter()
            .map(|c| {
                let raw = ChannelBuilder::new(c.topic)
                    .context(&context)
                    .message_encoding(c.encoding.clone())
                    .schema(c.schema.clone())
                    .build_raw()
                    .map_err(|source| LiveError::Channel {
                        topic: c.topic,
                        source,
                    })?;
                Ok((c.topic, raw))
            })
            .collect::<Result<BTreeMap<_, _>, LiveError>>()?;
        let joins = Arc::new(Joins::default());
        let build = inner_server(&context, &joins, runtime.handle());
        let bind_error = |reason: String| LiveError::Bind { addr, reason };
        let (listener, inner) = runtime.block_on(async {
            let listener = tokio::net::TcpListener::bind(addr)
                .await
                .map_err(|e| bind_error(e.to_string()))?;
            let inner = door::Inner::start(build)
                .await
                .map_err(|e| bind_error(format!("its inner server: {e}")))?;
            Ok::<_, LiveError>((listener, inner))
        })?;
        let addr = listener
            .local_addr()
            .map_err(|e| bind_error(e.to_string()))?;
        let door = runtime.spawn(door::Door::new(listener, inner.clone()).serve());
        Ok(Self {
            addr,
            channels,
            motion: MotionPace::default(),
            joins,
            inner: Some(inner),
            door: Some(door),
            _context: context,
            watcher: Some(watcher),
            runtime: Some(runtime),
        })
    }

    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Whether a client subscribed to a channel since the last call.
    pub fn take_joined(&self) -> bool {
        self.joins.0.swap(false, Ordering::AcqRel)
    }

    /// Stops serving: clients are disconnected. Takes at most twice [`STOP_WAIT`], whatever
    /// the clients do.
    pub fn stop(mut self) {
        self.shut_down();
    }

    fn shut_down(&mut self) {
        if let Some(watcher) = self.watcher.take() {
            watcher.stop();
        }
        // The door first: with it go the connections it holds (handshaking or spliced), so
        // the crate's server sees its clients leave.
        if let Some(door) = self.door.take() {
            door.abort();
        }
        if let (Some(inner), Some(runtime)) = (self.inner.take(), &self.runtime) {
            let stopping: Vec<_> = inner.take_handles().into_iter().map(|h| h.stop()).collect();
            let all_stopped = async {
                for s in stopping {
                    s.wait().await;
                }
            };
            // The timer is made inside the runtime, whose clock it needs.
            let bounded = async { tokio::time::timeout(STOP_WAIT, all_stopped).await };
            if runtime.block_on(bounded).is_err() {
                tracing::debug!("the live server's clients did not all close within {STOP_WAIT:?}");
            }
        }
        if let Some(runtime) = self.runtime.take() {
            // Drops every task left; waits for no client.
            runtime.shutdown_timeout(STOP_WAIT);
        }
    }
}

/// How the door builds the crate's server: on a free loopback port, on `runtime`, serving
/// `context`'s channels, telling `joins` of subscriptions.
fn inner_server(
    context: &Arc<Context>,
    joins: &Arc<Joins>,
    runtime: &tokio::runtime::Handle,
) -> door::BuildInner {
    let (context, joins, runtime) = (context.clone(), joins.clone(), runtime.clone());
    Box::new(move || {
        WebSocketServer::new()
            .name(format!("tes {}", env!("CARGO_PKG_VERSION")))
            .bind("127.0.0.1", 0)
            .context(&context)
            .message_backlog_size(BACKLOG)
            .listener(joins.clone())
            .tokio_runtime(&runtime)
    })
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        self.shut_down();
    }
}

impl Canvas for LiveServer {
    type Error = std::convert::Infallible;

    fn draw(&mut self, d: Drawing<'_>) -> Result<(), Self::Error> {
        if d.motion && !self.motion.admits(d.channel.topic, d.wall_ns) {
            return Ok(());
        }
        if let Some(channel) = self.channels.get(d.channel.topic) {
            channel.log_with_meta(d.data, PartialMetadata::with_log_time(d.wall_ns));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motion_goes_out_at_a_screens_pace_per_channel() {
        let mut pace = MotionPace::default();
        let frame = 1_000_000_000 / MOTION_PER_SECOND;
        // 500 pictures a second for one second: 30 go out, one per frame.
        let sent = (0..500u64)
            .filter(|i| pace.admits("/tf", i * 2_000_000))
            .count() as u64;
        assert_eq!(sent, MOTION_PER_SECOND);
        // Another channel has its own pace.
        assert!(pace.admits("/robot", 1));
        assert!(!pace.admits("/robot", frame));
        assert!(pace.admits("/robot", frame + 1));
    }
}
