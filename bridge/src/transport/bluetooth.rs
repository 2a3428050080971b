//! Bluetooth: a kernel RFCOMM socket straight to a paired NXT (`transport =
//! "bluetooth:ADDR"`), no `rfcomm bind` and no `/dev/rfcommN`.
//!
//! The NXT listens on RFCOMM channel 1 and frames its telegrams as on a serial link: a 2-byte
//! little-endian length, then the telegram (nxt-python's `bluetooth` backend sends and reads
//! the same). The socket comes from BlueR's `rfcomm` module (tokio streams); a current-thread
//! runtime of the link's own drives it, so the bridge's loop stays synchronous.

use std::io::ErrorKind;
use std::str::FromStr;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::runtime::Runtime;

use super::TransportError;
use super::link::{Connection, Device, Framing, LinkTiming, LinkTransport, OpenFailure};

/// The RFCOMM channel an NXT listens on.
pub const NXT_RFCOMM_CHANNEL: u8 = 1;

/// A brick's Bluetooth address and RFCOMM channel: `00:16:53:01:02:03` (channel 1) or
/// `00:16:53:01:02:03@1`.
///
/// ```
/// use tes_bridge::transport::BluetoothTarget;
///
/// let t: BluetoothTarget = "00:16:53:0a:0B:0c@2".parse()?;
/// assert_eq!(t.to_string(), "00:16:53:0A:0B:0C@2");
/// assert_eq!("00:16:53:0A:0B:0C".parse::<BluetoothTarget>()?.channel, 1);
/// assert!("00:16:53".parse::<BluetoothTarget>().is_err());
/// # Ok::<(), String>(())
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BluetoothTarget {
    /// The brick's address, most significant byte first (as written).
    pub address: [u8; 6],
    /// The RFCOMM channel (1–30).
    pub channel: u8,
}

impl FromStr for BluetoothTarget {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (address, channel) = match s.split_once('@') {
            Some((a, c)) => (a, c.parse::<u8>().ok().filter(|c| (1..=30).contains(c))),
            None => (s, Some(NXT_RFCOMM_CHANNEL)),
        };
        let channel = channel.ok_or_else(|| {
            format!("the RFCOMM channel after `@` must be 1 to 30 (the NXT's is 1), got {s:?}")
        })?;
        let bytes: Vec<u8> = address
            .split(':')
            .map(|b| {
                (b.len() == 2)
                    .then(|| u8::from_str_radix(b, 16).ok())
                    .flatten()
            })
            .collect::<Option<_>>()
            .filter(|v: &Vec<u8>| v.len() == 6)
            .ok_or_else(|| {
                format!(
                    "a Bluetooth address is six hexadecimal bytes separated by colons \
                     (e.g. 00:16:53:01:02:03, as `tes-bridge scan` or `bluetoothctl devices` \
                     lists it), got {address:?}"
                )
            })?;
        let mut out = [0u8; 6];
        out.copy_from_slice(&bytes);
        Ok(Self {
            address: out,
            channel,
        })
    }
}

impl std::fmt::Display for BluetoothTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.address;
        write!(
            f,
            "{:02X}:{:02X}:{:02X}:{:02X}:{:02X}:{:02X}@{}",
            a[0], a[1], a[2], a[3], a[4], a[5], self.channel
        )
    }
}

/// A paired NXT reached by a kernel RFCOMM socket.
#[derive(Debug)]
pub struct RfcommDevice {
    target: BluetoothTarget,
    connect_timeout: Duration,
    runtime: Arc<Runtime>,
}

impl RfcommDevice {
    /// The brick at `target`; a connection attempt gives up after `connect_timeout` (a brick
    /// out of range makes the kernel wait far longer).
    pub fn new(target: BluetoothTarget, connect_timeout: Duration) -> std::io::Result<Self> {
        Ok(Self {
            target,
            connect_timeout,
            runtime: Arc::new(link_runtime()?),
        })
    }
}

/// Talks to a brick over Bluetooth (see [`LinkTransport`] for the link's behaviour).
pub type BluetoothTransport = LinkTransport<RfcommDevice>;

impl LinkTransport<RfcommDevice> {
    /// A transport that connects to `target` at its first transaction; a connection attempt
    /// lasts at most the read timeout's double and 5 s.
    pub fn bluetooth(target: BluetoothTarget, timing: LinkTiming) -> Result<Self, TransportError> {
        let connect_timeout = (timing.read_timeout * 2).max(Duration::from_secs(5));
        let device =
            RfcommDevice::new(target, connect_timeout).map_err(|error| TransportError::Io {
                link: format!("bluetooth:{target}"),
                error,
            })?;
        Ok(Self::new(device, timing))
    }
}

