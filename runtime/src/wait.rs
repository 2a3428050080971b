//! How a process waits for its next input: the [`WaitStrategy`] every TES process takes from
//! its `wait` key.
//!
//! * `block` (default) — sleep on the event listener until notified: no CPU burnt while idle;
//! * `spin` — busy-poll the subscriber: lowest latency, one core fully used;
//! * `spin-then-block` — busy-poll for a bounded time, then sleep.

use std::fmt;
use std::str::FromStr;
use std::time::Duration;

/// How a process waits for its next input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum WaitStrategy {
    /// Sleep on the event until notified (no CPU while idle).
    #[default]
    Block,
    /// Busy-poll the subscriber (for a dedicated core).
    Spin,
    /// Busy-poll for up to the given time, then sleep on the event.
    SpinThenBlock(Duration),
}

impl WaitStrategy {
    /// The spin time of `spin-then-block` when none is given: 200 µs.
    pub const DEFAULT_SPIN: Duration = Duration::from_micros(200);
}

impl fmt::Display for WaitStrategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WaitStrategy::Block => f.write_str("block"),
            WaitStrategy::Spin => f.write_str("spin"),
            WaitStrategy::SpinThenBlock(d) if *d == Self::DEFAULT_SPIN => {
                f.write_str("spin-then-block")
            }
            WaitStrategy::SpinThenBlock(d) => write!(f, "spin-then-block:{}", d.as_micros()),
        }
    }
}

/// A wait strategy that is not `block`, `spin`, `spin-then-block` or `spin-then-block:<µs>`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown wait strategy {0:?}: expected block, spin, spin-then-block or spin-then-block:<microseconds>"
)]
pub struct BadWaitStrategy(pub String);

impl FromStr for WaitStrategy {
    type Err = BadWaitStrategy;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "block" => Ok(Self::Block),
            "spin" => Ok(Self::Spin),
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wait_strategies_parse_and_print() {
        for (text, strategy) in [
            ("block", WaitStrategy::Block),
            ("spin", WaitStrategy::Spin),
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
            "spin-then-block:",
            "spin-then-block:0",
            "sleep",
        ] {
            let err = bad.parse::<WaitStrategy>().unwrap_err();
            assert!(err.to_string().contains("expected block, spin"), "{err}");
        }
    }
}
