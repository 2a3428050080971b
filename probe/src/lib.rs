//! For build scripts: tells a crate's tests which independent Python clients (nxt-python,
//! PyPI's `mcap`, Zenoh, the viewers' clients) can be imported, as `cfg` flags. A test that
//! needs a client runs when it can be imported, and is reported ignored, with how to install
//! it, when it cannot. Under CI (`CI` set, and not `false`) every flag is set, so a missing
//! client fails its test instead of passing unseen. Installed a client since the last build?
//! Set `TES_PROBE_CLIENTS` to anything new (or touch the crate's build.rs) to probe again.
//!
//! ```no_run
//! // build.rs
//! use tes_probe::Client;
//!
//! tes_probe::tell_tests(&[Client {
//!     cfg: "tes_nxt_python",
//!     imports: "import nxt.locator, nxt.motor",
//! }]);
//! ```
//!
//! The tests then gate on the flag:
//! `#[cfg_attr(not(tes_nxt_python), ignore = "nxt-python is not installed: ...")]`.

use std::path::Path;
use std::process::{Command, Stdio};

/// A client some tests check against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Client {
    /// The `cfg` flag set when it can be imported (`tes_…`).
    pub cfg: &'static str,
    /// The Python statement that imports it, run as `python3 -c IMPORTS`.
    pub imports: &'static str,
}

/// Declares each client's flag, sets the flags of those that can be imported (all of them
/// under CI), and says when to probe again. Call it once from `build.rs`'s `main`.
pub fn tell_tests(clients: &[Client]) {
    tell_tests_using("python3", clients);
}

/// [`tell_tests`], the clients imported by `python` (a virtual environment's interpreter,
/// say) rather than `python3`.
pub fn tell_tests_using(python: &str, clients: &[Client]) {
    for client in clients {
        println!("cargo::rustc-check-cfg=cfg({})", client.cfg);
    }
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-env-changed=TES_PROBE_CLIENTS");
    println!("cargo::rerun-if-changed=build.rs");
    let under_ci = under_ci(std::env::var("CI").ok().as_deref());
    for client in clients {
        if under_ci || imports(python, client.imports) {
            println!("cargo::rustc-cfg={}", client.cfg);
        }
    }
}

/// Whether the value of `CI` says the build runs under CI.
fn under_ci(ci: Option<&str>) -> bool {
    ci.is_some_and(|v| !v.is_empty() && v != "false")
}

/// The Python the ROS 2 peers (PyPI's `cyclonedds` and `rosbags`) run on: `TES_ROS2_PYTHON`,
/// else the virtual environment `.ci/run` installs them in (`target/ros2-venv` of the
/// workspace holding `manifest_dir`, a crate's directory), else `python3`. A build script
/// that calls it is probed again when `TES_ROS2_PYTHON` changes.
pub fn ros2_peers_python(manifest_dir: &Path) -> String {
    println!("cargo::rerun-if-env-changed=TES_ROS2_PYTHON");
    if let Ok(python) = std::env::var("TES_ROS2_PYTHON")
        && !python.is_empty()
    {
        return python;
    }
    let venv = manifest_dir.join("../target/ros2-venv/bin/python");
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ci_is_set_unless_empty_or_false() {
        assert!(under_ci(Some("true")) && under_ci(Some("1")));
        assert!(!under_ci(None) && !under_ci(Some("")) && !under_ci(Some("false")));
    }

    #[test]
    fn a_statement_that_fails_is_no_import() {
        // Whatever is installed, this raises; and `python3` missing is no import either.
        assert!(!imports("python3", "raise SystemExit(1)"));
        assert!(!imports("/nonexistent/python", "pass"));
    }
}
