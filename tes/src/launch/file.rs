//! The launch file: read once into each process's typed settings, checked, and written to the
//! run directory for the children.

use super::*;

/// What to do when a child dies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Restart {
    /// Stop the others and exit non-zero.
    #[default]
    Never,
    /// Respawn it (up to `max_restarts` times).
    OnFailure,
}

/// The `[launch]` table (its keys are described in [`super::reference`]).
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LaunchSection {
    /// Episodes perception runs before the group stops (default 20).
    pub episodes: u32,
    /// The arena: 1, 2 or 3 (default 3, the paper's test arena).
    pub arena: u8,
    /// Real-time factor: 1.0 = physical time (the paper's 200 ms settle), 0 = as fast as
    /// possible (default).
    pub real_time_factor: f64,
    /// How every process waits: `block` (default), `spin`, `spin-then-block[:<µs>]`.
    pub wait: WaitStrategy,
    /// `never` (default) or `on-failure`.
    pub restart: Restart,
    /// Respawns allowed per child with `on-failure` (default 3).
    pub max_restarts: u32,
    /// Grace period of each shutdown step, ms (default 3000).
    pub grace_ms: u64,
    /// Prefix of every iceoryx2 service. Unset (the default), each launch gets one of its own,
    /// `tes-PID-XXXXXXXX/`, so any number of launches run side by side; a prefix already used
    /// by a running group is refused.
    pub service_prefix: String,
    /// The run folder itself, used as it is (no folder per run, never pruned). Unset (the
    /// default), each launch gets a folder of its own under `runs_dir`.
    pub run_dir: Option<PathBuf>,
    /// Where the per-launch run folders go (default: `runs` in the data directory).
    pub runs_dir: Option<PathBuf>,
    /// How many run folders `runs_dir` keeps: the oldest beyond it are removed when a launch
    /// starts (default 20; 0 keeps every one).
    pub keep_runs: u32,
    /// Seed of the world and the agent (default 1).
    pub seed: u64,
    /// A group whose controller sends no command for this long is stalled: the launcher
    /// names the process holding it up and stops the group (`restart = "never"`) or
    /// restarts that process (`on-failure`), ms of wall time (default 10000, at least 500).
    pub stall_timeout_ms: u64,
    /// Record the run to this MCAP file (`tes launch --record`); unset (the default): no
    /// recording.
    pub record: Option<PathBuf>,
    /// The processes this launch starts (`tes launch --roles`): some of `perception-sim`,
    /// `controller`, `bridge`; the others run on other hosts, reached through the link
    /// (`[launch.link]`). Empty (the default): all three, on this host, and no link.
    pub roles: Vec<String>,
    /// How a launch with roles reaches the other hosts.
    pub link: crate::link::LinkSection,
}

impl Default for LaunchSection {
    fn default() -> Self {
        Self {
            episodes: 20,
            arena: 3,
            real_time_factor: 0.0,
            wait: WaitStrategy::Block,
            restart: Restart::Never,
            max_restarts: 3,
            grace_ms: 3000,
            service_prefix: String::new(),
            run_dir: None,
            runs_dir: None,
            keep_runs: 20,
            seed: 1,
            stall_timeout_ms: 10_000,
            record: None,
            roles: Vec::new(),
            link: crate::link::LinkSection::default(),
        }
    }
}

/// The process name of errors about the `[launch]` table (and about the file as a whole).
pub(crate) const LAUNCH: &str = "launch";

/// Which process a table of a launch file is for.
pub(crate) fn process_of(table: &str) -> Option<&'static str> {
    match table {
        "launch" => Some(LAUNCH),
        "perception" => Some(tes_perception_sim::process::config::PROCESS),
        "controller" => Some(tes_controller::config::PROCESS),
        "bridge" => Some(tes_bridge::config::PROCESS),
        _ => None,
    }
}

/// The launch-wide values the launcher sets in the children's tables, as `(table, key)`:
/// each is set unless the table sets the key itself.
pub(crate) const INHERITED: [(&str, &str); 15] = [
    ("perception", "arena"),
    ("perception", "episodes"),
    ("perception", "real_time_factor"),
    ("perception", "wait"),
    ("perception", "service_prefix"),
    ("perception", "seed"),
    ("controller", "wait"),
    ("controller", "service_prefix"),
    ("controller", "seed"),
    ("bridge", "seed"),
    ("bridge", "use_command_degrees"),
    ("bridge", "ipc.service_prefix"),
    ("bridge", "ipc.wait"),
    ("bridge", "brick.time_scale"),
    ("bridge", "watchdog.deadline_ms"),
];

