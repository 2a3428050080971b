//! The launch file's reference: every key of every table, with its unit or allowed values and
//! what it does — the one place the keys are described.
//!
//! [`TABLES`] and [`KEYS`] hold the words; the values come from the code: the defaults are the
//! config structs' own `Default`s, serialised, and the keys the launcher fills in for the
//! children are [`INHERITED`]. Two renderings are made from them: a launch file with every key
//! at its default, each commented (`tes launch --print-config`), and the markdown page
//! `docs/config.md` (`tes launch --print-config=markdown`). The tests derive the key set from
//! the config structs themselves, so a key added to one of them without a line here fails them
//! with its name.

use std::fmt::Write as _;

use crate::file::{INHERITED, LaunchFile};

/// The reference cannot be rendered: a table's values do not serialise (a bug in a config
/// struct), or the text cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    /// A table's values cannot be serialised to TOML.
    #[error("cannot serialise the [{table}] settings")]
    Serialise {
        /// The table.
        table: String,
        /// Why.
        #[source]
        source: toml::ser::Error,
    },
    /// Writing into the text failed.
    #[error("cannot write the reference")]
    Format(#[from] std::fmt::Error),
}

type Result<T, E = ReferenceError> = std::result::Result<T, E>;

/// Where the reference comes from and how to regenerate `docs/config.md`, as the printed
/// reference and its tests say.
pub const REGENERATE: &str = "tes launch --print-config=markdown > docs/config.md";

/// A table of the launch file, in the order the reference lists them.
#[derive(Debug, Clone, Copy)]
pub struct Table {
    /// Its dotted name (`bridge.watchdog`).
    pub name: &'static str,
    /// Whether it is an array of tables (`[[bridge.actions]]`).
    pub array: bool,
    /// What it is for.
    pub about: &'static str,
}

/// One key of the launch file, as the reference describes it.
#[derive(Debug, Clone, Copy)]
pub struct Key {
    /// The table it is in ([`Table::name`]).
    pub table: &'static str,
    /// Its name in the table.
    pub key: &'static str,
    /// Its unit, or the values it takes.
    pub allowed: &'static str,
    /// What it does.
    pub meaning: &'static str,
    /// For a key that is unset by default (no TOML value can say "unset"): a value to show,
    /// commented out.
    pub example: Option<&'static str>,
    /// For a key the launcher fills in for a child ([`INHERITED`]): the value it sets.
    pub inherited: Option<&'static str>,
}

impl Key {
    /// Its dotted name from the top of the file (`bridge.watchdog.deadline_ms`).
    pub fn path(&self) -> String {
        format!("{}.{}", self.table, self.key)
    }

    /// The same key, unset by default and shown as `value` (TOML), commented out.
    const fn example(self, value: &'static str) -> Self {
        Self {
            example: Some(value),
            ..self
        }
    }

    /// The same key, filled in by the launcher with `value` unless the table sets it.
    const fn inherited(self, value: &'static str) -> Self {
        Self {
            inherited: Some(value),
            ..self
        }
    }
}

/// A key of `table`.
const fn key(
    table: &'static str,
    key: &'static str,
    allowed: &'static str,
    meaning: &'static str,
) -> Key {
    Key {
        table,
        key,
        allowed,
        meaning,
        example: None,
        inherited: None,
    }
}

/// Allowed values of every `wait` key.
const WAIT: &str = "`block` | `spin` | `spin-then-block` | `spin-then-block:<µs>`";
/// Allowed values of every `service_prefix` key.
const PREFIX: &str = "text, at most 64 bytes";
/// Allowed values of a boolean key.
const BOOL: &str = "`true` | `false`";

/// The tables of a launch file, in order (a table comes before the tables nested in it).
pub const TABLES: &[Table] = &[
    Table {
        name: "launch",
        array: false,
        about: "Launch-wide settings: the run (episodes, arena, pace, seed), how every process \
                waits, and how the launcher supervises the group. Several of them are copied \
                into the children's tables (the inherited keys).",
    },
    Table {
        name: "launch.link",
        array: false,
        about: "How a launch that starts only some of the processes (`roles`) reaches the \
                others on other hosts: one Zenoh session (docs/multi-host.md). Unused without \
                `roles`.",
    },
    Table {
        name: "perception",
        array: false,
        about: "The perception-sim process: the simulated world, which publishes an \
                observation per step and moves the robot by the bridge's motion reports.",
    },
    Table {
        name: "controller",
        array: false,
        about: "The controller process: the acting loop (observation to command within the \
                budget), learning the views of the library, and planning.",
    },
    Table {
        name: "bridge",
        array: false,
        about: "The bridge process: turns the controller's commands into NXT motor telegrams \
                over the transport (the simulated brick, or a real NXT over Bluetooth) and \
                reports the motion. Its nested tables follow.",
    },
    Table {
        name: "bridge.link_delay",
        array: false,
        about: "A simulated Bluetooth delay on each reply of the `sim` transport (and of \
                `bridge brick --pty`).",
    },
    Table {
        name: "bridge.serial",
        array: false,
        about: "The serial transport (`transport = \"serial:<path>\"`).",
    },
    Table {
        name: "bridge.watchdog",
        array: false,
        about: "The dead man's switch: the motors are braked when the commands stop.",
    },
    Table {
        name: "bridge.poll",
        array: false,
        about: "How the bridge polls the brick (periods in brick time: see \
                `[bridge.brick] time_scale`).",
    },
    Table {
        name: "bridge.ipc",
        array: false,
        about: "The bridge's side of iceoryx2: waiting for commands, and its latency figures.",
    },
    Table {
        name: "bridge.brick",
        array: false,
        about: "The simulated brick's physics and identity (`transport = \"sim\"`; a serial \
                transport ignores them).",
    },
    Table {
        name: "bridge.motors",
        array: false,
        about: "How the wheel motors are wired and driven.",
    },
    Table {
        name: "bridge.actions",
        array: true,
        about: "The action table: one entry per action id the controller may send, at least \
                one, ids unique. The default is the paper's three (section 5.2): forward, \
                turn left, turn right. Entries written in the file replace the whole table.",
    },
];

