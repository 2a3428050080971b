//! What tests of several crates share (feature `test-support`, for dev-dependencies only).

use std::process::{Child, Command, Stdio};

/// Busy shells at normal priority (`sh -c 'while :; do :; done'`): the load under which
/// background threads starve and a recorder once drew back in time. Killed when dropped,
/// even when the test fails.
#[derive(Debug)]
pub struct CpuHogs(Vec<Child>);

impl CpuHogs {
    /// Two busy shells per core.
    ///
    /// # Panics
    /// If a shell cannot be started (a test's set-up failing).
    pub fn two_per_core() -> Self {
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        let hogs = (0..2 * cores)
            .map(|_| {
                Command::new("sh")
                    .args(["-c", "while :; do :; done"])
                    .stdin(Stdio::null())
                    .spawn()
                    .expect("a busy shell starts")
            })
            .collect();
        Self(hogs)
    }
}

impl Drop for CpuHogs {
    fn drop(&mut self) {
        for hog in &mut self.0 {
            let _ = hog.kill();
            let _ = hog.wait();
        }
    }
}
