//! The perception process's settings: the `[perception]` table of a launch file (or a file of
//! its own), checked once into the values the process runs with ([`CheckedPerception`]).

use std::time::Duration;

use serde::{Deserialize, Serialize};
use tes_runtime::channel::WaitStrategy;
use tes_runtime::settings::Origin;

use crate::arena::ArenaId;

/// Settings of the perception-sim process (TOML; every key optional). Written back with serde
/// (`toml::to_string`), they read back the same. Each field's doc is its key's entry in the
/// launch file's reference (`tes launch --print-config`): what it does, then its unit or
/// values on a `Values:` line; the defaults are this struct's `Default`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerceptionConfig {
    /// The arena simulated.
    ///
    /// Values: `1` | `2` | `3`.
    pub arena: u32,
    /// Episodes to run before exiting.
    ///
    /// Values: count, at least 1.
    pub episodes: u32,
    /// Stop after this many actions in all, ending the episode then as truncated (for
    /// benchmarks that run a fixed number of actions).
    ///
    /// Values: count; 0 = no limit.
    pub actions: u64,
    /// Seed of the start poses and the wheel slip.
    ///
    /// Values: integer, 0 to 2^63 - 1.
    pub seed: u64,
    /// 1.0 = the paper's physical settle after each motion (`settle_ms`); 0 = none.
    ///
    /// Values: factor, finite, at least 0.
    pub real_time_factor: f64,
    /// The idle time after a motion, and after the robot is put at an episode's start, at
    /// real-time factor 1 (scaled by `real_time_factor`).
    ///
    /// Values: ms.
    pub settle_ms: u64,
    /// Actions after which an episode is cut off.
    ///
    /// Values: count, at least 1.
    pub step_cap: u32,
    /// How perception waits for motion reports (`auto`: anticipate announced messages
    /// only, block for any other; a launch resolves it, see `[launch] wait`).
    ///
    /// Values: `auto` | `block` | `spin` | `spin-then-block` | `spin-then-block:<µs>` |
    /// `anticipate`.
    pub wait: WaitStrategy,
    /// Prefixed to every iceoryx2 service name (to run groups side by side).
    ///
    /// Values: text, at most [`SERVICE_PREFIX_MAX`](tes_runtime::settings::SERVICE_PREFIX_MAX)
    /// bytes.
    pub service_prefix: String,
    /// Re-publish an observation (flagged RESYNC) when no motion report follows it within
    /// this time.
    ///
    /// Values: ms, at least 1.
    pub motor_timeout_ms: u64,
    /// The NXT output port driving the left wheel (as the bridge's `[bridge.motors]
    /// left_port`).
    ///
    /// Values: `0` (A) | `1` (B) | `2` (C); not `right_port`.
    pub left_port: usize,
    /// The NXT output port driving the right wheel (as the bridge's `[bridge.motors]
    /// right_port`).
    ///
    /// Values: `0` (A) | `1` (B) | `2` (C); not `left_port`.
    pub right_port: usize,
    /// Where to write the run's trajectory: one CSV row per action (state, action, effect,
    /// reward, poses before and after, why the episode ended). Unset: none; a launch writes
    /// `trajectory.csv` in its run folder.
    ///
    /// Values: path.
    ///
    /// Example: `"/path/to/trajectory.csv"`.
    pub trajectory: Option<std::path::PathBuf>,
    /// Where to write the run's summary as JSON at its end: observations, resyncs, reward,
    /// and the process's CPU over the actions after `warmup_actions` (`tes bench latency`
    /// reads it). Unset: none.
    ///
    /// Values: path.
    pub report: Option<std::path::PathBuf>,
    /// Actions left out of the report's CPU figure (the run's start).
    ///
    /// Values: count.
    pub warmup_actions: u64,
}

impl Default for PerceptionConfig {
    fn default() -> Self {
        Self {
            arena: 3,
            episodes: 20,
            actions: 0,
            seed: 1,
            real_time_factor: 0.0,
            settle_ms: 200,
            step_cap: 100,
            wait: WaitStrategy::Block,
            service_prefix: String::new(),
            motor_timeout_ms: 5000,
            left_port: 1,
            right_port: 2,
            trajectory: None,
            report: None,
            warmup_actions: 0,
        }
    }
}