/// Every key of every table, in the order the reference lists them.
pub const KEYS: &[Key] = &[
    // [launch]
    key(
        "launch",
        "episodes",
        "count, at least 1",
        "Episodes perception runs before the group stops (`--episodes` overrides it).",
    ),
    key(
        "launch",
        "arena",
        "`1` | `2` | `3`",
        "The arena perception simulates; 3 is the paper's test arena.",
    ),
    key(
        "launch",
        "real_time_factor",
        "factor, finite, at least 0",
        "The pace: 1.0 = physical time (the paper's 200 ms settle after each motion), 0 = as \
         fast as possible. It sets perception's settle time and the simulated brick's time \
         scale (1 / factor; 200 at 0).",
    ),
    key(
        "launch",
        "wait",
        WAIT,
        "How every process waits for its next input: `block` sleeps until notified (no CPU \
         while idle); `spin` busy-polls (lowest latency, a core per process); \
         `spin-then-block` busy-polls for 200 µs (or the µs given), then sleeps.",
    ),
    key(
        "launch",
        "restart",
        "`never` | `on-failure`",
        "What to do when a child dies: `never` stops the others and exits non-zero; \
         `on-failure` respawns it, at most `max_restarts` times.",
    ),
    key(
        "launch",
        "max_restarts",
        "count",
        "Respawns allowed per child with `restart = \"on-failure\"`.",
    ),
    key(
        "launch",
        "grace_ms",
        "ms",
        "Grace period of each shutdown step: SIGINT, then SIGTERM after this long, then \
         SIGKILL after as long again.",
    ),
    key(
        "launch",
        "service_prefix",
        PREFIX,
        "Prefix of every iceoryx2 service name. Empty: each launch gets one of its own, \
         `tes-PID-XXXXXXXX/`, so any number of launches run side by side; a prefix already \
         used by a running group is refused.",
    ),
    key(
        "launch",
        "run_dir",
        "path",
        "This launch's run folder, used as it is: no folder of its own per launch, never \
         pruned (it holds the lock that keeps a second launch out). Unset: each launch gets \
         a run folder of its own in `runs_dir`.",
    )
    .example("\"/path/to/run\""),
    key(
        "launch",
        "runs_dir",
        "path",
        "Where each launch makes its run folder, named by its UTC start time \
         (`2026-12-02T19-05-33Z`): the resolved launch file, the children's settings, output \
         and logs, `episodes.csv`, `trajectory.csv`, the latency reports and, at the end, \
         `rewards.svg`, `latency.svg` and `arena.svg`; `latest` links to the newest. Unset: \
         `runs` in the data directory (`$TES_DATA_DIR`, else `$XDG_DATA_HOME/tes`, else \
         `~/.local/share/tes`).",
    )
    .example("\"/path/to/runs\""),
    key(
        "launch",
        "keep_runs",
        "count; 0 = keep every one",
        "How many run folders `runs_dir` keeps: when a launch starts, the oldest beyond this \
         are removed.",
    ),
    key(
        "launch",
        "seed",
        "integer, 0 to 2^63 - 1",
        "Seed of the world, the agent and the simulated brick.",
    ),
    key(
        "launch",
        "stall_timeout_ms",
        "ms of wall time, at least 500",
        "A group whose controller sends no command for this long is stalled: the launcher \
         names the process holding it up and stops the group (`restart = \"never\"`) or \
         restarts that process (`on-failure`).",
    ),
    key(
        "launch",
        "record",
        "path of an MCAP file",
        "Record the run to this file (`tes launch --record` overrides it): the world map and          every observation, command, keep-alive and motor state, with the run's settings, seed          and starting library; `tes replay` reads it (docs/recording.md). A relative path is          taken from the directory `tes launch` runs in. Unset: no recording.",
    )
    .example("\"run.mcap\""),
    key(
        "launch",
        "roles",
        "list of `perception-sim`, `controller`, `bridge`",
        "The processes this launch starts (`tes launch --roles` overrides it); the others \
         run on other hosts, reached through the link (`[launch.link]`, docs/multi-host.md). \
         Empty: all three on this host, over shared memory only, and no link.",
    ),
    // [launch.link]
    key(
        "launch.link",
        "group",
        "text: ASCII letters, digits, `-`, `_`, `.`, parts separated by `/`; at most 64 bytes",
        "The group's name on Zenoh, the first part of every key: the launches of one group \
         give the same, two groups on one network different ones.",
    ),
    key(
        "launch.link",
        "mode",
        "`peer` | `client`",
        "`peer`: the launches connect to each other directly; `client`: through a Zenoh \
         router that `connect` names.",
    ),
    key(
        "launch.link",
        "listen",
        "list of TCP endpoints (`tcp/ADDRESS:PORT`)",
        "Where this launch accepts its peers' connections. The default listens on loopback \
         only; a host that other machines connect to names an address of its own, e.g. \
         `[\"tcp/192.168.1.20:7447\"]`.",
    ),
    key(
        "launch.link",
        "connect",
        "list of TCP endpoints (`tcp/ADDRESS:PORT`)",
        "The peers (or the router) this launch connects to.",
    ),
    key(
        "launch.link",
        "multicast_scouting",
        BOOL,
        "Find peers on the local network by UDP multicast (224.0.0.224:7446). Unset: on when \
         `connect` is empty, off when it names peers.",
    )
    .example("false"),
    key(
        "launch.link",
        "peer_timeout_ms",
        "ms, at least 100",
        "How long a launch waits for the launches of the other roles before it gives up \
         (non-zero exit; it names the roles it waited for). Nothing starts before they are \
         all there.",
    ),
    key(
        "launch.link",
        "restamp",
        BOOL,
        "Stamp observations and commands that arrive from a peer with this host's clock, \
         keeping the differences between their stamps (hosts' monotonic clocks differ); \
         `false` keeps the sender's stamps, for launches on one machine (tests, `tes bench \
         latency --via zenoh`).",
    ),
    // [perception]
    key(
        "perception",
        "arena",
        "`1` | `2` | `3`",
        "The arena simulated.",
    )
    .inherited("`[launch] arena`"),
    key(
        "perception",
        "episodes",
        "count, at least 1",
        "Episodes to run before exiting.",
    )
    .inherited("`[launch] episodes` (or `--episodes`)"),
    key(
        "perception",
        "actions",
        "count; 0 = no limit",
        "Stop after this many actions in all, ending the episode then as truncated (for \
         benchmarks that run a fixed number of actions).",
    ),
    key(
        "perception",
        "seed",
        "integer, 0 to 2^63 - 1",
        "Seed of the start poses and the wheel slip.",
    )
    .inherited("`[launch] seed`"),
    key(
        "perception",
        "real_time_factor",
        "factor, finite, at least 0",
        "1.0 = the paper's physical settle after each motion (`settle_ms`); 0 = none.",
    )
    .inherited("`[launch] real_time_factor`"),
    key(
        "perception",
        "settle_ms",
        "ms",
        "The idle time after a motion at real-time factor 1 (scaled by `real_time_factor`).",
    ),
    key(
        "perception",
        "step_cap",
        "count, at least 1",
        "Actions after which an episode is cut off.",
    ),
    key(
        "perception",
        "wait",
        WAIT,
        "How perception waits for motion reports.",
    )
    .inherited("`[launch] wait`"),
    key(
        "perception",
        "service_prefix",
        PREFIX,
        "Prefixed to every iceoryx2 service name.",
    )
    .inherited("`[launch] service_prefix` (the launch's own prefix when that is empty)"),
    key(
        "perception",
        "motor_timeout_ms",
        "ms, at least 1",
        "Re-publish an observation (flagged RESYNC) when no motion report follows it within \
         this time.",
    ),
    key(
        "perception",
        "left_port",
        "`0` (A) | `1` (B) | `2` (C); not `right_port`",
        "The NXT output port driving the left wheel (as `[bridge.motors] left_port`).",
    ),
    key(
        "perception",
        "right_port",
        "`0` (A) | `1` (B) | `2` (C); not `left_port`",
        "The NXT output port driving the right wheel (as `[bridge.motors] right_port`).",
    ),
    key(
        "perception",
        "trajectory",
        "path",
        "Where to write the run's trajectory: one CSV row per action (state, action, effect, \
         reward, poses before and after, why the episode ended). Unset: a launch writes \
         `trajectory.csv` in its run folder.",
    )
    .example("\"/path/to/trajectory.csv\""),
    // [controller]
    key(
        "controller",
        "library",
        "path",
        "The view library file. Unset: `library.tesl` in the data directory. Created at the \
         first save if missing; a file that exists but cannot be read stops the controller.",
    )
    .example("\"/path/to/library.tesl\""),
    key(
        "controller",
        "budget_us",
        "µs, at least 1",
        "The per-action latency budget, observation to command.",
    ),
    key(
        "controller",
        "wait",
        WAIT,
        "How the acting loop waits for observations.",
    )
    .inherited("`[launch] wait`"),
    key(
        "controller",
        "seed",
        "integer, 0 to 2^63 - 1",
        "Seed of the exploration.",
    )
    .inherited("`[launch] seed`"),
    key(
        "controller",
        "epsilon",
        "probability, 0 to 1",
        "Probability of a random action (paper section 5.2: 0.05).",
    ),
    key(
        "controller",
        "lambda",
        "finite, at least 0",
        "mDAGL's group-lasso strength for fresh views (paper: 0.05).",
    ),
    key(
        "controller",
        "alpha",
        "finite, above 0",
        "mDAGL's step scale for fresh views (paper section 5.2: 0.5).",
    ),
    key(
        "controller",
        "max_views",
        "count, at least 1",
        "The library's size limit M (paper: 20).",
    ),
    key(
        "controller",
        "service_prefix",
        PREFIX,
        "Prefixed to every iceoryx2 service name.",
    )
    .inherited("`[launch] service_prefix` (the launch's own prefix when that is empty)"),
    key(
        "controller",
        "map_timeout_s",
        "s, above 0",
        "How long to wait for perception's world map at the start.",
    ),
    key(
        "controller",
        "save_interval_s",
        "s, at least 0; 0 = after every episode",
        "Save the library at an episode's end only if this long has passed since the last \
         save; it is always saved at shutdown. A save copies every working view on the acting \
         loop, so saving after every episode at the fastest pace delays each episode's first \
         decision.",
    ),
    key(
        "controller",
        "plan_sweeps",
        "count, at least 1",
        "The most value-iteration sweeps the planner makes per hand-over of the model (an \
         unfinished plan continues at the next). Fewer leave more CPU to the loop on a small \
         machine, at the cost of staler plans.",
    ),
    key(
        "controller",
        "warmup_actions",
        "count",
        "Actions left out of the latency and allocation figures.",
    ),
    key(
        "controller",
        "report",
        "path",
        "Where to write the run's summary as JSON at exit. Unset: nowhere.",
    )
    .example("\"/path/to/report.json\""),
    key(
        "controller",
        "keepalive_ms",
        "ms; 0 = never; at most half the bridge's watchdog deadline in wall time",
        "While a command's move is under way, send the bridge a keep-alive this often, so \
         that the bridge's watchdog lets a long move go on while the controller lives and \
         brakes it once the controller is gone.",
    ),
    key(
        "controller",
        "acting_cpu",
        "CPU number | `\"auto\"` | `\"none\"`",
        "The CPU the acting loop's thread runs on. `auto`: with `wait = \"block\"` on two or \
         more CPUs, the last CPU this process may run on, else unpinned; `none`: unpinned. \
         Pinned, a blocking thread wakes where its memory is warm.",
    ),
    key(
        "controller",
        "planner_cpu",
        "CPU number | `\"auto\"` | `\"none\"`",
        "The planner thread's CPU. `auto`: when the acting thread is pinned, the first allowed \
         CPU other than its own, else unpinned; `none`: unpinned. A CPU number is refused with \
         between-polls planning (there is no planner thread).",
    ),
    key(
        "controller",
        "planning",
        "`auto` | `thread` | `between-polls` | `inline`",
        "Who plans: `thread`, a planner thread under SCHED_IDLE; `between-polls`, the acting \
         thread, in slices, while it spins waiting for the next observation (needs `wait = \
         \"spin\"` or `\"spin-then-block\"`); `inline`, the acting thread, each plan whole \
         right after the learning that follows the command, adopted at the next observation \
         (every run with the same seeds adopts the same plans at the same steps); `auto`, \
         between polls with `wait = \"spin\"`, else the thread.",
    ),
    key(
        "controller",
        "plan_slice",
        "states, at least 1",
        "With between-polls planning, the states' worth of planning done between two polls: \
         the most an observation arriving mid-slice waits.",
    ),
    key(
        "controller",
        "order",
        "`decide-first` | `learn-first`",
        "When the controller learns from an observation: `decide-first` publishes the command \
         first, then scores and updates the views and hands the planner the model; \
         `learn-first` does all that before deciding. Both make the same decisions; deciding \
         first keeps the learning off the decision's latency.",
    ),
    key(
        "controller",
        "planner_idle_spin_us",
        "µs, 0 = sleep at once",
        "With a planner thread: how long it polls for its next job after a plan before it \
         sleeps. It polls under SCHED_IDLE, with time nobody else wants, which keeps its CPU \
         out of the idle halt: a bridge woken by a command is put there and runs at once. 5 ms \
         covers an action at the simulator's fastest pace.",
    ),
    // [bridge]
    key(
        "bridge",
        "transport",
        "`\"sim\"` | `\"serial:<path>\"`",
        "What carries the telegrams: the simulated brick, in-process; or a serial device — a \
         real NXT over Bluetooth (`serial:/dev/rfcomm0`) or the pseudo-terminal that `bridge \
         brick --pty` serves.",
    ),
    key(
        "bridge",
        "seed",
        "integer, 0 to 2^63 - 1",
        "Seeds the simulated brick and the simulated link delay.",
    )
    .inherited("`[launch] seed`"),
    key(
        "bridge",
        "use_command_degrees",
        BOOL,
        "Drive the wheels by each command's `left_deg`/`right_deg` instead of looking its \
         action id up in `[[bridge.actions]]`.",
    )
    .inherited("`true`"),
    key(
        "bridge",
        "link_timeout_ms",
        "ms of wall time, at least 100",
        "A link to the brick that has not come up this long after the start, or has been \
         down this long since, stops the bridge with an error naming the transport (and with \
         it the launch).",
    ),
    // [bridge.link_delay]
    key("bridge.link_delay", "enabled", BOOL, "Delay each reply."),
    key(
        "bridge.link_delay",
        "mean_ms",
        "ms, at most 10000",
        "Mean delay per reply.",
    ),
    key(
        "bridge.link_delay",
        "jitter_ms",
        "ms, at most `mean_ms`",
        "Uniform jitter around the mean.",
    ),
    // [bridge.serial]
    key(
        "bridge.serial",
        "baud_rate",
        "bit/s",
        "Line speed (ignored by rfcomm and pseudo-terminals).",
    ),
    key(
        "bridge.serial",
        "read_timeout_ms",
        "ms, 10 to 60000",
        "Time to wait for a whole reply.",
    ),
    key(
        "bridge.serial",
        "reconnect_backoff_ms",
        "ms",
        "Wait between reconnection attempts.",
    ),
    key(
        "bridge.serial",
        "max_timeouts",
        "count, at least 1",
        "Consecutive timeouts before the device is reopened.",
    ),
    key(
        "bridge.serial",
        "exclusive",
        BOOL,
        "Open the device exclusively (TIOCEXCL): no second process on the same device.",
    ),
    // [bridge.watchdog]
    key(
        "bridge.watchdog",
        "deadline_ms",
        "ms of brick time, at least 50",
        "Brake the motors when no command or keep-alive arrives within this long while one \
         runs. It must exceed the longest action's duration.",
    )
    .inherited(
        "1000 × `[bridge.brick] time_scale` (at least × 1) with the simulated brick, one \
         second of wall time; 1000 with a serial transport",
    ),
    // [bridge.poll]
    key(
        "bridge.poll",
        "moving_period_ms",
        "ms, 1 to 1000, below `[bridge.watchdog] deadline_ms`",
        "Poll period (GETOUTPUTSTATE of the wheels) while a wheel moves.",
    ),
    key(
        "bridge.poll",
        "idle_period_ms",
        "ms, 10 to 600000",
        "Heartbeat period at rest: all ports and the battery are read and published.",
    ),
    key(
        "bridge.poll",
        "settle_polls",
        "count, 1 to 100",
        "Consecutive polls with idle wheels and unchanged counts before a move is settled.",
    ),
    key(
        "bridge.poll",
        "keepalive_period_ms",
        "ms, at least 1000",
        "Period of KEEPALIVE telegrams to the brick (they keep it from sleeping).",
    ),
    // [bridge.ipc]
    key(
        "bridge.ipc",
        "service_prefix",
        PREFIX,
        "Prefixed to every iceoryx2 service name.",
    )
    .inherited("`[launch] service_prefix` (the launch's own prefix when that is empty)"),
    key(
        "bridge.ipc",
        "wait",
        WAIT,
        "How the bridge waits for commands.",
    )
    .inherited("`[launch] wait`"),
    key(
        "bridge.ipc",
        "budget_us",
        "µs",
        "The per-action budget the observation-to-command latency is held to; overruns are \
         counted in the latency report.",
    ),
    key(
        "bridge.ipc",
        "warmup_commands",
        "count",
        "Commands left out of the latency report.",
    ),
    key(
        "bridge.ipc",
        "latency_report",
        "path",
        "Where to write the latency report (JSON: percentiles, maximum, misses) at exit. \
         Unset: nowhere.",
    )
    .example("\"/path/to/bridge-latency.json\""),
    key(
        "bridge.ipc",
        "latency_windows",
        "path",
        "Where to write the latency of every `latency_window` consecutive commands after the \
         warm-up, one CSV row per window, at exit: it shows drift over a long run. Unset: \
         nowhere.",
    )
    .example("\"/path/to/bridge-windows.csv\""),
    key(
        "bridge.ipc",
        "latency_window",
        "commands, at least 1",
        "Commands per window of `latency_windows`.",
    ),
    // [bridge.brick]
    key(
        "bridge.brick",
        "speed_per_power",
        "°/s per unit of power, above 0",
        "Steady speed per unit of power (an unloaded NXT motor: about 9 to 10).",
    ),
    key(
        "bridge.brick",
        "unregulated_speed_factor",
        "factor, above 0",
        "Steady speed of an unregulated motor relative to a regulated one (load, battery sag).",
    ),
    key(
        "bridge.brick",
        "time_constant_s",
        "s, above 0",
        "Time constant of the speed's response to power.",
    ),
    key(
        "bridge.brick",
        "coast_time_constant_s",
        "s, above 0",
        "Time constant of a coasting (floating) motor's slow-down.",
    ),
    key(
        "bridge.brick",
        "brake_time_constant_s",
        "s, above 0",
        "Time constant of a braking motor's slow-down.",
    ),
    key(
        "bridge.brick",
        "stop_speed_dps",
        "°/s, above 0",
        "Below this speed an undriven motor is at rest.",
    ),
    key(
        "bridge.brick",
        "speed_noise",
        "0 to 0.5",
        "Relative standard deviation of a command's steady speed (0 = noiseless).",
    ),
    key("bridge.brick", "battery_mv", "mV", "Fresh battery voltage."),
    key(
        "bridge.brick",
        "battery_noise_mv",
        "mV",
        "Half-width of the uniform noise on a battery reading (0 = noiseless).",
    ),
    key(
        "bridge.brick",
        "battery_drain_mv_per_s",
        "mV/s, at least 0",
        "Battery drain per powered motor per second.",
    ),
    key(
        "bridge.brick",
        "sleep_timeout_min",
        "minutes",
        "The sleep timeout KEEPALIVE reports.",
    ),
    key(
        "bridge.brick",
        "name",
        "at most 14 ASCII characters",
        "The brick name GETDEVICEINFO reports.",
    ),
    key(
        "bridge.brick",
        "address",
        "6 bytes",
        "The Bluetooth address GETDEVICEINFO reports.",
    ),
    key(
        "bridge.brick",
        "free_flash",
        "bytes",
        "The free user flash GETDEVICEINFO reports.",
    ),
    key(
        "bridge.brick",
        "time_scale",
        "factor, 0.001 to 10000",
        "How many times faster than the wall clock the simulated physics runs (1 = physical \
         time). The watchdog deadline and the poll periods are in brick time, so they scale \
         with it.",
    )
    .inherited("1 / `[launch] real_time_factor`, or 200 at real-time factor 0"),
    // [bridge.motors]
    key(
        "bridge.motors",
        "left_port",
        "`\"A\"` | `\"B\"` | `\"C\"`",
        "Output port of the left wheel motor.",
    ),
    key(
        "bridge.motors",
        "right_port",
        "`\"A\"` | `\"B\"` | `\"C\"`; not `left_port`",
        "Output port of the right wheel motor.",
    ),
    key(
        "bridge.motors",
        "power",
        "1 to 100",
        "Power (the speed set-point with regulation).",
    ),
    key(
        "bridge.motors",
        "brake",
        BOOL,
        "Brake at the tacho limit (MODE bit BRAKE) rather than coast.",
    ),
    key(
        "bridge.motors",
        "regulated",
        BOOL,
        "Turn on regulation (MODE bit REGULATED) with `regulation`.",
    ),
    key(
        "bridge.motors",
        "regulation",
        "`\"idle\"` | `\"speed\"` | `\"sync\"`; not `idle` when `regulated`",
        "The regulation mode.",
    ),
    key(
        "bridge.motors",
        "left_reversed",
        BOOL,
        "The left motor is mounted so that positive power drives the wheel backwards.",
    ),
    key(
        "bridge.motors",
        "right_reversed",
        BOOL,
        "The right motor is mounted so that positive power drives the wheel backwards.",
    ),
    key(
        "bridge.motors",
        "acknowledge",
        BOOL,
        "Ask the brick to acknowledge each SETOUTPUTSTATE (a Bluetooth round trip each).",
    ),
    // [[bridge.actions]]
    key(
        "bridge.actions",
        "id",
        "integer, at least 0, unique",
        "The action id the controller sends. Required in each entry.",
    ),
    key(
        "bridge.actions",
        "name",
        "text",
        "A name for logs (optional: empty when left out).",
    ),
    key(
        "bridge.actions",
        "left_deg",
        "degrees, within ±36000",
        "Signed rotation of the left wheel. Required in each entry.",
    ),
    key(
        "bridge.actions",
        "right_deg",
        "degrees, within ±36000",
        "Signed rotation of the right wheel. Required in each entry.",
    ),
];

