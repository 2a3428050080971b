//! The controller's settings: the `[controller]` table of a launch file (or a file of its
//! own), checked once into the values the process runs with ([`CheckedController`]).
//!
//! ```
//! use tes_controller::config::{ControllerConfig, Planning, PlanningMode};
//! use tes_runtime::channel::WaitStrategy;
//!
//! let cfg = ControllerConfig::from_toml("wait = \"spin\"\nbudget_us = 500")?;
//! assert_eq!((cfg.wait, cfg.planning), (WaitStrategy::Spin, PlanningMode::Auto));
//! let checked = cfg.check()?;
//! assert_eq!(checked.planning(), Planning::BetweenPolls);
//! assert_eq!(checked.placement().acting, None); // a spinning thread is not pinned
//! let err = ControllerConfig::from_toml("# settings\nplanning = \"later\"").unwrap_err();
//! assert_eq!((err.key.as_str(), err.line()), ("planning", Some(2)));
//! # Ok::<(), tes_controller::config::ConfigError>(())
//! ```

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tes_runtime::affinity::Placement;
use tes_runtime::channel::WaitStrategy;
use tes_runtime::settings::Origin;

/// When the acting loop learns from an observation: after the command it answers it with is
/// out (the default), or before deciding that command.
///
/// Both make the same decisions: the command comes from the last adopted plan, which the
/// observation's lesson cannot change. Deciding first takes the scoring and updating of every
/// view of the last action, and the model's hand-over to the planner, off the decision.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Order {
    /// Adopt a finished plan, decide, publish; then learn and hand the planner the model.
    #[default]
    DecideFirst,
    /// Learn, adopt a finished plan, decide, publish (the order before decide-first; kept as
    /// the baseline the latency benchmark compares against).
    LearnFirst,
}

impl std::fmt::Display for Order {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Order::DecideFirst => "decide-first",
            Order::LearnFirst => "learn-first",
        })
    }
}

impl std::str::FromStr for Order {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "decide-first" => Ok(Order::DecideFirst),
            "learn-first" => Ok(Order::LearnFirst),
            _ => Err(format!(
                "unknown order {s:?}: expected decide-first or learn-first"
            )),
        }
    }
}

