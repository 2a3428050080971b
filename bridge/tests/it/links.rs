//! The Bluetooth and USB links end to end against the simulated brick, each through an
//! in-memory pipe with its own framing: the Bluetooth link's byte stream (the same
//! [`StreamConnection`] an RFCOMM socket uses, over a tokio in-memory duplex) with 2-byte
//! lengths, and the USB link's packets (one telegram each, no length). Both meet junk, a
//! partial reply and the brick closing the link mid-reply, and recover as the serial link does.

use std::io::ErrorKind;
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, channel};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tes_bridge::brick::{SimBrick, SimBrickConfig};
use tes_bridge::nxt::{FrameDecoder, Reply, Request, Status, Telegram};
use tes_bridge::transport::link::{Connection, Device, Framing, OpenFailure};
use tes_bridge::transport::{
    LinkTiming, LinkTransport, StreamConnection, Transport, TransportError,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

/// What the brick does with the n-th request it answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fault {
    /// Answers.
    None,
    /// Sends junk first (bytes that are no frame; on USB, packets that are no reply), then
    /// answers.
    Junk,
    /// Sends the first half of its reply and no more.
    Partial,
    /// Sends the first half of its reply and closes the link.
    CloseMidReply,
}

/// The simulated brick behind a pipe, shared by every connection to it, with the faults to
/// play, one per request (then none).
#[derive(Clone)]
struct Brick {
    brick: Arc<Mutex<SimBrick>>,
    faults: Arc<Mutex<std::vec::IntoIter<Fault>>>,
}

impl Brick {
    fn new(faults: Vec<Fault>) -> Self {
        let brick = SimBrick::new(SimBrickConfig::default(), 3).expect("brick");
        Self {
            brick: Arc::new(Mutex::new(brick)),
            faults: Arc::new(Mutex::new(faults.into_iter())),
        }
    }

    /// The reply to `request` (if it asks for one) and the fault to play with it.
    fn answer(&self, request: &[u8]) -> Option<(Telegram, Fault)> {
        let reply = self.brick.lock().expect("brick").handle(request)?;
        let fault = self
            .faults
            .lock()
            .expect("faults")
            .next()
            .unwrap_or(Fault::None);
        Some((reply, fault))
    }
}

fn timing() -> LinkTiming {
    LinkTiming {
        read_timeout: Duration::from_millis(300),
        reconnect_backoff: Duration::from_millis(200),
        max_timeouts: 3,
    }
}

// ---- the Bluetooth link's framing: a byte stream with 2-byte lengths ----

/// A brick reached over an in-memory byte stream; each open is a new stream.
struct StreamBrick(Brick);

impl Device for StreamBrick {
    type Connection = StreamConnection<DuplexStream>;

    fn open(&mut self) -> Result<Self::Connection, OpenFailure> {
        let (client, server) = tokio::io::duplex(1024);
        let brick = self.0.clone();
        std::thread::spawn(move || serve_stream(server, &brick));
        StreamConnection::standalone(client).map_err(|e| OpenFailure::bare(e.to_string()))
    }

    fn describe(&self) -> String {
        "bluetooth:in-memory".into()
    }

    fn framing(&self) -> Framing {
        Framing::LengthPrefixed
    }
}

/// The brick's side of a byte stream: decodes requests, writes framed replies with faults.
fn serve_stream(mut stream: DuplexStream, brick: &Brick) {
    let Ok(runtime) = tokio::runtime::Builder::new_current_thread().build() else {
        return;
    };
    runtime.block_on(async move {
        let mut decoder = FrameDecoder::requests();
        let mut buf = [0u8; 256];
        while let Ok(n) = stream.read(&mut buf).await {
            if n == 0 {
                return;
            }
            for &b in &buf[..n] {
                let Some(Ok(request)) = decoder.push(b) else {
                    continue;
                };
                let Some((reply, fault)) = brick.answer(request.as_bytes()) else {
                    continue;
                };
                let frame = reply.to_frame().as_bytes().to_vec();
                let half = &frame[..frame.len() / 2];
                let sent = match fault {
                    Fault::None => stream.write_all(&frame).await,
                    Fault::Junk => {
                        let mut junky = vec![0x42, 0x00, 0x00, 0x41, 0x00, 0xFF, 0xFF, 0x05];
                        junky.extend(&frame);
                        stream.write_all(&junky).await
                    }
                    Fault::Partial => stream.write_all(half).await,
                    Fault::CloseMidReply => {
                        let _ = stream.write_all(half).await;
                        return;
                    }
                };
                if sent.is_err() {
                    return;
                }
            }
        }
    });
}