impl Device for RfcommDevice {
    type Connection = StreamConnection<bluer::rfcomm::Stream>;

    fn open(&mut self) -> Result<Self::Connection, OpenFailure> {
        let address = bluer::Address::new(self.target.address);
        let socket = bluer::rfcomm::SocketAddr::new(address, self.target.channel);
        let connect = bluer::rfcomm::Stream::connect(socket);
        let stream = self
            .runtime
            .block_on(async { tokio::time::timeout(self.connect_timeout, connect).await })
            .map_err(|_| {
                OpenFailure::new(
                    format!(
                        "the brick did not answer within {:.0} s",
                        self.connect_timeout.as_secs_f64()
                    ),
                    brick_unreachable_fix(&self.target),
                )
            })?
            .map_err(|e| diagnose(&e, &self.target))?;
        Ok(StreamConnection::new(stream, Arc::clone(&self.runtime)))
    }

    fn describe(&self) -> String {
        format!("bluetooth:{}", self.target)
    }

    fn framing(&self) -> Framing {
        Framing::LengthPrefixed
    }
}

/// The runtime a link's socket runs on: one thread, the caller's.
fn link_runtime() -> std::io::Result<Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .enable_time()
        .build()
}

/// What to do when the brick does not answer.
fn brick_unreachable_fix(target: &BluetoothTarget) -> String {
    let a = target.to_string();
    let address = a.split('@').next().unwrap_or(&a);
    format!(
        "is the brick switched on, within about 10 m, and paired with this computer? \
         `bluetoothctl pair {address}` pairs it (the brick asks for a PIN: 1234 by default)"
    )
}

/// Why this machine's kernel will not give this program a Bluetooth socket at all, when that
/// is why `e` happened: no Bluetooth in the kernel (for good), or no permission. `None` for
/// every other error. Shared by a connection's [`diagnose`] and `tes-bridge scan`.
pub(crate) fn kernel_refusal(e: &std::io::Error) -> Option<OpenFailure> {
    let cause = e.to_string();
    match e.raw_os_error()? {
        libc::EAFNOSUPPORT | libc::EPROTONOSUPPORT => Some(
            OpenFailure::new(
                format!(
                    "{cause}: this machine has no Bluetooth (its kernel offers no Bluetooth \
                     sockets)"
                ),
                "use a machine with a Bluetooth adapter and the kernel's bluetooth and rfcomm \
                 modules (`modprobe rfcomm`), or reach the brick by USB: `transport = \"usb\"`",
            )
            .for_good(),
        ),
        libc::EACCES | libc::EPERM => Some(OpenFailure::new(
            format!("{cause}: not allowed to open Bluetooth sockets"),
            "run as a user allowed to use Bluetooth (on most systems, any logged-in user; \
             in a container, grant it the host's network and NET_RAW)",
        )),
        _ => None,
    }
}

/// Whether the kernel offers Bluetooth RFCOMM sockets (an error no retry cures when it has
/// none). Shared by the launch's check before anything starts and `tes-bridge scan`.
pub(crate) fn kernel_support() -> Result<(), OpenFailure> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .build()
        .map_err(|e| OpenFailure::bare(format!("cannot start the Bluetooth runtime: {e}")))?;
    runtime
        .block_on(async { bluer::rfcomm::Socket::new() })
        .map(drop)
        .map_err(|e| {
            kernel_refusal(&e).unwrap_or_else(|| {
                OpenFailure::bare(format!("cannot open a Bluetooth socket: {e}"))
            })
        })
}