/// Settings of the controller process (TOML: the `[controller]` table of a launch file, or a
/// file of its own). Every key is optional. Written back with serde (`toml::to_string`), it
/// reads back the same. Each field's doc is its key's entry in the launch file's reference
/// (`tes launch --print-config`): what it does, then its unit or values on a `Values:` line;
/// the defaults are this struct's `Default`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ControllerConfig {
    /// The view library file. Unset: `library.tesl` in the data directory (`$TES_DATA_DIR`,
    /// else `$XDG_DATA_HOME/tes`, else `~/.local/share/tes`). Created at the first save if
    /// missing; a file that exists but cannot be read stops the controller.
    ///
    /// Values: path.
    ///
    /// Example: `"/path/to/library.tesl"`.
    pub library: Option<PathBuf>,
    /// The per-action latency budget, observation to command.
    ///
    /// Values: µs, at least [`MIN_BUDGET_US`](tes_runtime::settings::MIN_BUDGET_US).
    pub budget_us: u64,
    /// How the acting loop waits for observations (`auto`: anticipate announced messages
    /// only, block for any other; a launch resolves it, see `[launch] wait`).
    ///
    /// Values: `auto` | `block` | `spin` | `spin-then-block` | `spin-then-block:<µs>` |
    /// `anticipate`.
    pub wait: WaitStrategy,
    /// Seed of the exploration.
    ///
    /// Values: integer, 0 to 2^63 - 1.
    pub seed: u64,
    /// Probability of a random action (paper §5.2: 0.05).
    ///
    /// Values: probability, 0 to 1.
    pub epsilon: f64,
    /// mDAGL's group-lasso strength for fresh views (paper: 0.05).
    ///
    /// Values: finite, at least 0.
    pub lambda: f64,
    /// mDAGL's step scale for fresh views (paper §5.2: 0.5).
    ///
    /// Values: finite, above 0.
    pub alpha: f64,
    /// The library's size limit M (paper: 20).
    ///
    /// Values: count, at least 1.
    pub max_views: usize,
    /// Prefixed to every iceoryx2 service name (to run groups side by side).
    ///
    /// Values: text, at most [`SERVICE_PREFIX_MAX`](tes_runtime::settings::SERVICE_PREFIX_MAX)
    /// bytes.
    pub service_prefix: String,
    /// How long to wait for perception's world map at the start.
    ///
    /// Values: s, above 0.
    pub map_timeout_s: f64,
    /// Save the library at an episode's end only if this long has passed since the last
    /// save; it is always saved at shutdown. A save copies every working view on the acting
    /// loop, so saving after every episode at the fastest pace (dozens of episodes a second)
    /// delays each episode's first decision.
    ///
    /// Values: s, at least 0; 0 = after every episode.
    pub save_interval_s: f64,
    /// The most value-iteration sweeps the planner makes per hand-over of the model (an
    /// unfinished plan continues at the next). Fewer leave more CPU to the loop on a small
    /// machine, at the cost of staler plans.
    ///
    /// Values: count, at least 1.
    pub plan_sweeps: usize,
    /// Actions left out of the latency and allocation figures.
    ///
    /// Values: count.
    pub warmup_actions: u64,
    /// Where to write the run's summary as JSON at exit. Unset: nowhere.
    ///
    /// Values: path.
    ///
    /// Example: `"/path/to/report.json"`.
    pub report: Option<PathBuf>,
    /// While a command's move is under way, send the bridge a keep-alive this often. The
    /// bridge's watchdog brakes the motors when neither commands nor keep-alives arrive
    /// within its deadline, so with keep-alives it acts as a dead man's switch: a long move
    /// goes on while the controller lives and is braked once the controller is gone.
    ///
    /// Values: ms; 0 = never; at most half the bridge's watchdog deadline in wall time.
    pub keepalive_ms: u64,
    /// The CPU the acting loop's thread runs on. `auto`: with `wait = "block"` or `"anticipate"`
    /// on two or more CPUs, the last CPU this process may run on, else unpinned; `none`: unpinned.
    /// Pinned, a blocking thread wakes where its memory is warm instead of wherever the
    /// scheduler finds room, which shortens both its wake-up and its compute
    /// (docs/performance.md). A spinning thread never sleeps, so `auto` leaves it unpinned.
    ///
    /// Values: CPU number | `"auto"` | `"none"`.
    pub acting_cpu: Placement,
    /// The planner thread's CPU. `auto`: when the acting thread is pinned, the first allowed
    /// CPU other than its own (planning never runs on the acting thread's CPU), else
    /// unpinned; `none`: unpinned. A CPU number is refused with between-polls or inline
    /// planning (there is no planner thread).
    ///
    /// Values: CPU number | `"auto"` | `"none"`.
    pub planner_cpu: Placement,
    /// Who plans: `thread`, a planner thread under SCHED_IDLE; `between-polls`, the acting
    /// thread, in slices, while it spins waiting for the next observation (needs `wait =
    /// "spin"` or `"spin-then-block"`); `inline`, the acting thread, each plan whole right
    /// after the learning that follows the command, adopted at the next observation (every
    /// run with the same seeds adopts the same plans at the same steps, whatever the timing;
    /// the next observation waits for a plan that takes longer than the robot's move);
    /// `auto`, between polls with `wait = "spin"`, else the thread. Spinning on two cores
    /// leaves a planner thread almost no time; between polls, the spin does the planning.
    ///
    /// Values: `auto` | `thread` | `between-polls` | `inline`.
    pub planning: PlanningMode,
    /// With between-polls planning, the states' worth of planning done between two polls:
    /// the most an observation arriving mid-slice waits (the slice that starts an action's
    /// refresh or adopts the plan is the longest).
    ///
    /// Values: states, at least 1.
    pub plan_slice: usize,
    /// When the controller learns from an observation: `decide-first` adopts a finished
    /// plan, decides and publishes the command first, then scores and updates the views and
    /// hands the planner the model; `learn-first` does all that before deciding. Both make
    /// the same decisions; deciding first keeps the learning off the decision's latency.
    ///
    /// Values: `decide-first` | `learn-first`.
    pub order: Order,
    /// With a planner thread: how long it polls for its next job after a plan before it
    /// sleeps. It polls under SCHED_IDLE, so only with time nobody else wants (and not at
    /// all if the system refuses SCHED_IDLE). Polling keeps its CPU out of the idle halt: a
    /// bridge that sleeps on events, woken by a command, is put on that CPU and runs at
    /// once, where a halted virtual CPU takes tens of µs to come back; and the next
    /// hand-over wakes no sleeping thread. But at the simulator's fastest pace, where the
    /// next job comes within the spin, it never stops: a core kept busy. Unset, it follows
    /// `wait`: 5000 µs with `spin` and `spin-then-block` (which trade CPU for latency
    /// anyway), 0 with `block` and `anticipate`.
    ///
    /// Values: µs; 0 = sleep at once; unset = by `wait`.
    pub planner_idle_spin_us: Option<u64>,
}

