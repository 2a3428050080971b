//! What a controller run reports: a line per episode and a summary at the end.

use tes_runtime::latency::LatencyReport;

use crate::config::ThreadPlacement;

/// What a controller run did.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct ControllerSummary {
    /// Episodes that ended.
    pub episodes: u64,
    /// Commands published.
    pub actions: u64,
    /// Decisions over the latency budget (after the warm-up).
    pub misses: u64,
    /// Decision latency (observation stamped → command published), after the warm-up.
    pub latency: LatencyReport,
    /// The decision's first part: observation stamped → received by the acting loop (the
    /// publication and this process's wake-up; the operating system's share).
    #[serde(default)]
    pub wake: LatencyReport,
    /// The decision's second part: observation received → command published (the acting
    /// path's own work), against the same budget.
    #[serde(default)]
    pub compute: LatencyReport,
    /// Heap allocations on the acting path (observation received → command published) after
    /// the warm-up; `None` if the process does not count them (no
    /// [`CountingAllocator`](tes_runtime::alloc_count::CountingAllocator)).
    pub allocations: Option<u64>,
    /// Of `allocations`, those made inside iceoryx2 sending the command (0 since commands go
    /// through a blackboard entry; iceoryx2 0.10's publisher allocated one object per sample).
    pub ipc_allocations: Option<u64>,
    /// Observations refused (stale or duplicate sequence number, unknown state, bad reward).
    pub refused: u64,
    /// Library saves that failed (each is also logged).
    pub failed_saves: u64,
    /// Plans adopted from the planner.
    pub plans: u64,
    /// Who planned: `thread` or `between-polls` ([`Planning`](crate::config::Planning)).
    #[serde(default)]
    pub planning: String,
    /// Keep-alives sent to the bridge's watchdog while moves were under way
    /// ([`ControllerConfig::keepalive_ms`](crate::config::ControllerConfig::keepalive_ms)).
    #[serde(default)]
    pub keepalives: u64,
    /// Where the acting and planner threads ran ([`ControllerConfig::placement`](crate::config::ControllerConfig::placement)).
    #[serde(default)]
    pub placement: ThreadPlacement,
}

impl std::fmt::Display for ControllerSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let l = &self.latency;
        write!(
            f,
            "{} episodes, {} actions, decision latency p50 {} us p99 {} us max {} us, {} over the {} us budget \
             (wake-up p50 {} p99 {} max {} us; compute p50 {} p99 {} max {} us, {} over), ",
            self.episodes,
            self.actions,
            l.p50_us,
            l.p99_us,
            l.max_us,
            self.misses,
            l.budget_us,
            self.wake.p50_us,
            self.wake.p99_us,
            self.wake.max_us,
            self.compute.p50_us,
            self.compute.p99_us,
            self.compute.max_us,
            self.compute.misses,
        )?;
        match self.allocations {
            Some(n) => write!(
                f,
                "{n} allocations on the acting path ({} inside iceoryx2's send), ",
                self.ipc_allocations.unwrap_or(0)
            )?,
            None => f.write_str("allocations not counted, ")?,
        }
        write!(
            f,
            "{} observations refused, {} plans ({}), {} keep-alives; acting thread {}, planner {}",
            self.refused,
            self.plans,
            self.planning,
            self.keepalives,
            on_cpu(self.placement.acting),
            on_cpu(self.placement.planner),
        )
    }
}

/// "CPU n" or "unpinned".
pub(crate) fn on_cpu(cpu: Option<usize>) -> String {
    cpu.map_or("unpinned".to_owned(), |c| format!("CPU {c}"))
}

/// One finished episode, as printed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeLine {
    /// Episode index (from perception).
    pub episode: u32,
    /// Reward collected.
    pub reward: f64,
    /// Actions taken.
    pub steps: u32,
    /// Decision latency p50 / p99, µs.
    pub p50_us: u64,
    /// 99th percentile.
    pub p99_us: u64,
    /// Decisions over budget in the episode.
    pub misses: u64,
}

impl std::fmt::Display for EpisodeLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "episode {}: reward {:.2}, {} steps, decision latency p50 {} us p99 {} us, {} over budget",
            self.episode, self.reward, self.steps, self.p50_us, self.p99_us, self.misses
        )
    }
}