// ---- the USB link's framing: one telegram per packet ----

/// A brick reached over in-memory packet pipes; each open is a new pair.
struct PacketBrick(Brick);

/// The host's end of the packet pipes.
struct Packets {
    to_brick: Sender<Vec<u8>>,
    from_brick: Receiver<Vec<u8>>,
}

impl Device for PacketBrick {
    type Connection = Packets;

    fn open(&mut self) -> Result<Packets, OpenFailure> {
        let (to_brick, requests) = channel::<Vec<u8>>();
        let (replies, from_brick) = channel::<Vec<u8>>();
        let brick = self.0.clone();
        std::thread::spawn(move || serve_packets(&requests, &replies, &brick));
        Ok(Packets {
            to_brick,
            from_brick,
        })
    }

    fn describe(&self) -> String {
        "usb:in-memory".into()
    }

    fn framing(&self) -> Framing {
        Framing::Packets
    }
}

impl Connection for Packets {
    fn send(&mut self, frame: &[u8]) -> std::io::Result<()> {
        self.to_brick
            .send(frame.to_vec())
            .map_err(|_| std::io::Error::new(ErrorKind::BrokenPipe, "the brick went away"))
    }

    fn receive(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        match self.from_brick.recv_timeout(timeout) {
            Ok(packet) => {
                let n = packet.len().min(buf.len());
                buf[..n].copy_from_slice(&packet[..n]);
                Ok(n)
            }
            Err(RecvTimeoutError::Timeout) => Err(ErrorKind::TimedOut.into()),
            Err(RecvTimeoutError::Disconnected) => Err(std::io::Error::new(
                ErrorKind::UnexpectedEof,
                "the brick closed the link",
            )),
        }
    }

    fn discard_input(&mut self) {
        while self.from_brick.try_recv().is_ok() {}
    }
}

/// The brick's side of the packet pipes: one request per packet, one reply per packet.
fn serve_packets(requests: &Receiver<Vec<u8>>, replies: &Sender<Vec<u8>>, brick: &Brick) {
    while let Ok(request) = requests.recv() {
        let Some((reply, fault)) = brick.answer(&request) else {
            continue;
        };
        let packet = reply.as_bytes().to_vec();
        let half = packet[..packet.len() / 2].to_vec();
        let sent = match fault {
            Fault::None => replies.send(packet),
            // A packet of junk, and a reply type with no opcode: neither is a reply.
            Fault::Junk => replies
                .send(vec![0x42, 0x00, 0xFF])
                .and_then(|()| replies.send(vec![0x02]))
                .and_then(|()| replies.send(packet)),
            Fault::Partial => replies.send(half),
            Fault::CloseMidReply => {
                let _ = replies.send(half);
                return;
            }
        };
        if sent.is_err() {
            return;
        }
    }
}

// ---- the same scenarios on both links ----

fn battery<D: Device>(link: &mut LinkTransport<D>) -> Result<u16, TransportError> {
    match link.request(&Request::GetBatteryLevel)? {
        Reply::BatteryLevel {
            status: Status::Success,
            millivolts,
        } => Ok(millivolts),
        other => panic!("not a battery reading: {other:?}"),
    }
}

