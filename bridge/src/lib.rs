//! The TES bridge: the robot side of the paper's Fig. 7.
//!
//! Turns the controller's abstract actions into LEGO Mindstorms NXT direct commands and
//! reports the wheels' tacho counts back. The parts, each usable alone:
//!
//! - [`nxt`]: the NXT Bluetooth protocol subset, byte for byte — framing, SETOUTPUTSTATE,
//!   GETOUTPUTSTATE, RESETMOTORPOSITION, GETBATTERYLEVEL, KEEPALIVE, PLAYTONE,
//!   GETFIRMWAREVERSION, GETDEVICEINFO, replies and status codes. Allocation-free, never panics.
//! - [`brick`]: a simulated brick that answers telegrams like the firmware, with motor
//!   dynamics stepped by a clock you pass in; deterministic for a seed.
//! - [`transport`]: `sim` (the simulated brick in-process), the real links — `usb` (the
//!   NXT's bulk endpoints), `bluetooth:ADDR` (a kernel RFCOMM socket), `serial:PATH`
//!   (`/dev/rfcomm0`, or a pseudo-terminal) — and an optional simulated link delay; every
//!   exchange's round trip is timed.
//! - [`scan`]: the bricks this machine can reach over USB and Bluetooth, and why not.
//! - [`actions`]: the config-driven action → SETOUTPUTSTATE mapping (the paper's three
//!   actions by default).
//! - [`watchdog`]: brakes the motors when commands stop arriving while a motor runs.
//! - [`bridge`]: the logic tying these together, free of IPC; [`ipc`] runs it over iceoryx2;
//!   [`process`] builds it all from a config (the `tes-bridge run` binary and `tes launch`).
//! - [`pty`]: serves the simulated brick on a pseudo-terminal for any NXT client.
//! - [`config`]: the TOML configuration; `transport = "usb"` swaps in a real NXT.
//!
//! ```
//! use std::time::Duration;
//! use tes_bridge::actions::ActionMap;
//! use tes_bridge::brick::{SimBrick, SimBrickConfig};
//! use tes_bridge::clock::{Clock, ManualClock};
//! use tes_bridge::nxt::{Port, Reply, Request};
//! use tes_bridge::transport::{SimTransport, Transport};
//!
//! let clock = ManualClock::new();
//! let mut link = SimTransport::new(SimBrick::new(SimBrickConfig::default(), 1)?, clock.clone());
//! // Action 0 of the paper: both wheels 246°.
//! for cmd in ActionMap::paper_default().for_action(0)?.iter() {
//!     link.send(&Request::SetOutputState(*cmd))?;
//! }
//! clock.advance(Duration::from_secs(1));
//! let Reply::OutputState { state, .. } = link.request(&Request::GetOutputState { port: Port::C })? else {
//!     unreachable!("GETOUTPUTSTATE is answered with an output state");
//! };
//! assert!((246..270).contains(&state.tacho_count));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod actions;
pub mod brick;
pub mod bridge;
pub mod clock;
pub mod config;
pub mod ipc;
pub mod nxt;
pub mod process;
pub mod pty;
pub mod scan;
pub mod transport;
pub mod watchdog;
