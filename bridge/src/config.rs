//! The bridge's TOML configuration, validated once.
//!
//! Every key is optional; the defaults are the simulated brick and the paper's three actions.
//! Switching to a real NXT is one line: `transport = "usb"`, `"bluetooth:00:16:53:01:02:03"`
//! or `"serial:/dev/rfcomm0"`.
//!
//! The file's keys are [`BridgeSettings`] (read and written with serde, unknown keys refused);
//! [`BridgeSettings::check`] validates them once into the [`BridgeConfig`] the bridge runs
//! with. A bad key is a [`SettingError`] naming the key, and its line when read from text.
//!
//! ```
//! use tes_bridge::config::{BridgeConfig, TransportKind};
//!
//! let cfg = BridgeConfig::from_toml_str(r#"
//!     transport = "serial:/dev/rfcomm0"
//!     [watchdog]
//!     deadline_ms = 800
//! "#)?;
//! assert_eq!(cfg.transport, TransportKind::Serial("/dev/rfcomm0".into()));
//! assert_eq!(cfg.watchdog_deadline.as_millis(), 800);
//! assert!(BridgeConfig::from_toml_str("transport = \"usb:\"").is_err());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tes_runtime::channel::WaitStrategy;
use tes_runtime::settings::{MIN_BUDGET_US, Origin, SettingError};

use crate::actions::{ActionConfig, ActionMap, ActionSpec, MotorsConfig, paper_actions};
use crate::brick::SimBrickConfig;
use crate::transport::{BluetoothTarget, LinkTiming, SerialConfig};

/// Which transport carries the telegrams.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TransportKind {
    /// The simulated brick, in-process (`transport = "sim"`).
    Sim,
    /// A serial device (`transport = "serial:/dev/rfcomm0"`).
    Serial(PathBuf),
    /// A kernel RFCOMM socket to a paired brick (`transport = "bluetooth:00:16:53:01:02:03"`,
    /// optionally `@CHANNEL`).
    Bluetooth(BluetoothTarget),
    /// The brick's USB bulk endpoints (`transport = "usb"`, or `"usb:SERIAL"` for one of
    /// several bricks).
    Usb(Option<String>),
}

impl TransportKind {
    /// Whether this is a real brick's link (not the simulated brick).
    pub fn is_real(&self) -> bool {
        !matches!(self, TransportKind::Sim)
    }

    /// That this machine can carry the link at all: for `serial:PATH`, that PATH is a
    /// terminal device ([`check_serial_device`]); for `usb`, that the machine shows a USB
    /// bus; for `bluetooth:ADDR`, that its kernel offers Bluetooth sockets. A brick that is
    /// merely absent or switched off passes (it may come within the link's timeout). Run
    /// where the bridge runs, before it starts: the settings' own check
    /// ([`BridgeSettings::check`]) does not look at devices, as a host that does not play
    /// the bridge checks them too.
    pub fn check_device(&self) -> Result<(), DeviceError> {
        let here = |failure: crate::transport::link::OpenFailure| {
            if failure.impossible {
                Err(DeviceError::NotOnThisMachine {
                    transport: self.to_string(),
                    failure,
                })
            } else {
                Ok(())
            }
        };
        match self {
            TransportKind::Serial(path) => Ok(check_serial_device(path)?),
            TransportKind::Usb(_) => crate::transport::usb_bus().or_else(here),
            TransportKind::Bluetooth(_) => crate::transport::kernel_support().or_else(here),
            TransportKind::Sim => Ok(()),
        }
    }
}

/// Why the transport cannot carry the link on this machine, found before the bridge starts.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// `serial:PATH` names no terminal device.
    #[error(transparent)]
    Serial(#[from] SerialDeviceError),
    /// No retry can bring the link up here: no USB bus, no Bluetooth in the kernel.
    #[error("the link to the brick ({transport}) cannot be used on this machine: {failure}")]
    NotOnThisMachine {
        /// The transport, as the settings name it.
        transport: String,
        /// The cause and its fix.
        failure: crate::transport::link::OpenFailure,
    },
}

/// The fix said with every refused serial device.
const SERIAL_FIX: &str = "give the brick's serial device (`serial:/dev/rfcomm0` bound by \
    `rfcomm bind` to a paired brick), or `transport = \"bluetooth:ADDR\"` (no rfcomm device \
    needed), `\"usb\"`, or `\"sim\"` for the simulated brick";

/// Why `transport = "serial:PATH"` cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum SerialDeviceError {
    /// Nothing is at the path.
    #[error(
        "{} does not exist (is the brick paired and its rfcomm device bound? `transport = \
         \"sim\"` uses the simulated brick)",
        .0.display()
    )]
    Missing(PathBuf),
    /// Something is there, but not a terminal: `/dev/null`, `/dev/zero`, a FIFO, a file, a
    /// directory. Nothing was opened (a terminal only if the kernel could not say).
    #[error("{} is {kind}, not a terminal device: {SERIAL_FIX}", path.display())]
    NotATerminal {
        /// The path.
        path: PathBuf,
        /// What it is instead.
        kind: &'static str,
    },
    /// The path cannot be looked at.
    #[error("cannot look at {}: {error}", path.display())]
    Io {
        /// The path.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

/// The majors of Unix 98 pseudo-terminal slaves (`/dev/pts/N`), which sysfs does not list.
const PTY_SLAVE_MAJORS: std::ops::RangeInclusive<u64> = 136..=143;

/// Refuses a serial path that is not a terminal device, without opening it where the kernel
/// says what the device is (`/sys/dev/char/MAJOR:MINOR/subsystem` is `tty` for a terminal;
/// a pseudo-terminal's slave is told by its major): opening a serial device may connect
/// (rfcomm) or reset what is on the other end.
pub fn check_serial_device(path: &Path) -> Result<(), SerialDeviceError> {
    use std::os::unix::fs::{FileTypeExt, MetadataExt};
    let meta = match std::fs::metadata(path) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(SerialDeviceError::Missing(path.to_owned()));
        }
        Err(error) => {
            return Err(SerialDeviceError::Io {
                path: path.to_owned(),
                error,
            });
        }
    };
    let not_a_terminal = |kind| {
        Err(SerialDeviceError::NotATerminal {
            path: path.to_owned(),
            kind,
        })
    };
    if !meta.file_type().is_char_device() {
        return not_a_terminal(tes_files::kind_of(meta.file_type()));
    }
    let (major, minor) = (
        nix::sys::stat::major(meta.rdev()),
        nix::sys::stat::minor(meta.rdev()),
    );
    let subsystem = std::fs::read_link(format!("/sys/dev/char/{major}:{minor}/subsystem"));
    let is_terminal = match subsystem {
        Ok(class) => class.file_name().is_some_and(|name| name == "tty"),
        Err(_) if PTY_SLAVE_MAJORS.contains(&major) => true,
        // Neither sysfs nor the major says: ask the device itself, opened without blocking
        // and without becoming this process's terminal.
        Err(_) => opens_as_terminal(path),
    };
    if is_terminal {
        Ok(())
    } else {
        not_a_terminal("a character device")
    }
}

