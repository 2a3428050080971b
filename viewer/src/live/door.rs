//! The live server's front door: the listener viewers reach, with the bounds the `foxglove`
//! crate's server does not set, in front of that server (on a loopback port of its own).
//!
//! * At most [`CONNECTIONS_MAX`](super::CONNECTIONS_MAX) connections at once, handshaking or
//!   served; one more is answered `503` and closed at once.
//! * A connection has [`HANDSHAKE_DEADLINE`](super::HANDSHAKE_DEADLINE) to finish its
//!   upgrade, whose request may be at most [`REQUEST_HEAD_MAX`](super::REQUEST_HEAD_MAX)
//!   bytes; only a whole request reaches the crate's server.
//! * A served connection is spliced to the crate's server through buffers of fixed size; the
//!   viewer's frames are read as they pass ([`ClientFrames`]), and a message longer than
//!   [`CLIENT_MESSAGE_MAX`](super::CLIENT_MESSAGE_MAX) ends the connection.
//! * A failed `accept` (no file descriptor left) is said once; the listener is kept and
//!   retried every [`ACCEPT_RETRY`] until it accepts again, which is said too.
//! * The crate's server drops its own listener on any failed `accept`: a connection to it
//!   that is refused starts another one on the same channels.

use std::io;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use foxglove::{WebSocketServer, WebSocketServerHandle};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::task::JoinSet;

use super::frames::{ClientFrames, FrameError};
use super::handshake;
use super::{CLIENT_MESSAGE_MAX, CONNECTIONS_MAX, HANDSHAKE_DEADLINE, REQUEST_HEAD_MAX};

/// How long the door waits before trying a failed `accept` again.
pub const ACCEPT_RETRY: Duration = Duration::from_millis(100);

/// Each direction of a served connection goes through a buffer of this size.
pub const SPLICE_BUFFER: usize = 16 * 1024;

/// What a connection past the cap is told before it is closed.
const FULL_ANSWER: &[u8] =
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n\r\n";

/// What a request too long for the door is told before it is closed.
const TOO_LONG_ANSWER: &[u8] = b"HTTP/1.1 431 Request Header Fields Too Large\r\nContent-Length: \
                                 0\r\nConnection: close\r\n\r\n";

/// Builds the crate's server (bound to a free loopback port, on the live server's runtime and
/// context).
pub type BuildInner = Box<dyn Fn() -> WebSocketServer + Send + Sync>;

/// The crate's server behind the door, started again if its listener is gone.
pub struct Inner {
    build: BuildInner,
    addr: Mutex<SocketAddr>,
    /// Every server started, the current one last: stopped together.
    handles: Mutex<Vec<WebSocketServerHandle>>,
    restarting: tokio::sync::Mutex<()>,
}

impl Inner {
    /// Starts the crate's server.
    pub async fn start(build: BuildInner) -> Result<Arc<Self>, foxglove::FoxgloveError> {
        let handle = build().start().await?;
        Ok(Arc::new(Self {
            build,
            addr: Mutex::new(loopback(handle.port())),
            handles: Mutex::new(vec![handle]),
            restarting: tokio::sync::Mutex::new(()),
        }))
    }

    /// Takes every server started, to stop them.
    pub fn take_handles(&self) -> Vec<WebSocketServerHandle> {
        std::mem::take(&mut *self.handles.lock().unwrap_or_else(PoisonError::into_inner))
    }

    fn addr(&self) -> SocketAddr {
        *self.addr.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// A connection to the crate's server; one started anew if its listener is gone.
    async fn connect(&self) -> io::Result<TcpStream> {
        let addr = self.addr();
        match TcpStream::connect(addr).await {
            Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => {
                TcpStream::connect(self.restart(addr).await?).await
            }
            connected => connected,
        }
    }

    /// Starts the crate's server again in place of the one at `gone` (unless another
    /// connection already did); its address.
    async fn restart(&self, gone: SocketAddr) -> io::Result<SocketAddr> {
        let _one_at_a_time = self.restarting.lock().await;
        if self.addr() != gone {
            return Ok(self.addr());
        }
        tracing::warn!(
            "the live Foxglove server lost its inner listener (no file descriptor was left to \
             accept with); starting it again"
        );
        let handle = (self.build)().start().await.map_err(io::Error::other)?;
        let addr = loopback(handle.port());
        *self.addr.lock().unwrap_or_else(PoisonError::into_inner) = addr;
        self.handles
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push(handle);
        Ok(addr)
    }
}

fn loopback(port: u16) -> SocketAddr {
    SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port)
}

