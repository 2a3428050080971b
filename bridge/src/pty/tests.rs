//! The pty server against misbehaving clients: junk, bad lengths, abandoned half frames,
//! clients that never read. Each test serves a real pseudo-terminal in a thread and talks to it
//! through the device, as a client process would.

use std::fs::{File, OpenOptions};
use std::io::{ErrorKind, Read, Write};
use std::os::fd::AsFd;
use std::os::unix::fs::OpenOptionsExt;
use std::sync::Arc;
use std::sync::mpsc;
use std::thread;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::brick::SimBrickConfig;
use crate::clock::MonotonicClock;
use crate::nxt::{Opcode, PARTIAL_FRAME_TIMEOUT, Port, Reply, Request, Telegram};

/// Failure bound of every wait below (a hang fails the test instead of blocking it).
const LIMIT: Duration = Duration::from_secs(5);

/// A `PtyServer` serving in a thread; stopped (and, if it returns, joined) on drop.
struct Served {
    link: PathBuf,
    stop: Arc<AtomicBool>,
    done: mpsc::Receiver<Result<ServeStats, String>>,
    thread: Option<thread::JoinHandle<()>>,
    _dir: tempfile::TempDir,
}

impl Served {
    fn start() -> Self {
        let dir = tempfile::tempdir().expect("tempdir");
        let link = dir.path().join("nxt");
        let server = PtyServer::open(&link).expect("open a pty");
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, done) = mpsc::channel();
        let flag = Arc::clone(&stop);
        let thread = thread::spawn(move || {
            let mut brick = SimBrick::new(SimBrickConfig::default(), 5).expect("valid brick");
            let clock = MonotonicClock::new();
            let r = server
                .serve(&mut brick, &clock, None, &flag)
                .map_err(|e| e.to_string());
            let _ = tx.send(r);
        });
        Self {
            link,
            stop,
            done,
            thread: Some(thread),
            _dir: dir,
        }
    }

    /// Sets the stop flag and returns what `serve` returned; fails if it does not return.
    fn stop(mut self) -> ServeStats {
        self.stop.store(true, Ordering::SeqCst);
        let r = self
            .done
            .recv_timeout(LIMIT)
            .expect("serve returns once the stop flag is set");
        if let Some(t) = self.thread.take() {
            t.join().expect("the serving thread ends");
        }
        r.expect("serve succeeds")
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Join only a thread that has ended: a hung server must fail its test, not block it.
        if self.done.recv_timeout(LIMIT).is_ok()
            && let Some(t) = self.thread.take()
        {
            let _ = t.join();
        }
    }
}

/// A client of the device, reading replies with its own resynchronising decoder.
struct Client {
    file: File,
    decoder: FrameDecoder,
    /// Bytes read but not yet decoded (what followed the last reply returned).
    unread: Vec<u8>,
}

impl Client {
    fn open(link: &Path) -> Self {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc_flags())
            .open(link)
            .expect("open the pty slave");
        Self {
            file,
            decoder: FrameDecoder::replies(),
            unread: Vec::new(),
        }
    }

    /// Writes all of `bytes`, waiting for room (bounded by `LIMIT`).
    fn send(&mut self, bytes: &[u8]) {
        let end = Instant::now() + LIMIT;
        let mut rest = bytes;
        while !rest.is_empty() {
            match self.file.write(rest) {
                Ok(n) => rest = &rest[n..],
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    assert!(Instant::now() < end, "the device never took the bytes");
                    let mut fds = [PollFd::new(self.file.as_fd(), PollFlags::POLLOUT)];
                    let _ = poll(&mut fds, PollTimeout::from(10u16));
                }
                Err(e) => panic!("write: {e}"),
            }
        }
    }

    /// The next reply telegram within `within`, skipping junk.
    fn next_reply(&mut self, within: Duration) -> Option<Telegram> {
        let end = Instant::now() + within;
        let mut buf = [0u8; 256];
        loop {
            let now = Instant::now();
            while !self.unread.is_empty() {
                let b = self.unread.remove(0);
                if let Some(Ok(t)) = self.decoder.push_at(b, now) {
                    return Some(t);
                }
            }
            if now >= end {
                return None;
            }
            let mut fds = [PollFd::new(self.file.as_fd(), PollFlags::POLLIN)];
            let _ = poll(&mut fds, poll_timeout(end - now));
            match self.file.read(&mut buf) {
                Ok(n) => self.unread.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => {}
                Err(e) => panic!("read: {e}"),
            }
        }
    }

    /// The successful reply to `op` within `within`, skipping replies to other opcodes and
    /// error replies (which answer a mangled request, as `Transport::request` treats them).
    fn reply_to(&mut self, op: Opcode, within: Duration) -> Option<Reply> {
        let end = Instant::now() + within;
        while let Some(t) = self.next_reply(end.saturating_duration_since(Instant::now())) {
            if t.opcode() == op as u8 {
                let r = Reply::decode(t.as_bytes()).expect("the brick's replies decode");
                if r.status().is_success() {
                    return Some(r);
                }
            }
        }
        None
    }

    /// Asks `req` until answered, resending after 300 ms without a reply like a client's
    /// timeout (longer than the server's partial-frame timeout); fails after `LIMIT`.
    fn ask(&mut self, req: &Request) -> Reply {
        let end = Instant::now() + LIMIT;
        let frame = req.encode(true).to_frame();
        while Instant::now() < end {
            self.send(frame.as_bytes());
            if let Some(r) = self.reply_to(req.opcode(), Duration::from_millis(300)) {
                return r;
            }
        }
        panic!("no reply to {:?} within {LIMIT:?}", req.opcode());
    }
}