/// The defaults of a launch file, one TOML table per process (`launch`, `perception`,
/// `controller`, `bridge`): the config structs' `Default`s, serialised. Keys that are unset
/// by default are absent (TOML has no "unset").
pub fn defaults() -> Result<toml::Table> {
    values_of(&LaunchFile::default())
}

/// The values of `file`, one TOML table per process, as [`defaults`] gives the defaults'.
fn values_of(file: &LaunchFile) -> Result<toml::Table> {
    let mut tables = toml::Table::new();
    let mut put = |name: &str, value: Result<toml::Value, toml::ser::Error>| -> Result<()> {
        let value = value.map_err(|source| ReferenceError::Serialise {
            table: name.to_owned(),
            source,
        })?;
        tables.insert(name.to_owned(), value);
        Ok(())
    };
    put("launch", toml::Value::try_from(&file.launch))?;
    put("perception", toml::Value::try_from(&file.perception))?;
    put("controller", toml::Value::try_from(&file.controller))?;
    put("bridge", toml::Value::try_from(&file.bridge))?;
    Ok(tables)
}

/// The value at the dotted `path` of `root`, if any.
pub fn lookup<'a>(root: &'a toml::Table, path: &str) -> Option<&'a toml::Value> {
    let mut parts = path.split('.');
    let mut value = root.get(parts.next()?)?;
    for part in parts {
        value = value.as_table()?.get(part)?;
    }
    Some(value)
}