/// The tables of a launch file, as the parser reads them.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct Tables {
    launch: LaunchSection,
    perception: PerceptionConfig,
    controller: ControllerConfig,
    bridge: BridgeSettings,
}

/// A whole launch file: each table typed as its process reads it, and where it came from.
#[derive(Debug, Clone)]
pub(crate) struct LaunchFile {
    pub(crate) launch: LaunchSection,
    pub(crate) perception: PerceptionConfig,
    pub(crate) controller: ControllerConfig,
    pub(crate) bridge: BridgeSettings,
    /// The [`INHERITED`] keys the children's tables set themselves, as `table.key`
    /// (`perception.wait`): the launch-wide values do not replace them.
    pub(crate) own: BTreeSet<String>,
    /// Where the file came from (errors name it).
    pub(crate) origin: Origin,
    /// The file as the user wrote it (errors give the line of their key in it).
    pub(crate) text: Option<String>,
}

impl Default for LaunchFile {
    fn default() -> Self {
        let Tables {
            launch,
            perception,
            controller,
            bridge,
        } = Tables::default();
        Self {
            launch,
            perception,
            controller,
            bridge,
            own: BTreeSet::new(),
            origin: Origin::Defaults,
            text: None,
        }
    }
}

/// The children's settings as they are written to the run directory: the launch file's
/// tables with the launch-wide values set, each checked.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Children {
    pub(crate) bridge: BridgeSettings,
    pub(crate) controller: ControllerConfig,
    pub(crate) perception: PerceptionConfig,
}

/// The trajectory perception writes in the run folder, unless its table names a file.
pub(crate) const TRAJECTORY: &str = "trajectory.csv";

/// The latency report the bridge writes in the run folder, unless its table names a file.
pub(crate) const BRIDGE_REPORT: &str = "bridge-report.json";

impl Children {
    /// Has the children write their records into the run folder `run_dir` where their tables
    /// name no file of their own: perception's trajectory, the bridge's latency report.
    pub(crate) fn write_into(&mut self, run_dir: &Path) {
        self.perception
            .trajectory
            .get_or_insert_with(|| run_dir.join(TRAJECTORY));
        self.bridge
            .ipc
            .latency_report
            .get_or_insert_with(|| run_dir.join(BRIDGE_REPORT));
    }
}

impl LaunchFile {
    /// Parses a launch file's text, once, into the typed tables; a key that is unknown, of
    /// the wrong type or repeated is reported with `origin`, its line and its table and key.
    pub(crate) fn from_toml(text: &str, origin: Origin) -> Result<Self, SettingError> {
        let t: Tables = settings::parse_tables(LAUNCH, text, origin.clone(), process_of)?;
        let own = INHERITED
            .iter()
            .filter(|(table, key)| settings::is_set(text, Some(table), key))
            .map(|(table, key)| format!("{table}.{key}"))
            .collect();
        Ok(Self {
            launch: t.launch,
            perception: t.perception,
            controller: t.controller,
            bridge: t.bridge,
            own,
            origin,
            text: Some(text.to_owned()),
        })
    }

    /// Keeps `[table] key` as the table sets it: the launch-wide value does not replace it
    /// (what writing the key in the table does in a file).
    pub(crate) fn keep(&mut self, table: &str, key: &str) {
        self.own.insert(format!("{table}.{key}"));
    }

    /// The roles this launch plays, in [`Role::ALL`] order; `None` when it plays all three on
    /// one host (no link).
    pub(crate) fn roles(&self) -> Option<Vec<Role>> {
        let roles: Vec<Role> = Role::ALL
            .into_iter()
            .filter(|r| self.launch.roles.iter().any(|n| n == r.name()))
            .collect();
        (!roles.is_empty() && roles.len() < Role::ALL.len()).then_some(roles)
    }

    /// The arena perception runs: its own `arena` if its table sets one, else `[launch] arena`.
    pub(crate) fn arena(&self) -> u32 {
        if self.inherits("perception", "arena") {
            u32::from(self.launch.arena)
        } else {
            self.perception.arena
        }
    }

    /// Whether the launch-wide value goes into `[table] key`.
    fn inherits(&self, table: &str, key: &str) -> bool {
        !self.own.contains(&format!("{table}.{key}"))
    }