/// A setting that is unknown, mistyped or out of range, named by its key (and, read from a
/// file, by the file and line).
pub type ConfigError = tes_runtime::settings::SettingError;

/// The process name [`ConfigError`]s of these settings carry.
pub const PROCESS: &str = "perception";

/// A [`PerceptionConfig`] that passed [`PerceptionConfig::check`], with what its keys resolve
/// to.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedPerception {
    config: PerceptionConfig,
    arena: ArenaId,
    settle: Duration,
    motor_timeout: Duration,
}

impl CheckedPerception {
    /// The settings as given.
    pub fn config(&self) -> &PerceptionConfig {
        &self.config
    }

    /// The settings as given, taken out.
    pub fn into_config(self) -> PerceptionConfig {
        self.config
    }

    /// How perception waits for motion reports (`wait`).
    pub fn wait(&self) -> WaitStrategy {
        self.config.wait
    }

    /// The arena (`arena`).
    pub fn arena(&self) -> ArenaId {
        self.arena
    }

    /// The idle time after a motion: `settle_ms` × `real_time_factor`.
    pub fn settle(&self) -> Duration {
        self.settle
    }

    /// How long an observation waits for its motion report (`motor_timeout_ms`).
    pub fn motor_timeout(&self) -> Duration {
        self.motor_timeout
    }
}