fn libc_flags() -> i32 {
    (OFlag::O_NOCTTY | OFlag::O_NONBLOCK).bits()
}

fn battery_frame() -> Vec<u8> {
    Request::GetBatteryLevel
        .encode(true)
        .to_frame()
        .as_bytes()
        .to_vec()
}

fn is_battery(r: Option<Reply>) -> bool {
    matches!(r, Some(Reply::BatteryLevel { millivolts, .. }) if millivolts > 7000)
}

#[test]
fn a_stray_byte_does_not_lose_sync() {
    let served = Served::start();
    // 0x05 and 0x02 look like lengths; neither is followed by a request type byte.
    for stray in [0x42u8, 0x05, 0x02, 0x00] {
        let mut c = Client::open(&served.link);
        c.send(&[stray]);
        c.send(&battery_frame());
        // Answered at the first try, and the first reply is the battery's.
        let t = c.next_reply(LIMIT).expect("a reply");
        assert_eq!(
            t.opcode(),
            Opcode::GetBatteryLevel as u8,
            "stray 0x{stray:02X}"
        );
    }
    // A later client is answered too.
    let mut c = Client::open(&served.link);
    assert!(is_battery(c.ask(&Request::GetBatteryLevel).into()));
    let stats = served.stop();
    // Each stray byte was skipped as a bad header, or dropped with its client's open when it
    // was read apart from the request.
    assert!(stats.bad_frames + stats.stale_frames >= 4, "{stats:?}");
    assert_eq!((stats.telegrams, stats.replies), (5, 5), "{stats:?}");
}

#[test]
fn an_abandoned_half_frame_then_a_new_client_is_answered() {
    let served = Served::start();
    let half = &Request::GetOutputState { port: Port::C }
        .encode(true)
        .to_frame()
        .as_bytes()[..4]
        .to_vec();
    {
        let mut a = Client::open(&served.link);
        a.send(half);
    } // a closes with half a frame sent
    // A new client process comes milliseconds later, not microseconds: let the pty deliver
    // the half frame first (a client that comes sooner gets its retry answered).
    thread::sleep(Duration::from_millis(20));
    let mut b = Client::open(&served.link);
    match b.ask(&Request::GetOutputState { port: Port::B }) {
        Reply::OutputState { state, .. } => assert_eq!(state.port, Port::B),
        other => panic!("unexpected {other:?}"),
    }
    drop(b);
    let stats = served.stop();
    // Dropped as stale when the server read the half frame before the new client's request
    // (the usual case); skipped as junk by the retry when both came in one read.
    assert!(stats.stale_frames + stats.bad_frames >= 1, "{stats:?}");
    assert!(stats.clients >= 2, "inotify sees the clients: {stats:?}");
}

#[test]
fn an_abandoned_half_frame_is_dropped_after_the_timeout() {
    let served = Served::start();
    let mut c = Client::open(&served.link);
    // Junk ending inside a plausible GETOUTPUTSTATE body: it takes whatever comes next...
    c.send(&[0x03, 0x00, 0x00, 0x06]);
    // ...until the timeout; then the same client's request is answered at the first try.
    thread::sleep(PARTIAL_FRAME_TIMEOUT + Duration::from_millis(50));
    c.send(&battery_frame());
    assert!(is_battery(c.reply_to(Opcode::GetBatteryLevel, LIMIT)));
    drop(c);
    let stats = served.stop();
    assert_eq!(stats.stale_frames, 1, "{stats:?}");
    assert_eq!(stats.telegrams, 1, "{stats:?}");
}

/// `bad` then a GETBATTERYLEVEL request, sent in one write: only the request is answered, and
/// the server counts at least `bad_frames` bad frames.
fn only_the_request_after_is_answered(bad: &[u8], bad_frames: u64) {
    let served = Served::start();
    let mut c = Client::open(&served.link);
    let mut bytes = bad.to_vec();
    bytes.extend(battery_frame());
    c.send(&bytes);
    let t = c.next_reply(LIMIT).expect("a reply");
    assert_eq!(
        t.opcode(),
        Opcode::GetBatteryLevel as u8,
        "no reply to the bad frame"
    );
    drop(c);
    let stats = served.stop();
    assert!(stats.bad_frames >= bad_frames, "{stats:?}");
    assert_eq!((stats.telegrams, stats.replies), (1, 1), "{stats:?}");
}

