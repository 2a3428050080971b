//! Feeds arbitrary text to every settings parser: the controller's, perception's and the
//! bridge's (the `[controller]`, `[perception]` and `[bridge]` tables of a launch file), and
//! the launch file's as a whole (`tes_launch::LaunchFile`, with the children's settings it
//! derives).
//!
//! A parser must never panic; an error must name a key and a reason, and be placed in the
//! text it came from (at a line whenever the text sets the key); a settings value it accepts
//! must pass its own check and be usable as the process uses it at start (the durations it
//! computes from it must exist).
#![no_main]

use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use tes_bridge::config::{BridgeConfig, ConfigError};
use tes_controller::config::ControllerConfig;
use tes_launch::LaunchFile;
use tes_perception_sim::process::PerceptionConfig;
use tes_runtime::settings::Origin;

/// Every refusal names its process, a key and a reason, and is placed in the text.
macro_rules! assert_named {
    ($e:expr, $process:expr) => {{
        let e = &$e;
        assert_eq!(e.process, $process, "{e}");
        assert!(!e.key.is_empty() && !e.reason.is_empty(), "{e}");
        assert!(e.location.is_some(), "not placed: {e}");
    }};
}

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    match ControllerConfig::from_toml(&text) {
        Ok(cfg) => {
            let checked = cfg.check().expect("accepted settings pass their own check");
            // `controller::process::run` waits this long for the world map.
            assert!(
                Duration::try_from_secs_f64(cfg.map_timeout_s) == Ok(checked.map_timeout()),
                "controller map_timeout_s = {} accepted but is no duration",
                cfg.map_timeout_s
            );
        }
        Err(e) => assert_named!(e, "controller"),
    }
    match PerceptionConfig::from_toml(&text) {
        Ok(cfg) => {
            assert!(
                cfg.check().is_ok(),
                "accepted settings pass their own check"
            );
            // `perception_sim::process::run` settles for settle_ms × real_time_factor.
            let settle = Duration::from_millis(cfg.settle_ms).as_secs_f64() * cfg.real_time_factor;
            assert!(
                Duration::try_from_secs_f64(settle).is_ok(),
                "perception settle_ms = {} × real_time_factor = {} accepted but is no duration",
                cfg.settle_ms,
                cfg.real_time_factor
            );
        }
        Err(e) => assert_named!(e, "perception"),
    }
    match BridgeConfig::from_toml_str(&text) {
        Ok(cfg) => {
            // The bridge runs its periods on a clock `time_scale` times faster than the wall
            // clock, adding them to its time: a day of brick time must not overflow.
            let day = Duration::from_secs(86_400).as_secs_f64() * cfg.brick.time_scale;
            assert!(
                Duration::try_from_secs_f64(day)
                    .ok()
                    .and_then(|d| d.checked_add(cfg.watchdog_deadline))
                    .and_then(|d| d.checked_add(cfg.poll.idle_period()))
                    .and_then(|d| d.checked_add(cfg.poll.keepalive_period()))
                    .is_some(),
                "bridge brick.time_scale = {} accepted but overflows its clock",
                cfg.brick.time_scale
            );
            assert!(!cfg.actions.config().actions.is_empty());
        }
        Err(ConfigError::Setting(e)) => assert_named!(e, "bridge"),
        Err(e @ ConfigError::Read { .. }) => panic!("no file was read: {e}"),
    }
    // A launch file: its children's settings, the launch-wide values filled in, are each
    // checked again; a refusal names the table's process, a key and a reason, placed.
    if let Ok(file) = LaunchFile::from_toml(&text, Origin::Text)
        && let Err(e) = file.children()
    {
        assert!(!e.key.is_empty() && !e.reason.is_empty(), "{e}");
        assert!(e.location.is_some(), "not placed: {e}");
    }
});