/// Whether `path` opens (without blocking, not as the controlling terminal) as a terminal.
fn opens_as_terminal(path: &Path) -> bool {
    use std::io::IsTerminal;
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
        .is_ok_and(|file| file.is_terminal())
}

/// The forms a `transport` takes, for messages.
const TRANSPORT_FORMS: &str = "\"sim\", \"serial:PATH\", \"bluetooth:ADDR[@CHANNEL]\", \"usb\" or \
                               \"usb:SERIAL\"";

impl std::str::FromStr for TransportKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.split_once(':') {
            None if s == "sim" => Ok(TransportKind::Sim),
            None if s == "usb" => Ok(TransportKind::Usb(None)),
            Some(("serial", path)) if !path.is_empty() => {
                Ok(TransportKind::Serial(PathBuf::from(path)))
            }
            Some(("bluetooth", target)) => target.parse().map(TransportKind::Bluetooth),
            Some(("usb", serial)) if !serial.is_empty() => {
                Ok(TransportKind::Usb(Some(serial.to_owned())))
            }
            _ => Err(format!(
                "expected {TRANSPORT_FORMS} (e.g. \"bluetooth:00:16:53:01:02:03\"), got {s:?}"
            )),
        }
    }
}

impl std::fmt::Display for TransportKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TransportKind::Sim => f.write_str("sim"),
            TransportKind::Serial(p) => write!(f, "serial:{}", p.display()),
            TransportKind::Bluetooth(t) => write!(f, "bluetooth:{t}"),
            TransportKind::Usb(None) => f.write_str("usb"),
            TransportKind::Usb(Some(serial)) => write!(f, "usb:{serial}"),
        }
    }
}

/// Written as its string form: `"sim"`, `"serial:PATH"`, `"bluetooth:ADDR@CHANNEL"`, `"usb"`.
impl Serialize for TransportKind {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            TransportKind::Serial(p) if p.to_str().is_none() => Err(serde::ser::Error::custom(
                format!("the serial device {} is not UTF-8", p.display()),
            )),
            other => serializer.serialize_str(&other.to_string()),
        }
    }
}

/// Read from its string form (see [`TransportKind`]).
impl<'de> Deserialize<'de> for TransportKind {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = TransportKind;

            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                write!(f, "a transport: {TRANSPORT_FORMS}")
            }

            fn visit_str<E: serde::de::Error>(self, s: &str) -> Result<TransportKind, E> {
                s.parse().map_err(E::custom)
            }
        }
        deserializer.deserialize_str(Visitor)
    }
}

/// A configuration that could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {error}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What is wrong with it (part of the message, so not also chained as a source).
        error: tes_files::FileProblem,
    },
    /// A key is unknown, of the wrong type or out of range, or the TOML is malformed: the
    /// error every process reports for a bad key (with the file and line when read from
    /// one).
    #[error(transparent)]
    Setting(#[from] SettingError),
}

/// The process name [`SettingError`]s of these settings carry.
pub const PROCESS: &str = "bridge";

fn invalid(key: &str, reason: impl Into<String>) -> SettingError {
    SettingError::new(PROCESS, key, reason)
}

/// The range of `[brick] time_scale`. The bridge adds its periods to a clock running
/// `time_scale` times the wall clock: at 1e300 that clock is past `Duration::MAX` at once and
/// the first addition panics; at 1e-300 the brick never moves. 10 000 is 50 times the
/// launcher's fastest (200).
pub const TIME_SCALE_RANGE: std::ops::RangeInclusive<f64> = 0.001..=10_000.0;

/// The simulated brick's settings, `time_scale` within [`TIME_SCALE_RANGE`] included.
fn check_brick(brick: &SimBrickConfig) -> Result<(), SettingError> {
    brick
        .check()
        .map_err(|e| invalid(&format!("brick.{}", e.key), e.reason))?;
    if !TIME_SCALE_RANGE.contains(&brick.time_scale) {
        return Err(invalid(
            "brick.time_scale",
            format!(
                "must be in {}..={}, got {}",
                TIME_SCALE_RANGE.start(),
                TIME_SCALE_RANGE.end(),
                brick.time_scale
            ),
        ));
    }
    Ok(())
}

/// The default `link_timeout_ms`: long enough for a Bluetooth serial link to connect.
pub const DEFAULT_LINK_TIMEOUT_MS: u64 = 5000;

/// The least `link_timeout_ms`.
pub const MIN_LINK_TIMEOUT_MS: u64 = 100;

/// The longest `[link_delay] mean_ms`.
pub const MAX_LINK_DELAY_MEAN_MS: u64 = 10_000;

/// The range of `[serial] read_timeout_ms`.
pub const READ_TIMEOUT_MS_RANGE: std::ops::RangeInclusive<u64> = 10..=60_000;

/// The least `[watchdog] deadline_ms`.
pub const MIN_WATCHDOG_DEADLINE_MS: u64 = 50;

/// The range of `[poll] moving_period_ms` (which must also be shorter than the watchdog's
/// deadline).
pub const MOVING_PERIOD_MS_RANGE: std::ops::RangeInclusive<u64> = 1..=1000;

/// The range of `[poll] idle_period_ms`.
pub const IDLE_PERIOD_MS_RANGE: std::ops::RangeInclusive<u64> = 10..=600_000;

