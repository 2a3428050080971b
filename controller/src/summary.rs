//! What a controller run reports: a line per episode and a summary at the end.

use tes_runtime::channel::Catches;
use tes_runtime::cpu::CpuUse;
use tes_runtime::latency::LatencyReport;

use crate::config::ThreadPlacement;

/// What a controller run did.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct ControllerSummary {
    /// Episodes that ended.
    pub episodes: u64,
    /// Commands published.
    pub actions: u64,
    /// Of `actions`, those of an episode the run stopped before it ended (a stop requested
    /// mid-episode): learned from, though no episode line counts them.
    #[serde(default)]
    pub unfinished_steps: u64,
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
    /// When the acting loop learned: `decide-first` or `learn-first`
    /// ([`Order`](crate::acting::Order)).
    #[serde(default)]
    pub order: String,
    /// Deciding first, the work after the command: command published → learned from the
    /// observation and handed the planner the model, against the same budget (learning
    /// first, it is part of `compute` and this is empty).
    #[serde(default)]
    pub learn: LatencyReport,
    /// Observations published before the learning after the previous command had finished;
    /// each waited for it, and its decision's latency includes the wait.
    #[serde(default)]
    pub learning_overran: u64,
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
    /// The process's CPU after the warm-up (every thread: acting, planner, saver).
    #[serde(default)]
    pub cpu: Option<CpuUse>,
    /// Of `cpu`, the acting thread's.
    #[serde(default)]
    pub acting_thread_cpu: Option<CpuUse>,
    /// Waiting by `anticipate`: how observations came against their poll windows.
    #[serde(default)]
    pub catches: Option<Catches>,
    /// The view library the run loaded and what became of it; `None` if the run stopped
    /// before it loaded one (before the world map came).
    #[serde(default)]
    pub library: Option<LibraryFacts>,
}

/// How many views and finished tasks a view library holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct LibraryCounts {
    /// Views.
    pub views: usize,
    /// Tasks finished (a controller run is one task).
    pub tasks: u32,
}

impl LibraryCounts {
    /// The counts of `library`.
    pub fn of(library: &tes_learning::library::ViewLibrary) -> Self {
        Self {
            views: library.len(),
            tasks: library.tasks_seen(),
        }
    }
}

impl std::fmt::Display for LibraryCounts {
    /// "9 views, 3 tasks" (singular for one).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let plural = |n: u64| if n == 1 { "" } else { "s" };
        write!(
            f,
            "{} view{}, {} task{}",
            self.views,
            plural(self.views as u64),
            self.tasks,
            plural(u64::from(self.tasks))
        )
    }
}

/// What became of the library file at the end of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LibraryEnd {
    /// Saved at shutdown, with this run's task finished in it.
    Saved,
    /// Nothing was learned from a real motion, so the file was not written at shutdown (nor
    /// during the run): it is as it was when the run started (or still absent).
    #[default]
    LeftAsItWas,
    /// The save at shutdown failed (logged): the file holds its last good save — the one the
    /// run started from, or a save after one of its episodes.
    NotSaved,
}

/// The view library a controller run loaded and saved: the facts the end of a launch states.
#[derive(Debug, Clone, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct LibraryFacts {
    /// The library file (as displayed; a path that is not UTF-8 is shown lossily).
    #[serde(default)]
    pub path: String,
    /// True when there was no library file and the run started from an empty library.
    #[serde(default)]
    pub started_empty: bool,
    /// What the loaded library held.
    #[serde(default)]
    pub before: LibraryCounts,
    /// What the library saved at shutdown holds (`before` unless [`LibraryEnd::Saved`]).
    #[serde(default)]
    pub after: LibraryCounts,
    /// What became of the file.
    #[serde(default)]
    pub end: LibraryEnd,
}

impl std::fmt::Display for LibraryFacts {
    /// One line: `library PATH: 9 views, 3 tasks -> 11 views, 4 tasks (saved)`, or `started
    /// empty (no library file yet)` for the start, or what happened instead of a save.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "library {}: ", self.path)?;
        if self.started_empty {
            f.write_str("started empty (no library file yet)")?;
        } else {
            write!(f, "{}", self.before)?;
        }
        match (self.end, self.started_empty) {
            (LibraryEnd::Saved, _) => write!(f, " -> {} (saved)", self.after),
            (LibraryEnd::LeftAsItWas, false) => f.write_str("; left as it was: nothing learned"),
            (LibraryEnd::LeftAsItWas, true) => {
                f.write_str("; nothing learned, so no library file was written")
            }
            (LibraryEnd::NotSaved, _) => f.write_str(
                "; NOT saved at shutdown (the save failed: the file, if any, is its last good save)",
            ),
        }
    }
}

