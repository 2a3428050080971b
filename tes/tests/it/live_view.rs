//! `tes launch --foxglove` under clients that mean it harm: half-open WebSocket handshakes
//! held and renewed, clients sending 7 of 8 fragments of a 56 MiB message, a viewer that
//! subscribes to everything and never reads, and a launcher run out of file descriptors. The
//! launcher still ends its run on its own and on Ctrl-C within its grace period, its memory
//! stays small, and its live view says when it cannot accept and serves again afterwards.
//!
//! The clients are raw TCP sockets speaking just enough WebSocket (what no library would
//! send), so these tests need nothing installed.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;

use crate::common::*;

const LIMIT: Duration = Duration::from_secs(180);
/// The launch's grace period for its children (its default).
const GRACE: Duration = Duration::from_secs(3);
/// What the live server's stop may take (twice its `STOP_WAIT`).
const LIVE_STOP: Duration = Duration::from_secs(2);
/// Room over a bound for a loaded, shared machine.
const SLACK: Duration = Duration::from_secs(30);

/// A group serving Foxglove on a free loopback port, slow enough for clients to join during
/// its episodes; its address.
fn live_group(dir: &std::path::Path, episodes: u32) -> (Group, SocketAddr) {
    let toml = launch_file(dir, "real_time_factor = 0.1\nfoxglove = \"127.0.0.1:0\"\n");
    let group = Group::start(dir, &toml, episodes);
    let said = wait_for_lines(&group.stderr, LIMIT, "the live server's address", |seen| {
        seen.iter().any(|l| l.contains("live in Foxglove at ws://"))
    });
    let addr = said
        .iter()
        .find_map(|l| l.split("ws://").nth(1)?.split_whitespace().next())
        .and_then(|a| a.parse().ok())
        .expect("an address");
    (group, addr)
}

/// A connection that sent half an upgrade request (`None`: it could not connect).
fn half_open(addr: SocketAddr) -> Option<TcpStream> {
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(5)).ok()?;
    s.write_all(b"GET / HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\n")
        .ok()?;
    Some(s)
}

/// Whether the server has closed `s` (without waiting).
fn closed(s: &mut TcpStream) -> bool {
    let _ = s.set_nonblocking(true);
    let mut buf = [0u8; 512];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return true,
            Ok(_) => {}
            Err(e) => return e.kind() != ErrorKind::WouldBlock,
        }
    }
}

/// A thread keeping `held` half-open handshakes open against `addr`, opening new ones as
/// the server closes them, until dropped (or two minutes pass).
struct HalfOpens {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<usize>>,
}

impl HalfOpens {
    fn start(addr: SocketAddr, held: usize) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let thread = std::thread::spawn(move || {
            let until = Instant::now() + Duration::from_secs(120);
            let mut open: Vec<TcpStream> = Vec::new();
            let mut opened = 0;
            while !stopping.load(Ordering::SeqCst) && Instant::now() < until {
                open.retain_mut(|s| !closed(s));
                while open.len() < held {
                    let Some(s) = half_open(addr) else { break };
                    open.push(s);
                    opened += 1;
                }
                std::thread::sleep(Duration::from_millis(100));
            }
            opened
        });
        Self {
            stop,
            thread: Some(thread),
        }
    }

    /// Stops; how many connections it opened.
    fn end(mut self) -> usize {
        self.stop.store(true, Ordering::SeqCst);
        self.thread.take().and_then(|t| t.join().ok()).unwrap_or(0)
    }
}

impl Drop for HalfOpens {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// A connection through a whole upgrade offering `protocol` (`None`: refused, e.g. full).
fn upgraded(addr: SocketAddr, protocol: &str) -> Option<TcpStream> {
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(5)).ok()?;
    let request = format!(
        "GET / HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
         Sec-WebSocket-Protocol: {protocol}\r\n\r\n"
    );
    s.write_all(request.as_bytes()).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(60))).ok()?;
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") {
        s.read_exact(&mut byte).ok()?;
        head.push(byte[0]);
    }
    head.starts_with(b"HTTP/1.1 101").then_some(s)
}