/// Where the controller's threads run: CPUs, or `None` for unpinned
/// ([`ControllerConfig::placement`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ThreadPlacement {
    /// The acting loop's thread.
    pub acting: Option<usize>,
    /// The planner thread (never pinned with between-polls planning: there is none).
    pub planner: Option<usize>,
}

/// The `planning` key: who plans, as asked (`auto`, `thread` or `between-polls`);
/// [`Planning`] is what it resolves to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlanningMode {
    /// Between polls with `wait = "spin"`, else a planner thread (the default).
    #[default]
    Auto,
    /// A planner thread.
    Thread,
    /// The acting thread, between the polls of its spinning wait.
    BetweenPolls,
    /// The acting thread, each plan whole at its hand-over, adopted at the next observation.
    Inline,
}

impl std::fmt::Display for PlanningMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            PlanningMode::Auto => "auto",
            PlanningMode::Thread => "thread",
            PlanningMode::BetweenPolls => "between-polls",
            PlanningMode::Inline => "inline",
        })
    }
}

/// A `planning` value that is not `auto`, `thread`, `between-polls` or `inline`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown planning {0:?}: expected auto, thread, between-polls or inline")]
pub struct BadPlanningMode(pub String);

impl std::str::FromStr for PlanningMode {
    type Err = BadPlanningMode;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(PlanningMode::Auto),
            "thread" => Ok(PlanningMode::Thread),
            "between-polls" => Ok(PlanningMode::BetweenPolls),
            "inline" => Ok(PlanningMode::Inline),
            _ => Err(BadPlanningMode(s.to_owned())),
        }
    }
}

/// Who plans for the acting loop: [`ControllerConfig::planning`] resolved for the wait
/// strategy.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Planning {
    /// A planner thread.
    Thread,
    /// The acting thread, between the polls of its spinning wait.
    BetweenPolls,
    /// The acting thread, each plan whole at its hand-over (after the learning).
    Inline,
}

impl std::fmt::Display for Planning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Planning::Thread => "thread",
            Planning::BetweenPolls => "between-polls",
            Planning::Inline => "inline",
        })
    }
}

impl Default for ControllerConfig {
    fn default() -> Self {
        Self {
            library: None,
            budget_us: tes_runtime::settings::DEFAULT_BUDGET_US,
            wait: WaitStrategy::Block,
            seed: 1,
            epsilon: 0.05,
            lambda: 0.05,
            alpha: 0.5,
            max_views: 20,
            service_prefix: String::new(),
            map_timeout_s: 30.0,
            save_interval_s: 10.0,
            plan_sweeps: 500,
            warmup_actions: 0,
            report: None,
            keepalive_ms: 250,
            acting_cpu: Placement::Auto,
            planner_cpu: Placement::Auto,
            planning: PlanningMode::Auto,
            plan_slice: 32,
            order: Order::DecideFirst,
            planner_idle_spin_us: None,
        }
    }
}

/// A setting that is unknown, mistyped or out of range, named by its key (and, read from a
/// file, by the file and line).
pub type ConfigError = tes_runtime::settings::SettingError;

/// The process name [`ConfigError`]s of these settings carry.
pub const PROCESS: &str = "controller";

/// The planner thread's poll after a plan when `planner_idle_spin_us` is unset and the acting
/// loop spins, µs.
pub const DEFAULT_PLANNER_IDLE_SPIN_US: u64 = 5000;

/// A [`ControllerConfig`] that passed [`ControllerConfig::check`], with what its keys resolve
/// to on this machine: the wait strategy, who plans, where the threads run, the durations.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedController {
    config: ControllerConfig,
    planning: Planning,
    placement: ThreadPlacement,
    map_timeout: Duration,
    save_interval: Duration,
}

impl CheckedController {
    /// The settings as given.
    pub fn config(&self) -> &ControllerConfig {
        &self.config
    }

    /// The settings as given, taken out.
    pub fn into_config(self) -> ControllerConfig {
        self.config
    }