    /// `error`, about a key of `table`, placed at its line in the file.
    fn place(&self, error: SettingError, table: &str) -> SettingError {
        error.in_file(self.origin.clone(), Some(table), self.text.as_deref())
    }

    /// The children's settings: the tables with the launch-wide values set where a table
    /// does not set its own, every one checked (the first bad key is reported, placed in the
    /// file).
    pub(crate) fn children(&self) -> Result<Children, SettingError> {
        let l = &self.launch;
        check_launch(l).map_err(|e| self.place(e, "launch"))?;
        // TOML integers end at i64::MAX; a larger seed set in code is written as that.
        let seed = l.seed.min(i64::MAX.unsigned_abs());

        let mut perception = self.perception.clone();
        let inherit = |key| self.inherits("perception", key);
        if inherit("arena") {
            perception.arena = u32::from(l.arena);
        }
        if inherit("episodes") {
            perception.episodes = l.episodes;
        }
        if inherit("real_time_factor") {
            perception.real_time_factor = l.real_time_factor;
        }
        if inherit("wait") {
            perception.wait = l.wait;
        }
        if inherit("service_prefix") {
            perception.service_prefix.clone_from(&l.service_prefix);
        }
        if inherit("seed") {
            perception.seed = seed;
        }

        let mut controller = self.controller.clone();
        let inherit = |key| self.inherits("controller", key);
        if inherit("wait") {
            controller.wait = l.wait;
        }
        if inherit("service_prefix") {
            controller.service_prefix.clone_from(&l.service_prefix);
        }
        if inherit("seed") {
            controller.seed = seed;
        }

        let mut bridge = self.bridge.clone();
        let inherit = |key| self.inherits("bridge", key);
        if inherit("seed") {
            bridge.seed = seed;
        }
        if inherit("use_command_degrees") {
            bridge.use_command_degrees = true;
        }
        if inherit("ipc.service_prefix") {
            bridge.ipc.service_prefix.clone_from(&l.service_prefix);
        }
        if inherit("ipc.wait") {
            bridge.ipc.wait = l.wait;
        }
        let simulated = bridge.transport == TransportKind::Sim;
        let time_scale = if l.real_time_factor == 0.0 {
            FASTEST_TIME_SCALE
        } else {
            1.0 / l.real_time_factor
        };
        if inherit("brick.time_scale") {
            bridge.brick.time_scale = time_scale;
        }
        // The watchdog deadline is in brick time: at a speed-up, give the wall clock the
        // usual second, so a descheduled bridge on a busy machine does not brake a healthy
        // run. A real brick (serial transport) runs in physical time whatever the scale.
        if inherit("watchdog.deadline_ms") {
            let scale = if simulated { time_scale.max(1.0) } else { 1.0 };
            // Saturating: a deadline beyond i64::MAX ms is no deadline at all.
            bridge.watchdog.deadline_ms = ((1000.0 * scale).round() as i64).unsigned_abs();
        }

        // Every child's settings are checked here, so a bad key stops the launch before any
        // process starts.
        let bridge_cfg = bridge.check().map_err(|e| self.place(e, "bridge"))?;
        controller
            .check()
            .map_err(|e| self.place(e, "controller"))?;
        // The watchdog's deadline is brick time; the keep-alives are wall time.
        let wall_scale = if simulated {
            bridge_cfg.brick.time_scale
        } else {
            1.0
        };
        let deadline_wall_ms = bridge_cfg.watchdog_deadline.as_secs_f64() * 1000.0 / wall_scale;
        if controller.keepalive_ms as f64 * 2.0 > deadline_wall_ms {
            let reason = format!(
                "{} must be at most half the bridge's watchdog deadline ({deadline_wall_ms:.0} \
                 ms of wall time: watchdog.deadline_ms / brick.time_scale), or the watchdog \
                 brakes moves of a live controller",
                controller.keepalive_ms
            );
            let error = SettingError::new(tes_controller::config::PROCESS, "keepalive_ms", reason);
            return Err(self.place(error, "controller"));
        }
        perception
            .check()
            .map_err(|e| self.place(e, "perception"))?;
        Ok(Children {
            bridge,
            controller,
            perception,
        })
    }
}