/// The range of `[poll] settle_polls`.
pub const SETTLE_POLLS_RANGE: std::ops::RangeInclusive<u32> = 1..=100;

/// The least `[poll] keepalive_period_ms`.
pub const MIN_KEEPALIVE_PERIOD_MS: u64 = 1000;

/// The simulated Bluetooth link delay on each reply of the `sim` transport (and of
/// `tes-bridge brick --pty`): the `[link_delay]` table. Each field's doc is its key's entry in
/// the launch file's reference (`tes launch --print-config`), as for [`BridgeSettings`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct LinkDelayConfig {
    /// Delay each reply.
    ///
    /// Values: `true` | `false`.
    pub enabled: bool,
    /// Mean delay per reply.
    ///
    /// Values: ms, at most [`MAX_LINK_DELAY_MEAN_MS`].
    pub mean_ms: u64,
    /// Uniform jitter around the mean.
    ///
    /// Values: ms, at most `mean_ms`.
    pub jitter_ms: u64,
}

impl Default for LinkDelayConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            mean_ms: 30,
            jitter_ms: 10,
        }
    }
}

/// A real link's settings (the `[serial]` table: its timing keys apply to the USB and
/// Bluetooth links too). Each field's doc is its key's entry in the launch file's reference,
/// as for [`BridgeSettings`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct SerialSection {
    /// Line speed (ignored by rfcomm and pseudo-terminals).
    ///
    /// Values: bit/s.
    pub baud_rate: u32,
    /// Time to wait for a whole reply (every real link: serial, Bluetooth, USB).
    ///
    /// Values: ms, [`READ_TIMEOUT_MS_RANGE`].
    pub read_timeout_ms: u64,
    /// Wait between reconnection attempts (every real link).
    ///
    /// Values: ms.
    pub reconnect_backoff_ms: u64,
    /// Consecutive timeouts before the link is reopened (every real link).
    ///
    /// Values: count, at least 1.
    pub max_timeouts: u32,
    /// Open the device exclusively (TIOCEXCL): no second process on the same device.
    ///
    /// Values: `true` | `false`.
    pub exclusive: bool,
}

impl Default for SerialSection {
    fn default() -> Self {
        Self {
            baud_rate: 115_200,
            read_timeout_ms: 500,
            reconnect_backoff_ms: 1000,
            max_timeouts: 3,
            exclusive: true,
        }
    }
}

/// How the bridge polls the brick (the `[poll]` table; periods in brick time). Each field's
/// doc is its key's entry in the launch file's reference, as for [`BridgeSettings`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct PollConfig {
    /// Poll period (GETOUTPUTSTATE of the wheels) while a wheel moves.
    ///
    /// Values: ms, [`MOVING_PERIOD_MS_RANGE`], below `[bridge.watchdog] deadline_ms`.
    pub moving_period_ms: u64,
    /// Heartbeat period at rest: all ports and the battery are read and published.
    ///
    /// Values: ms, [`IDLE_PERIOD_MS_RANGE`].
    pub idle_period_ms: u64,
    /// Consecutive polls with idle wheels and unchanged counts before a move is settled.
    ///
    /// Values: count, [`SETTLE_POLLS_RANGE`].
    pub settle_polls: u32,
    /// Period of KEEPALIVE telegrams to the brick (they keep it from sleeping).
    ///
    /// Values: ms, at least [`MIN_KEEPALIVE_PERIOD_MS`].
    pub keepalive_period_ms: u64,
}

impl Default for PollConfig {
    fn default() -> Self {
        Self {
            moving_period_ms: 20,
            idle_period_ms: 1000,
            settle_polls: 2,
            keepalive_period_ms: 60_000,
        }
    }
}

impl PollConfig {
    /// The moving poll period.
    pub fn moving_period(&self) -> Duration {
        Duration::from_millis(self.moving_period_ms)
    }

    /// The idle heartbeat period.
    pub fn idle_period(&self) -> Duration {
        Duration::from_millis(self.idle_period_ms)
    }

    /// The brick keep-alive period.
    pub fn keepalive_period(&self) -> Duration {
        Duration::from_millis(self.keepalive_period_ms)
    }
}

/// iceoryx2 settings (the `[ipc]` table): waiting for commands, and the latency figures.
/// Each field's doc is its key's entry in the launch file's reference, as for
/// [`BridgeSettings`].
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct IpcConfig {
    /// Prefixed to every iceoryx2 service name (to run groups side by side).
    ///
    /// Values: text, at most [`SERVICE_PREFIX_MAX`](tes_runtime::settings::SERVICE_PREFIX_MAX)
    /// bytes.
    pub service_prefix: String,
    /// How the bridge waits for commands (`auto`: anticipate announced messages
    /// only, block for any other; a launch resolves it, see `[launch] wait`).
    ///
    /// Values: `auto` | `block` | `spin` | `spin-then-block` | `spin-then-block:<µs>` |
    /// `anticipate`.
    pub wait: WaitStrategy,
    /// The per-action budget the observation-to-command latency is held to; overruns are
    /// counted in the latency report.
    ///
    /// Values: µs, at least [`MIN_BUDGET_US`].
    pub budget_us: u64,
    /// Commands left out of the latency report.
    ///
    /// Values: count.
    pub warmup_commands: u64,
    /// Where to write the report at exit (JSON: the latency's percentiles, maximum and misses;
    /// the link's round trips under `link`).
    /// Unset: nowhere.
    ///
    /// Values: path.
    ///
    /// Example: `"/path/to/bridge-latency.json"`.
    pub latency_report: Option<std::path::PathBuf>,
    /// Where to write the latency of every `latency_window` consecutive commands after the
    /// warm-up, one CSV row per window, at exit: it shows drift over a long run. Unset:
    /// nowhere.
    ///
    /// Values: path.
    ///
    /// Example: `"/path/to/bridge-windows.csv"`.
    pub latency_windows: Option<std::path::PathBuf>,
    /// Commands per window of `latency_windows`.
    ///
    /// Values: commands, at least 1.
    pub latency_window: u64,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self {
            service_prefix: String::new(),
            wait: WaitStrategy::Block,
            budget_us: tes_runtime::settings::DEFAULT_BUDGET_US,
            warmup_commands: 0,
            latency_report: None,
            latency_windows: None,
            latency_window: 50_000,
        }
    }
}