/// Whether `value` is a table of its own in a TOML file: a table, or a non-empty array of
/// tables — not a key of the table holding it.
pub fn is_table(value: &toml::Value) -> bool {
    match value {
        toml::Value::Table(_) => true,
        toml::Value::Array(items) => !items.is_empty() && items.iter().all(|v| v.is_table()),
        _ => false,
    }
}

/// Whether the launcher fills `[table] key` in for a child ([`INHERITED`]).
fn is_inherited(table: &str, key: &str) -> bool {
    INHERITED.iter().any(|(t, k)| {
        // `bridge.ipc` + `wait` is INHERITED's `bridge` + `ipc.wait`.
        let full = format!("{t}.{k}");
        full.strip_prefix(table)
            .and_then(|rest| rest.strip_prefix('.'))
            == Some(key)
    })
}

/// How the reference describes a key the defaults have but [`KEYS`] does not (printed all
/// the same; the tests refuse it).
const UNDESCRIBED: Key = key(
    "",
    "",
    "?",
    "Not described yet: add it to KEYS in tes/src/launch/reference.rs.",
);

/// The keys of `table` in reference order, each with its description: the described ones,
/// then any key of its defaults `values` that is not described.
fn keys_of(table: &Table, values: Option<&toml::Table>) -> Vec<(String, Key)> {
    let mut keys: Vec<(String, Key)> = KEYS
        .iter()
        .filter(|k| k.table == table.name)
        .map(|k| (k.key.to_owned(), *k))
        .collect();
    for (name, value) in values.into_iter().flatten() {
        if !is_table(value) && !keys.iter().any(|(k, _)| k == name) {
            keys.push((name.clone(), UNDESCRIBED));
        }
    }
    keys
}

