//! The live server as viewers and hostile clients meet it on a loopback port: both names of
//! the protocol are served the same channels, and what a client does (half a handshake, too
//! many connections, a message too long, never reading) costs the server a bounded amount
//! and never holds up its stop.
//!
//! Clients are tungstenite's (the WebSocket library the `foxglove` crate's own server uses)
//! or raw TCP sockets for what no library sends.

use std::collections::BTreeSet;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use serde_json::Value;
use tes_runtime::background::{LAG_LIMIT, can_restore};
use tes_runtime::test_support::CpuHogs;
use tes_viewer::canvas::{Canvas, Drawing};
use tes_viewer::live::handshake::{SDK_V1, WEBSOCKET_V1};
use tes_viewer::live::{
    CLIENT_MESSAGE_MAX, CONNECTIONS_MAX, HANDSHAKE_DEADLINE, LiveServer, STOP_WAIT,
};
use tes_viewer::scene::{LOG, Scene, SceneSettings};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::{self, Message, WebSocket};

/// Generous for anything that should take a moment on a loaded machine.
const PATIENCE: Duration = Duration::from_secs(60);

fn start() -> (LiveServer, Scene) {
    let scene = Scene::new(SceneSettings::default());
    let server = LiveServer::start("127.0.0.1:0".parse().expect("an address"), scene.channels())
        .expect("the live server starts");
    (server, scene)
}

/// A tungstenite client offering `protocol`, and the protocol the server answered with.
fn viewer(addr: SocketAddr, protocol: &str) -> (WebSocket<TcpStream>, String) {
    let mut request = format!("ws://{addr}")
        .into_client_request()
        .expect("a request");
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_str(protocol).expect("a header"),
    );
    let stream = TcpStream::connect(addr).expect("connects");
    stream
        .set_read_timeout(Some(PATIENCE))
        .expect("a read timeout");
    let (ws, response) = tungstenite::client::client(request, stream).expect("upgraded");
    let chosen = response
        .headers()
        .get("sec-websocket-protocol")
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default()
        .to_owned();
    (ws, chosen)
}

/// The channels the server advertises to `ws`: topic → id.
fn advertised(ws: &mut WebSocket<TcpStream>, count: usize) -> Vec<(String, u64)> {
    let mut channels = Vec::new();
    while channels.len() < count {
        let Message::Text(text) = ws.read().expect("a message") else {
            continue;
        };
        let json: Value = serde_json::from_str(&text).expect("JSON");
        if json["op"] != "advertise" {
            continue;
        }
        for c in json["channels"].as_array().expect("channels") {
            let topic = c["topic"].as_str().expect("a topic").to_owned();
            channels.push((topic, c["id"].as_u64().expect("an id")));
        }
    }
    channels
}

fn subscribe(ws: &mut WebSocket<TcpStream>, subscription: u64, channel: u64) {
    let request = serde_json::json!({
        "op": "subscribe",
        "subscriptions": [{"id": subscription, "channelId": channel}],
    });
    ws.send(Message::text(request.to_string()))
        .expect("subscribes");
}

/// Draws `data` on `/log` until `ws` receives it on `subscription` (the subscription is taken
/// by the server's own thread, a moment after it is sent).
fn received_drawn(
    server: &mut LiveServer,
    scene: &Scene,
    ws: &mut WebSocket<TcpStream>,
    subscription: u32,
    data: &[u8],
) -> bool {
    let log = scene
        .channels()
        .find(|c| c.topic == LOG)
        .expect("a /log channel");
    ws.get_ref()
        .set_read_timeout(Some(Duration::from_millis(50)))
        .expect("a read timeout");
    let deadline = Instant::now() + PATIENCE;
    while Instant::now() < deadline {
        let Ok(()) = server.draw(Drawing {
            channel: log,
            data,
            stamp_ns: 1,
            wall_ns: 1,
            motion: false,
        });
        loop {
            match ws.read() {
                Ok(Message::Binary(m)) => {
                    let sub = u32::from_le_bytes([m[1], m[2], m[3], m[4]]);
                    if m[0] == 1 && sub == subscription && &m[13..] == data {
                        return true;
                    }
                }
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) =>
                {
                    break;
                }
                Err(e) => panic!("the viewer's connection failed: {e}"),
            }
        }
    }
    false
}

