//! What a process (or one of its threads) spends in CPU per action, and its share of a core:
//! the cost beside a latency figure.
//!
//! A [`CpuMeter`] is marked after each measured action; the first mark starts the measured
//! part (the warm-up before it is left out), the last ends it. Reading the CPU clock is one
//! system call and allocates nothing, so marks may follow the acting path.
//!
//! ```
//! use tes_runtime::cpu::CpuMeter;
//!
//! let mut meter = CpuMeter::process();
//! meter.mark(); // the warm-up ends
//! let mut x = 0u64;
//! for i in 0..100_000u64 {
//!     x = x.wrapping_add(i * i);
//! }
//! std::hint::black_box(x);
//! meter.mark(); // one action
//! let used = meter.report().expect("two marks");
//! assert_eq!(used.actions, 1);
//! assert!(used.core_share >= 0.0 && used.cpu_us <= used.wall_us + 1_000);
//! ```

use nix::time::{ClockId, clock_gettime};
use serde::{Deserialize, Serialize};

use crate::clock::monotonic_ns;

/// CPU used over a measured part of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct CpuUse {
    /// CPU time, µs (user and system).
    pub cpu_us: u64,
    /// Wall time, µs.
    pub wall_us: u64,
    /// Actions in that time.
    pub actions: u64,
    /// CPU time over wall time: 1.0 is one core kept busy.
    pub core_share: f64,
    /// CPU time per action, µs.
    pub us_per_action: f64,
}

impl CpuUse {
    /// The use of `cpu_ns` of CPU over `wall_ns` for `actions` actions.
    pub fn new(cpu_ns: u64, wall_ns: u64, actions: u64) -> Self {
        Self {
            cpu_us: cpu_ns / 1000,
            wall_us: wall_ns / 1000,
            actions,
            core_share: if wall_ns == 0 {
                0.0
            } else {
                cpu_ns as f64 / wall_ns as f64
            },
            us_per_action: if actions == 0 {
                0.0
            } else {
                cpu_ns as f64 / 1000.0 / actions as f64
            },
        }
    }
}

/// Which CPU clock a meter reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scope {
    Process,
    Thread,
}

/// Counts CPU and wall time between its first and last marks. Allocation-free.
#[derive(Debug, Clone, Copy)]
pub struct CpuMeter {
    scope: Scope,
    /// (CPU ns, wall ns) at the first mark.
    start: Option<(u64, u64)>,
    /// (CPU ns, wall ns) at the last mark.
    last: (u64, u64),
    actions: u64,
}

impl CpuMeter {
    /// The whole process's CPU (every thread).
    pub fn process() -> Self {
        Self::new(Scope::Process)
    }

    /// The CPU of the thread that marks it (create and mark it on that thread).
    pub fn this_thread() -> Self {
        Self::new(Scope::Thread)
    }

    fn new(scope: Scope) -> Self {
        Self {
            scope,
            start: None,
            last: (0, 0),
            actions: 0,
        }
    }

    /// Marks the end of an action: the first mark starts the measured part, each later one
    /// counts an action.
    pub fn mark(&mut self) {
        let now = (self.cpu_ns(), monotonic_ns());
        if self.start.is_none() {
            self.start = Some(now);
        } else {
            self.actions += 1;
        }
        self.last = now;
    }

    /// Whether the measured part has started.
    pub fn started(&self) -> bool {
        self.start.is_some()
    }

    /// The use between the first and the last mark (`None` before two marks).
    pub fn report(&self) -> Option<CpuUse> {
        let (cpu0, wall0) = self.start?;
        (self.actions > 0).then(|| {
            CpuUse::new(
                self.last.0.saturating_sub(cpu0),
                self.last.1.saturating_sub(wall0),
                self.actions,
            )
        })
    }

    fn cpu_ns(&self) -> u64 {
        let clock = match self.scope {
            Scope::Process => ClockId::CLOCK_PROCESS_CPUTIME_ID,
            Scope::Thread => ClockId::CLOCK_THREAD_CPUTIME_ID,
        };
        clock_gettime(clock)
            .map(|t| (t.tv_sec() as u64) * 1_000_000_000 + t.tv_nsec() as u64)
            .unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_and_per_action_costs_follow_from_the_times() {
        let u = CpuUse::new(30_000_000, 1_000_000_000, 100);
        assert_eq!((u.cpu_us, u.wall_us, u.actions), (30_000, 1_000_000, 100));
        assert!((u.core_share - 0.03).abs() < 1e-12);
        assert!((u.us_per_action - 300.0).abs() < 1e-9);
        let idle = CpuUse::new(0, 0, 0);
        assert_eq!((idle.core_share, idle.us_per_action), (0.0, 0.0));
    }

    #[test]
    fn a_sleeping_thread_uses_a_small_share_and_a_busy_one_most_of_a_core() {
        let mut sleeping = CpuMeter::this_thread();
        assert!(sleeping.report().is_none());
        sleeping.mark();
        std::thread::sleep(std::time::Duration::from_millis(30));
        sleeping.mark();
        let slept = sleeping.report().unwrap();
        assert!(slept.core_share < 0.5, "{slept:?}");
        assert!(slept.wall_us >= 30_000, "{slept:?}");

        let mut busy = CpuMeter::this_thread();
        busy.mark();
        let start = std::time::Instant::now();
        while start.elapsed() < std::time::Duration::from_millis(30) {
            std::hint::spin_loop();
        }
        busy.mark();
        let spun = busy.report().unwrap();
        // CPU can never exceed wall time on one thread (a loaded machine may deschedule it).
        assert!(spun.cpu_us <= spun.wall_us + 100, "{spun:?}");
        assert!(spun.cpu_us > slept.cpu_us, "{spun:?} {slept:?}");
    }
}