/// The launch file of the defaults: every key of every table, each with its meaning, unit or
/// allowed values, and default. Keys the launcher fills in for a child are commented out
/// (written in a child's table, even at its default, a key no longer follows `[launch]`), as
/// are keys unset by default (shown with an example value) — unless `set_all`, which writes
/// every one (for the tests: every key then reaches the parser).
pub fn render_toml(set_all: bool) -> Result<String> {
    let header = [
        "TES launch file: every key of every table, at its default.",
        "Printed by `tes launch --print-config`; read by `tes launch --config FILE`.",
        "Every key is optional: keep only those you change. Unknown keys are refused.",
        "Keys marked \"inherited\" are commented out: the launcher fills them in from [launch]",
        "unless the table sets them; uncomment one to give that process a value of its own.",
        "Keys unset by default are commented out with an example value.",
        "Reference: docs/config.md (tes launch --print-config=markdown).",
    ];
    render_values(&defaults()?, &header, set_all)
}

/// The launch file a run folder keeps: every key of `file` (the user's values, the defaults
/// for the rest), described as [`render_toml`] describes them, which `tes launch --config`
/// reads back as the same launch. The keys a child inherits from `[launch]` stay commented
/// out unless the file gave that child its own value.
pub fn render_resolved(file: &LaunchFile) -> Result<String> {
    let header = [
        "TES launch file of this run: every key, as the launch ran it (the file's values, the",
        "defaults for the rest). `tes launch --config THIS_FILE` runs it again (with a run",
        "folder of its own). What each child ran with, inherited keys filled in, is in",
        "ROLE.toml beside it.",
    ];
    let mut text = render_values(&values_of(file)?, &header, false)?;
    // A child's own value of an inherited key is part of the launch: write it out.
    for key in &file.own {
        // `bridge.ipc.wait` is the `wait` line of `[bridge.ipc]`.
        let Some((table, name)) = key.rsplit_once('.') else {
            continue;
        };
        let commented = format!("# {name} = ");
        if let Some(at) = find_in_table(&text, table, &commented) {
            text.replace_range(at..at + 2, "");
        }
    }
    Ok(text)
}