#[test]
fn a_client_offering_the_published_protocol_name_gets_what_an_sdk_client_gets() {
    let (mut server, scene) = start();
    let topics: BTreeSet<String> = scene.channels().map(|c| c.topic.to_owned()).collect();
    for name in [SDK_V1, WEBSOCKET_V1] {
        let (mut ws, chosen) = viewer(server.addr(), name);
        assert_eq!(chosen, name, "the answer names the protocol offered");
        let channels = advertised(&mut ws, topics.len());
        let seen: BTreeSet<String> = channels.iter().map(|(t, _)| t.clone()).collect();
        assert_eq!(seen, topics, "{name}");
        let log = channels
            .iter()
            .find(|(t, _)| t == LOG)
            .map(|&(_, id)| id)
            .expect("/log");
        subscribe(&mut ws, 7, log);
        let data = format!("a line for a {name} client");
        assert!(
            received_drawn(&mut server, &scene, &mut ws, 7, data.as_bytes()),
            "{name}: no message in {PATIENCE:?}"
        );
    }
    // A client offering a protocol neither name covers is still refused.
    let mut request = format!("ws://{}", server.addr())
        .into_client_request()
        .expect("a request");
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_static("chat.v2"),
    );
    let stream = TcpStream::connect(server.addr()).expect("connects");
    match tungstenite::client::client(request, stream) {
        Err(tungstenite::HandshakeError::Failure(tungstenite::Error::Http(r))) => {
            assert_eq!(r.status(), 400);
        }
        Ok((_, r)) => panic!("not refused: {r:?}"),
        Err(e) => panic!("not refused with 400: {e}"),
    }
}

/// A raw connection that sends half an upgrade request and holds.
fn half_open(addr: SocketAddr) -> TcpStream {
    let mut s = TcpStream::connect(addr).expect("connects");
    s.write_all(b"GET / HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\n")
        .expect("writes half a request");
    s
}

/// Whether the server closes `s` within `limit` (reads end, or the connection is reset).
fn closed_within(s: &mut TcpStream, limit: Duration) -> bool {
    s.set_read_timeout(Some(limit)).expect("a read timeout");
    let mut buf = [0u8; 4096];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return true,
            Ok(_) => {}
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                return false;
            }
            Err(_) => return true,
        }
    }
}

#[test]
fn half_open_handshakes_fill_at_most_the_cap_and_are_closed_at_the_deadline() {
    let (server, _scene) = start();
    let addr = server.addr();
    let mut held: Vec<TcpStream> = (0..CONNECTIONS_MAX).map(|_| half_open(addr)).collect();
    // One more than the cap is told so and closed at once.
    let mut extra = half_open(addr);
    extra
        .set_read_timeout(Some(PATIENCE))
        .expect("a read timeout");
    let mut answer = Vec::new();
    // What arrived before the close, whether it ended with a FIN or a reset.
    let _ = extra.read_to_end(&mut answer);
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer:?}");
    // Each held one is closed at the handshake deadline (with wide slack for a loaded
    // machine), and the slots are free again.
    for s in &mut held {
        assert!(closed_within(s, HANDSHAKE_DEADLINE + PATIENCE));
    }
    let (mut ws, _) = viewer(addr, SDK_V1);
    assert!(!advertised(&mut ws, 1).is_empty());
}

/// A raw connection through a whole upgrade offering `foxglove.sdk.v1`.
fn upgraded_raw(addr: SocketAddr) -> TcpStream {
    let mut s = TcpStream::connect(addr).expect("connects");
    let request = format!(
        "GET / HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
         Sec-WebSocket-Protocol: {SDK_V1}\r\n\r\n"
    );
    s.write_all(request.as_bytes()).expect("writes the request");
    s.set_read_timeout(Some(PATIENCE)).expect("a read timeout");
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") {
        s.read_exact(&mut byte).expect("reads the answer");
        head.push(byte[0]);
    }
    assert!(head.starts_with(b"HTTP/1.1 101"), "{head:?}");
    s
}

/// The header of a masked, non-final binary frame announcing `len` bytes.
fn fragment_header(opcode: u8, len: u64) -> Vec<u8> {
    let mut h = vec![opcode, 0x80 | 127];
    h.extend_from_slice(&len.to_be_bytes());
    h.extend_from_slice(&[1, 2, 3, 4]);
    h
}