impl IpcConfig {
    /// The wait strategy (`wait`). It is typed, so this no longer fails; kept for callers
    /// written when `wait` was a string.
    pub fn wait_strategy(&self) -> Result<WaitStrategy, tes_runtime::channel::BadWaitStrategy> {
        Ok(self.wait)
    }
}

/// The bridge's settings file as written: every key, typed, with its default (TOML: a file of
/// the bridge's own, or the `[bridge]` table of a launch file). [`check`](Self::check) turns
/// it into the [`BridgeConfig`] the bridge runs with. Written back with serde
/// (`toml::to_string`), it reads back the same. Each field's doc (and each field's of its
/// nested tables) is its key's entry in the launch file's reference (`tes launch
/// --print-config`): what it does, then its unit or values on a `Values:` line; the defaults
/// are the structs' `Default`s.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct BridgeSettings {
    /// What carries the telegrams: the simulated brick, in-process; a real NXT over USB
    /// (`usb`, or `usb:<serial>` to pick one of several), over Bluetooth by a kernel RFCOMM
    /// socket (`bluetooth:<address>`, channel 1 unless `@<channel>` follows), or a serial
    /// device (`serial:/dev/rfcomm0` bound by `rfcomm bind`, or the pseudo-terminal that
    /// `tes-bridge brick --pty` serves). `tes-bridge scan` lists the bricks it sees.
    ///
    /// Values: `"sim"` | `"usb"` | `"usb:<serial>"` | `"bluetooth:<address>[@<channel>]"` |
    /// `"serial:<path>"`.
    pub transport: TransportKind,
    /// Seeds the simulated brick and the simulated link delay.
    ///
    /// Values: integer, 0 to 2^63 - 1.
    pub seed: u64,
    /// Drive the wheels by each command's `left_deg`/`right_deg` instead of looking its
    /// action id up in `[[bridge.actions]]`.
    ///
    /// Values: `true` | `false`.
    pub use_command_degrees: bool,
    /// A link to the brick that has not come up this long after the start, or has been down
    /// this long since, stops the bridge with an error naming the transport (and with it the
    /// launch).
    ///
    /// Values: ms of wall time, at least [`MIN_LINK_TIMEOUT_MS`].
    pub link_timeout_ms: u64,
    /// `[link_delay]`.
    pub link_delay: LinkDelayConfig,
    /// `[serial]`.
    pub serial: SerialSection,
    /// `[watchdog]`.
    pub watchdog: WatchdogSection,
    /// `[poll]`.
    pub poll: PollConfig,
    /// `[ipc]`.
    pub ipc: IpcConfig,
    /// `[brick]`.
    pub brick: SimBrickConfig,
    /// `[motors]`.
    pub motors: MotorsConfig,
    /// `[[actions]]` (default: the paper's three).
    pub actions: Vec<ActionSpec>,
}

impl Default for BridgeSettings {
    fn default() -> Self {
        Self {
            transport: TransportKind::Sim,
            seed: 0,
            use_command_degrees: false,
            link_timeout_ms: DEFAULT_LINK_TIMEOUT_MS,
            link_delay: LinkDelayConfig::default(),
            serial: SerialSection::default(),
            watchdog: WatchdogSection::default(),
            poll: PollConfig::default(),
            ipc: IpcConfig::default(),
            brick: SimBrickConfig::default(),
            motors: MotorsConfig::default(),
            actions: paper_actions(),
        }
    }
}

/// The dead man's switch (the `[watchdog]` table). Its field's doc is its key's entry in the
/// launch file's reference, as for [`BridgeSettings`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct WatchdogSection {
    /// Brake the motors when no command or keep-alive arrives within this long while one
    /// runs. It must exceed the longest action's duration.
    ///
    /// Values: ms of brick time, at least [`MIN_WATCHDOG_DEADLINE_MS`].
    pub deadline_ms: u64,
}

impl Default for WatchdogSection {
    fn default() -> Self {
        Self { deadline_ms: 1000 }
    }
}

/// The validated bridge configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeConfig {
    /// `transport`: `"sim"` (default), `"usb"`, `"bluetooth:ADDR"` or `"serial:PATH"`.
    pub transport: TransportKind,
    /// `seed`: seeds the simulated brick and the simulated link delay (default 0).
    pub seed: u64,
    /// `use_command_degrees`: drive the wheels by the command's `left_deg`/`right_deg` instead
    /// of looking its action id up in `[[actions]]` (default false).
    pub use_command_degrees: bool,
    /// `link_timeout_ms` (default 5000): how long the link to the brick may be down — or not
    /// yet up after the start — before the bridge stops with [`LinkDown`](crate::process::ProcessError::LinkDown).
    pub link_timeout: Duration,
    /// `[link_delay]`: `None` when disabled.
    pub link_delay: Option<(Duration, Duration)>,
    /// `[serial]`.
    pub serial: SerialSection,
    /// `[watchdog] deadline_ms` (default 1000).
    pub watchdog_deadline: Duration,
    /// `[poll]`.
    pub poll: PollConfig,
    /// `[ipc]`.
    pub ipc: IpcConfig,
    /// `[brick]`: the simulated brick's physics, and `time_scale`, how many times faster than
    /// the wall clock it runs (default 1; see [`with_time_scale`](Self::with_time_scale)).
    pub brick: SimBrickConfig,
    /// `[motors]` and `[[actions]]`.
    pub actions: ActionMap,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        Self {
            transport: TransportKind::Sim,
            seed: 0,
            use_command_degrees: false,
            link_timeout: Duration::from_millis(DEFAULT_LINK_TIMEOUT_MS),
            link_delay: None,
            serial: SerialSection::default(),
            watchdog_deadline: Duration::from_millis(1000),
            poll: PollConfig::default(),
            ipc: IpcConfig::default(),
            brick: SimBrickConfig::default(),
            actions: ActionMap::paper_default(),
        }
    }
}

impl BridgeSettings {
    /// Parses TOML text with these keys (unknown keys refused); an error names the key and
    /// its line in `origin`.
    pub fn from_toml_in(text: &str, origin: Origin) -> Result<Self, SettingError> {
        tes_runtime::settings::parse_in(PROCESS, text, origin)
    }