/// Why a connection ended before it was served, or while it was.
#[derive(Debug, thiserror::Error)]
enum ConnectionEnd {
    #[error("did not finish its handshake within {0:?}")]
    Deadline(Duration),
    #[error("sent a request head longer than {REQUEST_HEAD_MAX} bytes")]
    HeadTooLong,
    #[error("closed during its handshake")]
    ClosedEarly,
    #[error("cannot reach the inner server: {0}")]
    Inner(#[source] io::Error),
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error(transparent)]
    Io(#[from] io::Error),
}

/// The door: its listener and what the connections share.
pub struct Door {
    listener: TcpListener,
    slots: Arc<Semaphore>,
    inner: Arc<Inner>,
}

impl Door {
    /// A door on `listener` to `inner`.
    pub fn new(listener: TcpListener, inner: Arc<Inner>) -> Self {
        Self {
            listener,
            slots: Arc::new(Semaphore::new(CONNECTIONS_MAX)),
            inner,
        }
    }

    /// Accepts viewers until the task is aborted; its connections are aborted with it.
    pub async fn serve(self) {
        let mut connections = JoinSet::new();
        let mut notices = Notices::default();
        loop {
            tokio::select! {
                accepted = self.listener.accept() => match accepted {
                    Ok((stream, peer)) => {
                        notices.accepting();
                        self.admit(stream, peer, &mut connections, &mut notices);
                    }
                    Err(e) => {
                        notices.cannot_accept(&e);
                        tokio::time::sleep(ACCEPT_RETRY).await;
                    }
                },
                Some(_) = connections.join_next(), if !connections.is_empty() => {}
            }
        }
    }

    /// Serves `stream` if a slot is free, else tells it the view is full and closes it.
    fn admit(
        &self,
        stream: TcpStream,
        peer: SocketAddr,
        connections: &mut JoinSet<()>,
        notices: &mut Notices,
    ) {
        match self.slots.clone().try_acquire_owned() {
            Ok(slot) => {
                connections.spawn(connection(stream, peer, self.inner.clone(), slot));
            }
            Err(_) => {
                notices.full(peer);
                // Best effort and never waiting: the connection is closed either way. What it
                // already sent is read first, so the close is a FIN after the answer rather
                // than a reset that may discard it.
                let mut unread = [0u8; 1024];
                let _ = stream.try_read(&mut unread);
                let _ = stream.try_write(FULL_ANSWER);
            }
        }
    }
}

/// What the door says of itself: each trouble once when it begins (a trouble that comes
/// back within [`SAID_EVERY`] is not said again), and the end of an outage it said.
#[derive(Debug, Default)]
struct Notices {
    failing_said: Option<Instant>,
    /// During an outage: whether its beginning was said.
    failing: Option<bool>,
    full_said: Option<Instant>,
    refused_since_said: u64,
}

/// How often one kind of trouble is said at most.
const SAID_EVERY: Duration = Duration::from_secs(60);

/// Whether a notice last said `at` may be said again.
fn due(at: Option<Instant>) -> bool {
    at.is_none_or(|at| at.elapsed() >= SAID_EVERY)
}

impl Notices {
    fn cannot_accept(&mut self, e: &io::Error) {
        if self.failing.is_some() {
            return;
        }
        let say = due(self.failing_said);
        if say {
            self.failing_said = Some(Instant::now());
            tracing::warn!(
                "the live Foxglove server cannot accept viewers: {e}; it keeps listening and \
                 tries again every {ACCEPT_RETRY:?}"
            );
        }
        self.failing = Some(say);
    }

    fn accepting(&mut self) {
        if self.failing.take() == Some(true) {
            let since = self
                .failing_said
                .map_or(0.0, |at| at.elapsed().as_secs_f64());
            tracing::warn!(
                "the live Foxglove server accepts viewers again ({since:.1} s after it could not)"
            );
        }
    }