/// Where the line starting with `line` is in the `[table]` section of `text`.
fn find_in_table(text: &str, table: &str, line: &str) -> Option<usize> {
    let header = format!("\n[{table}]\n");
    let start = text.find(&header)? + header.len();
    let end = text[start..].find("\n[").map_or(text.len(), |e| start + e);
    let at = text[start..end].find(&format!("\n{line}"))?;
    Some(start + at + 1)
}

/// [`render_toml`] of the values `tables`, after the comment lines `header`.
fn render_values(tables: &toml::Table, header: &[&str], set_all: bool) -> Result<String> {
    let defaults = tables;
    let mut out = String::new();
    for line in header {
        comment(&mut out, line);
    }
    for table in TABLES {
        let value = lookup(defaults, table.name);
        out.push('\n');
        comment(&mut out, table.about);
        if table.array {
            let items = value.and_then(toml::Value::as_array);
            for (i, item) in items.into_iter().flatten().enumerate() {
                if i > 0 {
                    out.push('\n');
                }
                writeln!(out, "[[{}]]", table.name)?;
                let values = item.as_table();
                for (name, k) in keys_of(table, values) {
                    write_key(&mut out, table, &name, &k, values, i == 0, set_all)?;
                }
            }
        } else {
            writeln!(out, "[{}]", table.name)?;
            let values = value.and_then(toml::Value::as_table);
            for (name, k) in keys_of(table, values) {
                write_key(&mut out, table, &name, &k, values, true, set_all)?;
            }
        }
    }
    Ok(out)
}

/// Writes `name` of `table`, described by `k`, where the table's (or the array entry's)
/// default values are `values`: its comment (if `described`), then its line.
fn write_key(
    out: &mut String,
    table: &Table,
    name: &str,
    k: &Key,
    values: Option<&toml::Table>,
    described: bool,
    set_all: bool,
) -> Result<()> {
    let value = values.and_then(|v| v.get(name));
    let inherited = is_inherited(table.name, name);
    if described {
        out.push('\n');
        comment(out, k.meaning);
        match value {
            // An entry of an array of tables: its values are right below.
            _ if table.array => comment(out, &format!("{}.", k.allowed)),
            Some(v) => comment(out, &format!("{}. Default: {v}.", k.allowed)),
            None => comment(out, &format!("{}. Default: unset.", k.allowed)),
        }
        if inherited {
            let from = k.inherited.unwrap_or("the launch-wide value");
            comment(
                out,
                &format!("Inherited: unless this table sets it, a launch sets it to {from}."),
            );
        }
    }
    match (value, k.example) {
        (Some(v), _) if inherited && !set_all => writeln!(out, "# {name} = {v}")?,
        (Some(v), _) => writeln!(out, "{name} = {v}")?,
        (None, Some(example)) if set_all => writeln!(out, "{name} = {example}")?,
        (None, Some(example)) => writeln!(out, "# {name} = {example}")?,
        (None, None) => {}
    }
    Ok(())
}

/// Appends `text` as TOML comment lines of at most [`WIDTH`] characters.
fn comment(out: &mut String, text: &str) {
    for line in wrap(text, WIDTH - 2) {
        out.push_str("# ");
        out.push_str(&line);
        out.push('\n');
    }
}

/// The width the printed file's comments are wrapped to.
const WIDTH: usize = 92;

/// `text` in lines of at most `width` characters, broken at spaces (a longer word gets a
/// line of its own).
fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        if !line.is_empty() && line.chars().count() + 1 + word.chars().count() > width {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(word);
    }
    if !line.is_empty() {
        lines.push(line);
    }
    lines
}

/// The reference page, `docs/config.md`: how the launch file is read, the inherited keys, and
/// per table a row per key (key, default, unit or allowed values, meaning).
pub fn render_markdown() -> Result<String> {
    let defaults = defaults()?;
    let mut out = String::new();
    out.push_str("# Launch file reference\n\n");
    writeln!(
        out,
        "<!-- Generated from tes/src/launch/reference.rs by `{REGENERATE}`; \
         do not edit by hand. -->\n"
    )?;
    out.push_str(INTRO);
    out.push_str("\n## Inherited keys\n\n");
    out.push_str(INHERITANCE);
    out.push_str("\n| key | in a launch |\n|---|---|\n");
    for (table, key) in INHERITED {
        let path = format!("{table}.{key}");
        let row = KEYS.iter().find(|k| k.path() == path);
        let (table, key) = row.map_or((table, key), |k| (k.table, k.key));
        let from = row
            .and_then(|k| k.inherited)
            .unwrap_or("the launch-wide value");
        writeln!(out, "| `[{table}] {key}` | {} |", cell(from))?;
    }
    for table in TABLES {
        let header = if table.array {
            format!("[[{}]]", table.name)
        } else {
            format!("[{}]", table.name)
        };
        writeln!(out, "\n## `{header}`\n")?;
        writeln!(out, "{}\n", table.about)?;
        out.push_str("| key | default | unit / allowed | meaning |\n|---|---|---|---|\n");
        let value = lookup(&defaults, table.name);
        // An array of tables: each key's defaults, entry by entry.
        let rows: Vec<&toml::Table> = match value {
            Some(toml::Value::Array(items)) => items.iter().filter_map(|v| v.as_table()).collect(),
            Some(toml::Value::Table(t)) => vec![t],
            _ => Vec::new(),
        };
        let first = rows.first().copied();
        for (name, k) in keys_of(table, first) {
            let values: Vec<String> = rows
                .iter()
                .filter_map(|r| r.get(&name))
                .map(|v| format!("`{v}`"))
                .collect();
            let mut default = if values.is_empty() {
                "unset".to_owned()
            } else {
                values.join(", ")
            };
            if let Some(example) = k.example.filter(|_| values.is_empty()) {
                default = format!("unset (e.g. `{example}`)");
            }
            let mut meaning = k.meaning.to_owned();
            if is_inherited(table.name, &name) {
                let from = k.inherited.unwrap_or("the launch-wide value");
                default = format!("{default}; in a launch: {from}");
                meaning = format!("**Inherited.** {meaning}");
            }
            writeln!(
                out,
                "| `{name}` | {} | {} | {} |",
                cell(&default),
                cell(k.allowed),
                cell(&meaning)
            )?;
        }
    }
    Ok(out)
}

