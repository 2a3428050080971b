//! Tells the integration tests whether PyPI's `mcap` (the independent reader `tes launch
//! --record` is checked against), PyPI's Zenoh (the stranger the link's TLS keeps out) and the
//! viewers' clients (Rerun, Foxglove's Protobuf classes, a WebSocket client) can be imported:
//! each test runs when its client can be, and is reported ignored, with how to install it, when
//! it cannot. Under CI (`CI` set) the test always runs, so a missing reader fails it instead of
//! passing unseen. Installed the reader since the last
//! build? Set `TES_PROBE_CLIENTS` to anything new (or `touch tes/build.rs`) to probe again.

use std::process::{Command, Stdio};

fn main() {
    println!("cargo::rustc-check-cfg=cfg(tes_mcap_reader)");
    println!("cargo::rustc-check-cfg=cfg(tes_zenoh_client)");
    println!("cargo::rustc-check-cfg=cfg(tes_viewer_clients)");
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-env-changed=TES_PROBE_CLIENTS");
    println!("cargo::rerun-if-changed=build.rs");
    let under_ci = std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "false");
    if under_ci || imports("import mcap.reader") {
        println!("cargo::rustc-cfg=tes_mcap_reader");
    }
    if under_ci || imports("import zenoh") {
        println!("cargo::rustc-cfg=tes_zenoh_client");
    }
    if under_ci
        || imports("import rerun, foxglove_schemas_protobuf, mcap_protobuf, websockets.sync.client")
    {
        println!("cargo::rustc-cfg=tes_viewer_clients");
    }
}

/// Whether `python3 -c CODE` succeeds.
fn imports(code: &str) -> bool {
    Command::new("python3")
        .args(["-c", code])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}
