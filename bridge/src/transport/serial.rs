//! A serial device as a link: Bluetooth SPP through `/dev/rfcommN`, or a pseudo-terminal.

use std::io::{ErrorKind, Read, Write};
use std::path::PathBuf;
use std::time::Duration;

use serialport::{ClearBuffer, SerialPort};

use super::TransportError;
use super::link::{Connection, Device, Framing, LinkTiming, LinkTransport, OpenFailure};

/// Settings of a [`SerialTransport`] (the `[serial]` table of the bridge config, plus the path
/// from `transport = "serial:PATH"`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialConfig {
    /// The device, e.g. `/dev/rfcomm0`.
    pub path: PathBuf,
    /// Line speed; ignored by rfcomm and pseudo-terminals, kept for USB-serial adapters.
    pub baud_rate: u32,
    /// How long to wait for the reply to a request (from the request's write to the reply's
    /// last byte); also the age after which a partial reply is dropped.
    pub read_timeout: Duration,
    /// Wait between reconnection attempts after the device failed.
    pub reconnect_backoff: Duration,
    /// Consecutive timeouts after which the device is closed and reopened.
    pub max_timeouts: u32,
    /// Open the device exclusively (TIOCEXCL), so no second process talks to the brick.
    pub exclusive: bool,
}

impl SerialConfig {
    /// Defaults for `path`: 115200 baud, 500 ms read timeout, 1 s back-off, reopen after 3
    /// timeouts in a row, exclusive.
    pub fn new(path: impl Into<PathBuf>) -> Self {
        let timing = LinkTiming::default();
        Self {
            path: path.into(),
            baud_rate: 115_200,
            read_timeout: timing.read_timeout,
            reconnect_backoff: timing.reconnect_backoff,
            max_timeouts: timing.max_timeouts,
            exclusive: true,
        }
    }

    /// The link's timing keys.
    pub fn timing(&self) -> LinkTiming {
        LinkTiming {
            read_timeout: self.read_timeout,
            reconnect_backoff: self.reconnect_backoff,
            max_timeouts: self.max_timeouts,
        }
    }
}

/// A serial device: opened with `serialport`, telegrams length-prefixed.
#[derive(Debug, Clone)]
pub struct SerialDevice {
    cfg: SerialConfig,
}

impl SerialDevice {
    /// The device `cfg` names.
    pub fn new(cfg: SerialConfig) -> Self {
        Self { cfg }
    }
}

/// Talks to a brick over a serial device (see [`LinkTransport`] for the link's behaviour).
pub type SerialTransport = LinkTransport<SerialDevice>;

impl LinkTransport<SerialDevice> {
    /// A transport that opens the device `cfg` names at its first transaction.
    pub fn serial(cfg: SerialConfig) -> Self {
        let timing = cfg.timing();
        Self::new(SerialDevice::new(cfg), timing)
    }

    /// Opens the device `cfg` names now.
    pub fn open_serial(cfg: SerialConfig) -> Result<Self, TransportError> {
        let timing = cfg.timing();
        Self::connect(SerialDevice::new(cfg), timing)
    }
}

impl Device for SerialDevice {
    type Connection = SerialConnection;

    fn open(&mut self) -> Result<SerialConnection, OpenFailure> {
        let path = self.cfg.path.to_string_lossy().into_owned();
        serialport::new(path, self.cfg.baud_rate)
            .timeout(self.cfg.read_timeout)
            .exclusive(self.cfg.exclusive)
            .open()
            .map(|port| SerialConnection { port })
            .map_err(|e| open_failure(&e))
    }

    fn describe(&self) -> String {
        format!("serial:{}", self.cfg.path.display())
    }

    fn framing(&self) -> Framing {
        Framing::LengthPrefixed
    }
}

/// An open serial device.
pub struct SerialConnection {
    port: Box<dyn SerialPort>,
}

impl Connection for SerialConnection {
    fn send(&mut self, frame: &[u8]) -> std::io::Result<()> {
        self.port.write_all(frame)?;
        self.port.flush()
    }

    fn receive(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        self.port.set_timeout(timeout)?;
        match self.port.read(buf) {
            // A terminal read of nothing is no end of stream: wait on.
            Ok(0) => Err(ErrorKind::Interrupted.into()),
            other => other,
        }
    }

    fn discard_input(&mut self) {
        let _ = self.port.clear(ClearBuffer::Input);
    }
}