/// Junk before a reply is skipped; the reply is the brick's.
fn junk_is_skipped<D: Device>(device: D) {
    let mut link = LinkTransport::new(device, timing());
    let mv = battery(&mut link).expect("a reply after the junk");
    assert!(mv > 7000, "{mv}");
    assert!(link.stats().bad_frames >= 1, "{:?}", link.stats());
    assert!(battery(&mut link).expect("the next reply") > 7000);
}

/// Half a reply times out; the next request gets its own whole reply, never the old half
/// completed by new bytes.
fn a_partial_reply_times_out_and_the_next_is_whole<D: Device>(device: D) {
    let mut link = LinkTransport::new(device, timing());
    let err = battery(&mut link).expect_err("half a reply is no reply");
    assert!(matches!(err, TransportError::Timeout(_)), "{err:?}");
    assert!(err.is_link_failure());
    assert!(battery(&mut link).expect("the next reply") > 7000);
    assert_eq!(link.stats().timeouts, 1);
    assert_eq!(link.stats().connects, 1, "a timeout is no reconnection");
}

/// The brick closing the link mid-reply is a link failure; the link is reopened after the
/// back-off and answers again.
fn a_link_closed_mid_reply_is_reopened<D: Device>(device: D) {
    let mut link = LinkTransport::new(device, timing());
    let err = battery(&mut link).expect_err("the link closed");
    assert!(
        matches!(&err, TransportError::Io { error, .. } if error.kind() == ErrorKind::UnexpectedEof),
        "{err:?}"
    );
    assert!(err.is_link_failure() && !err.is_impossible());
    assert!(!link.is_connected());
    let err = battery(&mut link).expect_err("down during the back-off");
    assert!(matches!(err, TransportError::Backoff { .. }), "{err:?}");
    std::thread::sleep(timing().reconnect_backoff + Duration::from_millis(50));
    assert!(battery(&mut link).expect("answered after reconnecting") > 7000);
    assert_eq!(link.stats().connects, 2);
}

#[test]
fn bluetooth_framing_skips_junk() {
    junk_is_skipped(StreamBrick(Brick::new(vec![Fault::Junk])));
}

#[test]
fn bluetooth_framing_drops_a_partial_reply() {
    a_partial_reply_times_out_and_the_next_is_whole(StreamBrick(Brick::new(vec![Fault::Partial])));
}

#[test]
fn bluetooth_framing_reopens_a_link_closed_mid_reply() {
    a_link_closed_mid_reply_is_reopened(StreamBrick(Brick::new(vec![Fault::CloseMidReply])));
}

#[test]
fn usb_framing_skips_junk() {
    junk_is_skipped(PacketBrick(Brick::new(vec![Fault::Junk])));
}

#[test]
fn usb_framing_drops_a_partial_reply() {
    a_partial_reply_times_out_and_the_next_is_whole(PacketBrick(Brick::new(vec![Fault::Partial])));
}

#[test]
fn usb_framing_reopens_a_link_closed_mid_reply() {
    a_link_closed_mid_reply_is_reopened(PacketBrick(Brick::new(vec![Fault::CloseMidReply])));
}

/// On USB no length goes on the wire: the brick sees the bare telegram.
#[test]
fn usb_framing_sends_bare_telegrams() {
    let (to_brick, requests) = channel::<Vec<u8>>();
    let (_replies, from_brick) = channel::<Vec<u8>>();
    let mut packets = Packets {
        to_brick,
        from_brick,
    };
    struct Once(Option<Packets>);
    impl Device for Once {
        type Connection = Packets;
        fn open(&mut self) -> Result<Packets, OpenFailure> {
            self.0
                .take()
                .ok_or_else(|| OpenFailure::bare("opened once"))
        }
        fn describe(&self) -> String {
            "usb:once".into()
        }
        fn framing(&self) -> Framing {
            Framing::Packets
        }
    }
    packets.discard_input();
    let mut link = LinkTransport::new(Once(Some(packets)), timing());
    link.send(&Request::KeepAlive).expect("sent");
    let sent = requests.recv().expect("a packet");
    assert_eq!(sent, Request::KeepAlive.encode(false).as_bytes());
}