/// `text` made safe for a markdown table cell (`|` escaped, even inside code spans, as GitHub
/// wants).
fn cell(text: &str) -> String {
    text.replace('|', "\\|")
}

/// The reference page's introduction: how the launch file is read.
const INTRO: &str = "\
`tes launch --config FILE` reads one TOML file with a table per process of the group: \
`[launch]` for the launch-wide settings, then `[perception]`, `[controller]` and `[bridge]` \
(with the bridge's nested tables). This page lists every key: its default, its unit or the \
values it takes, and what it does. `tes launch --print-config` prints the same keys as a \
launch file, every one at its default and commented, ready to edit; fed back to \
`tes launch --config`, that file runs the defaults.

## How the launch file is read

- Every table and every key is optional: a key left out has its default, and no file at all \
is the same as an empty one.
- The file is read once, before anything starts, each table into the typed settings of its \
process. A key that is unknown (a typo), of the wrong type or repeated is refused, naming \
the file, the line, the table and the key (`launch.toml:7:1: [controller] budjet_us: unknown \
field ...`).
- The launcher then fills in the inherited keys (below) and checks every process's settings \
(ranges, and keys that contradict each other, such as a keep-alive too slow for the bridge's \
watchdog); the first bad key is reported the same way, and nothing is started.
- It writes each child's settings, as the child runs them, to the run directory \
(`[launch] run_dir`): `perception-sim.toml`, `controller.toml`, `bridge.toml`.
- `--episodes N` overrides `[launch] episodes`.
";