/// The next frame the server sends: its opcode and payload.
fn read_frame(s: &mut TcpStream) -> std::io::Result<(u8, Vec<u8>)> {
    let mut h = [0u8; 2];
    s.read_exact(&mut h)?;
    let len = match h[1] & 0x7f {
        126 => {
            let mut b = [0u8; 2];
            s.read_exact(&mut b)?;
            u64::from(u16::from_be_bytes(b))
        }
        127 => {
            let mut b = [0u8; 8];
            s.read_exact(&mut b)?;
            u64::from_be_bytes(b)
        }
        n => u64::from(n),
    };
    let mut payload = vec![0u8; usize::try_from(len).expect("a frame that fits")];
    s.read_exact(&mut payload)?;
    Ok((h[0] & 0x0f, payload))
}

/// A masked text frame, as a client sends it.
fn write_text(s: &mut TcpStream, text: &str) -> std::io::Result<()> {
    let mask = [7u8, 1, 9, 3];
    let len = text.len();
    let mut f = vec![0x81];
    if len < 126 {
        f.push(0x80 | len as u8);
    } else {
        f.push(0x80 | 126);
        f.extend_from_slice(&(len as u16).to_be_bytes());
    }
    f.extend_from_slice(&mask);
    f.extend(text.bytes().enumerate().map(|(i, b)| b ^ mask[i % 4]));
    s.write_all(&f)
}

/// The channels advertised on `s`, by topic and id (reads until `count` are seen).
fn advertised(s: &mut TcpStream, count: usize) -> Vec<(String, u64)> {
    let mut channels = Vec::new();
    while channels.len() < count {
        let (opcode, payload) = read_frame(s).expect("a frame");
        if opcode != 1 {
            continue;
        }
        let json: Value = serde_json::from_slice(&payload).expect("JSON");
        if json["op"] == "advertise" {
            for c in json["channels"].as_array().expect("channels") {
                let topic = c["topic"].as_str().expect("a topic").to_owned();
                channels.push((topic, c["id"].as_u64().expect("an id")));
            }
        }
    }
    channels
}

/// The scene's channels, advertised to every viewer.
const CHANNELS: usize = 12;

/// A viewer that subscribes to every channel and never reads again.
fn non_reader(addr: SocketAddr) -> TcpStream {
    let mut s = upgraded(addr, "foxglove.sdk.v1").expect("the live server takes a viewer");
    let subscriptions: Vec<Value> = advertised(&mut s, CHANNELS)
        .iter()
        .enumerate()
        .map(|(n, (_, id))| serde_json::json!({"id": n, "channelId": id}))
        .collect();
    let request = serde_json::json!({"op": "subscribe", "subscriptions": subscriptions});
    write_text(&mut s, &request.to_string()).expect("subscribes");
    s
}

