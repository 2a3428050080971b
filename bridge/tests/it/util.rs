//! Process guards and helpers shared by the integration tests.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

/// A `tes-bridge brick --pty` child; killed and reaped on drop, whatever happens in the test.
pub struct BrickProcess {
    child: Option<Child>,
    pub link: PathBuf,
}

impl BrickProcess {
    /// Starts the brick server linked at `link` and waits for the link to appear.
    pub fn spawn(link: &Path, seed: u64) -> Self {
        let child = Command::new(env!("CARGO_BIN_EXE_tes-bridge"))
            .args(["brick", "--pty"])
            .arg(link)
            .args(["--seed", &seed.to_string()])
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn the bridge binary");
        let mut me = Self {
            child: Some(child),
            link: link.to_owned(),
        };
        let deadline = Instant::now() + Duration::from_secs(20);
        while std::fs::symlink_metadata(link).is_err() {
            if let Some(status) = me.child.as_mut().and_then(|c| c.try_wait().ok().flatten()) {
                panic!("tes-bridge brick exited early: {status}");
            }
            assert!(
                Instant::now() < deadline,
                "the brick server never linked {}",
                link.display()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        me
    }

    /// Sends SIGTERM and waits for the exit (SIGKILL after 10 s).
    pub fn terminate(mut self) -> ExitStatus {
        let mut child = self.child.take().expect("running");
        let _ = kill(Pid::from_raw(child.id() as i32), Signal::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            if let Ok(Some(status)) = child.try_wait() {
                return status;
            }
            if Instant::now() > deadline {
                let _ = child.kill();
                return child.wait().expect("reap");
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for BrickProcess {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// Polls `f` until it returns `Some` or `limit` passes (a failure timeout, not a timing check).
pub fn eventually<T>(limit: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let deadline = Instant::now() + limit;
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if Instant::now() > deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}
