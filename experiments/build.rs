//! Records `git describe` of the tree the crate is built from, as the code version result
//! folders carry (`tes_experiments::jobs::code_version`).
//!
//! Cargo reruns a build script whose `rerun-if-changed` path does not exist on every build
//! (and so recompiles this crate and relinks `tes`): only paths that exist are named. A fresh
//! clone has no `.git/packed-refs`, or a branch only in it and no loose ref file; naming
//! whichever of the two exists still sees every commit (a commit writes the loose ref).

use std::path::Path;
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_owned())
        .filter(|s| !s.is_empty())
}

/// Reruns the script when `path` changes, if it exists.
fn watch(path: &str) {
    if Path::new(path).exists() {
        println!("cargo:rerun-if-changed={path}");
    }
}

fn main() {
    if let Some(describe) = git(&["describe", "--always", "--dirty"]) {
        println!("cargo:rustc-env=TES_GIT_DESCRIBE={describe}");
    }
    // Rerun when the checked-out commit moves or the experiment or learning code changes.
    for path in ["HEAD", "packed-refs"] {
        if let Some(p) = git(&["rev-parse", "--git-path", path]) {
            watch(&p);
        }
    }
    if let Some(head) = git(&["symbolic-ref", "-q", "HEAD"])
        && let Some(p) = git(&["rev-parse", "--git-path", &head])
    {
        watch(&p);
    }
    for dir in ["src", "../learning/src", "../perception-sim/src"] {
        watch(dir);
    }
}