    /// Checks every key; the first bad one is reported (its key dotted: `poll.settle_polls`).
    /// Returns the configuration the bridge runs with.
    pub fn check(&self) -> Result<BridgeConfig, SettingError> {
        self.check_watchdog()?;
        self.check_poll()?;
        self.check_serial()?;
        self.check_link()?;
        check_brick(&self.brick)?;
        let actions = ActionMap::new(ActionConfig {
            motors: self.motors.clone(),
            actions: self.actions.clone(),
        })
        .map_err(|e| invalid(&e.key, e.reason))?;
        self.check_ipc()?;
        let raw = self;
        let ms = Duration::from_millis;
        let (d, s, p) = (raw.link_delay, raw.serial, raw.poll);
        Ok(BridgeConfig {
            transport: raw.transport.clone(),
            seed: raw.seed,
            use_command_degrees: raw.use_command_degrees,
            link_timeout: ms(raw.link_timeout_ms),
            link_delay: d.enabled.then(|| (ms(d.mean_ms), ms(d.jitter_ms))),
            serial: s,
            watchdog_deadline: ms(raw.watchdog.deadline_ms),
            poll: p,
            ipc: raw.ipc.clone(),
            brick: raw.brick.clone(),
            actions,
        })
    }

    /// `[watchdog]`: the deadline.
    fn check_watchdog(&self) -> Result<(), SettingError> {
        let raw = self;
        if raw.watchdog.deadline_ms < MIN_WATCHDOG_DEADLINE_MS {
            return Err(invalid(
                "watchdog.deadline_ms",
                format!(
                    "must be at least {MIN_WATCHDOG_DEADLINE_MS}, got {}",
                    raw.watchdog.deadline_ms
                ),
            ));
        }
        Ok(())
    }

    /// `[poll]`: the periods, within their ranges and the moving one within the watchdog's
    /// deadline.
    fn check_poll(&self) -> Result<(), SettingError> {
        let (raw, p) = (self, self.poll);
        if !MOVING_PERIOD_MS_RANGE.contains(&p.moving_period_ms) {
            return Err(invalid(
                "poll.moving_period_ms",
                format!(
                    "must be in {}..={}, got {}",
                    MOVING_PERIOD_MS_RANGE.start(),
                    MOVING_PERIOD_MS_RANGE.end(),
                    p.moving_period_ms
                ),
            ));
        }
        if p.moving_period_ms >= raw.watchdog.deadline_ms {
            return Err(invalid(
                "poll.moving_period_ms",
                format!(
                    "must be shorter than watchdog.deadline_ms ({})",
                    raw.watchdog.deadline_ms
                ),
            ));
        }
        if !IDLE_PERIOD_MS_RANGE.contains(&p.idle_period_ms) {
            return Err(invalid(
                "poll.idle_period_ms",
                format!(
                    "must be in {}..={}, got {}",
                    IDLE_PERIOD_MS_RANGE.start(),
                    IDLE_PERIOD_MS_RANGE.end(),
                    p.idle_period_ms
                ),
            ));
        }
        if !SETTLE_POLLS_RANGE.contains(&p.settle_polls) {
            return Err(invalid(
                "poll.settle_polls",
                format!(
                    "must be in {}..={}, got {}",
                    SETTLE_POLLS_RANGE.start(),
                    SETTLE_POLLS_RANGE.end(),
                    p.settle_polls
                ),
            ));
        }
        if p.keepalive_period_ms < MIN_KEEPALIVE_PERIOD_MS {
            return Err(invalid(
                "poll.keepalive_period_ms",
                format!(
                    "must be at least {MIN_KEEPALIVE_PERIOD_MS}, got {}",
                    p.keepalive_period_ms
                ),
            ));
        }
        Ok(())
    }

    /// `[serial]`: the read timeout and the timeouts allowed in a row.
    fn check_serial(&self) -> Result<(), SettingError> {
        let s = self.serial;
        if !READ_TIMEOUT_MS_RANGE.contains(&s.read_timeout_ms) {
            return Err(invalid(
                "serial.read_timeout_ms",
                format!(
                    "must be in {}..={}, got {}",
                    READ_TIMEOUT_MS_RANGE.start(),
                    READ_TIMEOUT_MS_RANGE.end(),
                    s.read_timeout_ms
                ),
            ));
        }
        if s.max_timeouts == 0 {
            return Err(invalid("serial.max_timeouts", "must be at least 1"));
        }
        Ok(())
    }

    /// The link's timeout and `[link_delay]`.
    fn check_link(&self) -> Result<(), SettingError> {
        let raw = self;
        if raw.link_timeout_ms < MIN_LINK_TIMEOUT_MS {
            return Err(invalid(
                "link_timeout_ms",
                format!(
                    "must be at least {MIN_LINK_TIMEOUT_MS}, got {}",
                    raw.link_timeout_ms
                ),
            ));
        }
        let d = raw.link_delay;
        if d.jitter_ms > d.mean_ms || d.mean_ms > MAX_LINK_DELAY_MEAN_MS {
            return Err(invalid(
                "link_delay.jitter_ms",
                format!(
                    "need jitter_ms <= mean_ms <= {MAX_LINK_DELAY_MEAN_MS}, got jitter {} mean {}",
                    d.jitter_ms, d.mean_ms
                ),
            ));
        }
        Ok(())
    }

    /// `[ipc]`: the service prefix, the latency window and the budget.
    fn check_ipc(&self) -> Result<(), SettingError> {
        let raw = self;
        tes_runtime::settings::service_prefix(
            PROCESS,
            "ipc.service_prefix",
            &raw.ipc.service_prefix,
        )?;
        if raw.ipc.latency_window == 0 {
            return Err(invalid("ipc.latency_window", "must be at least 1"));
        }
        if raw.ipc.budget_us < MIN_BUDGET_US {
            return Err(invalid(
                "ipc.budget_us",
                format!("must be at least {MIN_BUDGET_US}"),
            ));
        }
        Ok(())
    }
}

/// The largest bridge settings file read (a settings file is a few KiB).
pub const MAX_CONFIG_FILE_BYTES: u64 = 1 << 20;

