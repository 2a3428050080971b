//! Tells the integration tests whether PyPI's `mcap` (the independent reader `tes launch
//! --record` is checked against) and PyPI's Zenoh (the stranger the link's TLS keeps out) can
//! be imported: each test runs when its client can be, and is reported ignored, with how to
//! install it, when it cannot. Under CI (`CI` set) the test always runs,
//! so a missing reader fails it instead of passing unseen. Installed the reader since the last
//! build? Set `TES_PROBE_CLIENTS` to anything new (or `touch tes/build.rs`) to probe again.

use std::process::{Command, Stdio};

fn main() {
    println!("cargo::rustc-check-cfg=cfg(tes_mcap_reader)");
    println!("cargo::rustc-check-cfg=cfg(tes_zenoh_client)");
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