#[test]
fn a_message_longer_than_allowed_ends_only_its_own_connection() {
    let (mut server, scene) = start();
    let addr = server.addr();
    let (mut ws, _) = viewer(addr, SDK_V1);
    let log = advertised(&mut ws, scene.channels().count())
        .into_iter()
        .find(|(t, _)| t == LOG)
        .map(|(_, id)| id)
        .expect("/log");
    subscribe(&mut ws, 1, log);
    // One fragment of 7 MiB announced (7 of 8 of a 56 MiB message), and its bytes following.
    let mut greedy = upgraded_raw(addr);
    greedy
        .write_all(&fragment_header(0x02, 7 << 20))
        .expect("writes a header");
    let payload = vec![0u8; 1 << 20];
    for _ in 0..7 {
        if greedy.write_all(&payload).is_err() {
            break;
        }
    }
    assert!(closed_within(&mut greedy, PATIENCE));
    // Fragments that add up past the limit, each small, are caught too.
    let mut piecemeal = upgraded_raw(addr);
    let piece = CLIENT_MESSAGE_MAX as u64 / 4;
    for opcode in [0x02, 0x00, 0x00, 0x00, 0x00] {
        let mut frame = fragment_header(opcode, piece);
        frame.resize(frame.len() + piece as usize, 0);
        if piecemeal.write_all(&frame).is_err() {
            break;
        }
    }
    assert!(closed_within(&mut piecemeal, PATIENCE));
    // The viewer beside them is still served.
    assert!(received_drawn(
        &mut server,
        &scene,
        &mut ws,
        1,
        b"still here"
    ));
}

#[test]
fn stopping_takes_a_bounded_time_whatever_the_clients_do() {
    let (mut server, scene) = start();
    let addr = server.addr();
    let _half_open: Vec<TcpStream> = (0..4).map(|_| half_open(addr)).collect();
    // A viewer subscribed to everything that never reads, with the server drawing for it
    // until its queue is full.
    let (mut idle, _) = viewer(addr, SDK_V1);
    let channels = advertised(&mut idle, scene.channels().count());
    for (n, (_, id)) in channels.iter().enumerate() {
        subscribe(&mut idle, n as u64, *id);
    }
    let log = scene
        .channels()
        .find(|c| c.topic == LOG)
        .expect("a /log channel");
    let line = vec![b'x'; 4096];
    for _ in 0..4096 {
        let Ok(()) = server.draw(Drawing {
            channel: log,
            data: &line,
            stamp_ns: 1,
            wall_ns: 1,
            motion: false,
        });
    }
    // A client holding 3 of 4 fragments of a message within the limit.
    let mut holding = upgraded_raw(addr);
    let piece = CLIENT_MESSAGE_MAX as u64 / 4;
    for opcode in [0x02, 0x00, 0x00] {
        let mut frame = fragment_header(opcode, piece);
        frame.resize(frame.len() + piece as usize, 0);
        holding.write_all(&frame).expect("writes a fragment");
    }
    let began = Instant::now();
    server.stop();
    let took = began.elapsed();
    // Its own bound is twice STOP_WAIT; the slack is for a loaded machine.
    assert!(took < 2 * STOP_WAIT + PATIENCE, "stopping took {took:?}");
    drop(idle);
}

/// The scheduling policy of each of this process's threads named `name`.
fn policies_of_threads_named(name: &str) -> Vec<i32> {
    let tasks = std::fs::read_dir("/proc/self/task").expect("this process's threads");
    tasks
        .filter_map(|t| {
            let t = t.ok()?;
            let comm = std::fs::read_to_string(t.path().join("comm")).ok()?;
            let tid: libc::pid_t = t.file_name().to_str()?.parse().ok()?;
            // SAFETY: a query on a thread id of this process.
            (comm.trim() == name).then(|| unsafe { libc::sched_getscheduler(tid) })
        })
        .collect()
}

/// The server's threads run under `SCHED_IDLE`; with every core busy at normal priority they
/// would get almost no CPU and a viewer's handshake would time out. Their watcher raises them
/// back to normal scheduling once their beat is late (where this process may), and a viewer
/// is then served as on an idle machine.
#[test]
fn under_a_cpu_hog_the_servers_threads_are_raised_and_a_viewer_is_served() {
    let (mut server, scene) = start();
    let idle_before = policies_of_threads_named("foxglove");
    assert!(
        !idle_before.is_empty(),
        "the server's threads are named foxglove"
    );
    let hogs = CpuHogs::two_per_core();
    // Long enough for the beat to be late by the limit under the hog.
    std::thread::sleep(LAG_LIMIT * 5);
    let (mut ws, chosen) = viewer(server.addr(), SDK_V1);
    assert_eq!(chosen, SDK_V1);
    let channels = advertised(&mut ws, scene.channels().count());
    let log = channels
        .iter()
        .find(|(t, _)| t == LOG)
        .map(|&(_, id)| id)
        .expect("/log");
    subscribe(&mut ws, 3, log);
    assert!(
        received_drawn(&mut server, &scene, &mut ws, 3, b"a line under load"),
        "no message in {PATIENCE:?}"
    );
    let after = policies_of_threads_named("foxglove");
    drop(hogs);
    if can_restore() && idle_before.contains(&libc::SCHED_IDLE) {
        assert!(
            after.iter().all(|&p| p == libc::SCHED_OTHER),
            "raised to SCHED_OTHER ({}): {after:?}",
            libc::SCHED_OTHER
        );
    }
}