impl PerceptionConfig {
    /// Parses a TOML document with these keys (unknown keys are refused) and checks it; an
    /// error names the key and its line.
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        Self::from_toml_in(text, Origin::Text)
    }

    /// [`from_toml`](Self::from_toml) for a document from `origin` (the file the user gave),
    /// which an error names.
    pub fn from_toml_in(text: &str, origin: Origin) -> Result<Self, ConfigError> {
        let (cfg, _) = tes_runtime::settings::parse_checked(PROCESS, text, origin, Self::check)?;
        Ok(cfg)
    }

    /// Checks every key; the first bad one is reported. Returns the settings with what they
    /// resolve to (see [`CheckedPerception`]).
    pub fn check(&self) -> Result<CheckedPerception, ConfigError> {
        let bad = |key, reason: &str| Err(ConfigError::new(PROCESS, key, reason));
        let Ok(arena) = ArenaId::from_number(self.arena) else {
            return bad("arena", "must be 1, 2 or 3");
        };
        if self.episodes == 0 {
            return bad("episodes", "must be at least 1");
        }
        let settle =
            (self.real_time_factor.is_finite() && self.real_time_factor >= 0.0).then(|| {
                Duration::try_from_secs_f64(self.settle_ms as f64 / 1000.0 * self.real_time_factor)
            });
        let Some(Ok(settle)) = settle else {
            return bad(
                "real_time_factor",
                "must be a finite number >= 0 (and settle_ms x real_time_factor a duration)",
            );
        };
        if self.step_cap == 0 {
            return bad("step_cap", "must be at least 1");
        }
        if self.motor_timeout_ms == 0 {
            return bad("motor_timeout_ms", "must be at least 1");
        }
        tes_runtime::settings::service_prefix(PROCESS, "service_prefix", &self.service_prefix)?;
        let port_rule = "left_port and right_port must be different ports 0-2";
        if self.right_port > 2 && self.left_port <= 2 {
            return bad("right_port", port_rule);
        }
        if self.left_port > 2 || self.left_port == self.right_port {
            return bad("left_port", port_rule);
        }
        Ok(CheckedPerception {
            config: self.clone(),
            arena,
            settle,
            motor_timeout: Duration::from_millis(self.motor_timeout_ms),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_are_checked_by_key() {
        assert!(PerceptionConfig::default().check().is_ok());
        for (text, key) in [
            ("arena = 4", "arena"),
            ("episodes = 0", "episodes"),
            ("real_time_factor = 1e300", "real_time_factor"),
            ("real_time_factor = -1.0", "real_time_factor"),
            ("real_time_factor = nan", "real_time_factor"),
            ("step_cap = 0", "step_cap"),
            ("motor_timeout_ms = 0", "motor_timeout_ms"),
            ("wait = \"doze\"", "wait"),
            ("left_port = 2", "left_port"),
            ("left_port = 3", "left_port"),
            ("right_port = 3", "right_port"),
        ] {
            assert_eq!(
                PerceptionConfig::from_toml(text).unwrap_err().key,
                key,
                "{text}"
            );
        }
        assert!(
            PerceptionConfig::from_toml("arenna = 1")
                .unwrap_err()
                .reason
                .contains("arenna")
        );
        let checked = PerceptionConfig::from_toml("arena = 1\nreal_time_factor = 0.5")
            .unwrap()
            .check()
            .unwrap();
        assert_eq!(checked.arena(), ArenaId::Env1);
        assert_eq!(checked.settle(), Duration::from_millis(100));
        assert_eq!(checked.motor_timeout(), Duration::from_secs(5));
        assert_eq!(checked.wait(), WaitStrategy::Block);
    }

    /// Like every process's, perception's service prefix is held to the one limit.
    #[test]
    fn a_service_prefix_longer_than_the_limit_is_refused() {
        let fits = "p".repeat(tes_runtime::settings::SERVICE_PREFIX_MAX);
        let cfg = PerceptionConfig {
            service_prefix: fits.clone(),
            ..PerceptionConfig::default()
        };
        assert!(cfg.check().is_ok());
        let err = PerceptionConfig::from_toml(&format!("seed = 2\nservice_prefix = \"{fits}p\"\n"))
            .unwrap_err();
        assert_eq!(
            (err.process, err.key.as_str(), err.line()),
            (PROCESS, "service_prefix", Some(2))
        );
        assert_eq!(err.reason, "must be at most 64 bytes");
    }

    #[test]
    fn the_wait_key_parses_and_refuses_a_bad_value_naming_the_key() {
        for text in ["block", "spin", "spin-then-block", "spin-then-block:9"] {
            let cfg = PerceptionConfig::from_toml(&format!("wait = \"{text}\"")).unwrap();
            assert_eq!(cfg.wait, text.parse().unwrap());
        }
        for bad in ["\"doze\"", "\"spin-then-block:0\"", "1"] {
            let err = PerceptionConfig::from_toml(&format!("arena = 1\nwait = {bad}")).unwrap_err();
            assert_eq!((err.process, err.key.as_str()), (PROCESS, "wait"), "{bad}");
            assert_eq!(err.line(), Some(2), "{bad}");
        }
    }

    #[test]
    fn a_range_error_names_the_file_and_line() {
        let origin = Origin::File("perception.toml".into());
        let err = PerceptionConfig::from_toml_in("seed = 4\nstep_cap = 0\n", origin).unwrap_err();
        assert_eq!(
            err.to_string(),
            "perception.toml:2:1: step_cap: must be at least 1"
        );
    }

    #[test]
    fn settings_round_trip_through_toml() {
        let cfgs = [
            PerceptionConfig::default(),
            PerceptionConfig {
                arena: 2,
                episodes: u32::MAX,
                actions: 11_000,
                seed: u64::try_from(i64::MAX).unwrap(),
                real_time_factor: 0.01,
                settle_ms: 150,
                step_cap: 7,
                wait: WaitStrategy::SpinThenBlock(Duration::from_micros(20)),
                service_prefix: "tes-bench/1/".into(),
                motor_timeout_ms: 400,
                left_port: 0,
                right_port: 2,
                trajectory: Some("/tmp/run/trajectory.csv".into()),
                report: Some("/tmp/run/perception.json".into()),
                warmup_actions: 30,
            },
        ];
        for cfg in cfgs {
            let text = toml::to_string(&cfg).expect("serialises");
            let back = PerceptionConfig::from_toml(&text).expect("reads back");
            assert_eq!(back, cfg, "{text}");
            assert_eq!(back.check(), cfg.check());
        }
    }
}
