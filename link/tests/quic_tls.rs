//! The link's QUIC (TLS 1.3) and access control, between Zenoh sessions on loopback configured as
//! launches configure theirs ([`LinkSection::zenoh_config`]): members of the group's
//! authority talk; a certificate of another authority never connects; a member whose
//! certificate does not name the controller cannot send commands.

use std::net::UdpSocket;
use std::path::Path;
use std::sync::mpsc;
use std::time::Duration;

use tes_link::LinkSection;
use tes_link::keys::{HostFiles, KeySet, default_hosts, keygen};
use tes_link::refusals::{self, Denial};
use zenoh::Wait;

/// A free UDP port on loopback (QUIC runs over UDP).
fn free_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// A session with `host`'s files of `keys`, listening or connecting on `port`.
fn session(keys: &KeySet, host: &HostFiles, port: u16, listen: bool) -> zenoh::Session {
    let endpoint = vec![format!("quic/127.0.0.1:{port}")];
    let (listen, connect) = if listen {
        (endpoint, Vec::new())
    } else {
        (Vec::new(), endpoint)
    };
    let settings = LinkSection {
        group: "lab".into(),
        listen,
        connect,
        multicast_scouting: Some(false),
        tls_ca: Some(keys.authority.clone()),
        tls_cert: Some(host.cert.clone()),
        tls_key: Some(host.key.clone()),
        ..LinkSection::default()
    };
    settings.check().expect("settings");
    zenoh::open(settings.zenoh_config().expect("config"))
        .wait()
        .expect("session")
}

fn keys_in(dir: &Path) -> KeySet {
    keygen(dir, &default_hosts(), 7447).expect("keys")
}

/// What `robot` receives on `lab/command` within `wait`, while `sender` publishes for it.
fn commands_taken(robot: &zenoh::Session, sender: &zenoh::Session, wait: Duration) -> usize {
    let (tx, rx) = mpsc::channel();
    let _subscriber = robot
        .declare_subscriber("lab/command")
        .callback(move |_| {
            let _ = tx.send(());
        })
        .wait()
        .expect("subscriber");
    let deadline = std::time::Instant::now() + wait;
    while std::time::Instant::now() < deadline {
        sender.put("lab/command", vec![0u8; 8]).wait().expect("put");
        std::thread::sleep(Duration::from_millis(50));
    }
    rx.try_iter().count()
}

/// Both cases in one test: the refusals Zenoh logs go to one queue per process.
#[test]
fn strangers_are_refused_members_talk_and_only_the_controller_commands() {
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    tracing_subscriber::registry()
        .with(tes_link::refusals::layer())
        .try_init()
        .expect("the only subscriber");
    a_stranger_with_another_authority_is_refused();
    members_talk_and_only_the_controller_commands();
}

fn members_talk_and_only_the_controller_commands() {
    let dir = tempfile::tempdir().expect("temp dir");
    let keys = keys_in(&dir.path().join("group"));
    let port = free_port();
    let robot = session(&keys, &keys.hosts[0], port, true);
    let learner = session(&keys, &keys.hosts[1], port, false);
    assert!(
        commands_taken(&robot, &learner, Duration::from_secs(2)) > 0,
        "the controller's host is heard"
    );
    // A second session with the robot host's own (valid) certificate: connected, but its
    // commands are dropped by the robot's access control.
    let impostor = session(&keys, &keys.hosts[0], port, false);
    let peers: Vec<_> = robot.info().peers_zid().wait().collect();
    assert!(
        peers.contains(&impostor.zid()),
        "the impostor is connected: {peers:?}"
    );
    assert_eq!(
        commands_taken(&robot, &impostor, Duration::from_secs(2)),
        0,
        "a robot-host certificate may not command"
    );
    let denied = refusals::take();
    assert!(
        denied
            .iter()
            .any(|d| matches!(d, Denial::Message { peer, what, key }
            if *peer == impostor.zid().to_string() && what.starts_with("Put")
                && key == "lab/command")),
        "the denial is told: {denied:?}"
    );
    let stops = robot
        .declare_subscriber("lab/stop")
        .with(zenoh::handlers::FifoChannel::default())
        .wait()
        .expect("subscriber");
    std::thread::sleep(Duration::from_millis(300));
    impostor.put("lab/stop", "x clean bye").wait().expect("put");
    assert!(
        stops
            .recv_timeout(Duration::from_secs(3))
            .ok()
            .flatten()
            .is_some(),
        "any member may stop the group"
    );
}

fn a_stranger_with_another_authority_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let ours = keys_in(&dir.path().join("ours"));
    let theirs = keys_in(&dir.path().join("theirs"));
    let port = free_port();
    let robot = session(&ours, &ours.hosts[0], port, true);
    // The stranger's certificate names the controller, but another authority signed it.
    let stranger = session(&theirs, &theirs.hosts[1], port, false);
    assert_eq!(commands_taken(&robot, &stranger, Duration::from_secs(2)), 0);
    let peers: Vec<_> = robot.info().peers_zid().wait().collect();
    assert!(
        peers.is_empty(),
        "no transport with the stranger: {peers:?}"
    );
    let denied = refusals::take();
    assert!(
        denied.iter().any(|d| matches!(d, Denial::Connection(_))),
        "the refused connection is told: {denied:?}"
    );
}