    /// How the acting loop waits for observations (`wait`).
    pub fn wait(&self) -> WaitStrategy {
        self.config.wait
    }

    /// Who plans (`planning` resolved: [`ControllerConfig::planning_for`]).
    pub fn planning(&self) -> Planning {
        self.planning
    }

    /// Where the threads run (`acting_cpu`, `planner_cpu` resolved:
    /// [`ControllerConfig::placement`]).
    pub fn placement(&self) -> ThreadPlacement {
        self.placement
    }

    /// How long to wait for the world map (`map_timeout_s`).
    pub fn map_timeout(&self) -> Duration {
        self.map_timeout
    }

    /// The least time between two library saves at an episode's end (`save_interval_s`).
    pub fn save_interval(&self) -> Duration {
        self.save_interval
    }
}

impl ControllerConfig {
    /// Parses a TOML document holding these keys (unknown keys are refused) and checks it;
    /// an error names the key and its line.
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
    /// resolve to (see [`CheckedController`]).
    pub fn check(&self) -> Result<CheckedController, ConfigError> {
        let bad = |key, reason: &str| Err(ConfigError::new(PROCESS, key, reason));
        if self.budget_us < tes_runtime::settings::MIN_BUDGET_US {
            return bad("budget_us", "must be at least 1");
        }
        if !(0.0..=1.0).contains(&self.epsilon) {
            return bad("epsilon", "must be in [0, 1]");
        }
        if !(self.lambda.is_finite() && self.lambda >= 0.0) {
            return bad("lambda", "must be a finite number >= 0");
        }
        if !(self.alpha.is_finite() && self.alpha > 0.0) {
            return bad("alpha", "must be a finite number > 0");
        }
        if self.max_views == 0 {
            return bad("max_views", "must be at least 1");
        }
        if self.plan_sweeps == 0 {
            return bad("plan_sweeps", "must be at least 1");
        }
        let save_interval = match Duration::try_from_secs_f64(self.save_interval_s) {
            Ok(d) if self.save_interval_s >= 0.0 => d,
            _ => {
                return bad(
                    "save_interval_s",
                    "must be a number of seconds >= 0 that fits a duration",
                );
            }
        };
        let map_timeout = match Duration::try_from_secs_f64(self.map_timeout_s) {
            Ok(d) if self.map_timeout_s > 0.0 => d,
            _ => {
                return bad(
                    "map_timeout_s",
                    "must be a number of seconds > 0 that fits a duration",
                );
            }
        };
        if self.plan_slice == 0 {
            return bad("plan_slice", "must be at least 1");
        }
        tes_runtime::settings::service_prefix(PROCESS, "service_prefix", &self.service_prefix)?;
        let planning = self.planning_for(self.wait)?;
        let placement = self.placement(self.wait, planning)?;
        Ok(CheckedController {
            config: self.clone(),
            planning,
            placement,
            map_timeout,
            save_interval,
        })
    }

    /// How long the planner thread polls after a plan: `planner_idle_spin_us`, or by
    /// `strategy` when unset (see the key).
    pub fn planner_idle_spin(&self, strategy: WaitStrategy) -> Duration {
        let us = self.planner_idle_spin_us.unwrap_or(if strategy.spins() {
            DEFAULT_PLANNER_IDLE_SPIN_US
        } else {
            0
        });
        Duration::from_micros(us)
    }

    /// Where the acting and planner threads run, `auto` resolved (see
    /// [`ControllerConfig::acting_cpu`]); a CPU this process may not run on is refused,
    /// naming its key.
    pub fn placement(
        &self,
        strategy: WaitStrategy,
        planning: Planning,
    ) -> Result<ThreadPlacement, ConfigError> {
        let pair = tes_runtime::affinity::auto_pair();
        let acting = match self.acting_cpu {
            Placement::Cpu(c) => Some(c),
            Placement::Unpinned => None,
            Placement::Auto if !strategy.spins() => pair.map(|(rt, _)| rt),
            Placement::Auto => None,
        };
        let planner = match (planning, self.planner_cpu) {
            (Planning::BetweenPolls | Planning::Inline, _) => None,
            (Planning::Thread, Placement::Cpu(c)) => Some(c),
            (Planning::Thread, Placement::Unpinned) => None,
            (Planning::Thread, Placement::Auto) => acting.and_then(|a| {
                tes_runtime::affinity::allowed_cpus()
                    .into_iter()
                    .find(|&c| c != a)
            }),
        };
        tes_runtime::settings::cpu(PROCESS, "acting_cpu", acting)?;
        tes_runtime::settings::cpu(PROCESS, "planner_cpu", planner)?;
        Ok(ThreadPlacement { acting, planner })
    }