/// Greedy clients: each sends 7 of 8 fragments of a 56 MiB binary message (or as much as
/// the server takes), counts itself in `sent`, and holds its connection until `hold` is over.
struct Greedy {
    sent: Arc<AtomicUsize>,
    hold: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl Greedy {
    fn start(addr: SocketAddr, clients: usize) -> Self {
        let (sent, hold) = (
            Arc::new(AtomicUsize::new(0)),
            Arc::new(AtomicBool::new(true)),
        );
        let threads = (0..clients)
            .map(|_| {
                let (sent, hold) = (sent.clone(), hold.clone());
                std::thread::spawn(move || {
                    let connection = upgraded(addr, "foxglove.sdk.v1").map(send_seven_eighths);
                    sent.fetch_add(1, Ordering::SeqCst);
                    while hold.load(Ordering::SeqCst) {
                        std::thread::sleep(Duration::from_millis(50));
                    }
                    drop(connection);
                })
            })
            .collect();
        Self {
            sent,
            hold,
            threads,
        }
    }

    fn all_sent(&self) -> bool {
        self.sent.load(Ordering::SeqCst) == self.threads.len()
    }
}

impl Drop for Greedy {
    fn drop(&mut self) {
        self.hold.store(false, Ordering::SeqCst);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Sends 7 fragments of 7 MiB each, as far as the server takes them.
fn send_seven_eighths(mut s: TcpStream) -> TcpStream {
    let fragment = vec![0u8; 7 << 20];
    for n in 0..7u8 {
        let mut header = vec![if n == 0 { 0x02 } else { 0x00 }, 0x80 | 127];
        header.extend_from_slice(&(fragment.len() as u64).to_be_bytes());
        header.extend_from_slice(&[1, 2, 3, 4]);
        if s.write_all(&header).is_err() || s.write_all(&fragment).is_err() {
            break;
        }
    }
    s
}

/// The launcher's resident memory, in bytes.
fn rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("its status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .expect("VmRSS")
        * 1024
}

#[test]
fn a_launcher_ends_its_run_on_its_own_whatever_live_clients_hold() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (mut group, addr) = live_group(dir.path(), 3);
    let _idle = non_reader(addr);
    let attack = HalfOpens::start(addr, 300);
    group.wait_for_episodes(3, LIMIT);
    let ended = Instant::now();
    let (ok, out, err) = group.finish(GRACE + LIVE_STOP + SLACK);
    let took = ended.elapsed();
    let opened = attack.end();
    assert!(ok, "the launch failed: {out:?} {err:?}");
    assert!(
        opened >= 300,
        "the attack was under way: {opened} connections"
    );
    eprintln!("exited {took:?} after its last episode, {opened} half-open connections opened");
}

#[test]
fn a_launcher_stops_on_ctrl_c_with_small_memory_whatever_live_clients_send() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (mut group, addr) = live_group(dir.path(), 400);
    let pid = group.launcher.id();
    let before = rss(pid);
    let _idle = non_reader(addr);
    // 30 greedy clients at once (the connection cap refuses some), memory sampled meanwhile.
    let greedy = Greedy::start(addr, 30);
    let mut peak = before;
    let deadline = Instant::now() + LIMIT;
    while !greedy.all_sent() && Instant::now() < deadline {
        peak = peak.max(rss(pid));
        std::thread::sleep(Duration::from_millis(20));
    }
    let attack = HalfOpens::start(addr, 300);
    group.wait_for_episodes(1, LIMIT);
    for _ in 0..50 {
        peak = peak.max(rss(pid));
        std::thread::sleep(Duration::from_millis(20));
    }
    kill(Pid::from_raw(pid as i32), Signal::SIGINT).expect("SIGINT");
    let asked = Instant::now();
    let (ok, out, err) = group.finish(GRACE + LIVE_STOP + SLACK);
    let took = asked.elapsed();
    drop(greedy);
    attack.end();
    assert!(ok, "the group stopped cleanly on Ctrl-C: {out:?} {err:?}");
    assert!(
        peak < 300 << 20,
        "the launcher grew from {} MiB to {} MiB",
        before >> 20,
        peak >> 20
    );
    eprintln!(
        "RSS {} MiB before, {} MiB at most under attack; exited {took:?} after SIGINT",
        before >> 20,
        peak >> 20
    );
}

/// The launcher's open file descriptors.
fn open_fds(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .expect("its fds")
        .count()
}

#[test]
fn a_launcher_out_of_file_descriptors_says_so_once_and_serves_viewers_again() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (mut group, addr) = live_group(dir.path(), 400);
    let pid = group.launcher.id();
    group.wait_for_episodes(1, LIMIT);
    // Room for a few connections more than the launcher holds now: a served viewer takes 3
    // (its socket, the door's to the inner server, the inner server's).
    let limit = open_fds(pid) + 8;
    let set = Command::new("prlimit")
        .args([
            "--pid",
            &pid.to_string(),
            &format!("--nofile={limit}:{limit}"),
        ])
        .status()
        .expect("prlimit runs");
    assert!(set.success(), "prlimit --pid {pid} --nofile={limit}");
    // Many half-open handshakes at once: the launcher runs out of descriptors.
    let attack: Vec<TcpStream> = (0..64).filter_map(|_| half_open(addr)).collect();
    let said = group.wait_for_stderr("cannot accept viewers", LIMIT);
    drop(attack);
    let again = group.wait_for_stderr("accepts viewers again", LIMIT);
    // Served again, under the same low limit.
    let mut viewer = upgraded(addr, "foxglove.sdk.v1").expect("a viewer is served again");
    assert_eq!(advertised(&mut viewer, CHANNELS).len(), CHANNELS);
    drop(viewer);
    kill(Pid::from_raw(pid as i32), Signal::SIGINT).expect("SIGINT");
    let (ok, out, err) = group.finish(LIMIT);
    assert!(ok, "the group stopped cleanly on Ctrl-C: {out:?} {err:?}");
    let notices: Vec<&String> = said
        .iter()
        .chain(&again)
        .chain(&err)
        .filter(|l| l.contains("live Foxglove server"))
        .collect();
    let told = notices
        .iter()
        .filter(|l| l.contains("cannot accept viewers"))
        .count();
    assert_eq!(told, 1, "{notices:?}");
    eprintln!("under --nofile={limit}: {notices:#?}");
}
