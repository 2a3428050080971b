//! Records `git describe` of the tree the crate is built from, as the code version result
//! folders carry (`tes_experiments::jobs::code_version`).

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_owned())
        .filter(|s| !s.is_empty())
}

fn main() {
    if let Some(describe) = git(&["describe", "--always", "--dirty"]) {
        println!("cargo:rustc-env=TES_GIT_DESCRIBE={describe}");
    }
    // Rerun when the checked-out commit moves or the experiment or learning code changes.
    for path in ["HEAD", "packed-refs"] {
        if let Some(p) = git(&["rev-parse", "--git-path", path]) {
            println!("cargo:rerun-if-changed={p}");
        }
    }
    if let Some(head) = git(&["symbolic-ref", "-q", "HEAD"])
        && let Some(p) = git(&["rev-parse", "--git-path", &head])
    {
        println!("cargo:rerun-if-changed={p}");
    }
    for dir in ["src", "../learning/src", "../perception-sim/src"] {
        println!("cargo:rerun-if-changed={dir}");
    }
}
