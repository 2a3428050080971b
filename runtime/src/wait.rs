//! How a process waits for its next input: the [`WaitStrategy`] every TES process takes from
//! its `wait` key.
//!
//! * `auto` (default) — `anticipate` for a receiver whose messages are announced, `block` for
//!   one whose are not: a launch at the robot's pace (real-time factor above 0, where
//!   perception announces each observation) has the controller and the bridge anticipate and
//!   perception block; at the fastest pace, where nothing is announced, every process blocks
//!   ([`WaitStrategy::resolve`]). A receiver left with `auto` (outside a launch) anticipates
//!   announced messages only, and blocks for any other;
//! * `block` — sleep on the event listener until notified: no CPU burnt while idle;
//! * `spin` — busy-poll the subscriber: lowest latency, one core fully used;
//! * `spin-then-block` — busy-poll for a bounded time, then sleep;
//! * `anticipate` — sleep until shortly before the next message is due (announced by its
//!   sender, or learned from the gaps between messages), poll for a bounded window then, and
//!   block if it is late ([`crate::anticipate`]): the robot's pace at almost `spin`'s
//!   latency and almost `block`'s CPU.
//!
//! In a settings file a strategy is its string form (serde reads and writes it as the
//! [`FromStr`] and [`Display`](fmt::Display) forms below):
//!
//! ```
//! use tes_runtime::wait::WaitStrategy;
//!
//! #[derive(serde::Deserialize, serde::Serialize)]
//! struct Settings {
//!     wait: WaitStrategy,
//! }
//! let s: Settings = toml::from_str("wait = \"spin-then-block:50\"")?;
//! assert_eq!(s.wait.to_string(), "spin-then-block:50");
//! assert_eq!(toml::to_string(&s)?, "wait = \"spin-then-block:50\"\n");
//! assert!(toml::from_str::<Settings>("wait = \"nap\"").is_err());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::fmt;
use std::str::FromStr;
use std::time::Duration;

/// The idle tick: the longest a process's loop waits for its next input before it looks
/// again at its stop flag and its other chores (perception's map updates, the controller's
/// keep-alives, the bridge's stop flag).
pub const IDLE_TICK: Duration = Duration::from_millis(100);

/// How a process waits for its next input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum WaitStrategy {
    /// `Anticipate` where the messages are announced, `Block` where they are not
    /// ([`WaitStrategy::resolve`]).
    #[default]
    Auto,
    /// Sleep on the event until notified (no CPU while idle).
    Block,
    /// Busy-poll the subscriber (for a dedicated core).
    Spin,
    /// Busy-poll for up to the given time, then sleep on the event.
    SpinThenBlock(Duration),
    /// Sleep until shortly before the next message is due, poll for a bounded window, then
    /// block.
    Anticipate,
}

impl WaitStrategy {
    /// The spin time of `spin-then-block` when none is given: 200 µs.
    pub const DEFAULT_SPIN: Duration = Duration::from_micros(200);

    /// Whether it busy-polls while idle (`spin`, and `spin-then-block`'s first part): the
    /// strategies that trade CPU for latency whatever the pace.
    pub fn spins(self) -> bool {
        matches!(self, Self::Spin | Self::SpinThenBlock(_))
    }

    /// What a receiver waits by when its messages are `announced` (a heads-up before each,
    /// as perception gives at the robot's pace) or not: `auto` becomes `anticipate` or
    /// `block`; any other strategy stays as it is.
    ///
    /// ```
    /// use tes_runtime::wait::WaitStrategy;
    ///
    /// assert_eq!(WaitStrategy::Auto.resolve(true), WaitStrategy::Anticipate);
    /// assert_eq!(WaitStrategy::Auto.resolve(false), WaitStrategy::Block);
    /// assert_eq!(WaitStrategy::Spin.resolve(true), WaitStrategy::Spin);
    /// ```
    pub fn resolve(self, announced: bool) -> WaitStrategy {
        match self {
            Self::Auto if announced => Self::Anticipate,
            Self::Auto => Self::Block,
            other => other,
        }
    }

    /// Whether a receiver waiting by it may anticipate its messages: `anticipate`, and
    /// `auto` left unresolved (which anticipates announced messages only).
    pub fn anticipates(self) -> bool {
        matches!(self, Self::Anticipate | Self::Auto)
    }
}

impl fmt::Display for WaitStrategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WaitStrategy::Auto => f.write_str("auto"),
            WaitStrategy::Block => f.write_str("block"),
            WaitStrategy::Spin => f.write_str("spin"),
            WaitStrategy::Anticipate => f.write_str("anticipate"),
            WaitStrategy::SpinThenBlock(d) if *d == Self::DEFAULT_SPIN => {
                f.write_str("spin-then-block")
            }
            WaitStrategy::SpinThenBlock(d) => write!(f, "spin-then-block:{}", d.as_micros()),
        }
    }
}