impl BridgeConfig {
    /// Reads and validates a TOML file; an error names the file, the line and the key.
    ///
    /// The file is read as every TES file is ([`tes_files::read_text`]): a FIFO, a device or
    /// a file over [`MAX_CONFIG_FILE_BYTES`] is refused without being read.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = tes_files::read_text(path, MAX_CONFIG_FILE_BYTES).map_err(|error| {
            ConfigError::Read {
                path: path.to_owned(),
                error,
            }
        })?;
        Self::from_toml_in(&text, Origin::File(path.to_owned()))
    }

    /// Parses and validates TOML text (an error's origin is `<string>`).
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        Self::from_toml_in(text, Origin::Text)
    }

    /// Parses and validates TOML text from `origin`, which an error names with the line of
    /// the key.
    pub fn from_toml_in(text: &str, origin: Origin) -> Result<Self, ConfigError> {
        let (_, config) =
            tes_runtime::settings::parse_checked(PROCESS, text, origin, BridgeSettings::check)?;
        Ok(config)
    }

    /// Sets `seed` (the simulated brick's and the link delay's).
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// Sets `[ipc] service_prefix`; refused (key `ipc.service_prefix`) beyond
    /// [`SERVICE_PREFIX_MAX`](tes_runtime::settings::SERVICE_PREFIX_MAX) bytes.
    pub fn with_service_prefix(mut self, prefix: impl Into<String>) -> Result<Self, ConfigError> {
        let prefix = prefix.into();
        tes_runtime::settings::service_prefix(PROCESS, "ipc.service_prefix", &prefix)?;
        self.ipc.service_prefix = prefix;
        Ok(self)
    }

    /// Sets `[brick] time_scale`: the simulated brick runs `k` times faster than the wall
    /// clock, and with it every period and deadline of the bridge (they are brick time).
    /// Refused (key `brick.time_scale`) unless finite and > 0 and within
    /// [`TIME_SCALE_RANGE`]; ignored by serial transports.
    ///
    /// ```
    /// use tes_bridge::config::BridgeConfig;
    ///
    /// let cfg = BridgeConfig::default().with_seed(3).with_time_scale(200.0)?;
    /// assert_eq!(cfg.brick.time_scale, 200.0);
    /// let err = BridgeConfig::default().with_time_scale(0.0).unwrap_err();
    /// assert!(err.to_string().contains("brick.time_scale"));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn with_time_scale(mut self, k: f64) -> Result<Self, ConfigError> {
        self.brick.time_scale = k;
        check_brick(&self.brick)?;
        Ok(self)
    }

    /// The timing of every real link (the `[serial]` table's timing keys).
    pub fn link_timing(&self) -> LinkTiming {
        LinkTiming {
            read_timeout: Duration::from_millis(self.serial.read_timeout_ms),
            reconnect_backoff: Duration::from_millis(self.serial.reconnect_backoff_ms),
            max_timeouts: self.serial.max_timeouts,
        }
    }

    /// The serial settings for `path`.
    pub fn serial_config(&self, path: &Path) -> SerialConfig {
        SerialConfig {
            path: path.to_owned(),
            baud_rate: self.serial.baud_rate,
            read_timeout: Duration::from_millis(self.serial.read_timeout_ms),
            reconnect_backoff: Duration::from_millis(self.serial.reconnect_backoff_ms),
            max_timeouts: self.serial.max_timeouts,
            exclusive: self.serial.exclusive,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_config_is_the_default() {
        assert_eq!(
            BridgeConfig::from_toml_str("").expect("valid"),
            BridgeConfig::default()
        );
    }

    #[test]
    fn example_config_is_the_default() {
        let text = include_str!("../bridge.example.toml");
        assert_eq!(
            BridgeConfig::from_toml_str(text).expect("valid"),
            BridgeConfig::default()
        );
    }

    #[test]
    fn full_config_parses() {
        let cfg = BridgeConfig::from_toml_str(
            r#"
            transport = "sim"
            seed = 9
            use_command_degrees = true
            [link_delay]
            enabled = true
            mean_ms = 30
            jitter_ms = 5
            [serial]
            read_timeout_ms = 250
            [watchdog]
            deadline_ms = 700
            [poll]
            moving_period_ms = 10
            [ipc]
            service_prefix = "test/"
            [brick]
            speed_noise = 0.0
            [motors]
            power = 50
            [[actions]]
            id = 0
            left_deg = 100
            right_deg = 100
            "#,
        )
        .expect("valid");
        assert_eq!(
            cfg.link_delay,
            Some((Duration::from_millis(30), Duration::from_millis(5)))
        );
        assert_eq!(
            cfg.serial_config(Path::new("/dev/x")).read_timeout,
            Duration::from_millis(250)
        );
        assert_eq!(cfg.actions.config().motors.power, 50);
        assert_eq!(cfg.ipc.service_prefix, "test/");
        assert_eq!(cfg.brick.speed_noise, 0.0);
    }

    #[test]
    fn a_settings_file_that_is_a_fifo_or_a_device_is_refused_unread() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let fifo = dir.path().join("bridge.toml");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
        for (path, kind) in [
            (fifo.as_path(), "a FIFO"),
            (Path::new("/dev/zero"), "a character device"),
        ] {
            let message = BridgeConfig::load(path).expect_err("refused").to_string();
            assert!(
                message.contains(&format!("is {kind}, not a regular file")),
                "{message}"
            );
            assert!(message.contains(&path.display().to_string()), "{message}");
        }
        let big = dir.path().join("big.toml");
        std::fs::File::create(&big)
            .and_then(|f| f.set_len(MAX_CONFIG_FILE_BYTES + 1))
            .expect("sparse file");
        let message = BridgeConfig::load(&big).expect_err("refused").to_string();
        assert!(message.contains("more than the 1048576 bytes"), "{message}");
    }

    #[test]
    fn errors_name_the_key() {
        let msg = |s: &str| {
            BridgeConfig::from_toml_str(s)
                .expect_err("invalid")
                .to_string()
        };
        assert!(msg("transport = \"serial:\"").contains("transport"));
        assert!(msg("[watchdog]\ndeadline_ms = 10").contains("watchdog.deadline_ms"));
        assert!(msg("[poll]\nmoving_period_ms = 2000").contains("poll.moving_period_ms"));
        assert!(msg("[brick]\ntime_constant_s = -1.0").contains("brick.time_constant_s"));
        assert!(msg("[motors]\npower = 101").contains("motors.power"));
        assert!(msg("[link_delay]\njitter_ms = 40").contains("link_delay.jitter_ms"));
        // Unknown keys are refused, with the key in the parser's message.
        assert!(msg("[watchdog]\ndeadline = 10").contains("deadline"));
        assert!(msg("bogus = 1").contains("bogus"));
    }

    /// Settings that are each in range but contradict each other are refused at load,
    /// naming the key and the reason, as are the `[ipc]` keys.
    #[test]
    fn contradictory_settings_name_the_key_and_reason() {
        let invalid = |s: &str| match BridgeConfig::from_toml_str(s) {
            Err(ConfigError::Setting(e)) => (e.key, e.reason),
            other => panic!("{s:?}: expected an invalid key, got {other:?}"),
        };
        let cases = [
            (
                "[watchdog]\ndeadline_ms = 100\n[poll]\nmoving_period_ms = 100",
                "poll.moving_period_ms",
                "must be shorter than watchdog.deadline_ms (100)",
            ),
            (
                "[link_delay]\nmean_ms = 5\njitter_ms = 6",
                "link_delay.jitter_ms",
                "need jitter_ms <= mean_ms",
            ),
            (
                "[motors]\nleft_port = \"B\"\nright_port = \"B\"",
                "motors.right_port",
                "must differ from left_port",
            ),
            (
                "[[actions]]\nid = 4\nleft_deg = 1\nright_deg = 1\n\
                 [[actions]]\nid = 4\nleft_deg = 2\nright_deg = 2",
                "actions[1].id",
                "duplicate action id 4",
            ),
            ("[ipc]\nwait = \"nap\"", "ipc.wait", "nap"),
            (
                "transport = \"usb:\"",
                "transport",
                "expected \"sim\", \"serial:PATH\", \"bluetooth:ADDR[@CHANNEL]\"",
            ),
            (
                "transport = \"bluetooth:00:16:53\"",
                "transport",
                "six hexadecimal bytes",
            ),
            (
                "transport = \"bluetooth:00:16:53:01:02:03@0\"",
                "transport",
                "channel after `@` must be 1 to 30",
            ),
            ("[ipc]\nbudget_us = 0", "ipc.budget_us", "at least 1"),
            (
                "[ipc]\nlatency_window = 0",
                "ipc.latency_window",
                "at least 1",
            ),
            (
                "[serial]\nmax_timeouts = 0",
                "serial.max_timeouts",
                "at least 1",
            ),
        ];
        for (text, key, reason) in cases {
            let (k, r) = invalid(text);
            assert_eq!(k, key, "{text}");
            assert!(r.contains(reason), "{text}: {r}");
        }
        // A value of the wrong type is a parse error naming the key.
        let err = BridgeConfig::from_toml_str("[watchdog]\ndeadline_ms = \"soon\"")
            .expect_err("wrong type")
            .to_string();
        assert!(err.contains("deadline_ms"), "{err}");
    }

    #[test]
    fn time_scale_is_a_positive_finite_brick_key() {
        assert_eq!(BridgeConfig::default().brick.time_scale, 1.0);
        let cfg = BridgeConfig::from_toml_str("[brick]\ntime_scale = 200.0").expect("valid");
        assert_eq!(cfg.brick.time_scale, 200.0);
        let cfg = BridgeConfig::from_toml_str("[brick]\ntime_scale = 0.5").expect("valid");
        assert_eq!(cfg.brick.time_scale, 0.5);
        for bad in ["0.0", "-1.0", "inf", "nan"] {
            let err = BridgeConfig::from_toml_str(&format!("[brick]\ntime_scale = {bad}"))
                .expect_err(bad)
                .to_string();
            assert!(err.contains("brick.time_scale"), "{bad}: {err}");
            assert!(err.contains("finite and > 0"), "{bad}: {err}");
        }
        // Found writing the config_parse fuzz target: a scale that overflows the brick
        // clock (the first `now + period` panicked) or freezes the brick is refused too.
        for bad in ["1e300", "10000.5", "1e-300", "0.0009"] {
            let err = BridgeConfig::from_toml_str(&format!("[brick]\ntime_scale = {bad}"))
                .expect_err(bad)
                .to_string();
            assert!(err.contains("brick.time_scale"), "{bad}: {err}");
            assert!(err.contains("must be in 0.001..=10000"), "{bad}: {err}");
        }
        for edge in ["0.001", "10000.0"] {
            BridgeConfig::from_toml_str(&format!("[brick]\ntime_scale = {edge}")).expect(edge);
        }
        // A serial transport accepts it (and ignores it when running).
        let cfg = BridgeConfig::from_toml_str(
            "transport = \"serial:/dev/rfcomm0\"\n[brick]\ntime_scale = 4.0",
        )
        .expect("valid");
        assert_eq!(cfg.brick.time_scale, 4.0);
    }

    #[test]
    fn launcher_overrides_without_a_file() {
        let cfg = BridgeConfig::default()
            .with_seed(11)
            .with_service_prefix("launch/7/")
            .expect("short prefix")
            .with_time_scale(50.0)
            .expect("valid scale");
        assert_eq!(cfg.seed, 11);
        assert_eq!(cfg.ipc.service_prefix, "launch/7/");
        assert_eq!(cfg.brick.time_scale, 50.0);
        let same = BridgeConfig::from_toml_str(
            "seed = 11\n[ipc]\nservice_prefix = \"launch/7/\"\n[brick]\ntime_scale = 50.0",
        )
        .expect("valid");
        assert_eq!(cfg, same);
        let long = "x".repeat(65);
        let err = BridgeConfig::default()
            .with_service_prefix(long)
            .expect_err("too long");
        assert!(err.to_string().contains("ipc.service_prefix"), "{err}");
        for bad in [0.0, -2.0, f64::NAN, f64::INFINITY, 1e300, 1e-300] {
            let err = BridgeConfig::default()
                .with_time_scale(bad)
                .expect_err("bad scale");
            assert!(err.to_string().contains("brick.time_scale"), "{bad}: {err}");
        }
    }

    /// The string-valued keys are enums: `transport` and `[ipc] wait` read their words, and
    /// refuse anything else naming the key and its line.
    #[test]
    fn every_enum_key_parses_and_refuses_a_bad_value_naming_the_key() {
        for (text, transport) in [
            ("sim", TransportKind::Sim),
            (
                "serial:/dev/rfcomm0",
                TransportKind::Serial("/dev/rfcomm0".into()),
            ),
            (
                "bluetooth:00:16:53:0A:0B:0C@1",
                TransportKind::Bluetooth(BluetoothTarget {
                    address: [0x00, 0x16, 0x53, 0x0A, 0x0B, 0x0C],
                    channel: 1,
                }),
            ),
            ("usb", TransportKind::Usb(None)),
            (
                "usb:0016530A0B0C",
                TransportKind::Usb(Some("0016530A0B0C".into())),
            ),
        ] {
            let cfg = BridgeConfig::from_toml_str(&format!("transport = \"{text}\"")).unwrap();
            assert_eq!(cfg.transport, transport);
            assert_eq!(transport.to_string(), text);
        }
        for text in ["block", "spin", "spin-then-block", "spin-then-block:25"] {
            let cfg = BridgeConfig::from_toml_str(&format!("[ipc]\nwait = \"{text}\"")).unwrap();
            assert_eq!(cfg.ipc.wait.to_string(), text);
            assert_eq!(cfg.ipc.wait_strategy(), Ok(cfg.ipc.wait));
        }
        for (text, key, line) in [
            ("seed = 1\ntransport = \"usb:\"", "transport", 2),
            ("transport = \"serial:\"", "transport", 1),
            ("transport = 5", "transport", 1),
            ("[poll]\n[ipc]\nwait = \"nap\"", "ipc.wait", 3),
            ("[ipc]\nwait = \"spin-then-block:0\"", "ipc.wait", 2),
            ("[motors]\nregulation = \"fast\"", "motors.regulation", 2),
        ] {
            let err = BridgeSettings::from_toml_in(text, Origin::Text).unwrap_err();
            assert_eq!((err.process, err.key.as_str()), (PROCESS, key), "{text}");
            assert_eq!(err.line(), Some(line), "{text}");
        }
    }

    /// A bad key of a bridge file, unknown or out of range, is reported with the file, the
    /// line and the key.
    #[test]
    fn a_bad_key_names_the_file_line_and_key() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bridge.toml");
        for (text, line, key) in [
            (
                "seed = 1\n[watchdog]\ndeadline = 10\n",
                3,
                "watchdog.deadline",
            ),
            (
                "seed = 1\n[watchdog]\ndeadline_ms = 10\n",
                3,
                "watchdog.deadline_ms",
            ),
            (
                "[[actions]]\nid = 1\nleft_deg = 1\nright_deg = 1\n\
                 [[actions]]\nid = 1\nleft_deg = 1\nright_deg = 2\n",
                6,
                "actions[1].id",
            ),
        ] {
            std::fs::write(&path, text).unwrap();
            let err = BridgeConfig::load(&path).unwrap_err();
            let ConfigError::Setting(e) = &err else {
                panic!("{err}")
            };
            assert_eq!((e.key.as_str(), e.line()), (key, Some(line)), "{text}");
            let shown = err.to_string();
            let prefix = format!("{}:{line}:1: {key}: ", path.display());
            assert!(shown.starts_with(&prefix), "{shown}");
        }
    }

    /// Written with serde and read back, the settings are the same, and so is the
    /// configuration they check into.
    #[test]
    fn settings_round_trip_through_toml() {
        let example: BridgeSettings =
            toml::from_str(include_str!("../bridge.example.toml")).expect("valid");
        assert_eq!(example, BridgeSettings::default());
        let mut busy = BridgeSettings {
            transport: TransportKind::Serial("/dev/rfcomm1".into()),
            seed: 7,
            use_command_degrees: true,
            ..BridgeSettings::default()
        };
        busy.link_delay.enabled = true;
        busy.watchdog.deadline_ms = 200_000;
        busy.ipc.wait = WaitStrategy::SpinThenBlock(Duration::from_micros(80));
        busy.ipc.service_prefix = "tes/9/".into();
        busy.ipc.latency_report = Some("/tmp/bridge.json".into());
        busy.brick.time_scale = 200.0;
        busy.actions.truncate(1);
        for settings in [BridgeSettings::default(), busy] {
            let text = toml::to_string(&settings).expect("serialises");
            let back = BridgeSettings::from_toml_in(&text, Origin::Text).expect("reads back");
            assert_eq!(back, settings, "{text}");
            assert_eq!(back.check(), settings.check());
            assert!(settings.check().is_ok());
        }
    }

    /// `/dev/null`, `/dev/zero`, a FIFO, a file and a directory are refused as no terminal,
    /// with the fix; a missing path says it does not exist; a pseudo-terminal passes.
    #[test]
    fn serial_paths_that_are_not_terminals_are_refused_with_the_fix() {
        let dir = tempfile::tempdir().expect("temp dir");
        let fifo = dir.path().join("fifo");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
        let file = dir.path().join("file");
        std::fs::write(&file, "").expect("file");
        for (path, kind) in [
            (Path::new("/dev/null"), "a character device"),
            (Path::new("/dev/zero"), "a character device"),
            (fifo.as_path(), "a FIFO"),
            (file.as_path(), "a regular file"),
            (dir.path(), "a directory"),
        ] {
            let transport = TransportKind::Serial(path.to_owned());
            let e = transport.check_device().expect_err("not a terminal");
            let text = e.to_string();
            assert!(
                text.starts_with(&format!(
                    "{} is {kind}, not a terminal device",
                    path.display()
                )),
                "{text}"
            );
            assert!(text.contains("`rfcomm bind`"), "{text}");
        }
        let missing = TransportKind::Serial(dir.path().join("rfcomm9"));
        let e = missing.check_device().expect_err("missing");
        assert!(e.to_string().contains("does not exist"), "{e}");
        let pty = nix::pty::openpty(None, None).expect("a pseudo-terminal");
        let slave = nix::unistd::ttyname(&pty.slave).expect("its name");
        TransportKind::Serial(slave)
            .check_device()
            .expect("a terminal");
        TransportKind::Sim.check_device().expect("no device");
    }
}