    /// Who plans, given the wait strategy (checked: `between-polls` needs a spinning wait, and
    /// has no planner thread to pin).
    pub fn planning_for(&self, strategy: WaitStrategy) -> Result<Planning, ConfigError> {
        let bad = |reason: &str| Err(ConfigError::new(PROCESS, "planning", reason));
        let planning = match self.planning {
            PlanningMode::Auto if strategy == WaitStrategy::Spin => Planning::BetweenPolls,
            PlanningMode::Auto | PlanningMode::Thread => Planning::Thread,
            PlanningMode::BetweenPolls => Planning::BetweenPolls,
            PlanningMode::Inline => Planning::Inline,
        };
        if planning == Planning::Inline
            && let Placement::Cpu(_) = self.planner_cpu
        {
            return bad(
                "planner_cpu pins the planner thread, and inline planning has none \
                 (it runs on the acting thread: see acting_cpu)",
            );
        }
        if planning == Planning::BetweenPolls {
            if strategy == WaitStrategy::Block {
                return bad(
                    "between-polls needs wait = \"spin\" or \"spin-then-block\": a loop that \
                     blocks never polls",
                );
            }
            if let Placement::Cpu(_) = self.planner_cpu {
                return bad(
                    "planner_cpu pins the planner thread, and between-polls planning has none \
                     (it runs on the acting thread: see acting_cpu)",
                );
            }
        }
        Ok(planning)
    }

    /// The library file: the configured one or [`default_library_path`].
    pub fn library_path(&self) -> PathBuf {
        self.library.clone().unwrap_or_else(default_library_path)
    }
}

/// The default data directory: `$TES_DATA_DIR`, else `$XDG_DATA_HOME/tes`, else
/// `$HOME/.local/share/tes`, else `./tes-data`.
pub fn default_data_dir() -> PathBuf {
    let env = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    env("TES_DATA_DIR")
        .or_else(|| env("XDG_DATA_HOME").map(|d| d.join("tes")))
        .or_else(|| env("HOME").map(|h| h.join(".local/share/tes")))
        .unwrap_or_else(|| PathBuf::from("tes-data"))
}