/// A failed connection, said as its cause and what to do.
fn diagnose(e: &std::io::Error, target: &BluetoothTarget) -> OpenFailure {
    if let Some(refusal) = kernel_refusal(e) {
        return refusal;
    }
    let cause = e.to_string();
    match e.raw_os_error() {
        Some(libc::ENODEV) | Some(libc::EADDRNOTAVAIL) => OpenFailure::new(
            format!("{cause}: no Bluetooth adapter"),
            "plug in an adapter and check `bluetoothctl list`, or use `transport = \"usb\"`",
        ),
        Some(libc::ENETDOWN) | Some(libc::ERFKILL) => OpenFailure::new(
            format!("{cause}: the Bluetooth adapter is off"),
            "switch it on: `bluetoothctl power on` (and `rfkill unblock bluetooth` if it is blocked)",
        ),
        Some(libc::EBUSY) | Some(libc::EISCONN) => OpenFailure::new(
            format!("{cause}: the brick's link is in use"),
            "another program (an `rfcomm` binding, nxt-python, a second bridge) holds it: \
             release it first",
        ),
        Some(libc::ECONNREFUSED) => OpenFailure::new(
            format!("{cause}: the brick refused the connection"),
            format!(
                "the NXT listens on channel {}; is this the brick's address, and is it \
                 paired? {}",
                NXT_RFCOMM_CHANNEL,
                brick_unreachable_fix(target)
            ),
        ),
        Some(libc::EHOSTDOWN)
        | Some(libc::EHOSTUNREACH)
        | Some(libc::ETIMEDOUT)
        | Some(libc::ECONNRESET)
        | Some(libc::ECONNABORTED) => OpenFailure::new(
            format!("{cause}: the brick did not answer"),
            brick_unreachable_fix(target),
        ),
        _ => OpenFailure::bare(cause),
    }
}

/// A byte stream to a brick (an RFCOMM socket; in tests, an in-memory pipe), read and written
/// on the link's runtime.
pub struct StreamConnection<S> {
    stream: S,
    runtime: Arc<Runtime>,
}

impl<S> StreamConnection<S> {
    /// `stream`, driven by `runtime`.
    pub fn new(stream: S, runtime: Arc<Runtime>) -> Self {
        Self { stream, runtime }
    }

    /// A connection over `stream` with a runtime of its own.
    pub fn standalone(stream: S) -> std::io::Result<Self> {
        Ok(Self::new(stream, Arc::new(link_runtime()?)))
    }
}

impl<S: AsyncRead + AsyncWrite + Unpin> Connection for StreamConnection<S> {
    fn send(&mut self, frame: &[u8]) -> std::io::Result<()> {
        let stream = &mut self.stream;
        self.runtime.block_on(async {
            stream.write_all(frame).await?;
            stream.flush().await
        })
    }

    fn receive(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        let stream = &mut self.stream;
        let read = self
            .runtime
            .block_on(async { tokio::time::timeout(timeout, stream.read(buf)).await });
        match read {
            Err(_) => Err(ErrorKind::TimedOut.into()),
            Ok(Ok(0)) => Err(std::io::Error::new(
                ErrorKind::UnexpectedEof,
                "the brick closed the link",
            )),
            Ok(other) => other,
        }
    }

    fn discard_input(&mut self) {
        let mut buf = [0u8; 64];
        let stream = &mut self.stream;
        // Reads what is there now, without waiting: the timeout polls the read first.
        self.runtime.block_on(async {
            while let Ok(Ok(n)) = tokio::time::timeout(Duration::ZERO, stream.read(&mut buf)).await
            {
                if n == 0 {
                    break;
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    proptest! {
        /// Every address and channel reads back from its written form.
        #[test]
        fn targets_round_trip(address in any::<[u8; 6]>(), channel in 1u8..=30) {
            let target = BluetoothTarget { address, channel };
            prop_assert_eq!(target.to_string().parse::<BluetoothTarget>(), Ok(target));
        }

        /// Any text is a target or a message, never a panic.
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,40}") {
            let _ = text.parse::<BluetoothTarget>();
        }
    }

    /// Each failure is said as its cause and fix; a machine without Bluetooth is told apart
    /// (no retry can help there).
    #[test]
    fn failures_are_diagnosed() {
        let target: BluetoothTarget = "00:16:53:01:02:03".parse().expect("target");
        let said = |errno| diagnose(&std::io::Error::from_raw_os_error(errno), &target);
        let none = said(libc::EAFNOSUPPORT);
        assert!(none.impossible && none.cause.contains("this machine has no Bluetooth"));
        assert!(none.to_string().contains("transport = \"usb\""), "{none}");
        let off = said(libc::ENETDOWN);
        assert!(!off.impossible && off.to_string().contains("bluetoothctl power on"));
        let away = said(libc::EHOSTDOWN);
        assert!(
            away.to_string()
                .contains("bluetoothctl pair 00:16:53:01:02:03"),
            "{away}"
        );
        assert!(said(libc::ECONNREFUSED).to_string().contains("channel 1"));
    }
}