/// Checks the `[launch]` table's own keys.
pub(crate) fn check_launch(l: &LaunchSection) -> Result<(), SettingError> {
    let bad = |key, reason: String| Err(SettingError::new(LAUNCH, key, reason));
    if !(1..=3).contains(&l.arena) {
        return bad("arena", format!("must be 1, 2 or 3, got {}", l.arena));
    }
    if !(l.real_time_factor.is_finite() && l.real_time_factor >= 0.0) {
        return bad("real_time_factor", "must be a finite number >= 0".into());
    }
    if l.episodes == 0 {
        return bad("episodes", "must be at least 1".into());
    }
    if l.stall_timeout_ms < 500 {
        return bad(
            "stall_timeout_ms",
            format!("must be at least 500, got {}", l.stall_timeout_ms),
        );
    }
    if l.service_prefix.len() > 64 {
        return bad("service_prefix", "must be at most 64 bytes".into());
    }
    let mut seen = BTreeSet::new();
    for role in &l.roles {
        if crate::link::parse_role(role).is_none() {
            return bad(
                "roles",
                format!(
                    "unknown role {role:?}: the roles are \"perception-sim\", \"controller\" \
                     and \"bridge\""
                ),
            );
        }
        if !seen.insert(role.as_str()) {
            return bad("roles", format!("{role:?} is listed twice"));
        }
    }
    if !l.roles.is_empty() {
        l.link.check().or_else(|(key, reason)| bad(key, reason))?;
    }
    Ok(())
}

/// The simulated brick's speed-up at real-time factor 0 ("as fast as possible"): motor
/// motion runs this many times faster than physical time.
pub(crate) const FASTEST_TIME_SCALE: f64 = 200.0;

/// A launch file that cannot be used; when one is refused, nothing is started.
#[derive(Debug)]
pub(crate) enum LaunchFileError {
    /// It cannot be read: missing, unreadable, or not UTF-8 text.
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// A key is unknown, of the wrong type, repeated or out of range, the settings contradict
    /// each other, or the text is not TOML: placed in the file (its origin, line, table and
    /// key).
    Setting(SettingError),
    /// The children's settings cannot be serialised (a bug).
    Write {
        /// The launch file (or the embedded defaults).
        origin: Origin,
        /// Why.
        error: anyhow::Error,
    },
    /// The run directory cannot be created or written (disk full, read-only, permissions).
    RunDir {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// Another group owns the run directory.
    Busy(LockError),
}

impl std::fmt::Display for LaunchFileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let what = |origin: &Origin| match origin {
            Origin::File(_) => "launch file",
            Origin::Text | Origin::Defaults => "launch settings",
        };
        match self {
            LaunchFileError::Read { path, error } => {
                write!(f, "cannot read the launch file {}: {error}", path.display())?
            }
            LaunchFileError::Setting(error) => {
                let origin = error
                    .location
                    .as_ref()
                    .map_or(&Origin::Defaults, |l| &l.origin);
                write!(f, "{} {error}", what(origin))?;
            }
            LaunchFileError::Write { origin, error } => {
                write!(f, "{} {origin}: {error:#}", what(origin))?;
            }
            LaunchFileError::RunDir { path, error } => write!(
                f,
                "cannot write the run directory: {}: {}",
                path.display(),
                tes_runtime::cause::explain(error)
            )?,
            LaunchFileError::Busy(LockError::Held { path, pid, .. }) => write!(
                f,
                "the run directory {} is in use by another tes launch{}; stop that one first, \
                 or give this launch a data directory of its own (TES_DATA_DIR) or another \
                 [launch] run_dir",
                path.parent().unwrap_or(path).display(),
                pid.map(|p| format!(" (pid {p})")).unwrap_or_default()
            )?,
            LaunchFileError::Busy(LockError::Io { path, error, .. }) => write!(
                f,
                "cannot lock the run directory: {}: {}",
                path.display(),
                tes_runtime::cause::explain(error)
            )?,
        }
        f.write_str("; nothing was started")
    }
}

impl std::error::Error for LaunchFileError {}

/// Reads and parses a launch file; a problem is reported with the file, the line and the key.
pub(crate) fn read_launch_file(path: &Path) -> Result<LaunchFile, LaunchFileError> {
    let text = std::fs::read_to_string(path).map_err(|error| LaunchFileError::Read {
        path: path.to_owned(),
        error,
    })?;
    LaunchFile::from_toml(&text, Origin::File(path.to_owned())).map_err(LaunchFileError::Setting)
}