/// `n` and `noun`, plural unless `n` is 1: "1 step", "20 steps".
pub fn count(n: u64, noun: &str) -> String {
    match n {
        1 => format!("1 {noun}"),
        _ => format!("{n} {noun}s"),
    }
}

impl std::fmt::Display for ControllerSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.actions == 0 {
            // No decision was made (no world map or no observation came): no latency,
            // budget or planner to speak of.
            return write!(
                f,
                "{}, 0 actions: no decision was made{}",
                count(self.episodes, "episode"),
                match self.refused {
                    0 => String::new(),
                    n => format!(" ({} refused)", count(n, "observation")),
                }
            );
        }
        let l = &self.latency;
        write!(
            f,
            "{}, {}{}, decision latency p50 {} us p99 {} us max {} us, {} over the {} us budget \
             (wake-up p50 {} p99 {} max {} us; compute p50 {} p99 {} max {} us, {} over), ",
            count(self.episodes, "episode"),
            count(self.actions, "action"),
            match self.unfinished_steps {
                0 => String::new(),
                n => format!(" ({n} in the unfinished episode)"),
            },
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
        if self.learn.count > 0 {
            write!(
                f,
                "learning after the command p50 {} p99 {} max {} us, {} waited for it, ",
                self.learn.p50_us,
                self.learn.p99_us,
                self.learn.max_us,
                count(self.learning_overran, "observation")
            )?;
        }
        match self.allocations {
            Some(n) => write!(
                f,
                "{} on the acting path ({} inside iceoryx2's send), ",
                count(n, "allocation"),
                self.ipc_allocations.unwrap_or(0)
            )?,
            None => f.write_str("allocations not counted, ")?,
        }
        write!(
            f,
            "{} refused, {} ({}), {}; acting thread {}, planner {}",
            count(self.refused, "observation"),
            count(self.plans, "plan"),
            self.planning,
            count(self.keepalives, "keep-alive"),
            on_cpu(self.placement.acting),
            on_cpu(self.placement.planner),
        )
    }
}

/// "CPU n" or "unpinned".
pub(crate) fn on_cpu(cpu: Option<usize>) -> String {
    cpu.map_or("unpinned".to_owned(), |c| format!("CPU {c}"))
}

/// One finished episode, as printed (and read back by the launcher: [`EpisodeLine::parse`]).
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
    /// The episode's slowest decision, µs.
    pub max_us: u64,
    /// Decisions over budget in the episode.
    pub misses: u64,
}

impl std::fmt::Display for EpisodeLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "episode {}: reward {:.2}, {}, decision latency p50 {} us p99 {} us max {} us, \
             {} over budget",
            self.episode,
            self.reward,
            count(u64::from(self.steps), "step"),
            self.p50_us,
            self.p99_us,
            self.max_us,
            self.misses
        )
    }
}

