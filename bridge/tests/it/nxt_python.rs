//! The simulated brick against an independent NXT client: nxt-python's devfile backend.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::util::BrickProcess;

/// Ignored, with its reason, where nxt-python cannot be imported; under CI it always runs
/// (see `build.rs`).
#[test]
#[cfg_attr(
    not(tes_nxt_python),
    ignore = "nxt-python is not installed: python3 -m pip install nxt-python==3.5.1"
)]
fn nxt_python_drives_the_simulated_brick() {
    let dir = tempfile::tempdir().expect("tempdir");
    let brick = BrickProcess::spawn(&dir.path().join("nxt"), 21);
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/nxt_client.py");
    let mut child = Command::new("python3")
        .arg("-u")
        .arg(script)
        .arg(&brick.link)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn python3");
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break Some(s);
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = child.wait_with_output().expect("output");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    let status =
        status.unwrap_or_else(|| panic!("nxt-python client timed out\n{stdout}\n{stderr}"));
    assert!(
        status.success(),
        "nxt-python client failed: {status}\n{stdout}\n{stderr}"
    );
    assert!(
        stdout.contains("nxt-python client: all checks passed"),
        "{stdout}\n{stderr}"
    );
    drop(brick);
}