/// A wait strategy that is not `auto`, `block`, `spin`, `spin-then-block`,
/// `spin-then-block:<µs>` or `anticipate`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown wait strategy {0:?}: expected auto, block, spin, spin-then-block, spin-then-block:<microseconds> or anticipate"
)]
pub struct BadWaitStrategy(pub String);

impl FromStr for WaitStrategy {
    type Err = BadWaitStrategy;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(Self::Auto),
            "block" => Ok(Self::Block),
            "spin" => Ok(Self::Spin),
            "anticipate" => Ok(Self::Anticipate),
            "spin-then-block" => Ok(Self::SpinThenBlock(Self::DEFAULT_SPIN)),
            other => other
                .strip_prefix("spin-then-block:")
                .and_then(|us| us.parse::<u64>().ok())
                .filter(|&us| us > 0)
                .map(|us| Self::SpinThenBlock(Duration::from_micros(us)))
                .ok_or_else(|| BadWaitStrategy(s.to_owned())),
        }
    }
}

impl serde::Serialize for WaitStrategy {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for WaitStrategy {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = WaitStrategy;

            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(
                    "a wait strategy: auto, block, spin, spin-then-block, spin-then-block:<microseconds> or anticipate",
                )
            }

            fn visit_str<E: serde::de::Error>(self, s: &str) -> Result<WaitStrategy, E> {
                s.parse().map_err(E::custom)
            }
        }
        deserializer.deserialize_str(Visitor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wait_strategies_parse_and_print() {
        for (text, strategy) in [
            ("auto", WaitStrategy::Auto),
            ("block", WaitStrategy::Block),
            ("spin", WaitStrategy::Spin),
            ("anticipate", WaitStrategy::Anticipate),
            (
                "spin-then-block",
                WaitStrategy::SpinThenBlock(WaitStrategy::DEFAULT_SPIN),
            ),
            (
                "spin-then-block:50",
                WaitStrategy::SpinThenBlock(Duration::from_micros(50)),
            ),
        ] {
            assert_eq!(text.parse::<WaitStrategy>(), Ok(strategy));
            assert_eq!(strategy.to_string(), text);
        }
        for bad in [
            "",
            "Block",
            "Auto",
            "spin-then-block:",
            "spin-then-block:0",
            "sleep",
        ] {
            let err = bad.parse::<WaitStrategy>().unwrap_err();
            assert!(
                err.to_string().contains("expected auto, block, spin"),
                "{err}"
            );
        }
    }

    #[derive(Debug, PartialEq, serde::Deserialize, serde::Serialize)]
    struct Settings {
        wait: WaitStrategy,
    }

    #[test]
    fn wait_strategies_are_read_and_written_as_their_string_form() {
        for text in [
            "auto",
            "block",
            "spin",
            "spin-then-block",
            "spin-then-block:50",
            "anticipate",
        ] {
            let doc = format!("wait = \"{text}\"\n");
            let s: Settings = toml::from_str(&doc).expect(text);
            assert_eq!(s.wait, text.parse().expect(text));
            assert_eq!(toml::to_string(&s).expect(text), doc);
        }
        for bad in ["nap", "spin-then-block:0", "Block", ""] {
            let err = toml::from_str::<Settings>(&format!("wait = \"{bad}\"")).expect_err(bad);
            // The same reason as `FromStr`'s, about the `wait` value.
            let reason = bad.parse::<WaitStrategy>().unwrap_err().to_string();
            assert_eq!(err.message(), reason, "{bad}");
            assert!(err.span().is_some(), "{bad}");
        }
        let err = toml::from_str::<Settings>("wait = 5").expect_err("a number");
        assert!(err.message().contains("a wait strategy"), "{err}");
    }

    #[test]
    fn auto_anticipates_what_is_announced_and_blocks_for_the_rest() {
        assert_eq!(WaitStrategy::default(), WaitStrategy::Auto);
        assert_eq!(WaitStrategy::Auto.resolve(true), WaitStrategy::Anticipate);
        assert_eq!(WaitStrategy::Auto.resolve(false), WaitStrategy::Block);
        for other in [
            WaitStrategy::Block,
            WaitStrategy::Spin,
            WaitStrategy::SpinThenBlock(WaitStrategy::DEFAULT_SPIN),
            WaitStrategy::Anticipate,
        ] {
            assert_eq!(other.resolve(true), other);
            assert_eq!(other.resolve(false), other);
        }
    }
}