    fn full(&mut self, peer: SocketAddr) {
        self.refused_since_said += 1;
        if due(self.full_said) {
            tracing::warn!(
                "the live Foxglove server is full ({CONNECTIONS_MAX} connections): refused \
                 {peer} ({} refused since last said)",
                self.refused_since_said
            );
            self.full_said = Some(Instant::now());
            self.refused_since_said = 0;
        }
    }
}

/// One viewer's connection: its handshake within the deadline, then the splice. Holds its
/// slot until it ends.
async fn connection(
    client: TcpStream,
    peer: SocketAddr,
    inner: Arc<Inner>,
    _slot: OwnedSemaphorePermit,
) {
    let opened = tokio::time::timeout(HANDSHAKE_DEADLINE, open(client, &inner)).await;
    let ended = match opened {
        Err(_) => Err(ConnectionEnd::Deadline(HANDSHAKE_DEADLINE)),
        Ok(Err(e)) => Err(e),
        Ok(Ok(opened)) => splice(opened).await,
    };
    match ended {
        Ok(()) => tracing::debug!("live viewer {peer} left"),
        Err(e) => tracing::info!("live viewer {peer} dropped: it {e}"),
    }
}

/// A connection whose handshake went through: the viewer, the crate's server, and the
/// viewer's bytes that came after its request.
struct Opened {
    client: TcpStream,
    server: TcpStream,
    early: Vec<u8>,
}

/// Reads the viewer's upgrade request, passes it on, and passes the answer back.
async fn open(mut client: TcpStream, inner: &Inner) -> Result<Opened, ConnectionEnd> {
    client.set_nodelay(true)?;
    let (head, early) = match read_head(&mut client).await {
        Err(ConnectionEnd::HeadTooLong) => {
            let _ = client.write_all(TOO_LONG_ANSWER).await;
            return Err(ConnectionEnd::HeadTooLong);
        }
        read => read?,
    };
    let upgrade = handshake::upgrade_request(&head);
    let mut server = inner.connect().await.map_err(ConnectionEnd::Inner)?;
    server.set_nodelay(true)?;
    server.write_all(&upgrade.head).await?;
    let (answer, after) = read_head(&mut server).await?;
    let answer = match upgrade.answer_as {
        Some(name) => handshake::answer_as(&answer, name),
        None => answer,
    };
    client.write_all(&answer).await?;
    client.write_all(&after).await?;
    Ok(Opened {
        client,
        server,
        early,
    })
}

/// An HTTP head read from `stream` (at most [`REQUEST_HEAD_MAX`] bytes), and what came after
/// it in the same reads.
async fn read_head(stream: &mut TcpStream) -> Result<(Vec<u8>, Vec<u8>), ConnectionEnd> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    loop {
        let n = stream.read(&mut chunk).await?;
        if n == 0 {
            return Err(ConnectionEnd::ClosedEarly);
        }
        let searched_from = buf.len().saturating_sub(3);
        buf.extend_from_slice(&chunk[..n]);
        if let Some(end) = handshake::head_len(&buf[searched_from..]) {
            let rest = buf.split_off(searched_from + end);
            return Ok((buf, rest));
        }
        if buf.len() > REQUEST_HEAD_MAX {
            return Err(ConnectionEnd::HeadTooLong);
        }
    }
}

/// Copies each way until either side closes or the viewer sends too long a message.
async fn splice(opened: Opened) -> Result<(), ConnectionEnd> {
    let Opened {
        client,
        server,
        early,
    } = opened;
    let (mut from_client, mut to_client) = client.into_split();
    let (mut from_server, mut to_server) = server.into_split();
    let upstream = async {
        let mut frames = ClientFrames::new(CLIENT_MESSAGE_MAX as u64);
        frames.feed(&early)?;
        to_server.write_all(&early).await?;
        let mut buf = vec![0u8; SPLICE_BUFFER];
        loop {
            let n = from_client.read(&mut buf).await?;
            if n == 0 {
                return Ok::<(), ConnectionEnd>(());
            }
            frames.feed(&buf[..n])?;
            to_server.write_all(&buf[..n]).await?;
        }
    };
    let downstream = async {
        let mut buf = vec![0u8; SPLICE_BUFFER];
        loop {
            let n = from_server.read(&mut buf).await?;
            if n == 0 {
                return Ok::<(), ConnectionEnd>(());
            }
            to_client.write_all(&buf[..n]).await?;
        }
    };
    tokio::select! {
        ended = upstream => ended,
        ended = downstream => ended,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_inner_server_whose_listener_is_gone_is_started_again() {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("a runtime");
        let context = foxglove::Context::new();
        let on = runtime.handle().clone();
        let build: BuildInner = Box::new(move || {
            WebSocketServer::new()
                .bind("127.0.0.1", 0)
                .context(&context)
                .tokio_runtime(&on)
        });
        runtime.block_on(async {
            let inner = Inner::start(build).await.expect("the inner server starts");
            let first = inner.addr();
            // Its listener dropped, as the crate does after a failed accept.
            for handle in inner.take_handles() {
                handle.stop().wait().await;
            }
            let deadline = Instant::now() + Duration::from_secs(30);
            while TcpStream::connect(first).await.is_ok() {
                assert!(
                    Instant::now() < deadline,
                    "the stopped server still listens"
                );
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
            let connected = inner.connect().await;
            assert!(connected.is_ok(), "{connected:?}");
            assert_ne!(inner.addr(), first);
            assert_eq!(
                inner.take_handles().len(),
                1,
                "the new server is kept to stop"
            );
        });
    }
}