/// Why a serial device did not open, said as its cause and fix.
fn open_failure(e: &serialport::Error) -> OpenFailure {
    match e.kind() {
        serialport::ErrorKind::NoDevice
        | serialport::ErrorKind::Io(std::io::ErrorKind::NotFound) => OpenFailure::new(
            format!("{e}: no such device"),
            "is the brick paired and the rfcomm device bound? `transport = \"bluetooth:ADDR\"` \
             needs no rfcomm device",
        ),
        serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => OpenFailure::new(
            format!("{e}: permission denied"),
            "add the user to the dialout group",
        ),
        _ => OpenFailure::bare(e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    //! The transport against a scripted brick on the master side of a pseudo-terminal.

    use std::os::fd::{AsFd, OwnedFd};
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::thread;

    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

    use super::*;
    use crate::nxt::{FrameDecoder, Reply, Request, Status};
    use crate::transport::Transport;
    use crate::transport::TransportError;

    /// What the scripted brick does after receiving a request.
    enum Step {
        Write(Vec<u8>),
        Sleep(Duration),
    }

    /// A pty whose master side answers the n-th request with the n-th script; stopped on drop.
    struct ScriptedBrick {
        path: PathBuf,
        quit: Arc<AtomicBool>,
        thread: Option<thread::JoinHandle<()>>,
        _slave: OwnedFd,
    }

    impl ScriptedBrick {
        fn start(scripts: Vec<Vec<Step>>) -> Self {
            let pty = nix::pty::openpty(None, None).expect("openpty");
            let mut t = tcgetattr(&pty.slave).expect("tcgetattr");
            cfmakeraw(&mut t);
            tcsetattr(&pty.slave, SetArg::TCSANOW, &t).expect("tcsetattr");
            let path = nix::unistd::ttyname(&pty.slave).expect("ttyname");
            let quit = Arc::new(AtomicBool::new(false));
            let flag = Arc::clone(&quit);
            let master = pty.master;
            let thread = thread::spawn(move || {
                let mut decoder = FrameDecoder::requests();
                let mut scripts = scripts.into_iter();
                let mut buf = [0u8; 256];
                while !flag.load(Ordering::SeqCst) {
                    let mut fds = [PollFd::new(master.as_fd(), PollFlags::POLLIN)];
                    if !matches!(poll(&mut fds, PollTimeout::from(20u16)), Ok(n) if n > 0) {
                        continue;
                    }
                    let Ok(n) = nix::unistd::read(&master, &mut buf) else {
                        continue;
                    };
                    for &b in &buf[..n] {
                        if let Some(Ok(_)) = decoder.push(b) {
                            for step in scripts.next().unwrap_or_default() {
                                match step {
                                    Step::Write(bytes) => {
                                        nix::unistd::write(&master, &bytes).expect("write");
                                    }
                                    Step::Sleep(d) => thread::sleep(d),
                                }
                            }
                        }
                    }
                }
            });
            Self {
                path,
                quit,
                thread: Some(thread),
                _slave: pty.slave,
            }
        }

        fn transport(&self) -> SerialTransport {
            let mut cfg = SerialConfig::new(&self.path);
            cfg.read_timeout = Duration::from_millis(300);
            cfg.exclusive = false;
            SerialTransport::open_serial(cfg).expect("open the pty")
        }
    }

    impl Drop for ScriptedBrick {
        fn drop(&mut self) {
            self.quit.store(true, Ordering::SeqCst);
            if let Some(t) = self.thread.take() {
                let _ = t.join();
            }
        }
    }

    fn frame(reply: Reply) -> Vec<u8> {
        reply.encode().to_frame().as_bytes().to_vec()
    }

    fn battery(millivolts: u16) -> Reply {
        Reply::BatteryLevel {
            status: Status::Success,
            millivolts,
        }
    }

    fn keep_alive() -> Reply {
        Reply::KeepAlive {
            status: Status::Success,
            sleep_timeout_ms: 600_000,
        }
    }

    #[test]
    fn junk_and_bad_lengths_before_a_reply_are_skipped() {
        let mut junk = vec![0x42, 0x00, 0x00, 0x41, 0x00, 0xFF, 0xFF, 0x05];
        junk.extend(frame(battery(8100)));
        let brick = ScriptedBrick::start(vec![vec![Step::Write(junk)]]);
        let mut link = brick.transport();
        assert_eq!(
            link.request(&Request::GetBatteryLevel).ok(),
            Some(battery(8100))
        );
        assert!(link.stats().bad_frames >= 4, "{:?}", link.stats());
    }

    #[test]
    fn a_half_reply_older_than_the_timeout_is_dropped() {
        let half = frame(battery(8000))[..4].to_vec();
        let brick = ScriptedBrick::start(vec![
            // The first request gets half a reply, and the rest only after the timeout.
            vec![
                Step::Write(half),
                Step::Sleep(Duration::from_millis(400)),
                Step::Write(frame(battery(8000))[4..].to_vec()),
            ],
            vec![Step::Write(frame(battery(8200)))],
        ]);
        let mut link = brick.transport();
        let err = link.request(&Request::GetBatteryLevel).err();
        assert!(matches!(err, Some(TransportError::Timeout(_))), "{err:?}");
        // The next request's answer is its own, not the old half completed by new bytes.
        assert_eq!(
            link.request(&Request::GetBatteryLevel).ok(),
            Some(battery(8200))
        );
        assert_eq!(link.stats().timeouts, 1);
    }

    #[test]
    fn a_reply_to_another_opcode_is_not_taken_as_the_answer() {
        let mut two = frame(keep_alive());
        two.extend(frame(battery(7900)));
        let brick = ScriptedBrick::start(vec![
            vec![Step::Write(two)],
            // Only a reply to another opcode: a timeout, not an answer.
            vec![Step::Write(frame(keep_alive()))],
        ]);
        let mut link = brick.transport();
        assert_eq!(
            link.request(&Request::GetBatteryLevel).ok(),
            Some(battery(7900))
        );
        assert_eq!(link.stats().stale_replies, 1);
        let err = link.request(&Request::GetBatteryLevel).err();
        assert!(matches!(err, Some(TransportError::Timeout(_))), "{err:?}");
        assert_eq!(link.stats().stale_replies, 2);
    }
}