#[test]
fn a_zero_length_header_gets_no_reply_and_is_skipped() {
    only_the_request_after_is_answered(&[0x00, 0x00], 1);
}

#[test]
fn a_length_over_64_gets_no_reply_and_is_skipped() {
    // Length 65 with 65 body bytes, then 0xFFFF, then the request.
    let mut bad = vec![0x41, 0x00];
    bad.extend([0xAA; 65]);
    bad.extend([0xFF, 0xFF]);
    only_the_request_after_is_answered(&bad, 2);
}

#[test]
fn well_framed_bad_telegrams_get_error_statuses() {
    let served = Served::start();
    let mut c = Client::open(&served.link);
    // Unknown opcode: 0xBE. Body too short for GETOUTPUTSTATE: 0xBF.
    c.send(&[0x02, 0x00, 0x00, 0x7E]);
    assert_eq!(
        c.next_reply(LIMIT).expect("a reply").as_bytes(),
        &[0x02, 0x7E, 0xBE]
    );
    c.send(&[0x02, 0x00, 0x00, 0x06]);
    assert_eq!(
        c.next_reply(LIMIT).expect("a reply").as_bytes(),
        &[0x02, 0x06, 0xBF]
    );
    // A type byte alone has no opcode to answer: no reply, and the next request is answered.
    c.send(&[0x01, 0x00, 0x00]);
    c.send(&battery_frame());
    let t = c.next_reply(LIMIT).expect("a reply");
    assert_eq!(t.opcode(), Opcode::GetBatteryLevel as u8);
}

/// Floods the device with GETOUTPUTSTATE requests and never reads, until `quit` (or the pty
/// closes); returns the bytes written.
fn flood(link: &Path, quit: Arc<AtomicBool>) -> thread::JoinHandle<usize> {
    let mut a = Client::open(link);
    thread::spawn(move || {
        let frame = Request::GetOutputState { port: Port::A }
            .encode(true)
            .to_frame();
        let chunk: Vec<u8> = frame.as_bytes().repeat(200);
        let mut sent = 0usize;
        let mut rest: &[u8] = &[];
        while !quit.load(Ordering::SeqCst) {
            if rest.is_empty() {
                rest = &chunk;
            }
            // Frames stay whole: a short write is finished before the next chunk.
            match a.file.write(rest) {
                Ok(n) => {
                    sent += n;
                    rest = &rest[n..];
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    thread::sleep(Duration::from_millis(1));
                }
                // The server is gone (the pty closed): the flood is over.
                Err(_) => break,
            }
        }
        sent
    })
}

#[test]
fn a_client_that_never_reads_replies_cannot_wedge_serve() {
    let served = Served::start();
    // A client floods requests and never reads; then it goes away.
    let quit = Arc::new(AtomicBool::new(false));
    let a = flood(&served.link, Arc::clone(&quit));
    thread::sleep(Duration::from_millis(300));
    quit.store(true, Ordering::SeqCst);
    assert!(a.join().expect("the flooder ends") > 0);
    // The next client is answered.
    let mut b = Client::open(&served.link);
    assert!(is_battery(b.ask(&Request::GetBatteryLevel).into()));
    drop(b);
    // The stop flag ends serve while another flood goes on.
    let quit = Arc::new(AtomicBool::new(false));
    let c = flood(&served.link, Arc::clone(&quit));
    thread::sleep(Duration::from_millis(200));
    let stats = served.stop();
    quit.store(true, Ordering::SeqCst);
    let _ = c.join();
    assert!(stats.replies_dropped > 0, "{stats:?}");
    assert!(stats.telegrams > stats.replies, "{stats:?}");
}

#[test]
fn junk_then_a_request_is_answered() {
    let served = Served::start();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut c = Client::open(&served.link);
    for round in 0..12 {
        let len = rng.random_range(0..300usize);
        let mut junk: Vec<u8> = (0..len).map(|_| rng.random::<u8>()).collect();
        if round % 3 == 0 {
            // The worst case: junk ending inside a plausible body.
            junk.extend([0x0A, 0x00, 0x00, 0x04]);
        }
        c.send(&junk);
        let reply = if round % 2 == 0 {
            c.ask(&Request::GetOutputState { port: Port::C })
        } else {
            c.ask(&Request::GetBatteryLevel)
        };
        match reply {
            Reply::OutputState { state, .. } => assert_eq!(state.port, Port::C),
            Reply::BatteryLevel { millivolts, .. } => assert!(millivolts > 7000),
            other => panic!("round {round}: unexpected {other:?}"),
        }
    }
    drop(c);
    let stats = served.stop();
    assert!(stats.skipped_bytes > 0, "{stats:?}");
}
