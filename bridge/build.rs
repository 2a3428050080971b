//! Tells the tests whether nxt-python, the independent NXT client the simulated brick is
//! tested against, can be imported: its test runs when it can, and is reported ignored, with
//! how to install it, when it cannot. Under CI (`CI` set) the test always runs, so a missing
//! client fails it instead of passing unseen. Installed the client since the last build? Set
//! `TES_PROBE_CLIENTS` to anything new (or `touch bridge/build.rs`) to probe again.

use std::process::{Command, Stdio};

fn main() {
    println!("cargo::rustc-check-cfg=cfg(tes_nxt_python)");
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-env-changed=TES_PROBE_CLIENTS");
    println!("cargo::rerun-if-changed=build.rs");
    let under_ci = std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "false");
    if under_ci || imports("import nxt.locator, nxt.motor") {
        println!("cargo::rustc-cfg=tes_nxt_python");
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