/// The default view library file: `library.tesl` in [`default_data_dir`].
pub fn default_library_path() -> PathBuf {
    default_data_dir().join("library.tesl")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_are_checked_by_key() {
        assert!(ControllerConfig::default().check().is_ok());
        let cfg = ControllerConfig::from_toml("budget_us = 500\nwait = \"spin\"\n").unwrap();
        assert_eq!(cfg.budget_us, 500);
        assert_eq!(cfg.check().map(|c| c.wait()), Ok(WaitStrategy::Spin));
        for (text, key) in [
            ("budget_us = 0", "budget_us"),
            ("epsilon = 2.0", "epsilon"),
            ("alpha = 0.0", "alpha"),
            ("wait = \"nap\"", "wait"),
            ("max_views = 0", "max_views"),
            ("map_timeout_s = 1e300", "map_timeout_s"),
            ("map_timeout_s = nan", "map_timeout_s"),
            ("save_interval_s = -1.0", "save_interval_s"),
            ("acting_cpu = 100000", "acting_cpu"),
            ("planner_cpu = 100000", "planner_cpu"),
            ("plan_slice = 0", "plan_slice"),
            ("planning = \"later\"", "planning"),
            // Contradictions: a blocking loop never polls; no planner thread to pin.
            ("planning = \"between-polls\"", "planning"),
            (
                "planning = \"between-polls\"\nwait = \"spin\"\nplanner_cpu = 0",
                "planning",
            ),
            ("planning = \"inline\"\nplanner_cpu = 0", "planning"),
        ] {
            let err = ControllerConfig::from_toml(text).unwrap_err();
            assert_eq!(err.key, key, "{text}");
        }
        // Who plans, by default and when asked.
        for (text, planning) in [
            ("", Planning::Thread),
            ("wait = \"spin\"", Planning::BetweenPolls),
            ("wait = \"spin-then-block\"", Planning::Thread),
            ("wait = \"spin\"\nplanning = \"thread\"", Planning::Thread),
            ("planning = \"inline\"", Planning::Inline),
            ("wait = \"spin\"\nplanning = \"inline\"", Planning::Inline),
            (
                "wait = \"spin-then-block\"\nplanning = \"between-polls\"",
                Planning::BetweenPolls,
            ),
        ] {
            let cfg = ControllerConfig::from_toml(text).unwrap();
            let checked = cfg.check().unwrap();
            assert_eq!(checked.planning(), planning, "{text}");
            assert_eq!(cfg.planning_for(checked.wait()), Ok(planning), "{text}");
        }
        let err = ControllerConfig::from_toml("budjet_us = 5").unwrap_err();
        assert!(err.reason.contains("budjet_us"), "{err}");
        let err = ControllerConfig::from_toml("acting_cpu = \"fast\"").unwrap_err();
        assert!(err.reason.contains("\"none\""), "{err}");
    }

    /// Like every process's, the controller's service prefix is held to the one limit.
    #[test]
    fn a_service_prefix_longer_than_the_limit_is_refused() {
        let fits = "c".repeat(tes_runtime::settings::SERVICE_PREFIX_MAX);
        let cfg = ControllerConfig {
            service_prefix: fits.clone(),
            ..ControllerConfig::default()
        };
        assert!(cfg.check().is_ok());
        let err = ControllerConfig::from_toml(&format!("seed = 2\nservice_prefix = \"{fits}c\"\n"))
            .unwrap_err();
        assert_eq!(
            (err.process, err.key.as_str(), err.line()),
            (PROCESS, "service_prefix", Some(2))
        );
        assert_eq!(err.reason, "must be at most 64 bytes");
    }

    /// The string-valued keys are enums: each of their words reads, and anything else is
    /// refused naming the key and its line.
    #[test]
    fn every_enum_key_parses_and_refuses_a_bad_value_naming_the_key() {
        for (text, wait) in [
            ("block", WaitStrategy::Block),
            ("spin", WaitStrategy::Spin),
            (
                "spin-then-block",
                WaitStrategy::SpinThenBlock(WaitStrategy::DEFAULT_SPIN),
            ),
            (
                "spin-then-block:70",
                WaitStrategy::SpinThenBlock(Duration::from_micros(70)),
            ),
        ] {
            let cfg = ControllerConfig::from_toml(&format!("wait = \"{text}\"")).unwrap();
            assert_eq!(cfg.wait, wait, "{text}");
        }
        for (text, mode) in [
            ("auto", PlanningMode::Auto),
            ("thread", PlanningMode::Thread),
            ("between-polls", PlanningMode::BetweenPolls),
            ("inline", PlanningMode::Inline),
        ] {
            let cfg =
                ControllerConfig::from_toml(&format!("wait = \"spin\"\nplanning = \"{text}\""))
                    .unwrap();
            assert_eq!(cfg.planning, mode, "{text}");
            assert_eq!(text.parse(), Ok(mode));
            assert_eq!(mode.to_string(), text);
        }
        for (text, key, reason) in [
            ("wait = \"nap\"", "wait", "unknown wait strategy \"nap\""),
            ("wait = 3", "wait", "a wait strategy"),
            (
                "planning = \"later\"",
                "planning",
                "unknown variant `later`",
            ),
            ("planning = \"Thread\"", "planning", "expected one of"),
            ("acting_cpu = \"fast\"", "acting_cpu", "\"none\""),
            ("planner_cpu = -1", "planner_cpu", "\"auto\""),
        ] {
            let err = ControllerConfig::from_toml(&format!("seed = 2\n{text}\n")).unwrap_err();
            assert_eq!((err.process, err.key.as_str()), (PROCESS, key), "{text}");
            assert_eq!(err.line(), Some(2), "{text}");
            assert!(err.reason.contains(reason), "{text}: {err}");
        }
        assert!("later".parse::<PlanningMode>().is_err());
        for (text, order) in [
            ("decide-first", Order::DecideFirst),
            ("learn-first", Order::LearnFirst),
        ] {
            let cfg = ControllerConfig::from_toml(&format!("order = \"{text}\"")).unwrap();
            assert_eq!(cfg.order, order, "{text}");
        }
        let err = ControllerConfig::from_toml("seed = 2\norder = \"later\"\n").unwrap_err();
        assert_eq!((err.key.as_str(), err.line()), ("order", Some(2)), "{err}");
    }

    /// What `check` finds wrong is placed at the key's line of the file it came from.
    #[test]
    fn a_range_error_names_the_file_and_line() {
        let origin = Origin::File("/etc/tes/controller.toml".into());
        let err = ControllerConfig::from_toml_in("seed = 3\n\nepsilon = 2.0\n", origin.clone())
            .unwrap_err();
        assert_eq!((err.key.as_str(), err.line()), ("epsilon", Some(3)));
        assert_eq!(
            err.to_string(),
            "/etc/tes/controller.toml:3:1: epsilon: must be in [0, 1]"
        );
        // A contradiction involving a default: placed at the key that is in the file.
        let err =
            ControllerConfig::from_toml_in("planning = \"between-polls\"", origin).unwrap_err();
        assert_eq!((err.key.as_str(), err.line()), ("planning", Some(1)));
    }

    /// Written with serde and read back, settings are the same, and so is what they resolve
    /// to.
    #[test]
    fn settings_round_trip_through_toml() {
        let cpu = tes_runtime::affinity::allowed_cpus()[0];
        let cfgs = [
            ControllerConfig::default(),
            ControllerConfig {
                library: Some("/data/tes/library.tesl".into()),
                budget_us: 700,
                wait: WaitStrategy::SpinThenBlock(Duration::from_micros(35)),
                seed: u64::try_from(i64::MAX).unwrap(),
                epsilon: 0.25,
                lambda: 0.0,
                alpha: 1e-3,
                max_views: 3,
                service_prefix: "group/7/".into(),
                map_timeout_s: 2.5,
                save_interval_s: 0.0,
                plan_sweeps: 9,
                warmup_actions: 11,
                report: Some("/tmp/report.json".into()),
                keepalive_ms: 0,
                acting_cpu: Placement::Cpu(cpu),
                planner_cpu: Placement::Unpinned,
                planning: PlanningMode::BetweenPolls,
                plan_slice: 5,
                order: Order::LearnFirst,
                planner_idle_spin_us: Some(0),
            },
            ControllerConfig {
                wait: WaitStrategy::Spin,
                planning: PlanningMode::Thread,
                ..ControllerConfig::default()
            },
        ];
        for cfg in cfgs {
            let text = toml::to_string(&cfg).expect("serialises");
            let back = ControllerConfig::from_toml(&text).expect("reads back");
            assert_eq!(back, cfg, "{text}");
            assert_eq!(back.check(), cfg.check(), "{text}");
        }
    }

    /// `auto` pins a blocking acting thread to the last allowed CPU and the planner to the
    /// first other one; spinning, between polls, with one CPU, or when told, it does not.
    #[test]
    fn threads_are_placed_by_the_wait_and_the_keys() {
        let allowed = tes_runtime::affinity::allowed_cpus();
        let placed = |text: &str| {
            let cfg = ControllerConfig::from_toml(text).unwrap();
            let checked = cfg.check().unwrap();
            let planning = cfg.planning_for(checked.wait()).unwrap();
            let p = cfg.placement(checked.wait(), planning).unwrap();
            assert_eq!(p, checked.placement(), "{text}");
            (p.acting, p.planner)
        };
        let (first, last) = (allowed.first().copied(), allowed.last().copied());
        let pair = (allowed.len() >= 2).then_some((last, first));
        assert_eq!(placed(""), pair.unwrap_or((None, None)));
        assert_eq!(placed("wait = \"spin\""), (None, None));
        assert_eq!(
            placed("wait = \"spin\"\nplanning = \"thread\""),
            (None, None)
        );
        assert_eq!(placed("wait = \"spin-then-block\""), (None, None));
        assert_eq!(placed("acting_cpu = \"none\""), (None, None));
        assert_eq!(
            placed("planner_cpu = \"none\""),
            (pair.and_then(|(a, _)| a), None)
        );
        // Told where, the planner goes elsewhere by itself.
        let cpu = allowed[0];
        let other = allowed.iter().copied().find(|&c| c != cpu);
        assert_eq!(placed(&format!("acting_cpu = {cpu}")), (Some(cpu), other));
        assert_eq!(
            placed(&format!(
                "acting_cpu = {cpu}\nwait = \"spin\"\nplanner_cpu = \"auto\""
            )),
            (Some(cpu), None)
        );
        assert_eq!(
            placed(&format!("acting_cpu = \"none\"\nplanner_cpu = {cpu}")),
            (None, Some(cpu))
        );
    }
}