/// The reference page's paragraph on the keys the children inherit.
const INHERITANCE: &str = "\
Some keys of the children's tables are one setting for the whole group: the seed, how the \
processes wait, the service prefix, the arena and the pace. The launcher fills them in from \
`[launch]` for each child whose table does not set the key itself; a table that sets one \
keeps its own value, even when it equals the default. So `[launch] wait = \"spin\"` makes \
every process spin, and adding `[perception] wait = \"block\"` leaves perception blocking. \
The printed launch file therefore has these keys commented out: uncommenting one takes that \
process off the launch-wide value.
";

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use serde::de::{DeserializeOwned, Visitor};
    use tes_bridge::actions::{ActionSpec, MotorsConfig};
    use tes_bridge::brick::SimBrickConfig;
    use tes_bridge::config::{
        IpcConfig, LinkDelayConfig, PollConfig, SerialSection, WatchdogSection,
    };
    use tes_runtime::settings::Origin;

    use super::*;
    use crate::file::LaunchSection;
    use tes_bridge::config::BridgeSettings;
    use tes_controller::config::ControllerConfig;
    use tes_perception_sim::process::PerceptionConfig;

    /// Stops a [`FieldNames`] probe once it has seen the struct's fields.
    #[derive(Debug)]
    struct Seen;

    impl std::fmt::Display for Seen {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("field names seen")
        }
    }

    impl std::error::Error for Seen {}

    impl serde::de::Error for Seen {
        fn custom<T: std::fmt::Display>(_: T) -> Self {
            Seen
        }
    }

    /// A deserializer that reads nothing: it records the field names a derived
    /// `Deserialize` of a struct asks for — every field, `Option`s included, which a
    /// serialised default leaves out.
    struct FieldNames<'a>(&'a mut &'static [&'static str]);

    impl<'de> serde::Deserializer<'de> for FieldNames<'_> {
        type Error = Seen;

        fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Seen> {
            Err(Seen)
        }

        fn deserialize_struct<V: Visitor<'de>>(
            self,
            _: &'static str,
            fields: &'static [&'static str],
            _: V,
        ) -> Result<V::Value, Seen> {
            *self.0 = fields;
            Err(Seen)
        }

        serde::forward_to_deserialize_any! {
            bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
            byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map enum
            identifier ignored_any
        }
    }

    /// The field names of the struct `T`, as its `Deserialize` knows them.
    fn fields_of<T: DeserializeOwned>() -> &'static [&'static str] {
        let mut fields: &'static [&'static str] = &[];
        assert!(T::deserialize(FieldNames(&mut fields)).is_err());
        assert!(
            !fields.is_empty(),
            "{} is not a struct",
            std::any::type_name::<T>()
        );
        fields
    }

    /// Every table of the launch file and the struct it is read into, as the parser's field
    /// names.
    fn struct_fields() -> Vec<(&'static str, &'static [&'static str])> {
        vec![
            ("launch", fields_of::<LaunchSection>()),
            ("launch.link", fields_of::<tes_link::LinkSection>()),
            ("perception", fields_of::<PerceptionConfig>()),
            ("controller", fields_of::<ControllerConfig>()),
            ("bridge", fields_of::<BridgeSettings>()),
            ("bridge.link_delay", fields_of::<LinkDelayConfig>()),
            ("bridge.serial", fields_of::<SerialSection>()),
            ("bridge.watchdog", fields_of::<WatchdogSection>()),
            ("bridge.poll", fields_of::<PollConfig>()),
            ("bridge.ipc", fields_of::<IpcConfig>()),
            ("bridge.brick", fields_of::<SimBrickConfig>()),
            ("bridge.motors", fields_of::<MotorsConfig>()),
            ("bridge.actions", fields_of::<ActionSpec>()),
        ]
    }

    /// The dotted tables and keys of `value` (a table at `path`), into `tables` and `keys`.
    fn walk(
        path: &str,
        value: &toml::Value,
        tables: &mut BTreeSet<String>,
        keys: &mut BTreeSet<String>,
    ) {
        tables.insert(path.to_owned());
        let entries: Vec<&toml::Table> = match value {
            toml::Value::Table(t) => vec![t],
            toml::Value::Array(items) => items.iter().filter_map(|v| v.as_table()).collect(),
            _ => Vec::new(),
        };
        for table in entries {
            for (name, v) in table {
                let at = format!("{path}.{name}");
                if is_table(v) {
                    walk(&at, v, tables, keys);
                } else {
                    keys.insert(at);
                }
            }
        }
    }

    /// The keys the config structs know, dotted from the top of the file: every key of the
    /// serialised defaults, and every field name of each table's struct that is not itself a
    /// table (the fields unset by default, which serialising leaves out).
    fn struct_keys() -> BTreeSet<String> {
        let defaults = defaults().expect("defaults serialise");
        let (mut tables, mut keys) = (BTreeSet::new(), BTreeSet::new());
        for (name, value) in &defaults {
            walk(name, value, &mut tables, &mut keys);
        }
        let typed = struct_fields();
        let typed_tables: BTreeSet<String> = typed.iter().map(|(t, _)| t.to_string()).collect();
        assert_eq!(
            tables, typed_tables,
            "a table of the launch file has no struct in struct_fields() (or one is gone): \
             add it there and to TABLES in tes/src/launch/reference.rs"
        );
        for (table, fields) in typed {
            for field in fields {
                let at = format!("{table}.{field}");
                if !tables.contains(&at) {
                    keys.insert(at);
                }
            }
        }
        keys
    }

    fn reference_keys() -> BTreeSet<String> {
        KEYS.iter().map(Key::path).collect()
    }

    /// Adding a field to any config struct without describing it fails here, naming it.
    #[test]
    fn every_key_of_every_config_struct_is_in_the_reference() {
        let missing: Vec<String> = struct_keys()
            .difference(&reference_keys())
            .cloned()
            .collect();
        assert!(
            missing.is_empty(),
            "keys the config structs know but the launch file reference does not describe: \
             {missing:?}; add a line for each to KEYS in tes/src/launch/reference.rs, e.g. \
             key(\"controller\", \"name\", \"unit or allowed values\", \"what it does\"), then \
             regenerate the docs: {REGENERATE}"
        );
    }

    #[test]
    fn every_key_in_the_reference_is_known_to_the_parser() {
        let unknown: Vec<String> = reference_keys()
            .difference(&struct_keys())
            .cloned()
            .collect();
        assert!(
            unknown.is_empty(),
            "keys in tes/src/launch/reference.rs that no config struct has: {unknown:?}"
        );
        assert_eq!(
            reference_keys().len(),
            KEYS.len(),
            "a key is described twice"
        );
        for table in KEYS.iter().map(|k| k.table) {
            assert!(TABLES.iter().any(|t| t.name == table), "no table {table}");
        }
        // Every key written, the ones commented out by default included: the parser (which
        // refuses unknown keys) takes them all, and the children's tables then set every
        // inherited key themselves.
        let every = render_toml(true).expect("renders");
        let file =
            LaunchFile::from_toml(&every, Origin::Text).unwrap_or_else(|e| panic!("{e}\n{every}"));
        let own: BTreeSet<String> = INHERITED.iter().map(|(t, k)| format!("{t}.{k}")).collect();
        assert_eq!(file.own, own);
    }

    /// The printed file is the defaults: each table reads back as its default, no child table
    /// sets an inherited key, and the children's settings are those of no file at all.
    #[test]
    fn the_printed_file_reads_back_as_the_defaults() {
        let text = render_toml(false).expect("renders");
        let file =
            LaunchFile::from_toml(&text, Origin::Text).unwrap_or_else(|e| panic!("{e}\n{text}"));
        let defaults = LaunchFile::default();
        assert_eq!(
            format!("{:?}", file.launch),
            format!("{:?}", defaults.launch)
        );
        assert_eq!(file.perception, defaults.perception);
        assert_eq!(file.controller, defaults.controller);
        assert_eq!(file.bridge, defaults.bridge);
        assert!(file.own.is_empty(), "{:?}", file.own);
        assert_eq!(
            file.children().expect("valid"),
            defaults.children().expect("valid")
        );
    }

    /// The keys the reference marks inherited are exactly the ones the launcher fills in.
    #[test]
    fn the_inherited_keys_are_the_launchers() {
        for (table, key) in INHERITED {
            let path = format!("{table}.{key}");
            let row = KEYS.iter().find(|k| k.path() == path);
            assert!(
                row.is_some_and(|k| k.inherited.is_some() && is_inherited(k.table, k.key)),
                "{path} is inherited: describe it with .inherited(...)"
            );
        }
        for k in KEYS.iter().filter(|k| k.inherited.is_some()) {
            assert!(
                is_inherited(k.table, k.key),
                "{} is not in INHERITED",
                k.path()
            );
        }
        assert!(!is_inherited("bridge", "wait"));
        assert!(!is_inherited("bridge.i", "pc.wait"));
    }

    #[test]
    fn the_markdown_has_a_row_per_key_and_escapes_pipes() {
        let md = render_markdown().expect("renders");
        for table in TABLES {
            let header = if table.array {
                format!("## `[[{}]]`", table.name)
            } else {
                format!("## `[{}]`", table.name)
            };
            assert!(md.contains(&header), "{header}");
        }
        for k in KEYS {
            assert!(md.contains(&format!("\n| `{}` |", k.key)), "{}", k.path());
        }
        // Every row of a key table has its four cells.
        for line in md
            .lines()
            .filter(|l| l.starts_with("| `") && !l.starts_with("| `["))
        {
            let cells = line.replace("\\|", "").matches('|').count();
            assert_eq!(cells, 5, "{line}");
        }
    }

    #[test]
    fn comments_are_wrapped_without_losing_a_word() {
        let text = "a few words, and one-very-long-word-that-does-not-fit, then more";
        for width in [1, 5, 12, 40, 200] {
            let lines = wrap(text, width);
            assert_eq!(lines.join(" "), text, "{width}");
            for line in &lines {
                assert!(
                    line.chars().count() <= width || !line.contains(' '),
                    "{width}: {line:?}"
                );
            }
        }
        assert!(wrap("", 10).is_empty());
        let printed = render_toml(false).expect("renders");
        for line in printed.lines().filter(|l| l.starts_with("# ")) {
            assert!(
                line.chars().count() <= WIDTH || !line[2..].contains(' '),
                "{line}"
            );
        }
    }
}