/// A launch ready to start: its children's settings written, its run directory owned.
#[derive(Debug)]
pub(crate) struct Prepared {
    /// The children, in start order.
    pub(crate) specs: Vec<ChildSpec>,
    /// This launch's run folder: the children's settings, output and logs, the resolved launch
    /// file, the episode table, the trajectories and, at the end, the pictures.
    pub(crate) run_dir: PathBuf,
    /// Old run folders removed to keep `[launch] keep_runs`.
    pub(crate) pruned: Vec<PathBuf>,
    /// The group's service prefix (its own unless the file sets one).
    pub(crate) service_prefix: String,
    /// The run directory's lock, held for the group's life.
    pub(crate) _lock: Lock,
}

/// A service prefix no other launch has: this process's id and the clock's low bits.
pub(crate) fn unique_service_prefix() -> String {
    let ns = tes_runtime::clock::monotonic_ns();
    format!("tes-{}-{:08x}/", std::process::id(), ns & 0xffff_ffff)
}

/// The resolved launch file a run folder keeps.
pub(crate) const RESOLVED_LAUNCH_FILE: &str = "launch.toml";

/// Checks every child's settings, takes the run directory for this launch and writes their
/// settings there. A launch without a service prefix gets one of its own.
pub(crate) fn prepare(file: &LaunchFile) -> Result<Prepared, LaunchFileError> {
    let as_given = file;
    let mut file = file.clone();
    if file.launch.service_prefix.is_empty() {
        file.launch.service_prefix = unique_service_prefix();
    }
    let mut children = file.children().map_err(LaunchFileError::Setting)?;
    let unwritable = |error: anyhow::Error| LaunchFileError::Write {
        origin: file.origin.clone(),
        error,
    };
    let run_dir_error = |path: &Path| {
        let path = path.to_owned();
        move |error| LaunchFileError::RunDir { path, error }
    };
    let (run_dir, pruned, lock) = match &file.launch.run_dir {
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(run_dir_error(dir))?;
            let lock = Lock::acquire(&dir.join("launch.lock"), "run directory")
                .map_err(LaunchFileError::Busy)?;
            (dir.clone(), Vec::new(), lock)
        }
        None => {
            let runs = file
                .launch
                .runs_dir
                .clone()
                .unwrap_or_else(|| default_data_dir().join(RUNS));
            std::fs::create_dir_all(&runs).map_err(run_dir_error(&runs))?;
            // One launch per data directory: the library and the runs are its.
            let lock = Lock::acquire(&runs.join("launch.lock"), "run directory")
                .map_err(LaunchFileError::Busy)?;
            let dir = run_folder::create(&runs, std::time::SystemTime::now())
                .map_err(run_dir_error(&runs))?;
            let pruned = run_folder::prune(&runs, file.launch.keep_runs, &dir);
            run_folder::point_latest_at(&runs, &dir);
            (dir, pruned, lock)
        }
    };
    // As given: a launch without a service prefix of its own gets a new one when rerun.
    let resolved = reference::render_resolved(as_given)
        .context("cannot write the resolved launch file")
        .map_err(unwritable)?;
    let resolved_path = run_dir.join(RESOLVED_LAUNCH_FILE);
    std::fs::write(&resolved_path, resolved).map_err(run_dir_error(&resolved_path))?;
    children.write_into(&run_dir);
    let texts = [
        ("bridge", toml::to_string(&children.bridge)),
        ("controller", toml::to_string(&children.controller)),
        ("perception-sim", toml::to_string(&children.perception)),
    ];
    let mut specs = Vec::new();
    let plays =
        |role: &str| file.launch.roles.is_empty() || file.launch.roles.iter().any(|r| r == role);
    for (role, text) in texts.into_iter().filter(|(role, _)| plays(role)) {
        let text = text
            .with_context(|| format!("cannot write the {role}'s settings"))
            .map_err(unwritable)?;
        let path = run_dir.join(format!("{role}.toml"));
        std::fs::write(&path, text).map_err(|error| LaunchFileError::RunDir {
            path: path.clone(),
            error,
        })?;
        let role = ROLES
            .into_iter()
            .find(|r| *r == role)
            .unwrap_or("controller");
        specs.push(ChildSpec { role, config: path });
    }
    Ok(Prepared {
        specs,
        run_dir,
        pruned,
        service_prefix: file.launch.service_prefix.clone(),
        _lock: lock,
    })
}
