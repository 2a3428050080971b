//! Rerun's own viewer following a group live, as a user attaches it: `python3
//! python/tes/rerun_view.py --live ADDR -o FILE.rrd`, a Foxglove WebSocket client of the
//! launcher's live server that logs every drawing through rerun-sdk (`tes bench latency
//! --rerun`). It runs as a user would run it, at normal priority, on any CPU.

use std::io::Read;
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

use crate::error::{BenchError, Result};

/// How long the script has to finish its file once the group is gone or it is told to stop.
const FINISH: Duration = Duration::from_secs(20);

/// A running `rerun_view.py --live`; [`stop`](Self::stop) ends it.
#[derive(Debug)]
pub struct RerunClient {
    child: Option<Child>,
}

impl RerunClient {
    /// Starts `python3 SCRIPT --live ADDR -o RRD`.
    pub fn spawn(script: &Path, addr: SocketAddr, rrd: &Path) -> Result<Self> {
        let child = Command::new("python3")
            .arg(script)
            .arg("--live")
            .arg(addr.to_string())
            .arg("-o")
            .arg(rrd)
            .env("RERUN_ANALYTICS", "0")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(BenchError::io(format!(
                "cannot start python3 {} --live {addr}",
                script.display()
            )))?;
        Ok(Self { child: Some(child) })
    }

    /// Ends the script (it stops by itself once the group's server closes; else Ctrl-C, then
    /// a kill); returns the drawings it logged, as it says on stderr (`drew N messages`).
    pub fn stop(mut self) -> Result<u64> {
        let Some(mut child) = self.child.take() else {
            return Ok(0);
        };
        let status = finish(&mut child)?;
        let mut said = String::new();
        if let Some(mut stderr) = child.stderr.take() {
            let _ = stderr.read_to_string(&mut said);
        }
        said.lines()
            .find_map(|l| {
                l.strip_prefix("drew ")?
                    .strip_suffix(" messages")?
                    .parse()
                    .ok()
            })
            .ok_or_else(|| {
                BenchError::Run(format!(
                    "rerun_view.py --live ended with {status} without saying what it drew: {}",
                    said.trim()
                ))
            })
    }
}

/// Waits for `child` to end, asking it with Ctrl-C after [`FINISH`] and killing it after as
/// long again.
fn finish(child: &mut Child) -> Result<std::process::ExitStatus> {
    let started = Instant::now();
    let mut interrupted = false;
    loop {
        if let Some(status) = child
            .try_wait()
            .map_err(BenchError::io("cannot wait for rerun_view.py".into()))?
        {
            return Ok(status);
        }
        if !interrupted && started.elapsed() >= FINISH {
            let _ = kill(Pid::from_raw(child.id() as i32), Signal::SIGINT);
            interrupted = true;
        } else if started.elapsed() >= 2 * FINISH {
            let _ = child.kill();
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

impl Drop for RerunClient {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}
