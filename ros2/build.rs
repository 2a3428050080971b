//! Tells the integration tests whether the independent ROS 2 peers can be imported: PyPI's
//! `cyclonedds` (a ROS 2 middleware, Eclipse Cyclone DDS) and `rosbags` (a rosbag2 reader),
//! from the Python the tests use (`TES_ROS2_PYTHON`, else `target/ros2-venv/bin/python`, else
//! `python3`). Each test runs when its peer can be imported and is reported ignored, with how
//! to install it, when it cannot. Under CI (`CI` set) they always run, so a missing peer fails
//! them. Installed a peer since the last build? Set `TES_PROBE_CLIENTS` to anything new.

use std::path::PathBuf;
use std::process::{Command, Stdio};

fn main() {
    println!("cargo::rustc-check-cfg=cfg(tes_cyclonedds)");
    println!("cargo::rustc-check-cfg=cfg(tes_rosbags)");
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-env-changed=TES_PROBE_CLIENTS");
    println!("cargo::rerun-if-env-changed=TES_ROS2_PYTHON");
    println!("cargo::rerun-if-changed=build.rs");
    let under_ci = std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "false");
    let python = python();
    if under_ci || imports(&python, "import cyclonedds.domain") {
        println!("cargo::rustc-cfg=tes_cyclonedds");
    }
    if under_ci || imports(&python, "import rosbags.rosbag2") {
        println!("cargo::rustc-cfg=tes_rosbags");
    }
}

/// The Python the tests run their peers with.
fn python() -> String {
    if let Ok(p) = std::env::var("TES_ROS2_PYTHON") {
        return p;
    }
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default());
    let venv = manifest.join("../target/ros2-venv/bin/python");
    if venv.exists() {
        return venv.display().to_string();
    }
    "python3".into()
}

/// Whether `PYTHON -c CODE` succeeds.
fn imports(python: &str, code: &str) -> bool {
    Command::new(python)
        .args(["-c", code])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}