impl EpisodeLine {
    /// Reads a line as [`Display`](std::fmt::Display) writes it (the reward to its two
    /// printed decimals); `None` for any other line.
    ///
    /// ```
    /// use tes_controller::summary::EpisodeLine;
    ///
    /// let line = EpisodeLine { episode: 3, reward: 1.5, steps: 12, p50_us: 4, p99_us: 9, max_us: 31, misses: 0 };
    /// assert_eq!(EpisodeLine::parse(&line.to_string()), Some(line));
    /// assert_eq!(EpisodeLine::parse("controller: done"), None);
    /// ```
    pub fn parse(text: &str) -> Option<Self> {
        let rest = text.strip_prefix("episode ")?;
        let (episode, rest) = rest.split_once(": reward ")?;
        let (reward, rest) = rest.split_once(", ")?;
        let (steps, rest) = rest.split_once(", decision latency p50 ")?;
        let steps = steps
            .strip_suffix(" steps")
            .or_else(|| steps.strip_suffix(" step"))?;
        let (p50, rest) = rest.split_once(" us p99 ")?;
        let (p99, rest) = rest.split_once(" us max ")?;
        let (max, rest) = rest.split_once(" us, ")?;
        let misses = rest.strip_suffix(" over budget")?;
        Some(Self {
            episode: episode.parse().ok()?,
            reward: reward.parse().ok()?,
            steps: steps.parse().ok()?,
            p50_us: p50.parse().ok()?,
            p99_us: p99.parse().ok()?,
            max_us: max.parse().ok()?,
            misses: misses.parse().ok()?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The launcher reads back every episode line the controller prints.
        #[test]
        fn episode_lines_read_back(
            episode: u32, centi in -100_000i64..100_000, steps: u32,
            p50_us: u64, p99_us: u64, max_us: u64, misses: u64,
        ) {
            let line = EpisodeLine {
                episode, reward: centi as f64 / 100.0, steps, p50_us, p99_us, max_us, misses,
            };
            let back = EpisodeLine::parse(&line.to_string()).expect("reads back");
            proptest::prop_assert_eq!(back, line);
        }
    }

    /// A run that decided nothing (a brick that never answered) says so, with no latency,
    /// budget or planner of a decision that never was; one of anything is singular.
    #[test]
    fn a_summary_without_decisions_says_so_and_counts_are_singular_for_one() {
        let nothing = ControllerSummary::default().to_string();
        assert_eq!(nothing, "0 episodes, 0 actions: no decision was made");
        let one = ControllerSummary {
            episodes: 1,
            actions: 1,
            plans: 1,
            refused: 1,
            keepalives: 1,
            planning: "thread".into(),
            ..ControllerSummary::default()
        }
        .to_string();
        assert!(one.starts_with("1 episode, 1 action, "), "{one}");
        assert!(
            one.contains("1 observation refused, 1 plan (thread), 1 keep-alive;"),
            "{one}"
        );
        let line = EpisodeLine {
            episode: 0,
            reward: 1.0,
            steps: 1,
            p50_us: 1,
            p99_us: 1,
            max_us: 1,
            misses: 0,
        };
        assert!(line.to_string().contains(", 1 step, "), "{line}");
    }

    fn facts(started_empty: bool, end: LibraryEnd) -> LibraryFacts {
        LibraryFacts {
            path: "/data/library.tesl".into(),
            started_empty,
            before: LibraryCounts { views: 9, tasks: 3 },
            after: LibraryCounts {
                views: 11,
                tasks: 4,
            },
            end,
        }
    }

    #[test]
    fn the_library_line_says_before_after_and_what_became_of_the_file() {
        let cases = [
            (
                false,
                LibraryEnd::Saved,
                "library /data/library.tesl: 9 views, 3 tasks -> 11 views, 4 tasks (saved)",
            ),
            (
                true,
                LibraryEnd::Saved,
                "library /data/library.tesl: started empty (no library file yet) -> 11 views, \
                 4 tasks (saved)",
            ),
            (
                false,
                LibraryEnd::LeftAsItWas,
                "library /data/library.tesl: 9 views, 3 tasks; left as it was: nothing learned",
            ),
            (
                true,
                LibraryEnd::LeftAsItWas,
                "library /data/library.tesl: started empty (no library file yet); nothing \
                 learned, so no library file was written",
            ),
            (
                false,
                LibraryEnd::NotSaved,
                "library /data/library.tesl: 9 views, 3 tasks; NOT saved at shutdown (the save \
                 failed: the file, if any, is its last good save)",
            ),
        ];
        for (started_empty, end, line) in cases {
            assert_eq!(facts(started_empty, end).to_string(), line);
        }
        let one = LibraryCounts { views: 1, tasks: 1 };
        assert_eq!(one.to_string(), "1 view, 1 task");
        assert_eq!(LibraryCounts::default().to_string(), "0 views, 0 tasks");
    }

    /// The report round-trips through JSON, and a report written before the library facts
    /// existed still reads (without them).
    #[test]
    fn the_report_round_trips_and_older_reports_still_read() {
        let summary = ControllerSummary {
            episodes: 4,
            library: Some(facts(false, LibraryEnd::Saved)),
            ..ControllerSummary::default()
        };
        let json = serde_json::to_string(&summary).unwrap();
        assert!(json.contains("\"end\":\"saved\""), "{json}");
        let back: ControllerSummary = serde_json::from_str(&json).unwrap();
        assert_eq!(back, summary);

        let mut old = serde_json::to_value(ControllerSummary::default()).unwrap();
        old.as_object_mut().unwrap().remove("library");
        let back: ControllerSummary = serde_json::from_value(old).unwrap();
        assert_eq!(back.library, None);
        let partial: LibraryFacts = serde_json::from_str(r#"{"path": "/x"}"#).unwrap();
        assert_eq!(partial.end, LibraryEnd::LeftAsItWas);
    }
}
