//! The iceoryx2 plumbing every TES process shares: its node, its error, the settings of every
//! publish–subscribe service, and the clean-up of resources dead processes left behind.

use std::fmt;

use iceoryx2::prelude::*;
use iceoryx2::service::Service;

use tes_topics::{Role, ServiceNames};

/// A process's iceoryx2 node ([`group_node`]): its ports are opened on it, and it outlives
/// them.
pub type ProcessNode = Node<ipc::Service>;

/// The listening end of an event service.
pub(crate) type Listener<S = ipc::Service> = iceoryx2::port::listener::Listener<S>;

/// Samples a subscriber can hold before the oldest is dropped. The control loop has one sample
/// in flight; the slack absorbs a receiver descheduled on a loaded machine, and receivers
/// detect any loss by the payloads' sequence numbers.
pub const BUFFER: usize = 16;

/// An iceoryx2 failure; `context` says which step.
#[derive(Debug, thiserror::Error)]
#[error("iceoryx2: cannot {context}: {message}")]
pub struct IpcError {
    /// The step that failed.
    pub context: &'static str,
    /// iceoryx2's error.
    pub message: String,
}

/// Maps an iceoryx2 error to an [`IpcError`] naming the step.
pub fn ipc_err<E: fmt::Debug>(context: &'static str) -> impl FnOnce(E) -> IpcError {
    move |e| {
        let mut message = format!("{e:?}");
        if crate::cause::is_out_of_descriptors() {
            message
                .push_str(" — this process has too many open files: raise the limit (ulimit -n)");
        }
        IpcError { context, message }
    }
}

/// The environment variable that names a process's iceoryx2 domain: processes with different
/// domains share no iceoryx2 resource (their files start with `iox2_<domain>_`), so two
/// groups on one machine cannot reach each other through shared memory (the multi-host
/// tests run two "hosts" this way). Unset or empty: iceoryx2's default domain.
pub const DOMAIN_VAR: &str = "TES_IPC_DOMAIN";

/// The iceoryx2 config of this process: the defaults, in the domain [`DOMAIN_VAR`] names.
/// A domain name iceoryx2 cannot use as a file name prefix is ignored with a warning.
pub fn config() -> &'static Config {
    static CONFIG: std::sync::OnceLock<Config> = std::sync::OnceLock::new();
    CONFIG.get_or_init(|| match std::env::var(DOMAIN_VAR) {
        Ok(domain) if !domain.is_empty() => domain_config(&domain).unwrap_or_else(|| {
            eprintln!(
                "{DOMAIN_VAR}={domain:?} is not a domain name (ASCII letters, digits, '-'); \
                 using the default domain"
            );
            Config::default()
        }),
        _ => Config::default(),
    })
}

/// The iceoryx2 config of domain `domain`, if it is a domain name (ASCII letters, digits,
/// '-': nothing iceoryx2 or a file name would read otherwise).
fn domain_config(domain: &str) -> Option<Config> {
    let valid = !domain.is_empty()
        && domain
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-');
    let name = iceoryx2::prelude::FileName::new(domain_prefix(domain).as_bytes()).ok()?;
    valid.then(|| {
        let mut config = Config::default();
        config.global.prefix = name;
        config
    })
}

/// The file name prefix of domain `domain`'s iceoryx2 files.
fn domain_prefix(domain: &str) -> String {
    format!("iox2_{domain}_")
}

/// Where iceoryx2 keeps its files: shared memory, and its directory under the temporary one.
fn iceoryx2_dirs() -> [std::path::PathBuf; 2] {
    [
        std::path::PathBuf::from("/dev/shm"),
        std::env::temp_dir().join("iceoryx2"),
    ]
}

/// The domains (other than the default) that have files on this machine, from their names
/// (`iox2_<domain>_<hash>_…`; the default domain's are `iox2_<hash>_…`).
fn domains_on_machine() -> Vec<String> {
    let mut domains = Vec::new();
    for path in files_under(&iceoryx2_dirs()) {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
        let Some(rest) = name.as_deref().and_then(|n| n.strip_prefix("iox2_")) else {
            continue;
        };
        let Some((domain, _)) = rest.split_once('_') else {
            continue;
        };
        let is_hash = domain.len() == 40 && domain.bytes().all(|b| b.is_ascii_hexdigit());
        if !is_hash && domain_config(domain).is_some() && !domains.iter().any(|d| d == domain) {
            domains.push(domain.to_owned());
        }
    }
    domains
}

/// Every regular file under `dirs`, recursively (unreadable directories are skipped).
fn files_under(dirs: &[std::path::PathBuf]) -> Vec<std::path::PathBuf> {
    let mut files = Vec::new();
    let mut pending = dirs.to_vec();
    while let Some(dir) = pending.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries.filter_map(Result::ok) {
            match entry.file_type() {
                Ok(t) if t.is_dir() => pending.push(entry.path()),
                Ok(_) => files.push(entry.path()),
                Err(_) => {}
            }
        }
    }
    files
}

/// Removes everything iceoryx2 keeps of domain `domain` on this machine — its dead nodes'
/// resources, then its remaining files, the management segment iceoryx2 keeps per domain
/// included — unless a process still runs in it. Returns whether the domain was removed
/// (`false`: a node of it is alive, and nothing was touched). For the owner of a domain once
/// its processes have ended (the latency bench's, a test's), and for `tes status --clean`.
pub fn remove_domain(domain: &str) -> Result<bool, IpcError> {
    let Some(config) = domain_config(domain) else {
        return Err(IpcError {
            context: "remove a domain",
            message: format!("{domain:?} is not a domain name"),
        });
    };
    let mut alive = false;
    let mut failures = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        match state {
            NodeState::<ipc::Service>::Dead(view) => {
                if let Err(e) = view.try_remove_stale_resources() {
                    failures.push(format!("{e:?}"));
                }
            }
            NodeState::Alive(_) | NodeState::Inaccessible(_) | NodeState::Undefined(_) => {
                alive = true;
            }
        }
        CallbackProgression::Continue
    })
    .map_err(ipc_err("list a domain's nodes"))?;
    if alive {
        return Ok(false);
    }
    if let Some(first) = failures.first() {
        return Err(IpcError {
            context: "remove a dead node's stale resources",
            message: format!("{first} ({} failures)", failures.len()),
        });
    }
    let prefix = domain_prefix(domain);
    for path in files_under(&iceoryx2_dirs()) {
        let ours = path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with(&prefix));
        let removed = if ours {
            std::fs::remove_file(&path)
        } else {
            Ok(())
        };
        match removed {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(IpcError {
                    context: "remove a domain's file",
                    message: format!("{}: {e}", path.display()),
                });
            }
            _ => {}
        }
    }
    Ok(true)
}

/// How recently a domain's files may have changed for [`clean_stale_domains`] to leave it: a
/// process creates its domain's files a moment before its node appears in the registry.
const DOMAIN_SETTLE: std::time::Duration = std::time::Duration::from_secs(10);

/// [`remove_domain`] for every domain other than the default with files on this machine, no
/// live process, and no file changed in the last 10 s (a process just starting in it has no
/// node yet): what dead groups, benches and tests in domains of their own left. Returns how
/// many domains were removed.
pub fn clean_stale_domains() -> Result<usize, IpcError> {
    let mut removed = 0;
    for domain in domains_on_machine() {
        if !recently_changed(&domain) {
            removed += usize::from(remove_domain(&domain)?);
        }
    }
    Ok(removed)
}

/// Whether any of `domain`'s files changed within [`DOMAIN_SETTLE`] (or cannot be dated).
fn recently_changed(domain: &str) -> bool {
    let prefix = domain_prefix(domain);
    files_under(&iceoryx2_dirs()).iter().any(|path| {
        let ours = path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with(&prefix));
        ours && std::fs::metadata(path)
            .and_then(|m| m.modified())
            .map_or(true, |t| {
                t.elapsed().map_or(true, |age| age < DOMAIN_SETTLE)
            })
    })
}

/// Creates a process's iceoryx2 node with an explicit default config (no "no config file"
/// warning); `handle_signals` lets iceoryx2 turn SIGINT/SIGTERM into a termination request
/// (a launcher that handles signals itself passes `false`).
pub fn node(handle_signals: bool) -> Result<Node<ipc::Service>, IpcError> {
    node_of::<ipc::Service>(handle_signals)
}

/// [`node`] of iceoryx2's `ipc_threadsafe` service: its ports are `Send` and `Sync` (each
/// guarded by a mutex), for channels used from threads we do not own (Zenoh's callbacks).
/// It reaches the same services as [`node`]'s: the two differ only in the ports' locking.
pub fn shared_node(handle_signals: bool) -> Result<Node<ipc_threadsafe::Service>, IpcError> {
    node_of::<ipc_threadsafe::Service>(handle_signals)
}

fn node_of<S: Service>(handle_signals: bool) -> Result<Node<S>, IpcError> {
    let mode = if handle_signals {
        SignalHandlingMode::HandleTerminationRequests
    } else {
        SignalHandlingMode::Disabled
    };
    NodeBuilder::new()
        .config(config())
        .signal_handling_mode(mode)
        .create::<S>()
        .map_err(ipc_err("create the node"))
}

/// Creates a process's iceoryx2 node named `name` (otherwise as [`node`]), so that a list of
/// the machine's nodes says whose it is. A name iceoryx2 cannot take (longer than
/// [`NODE_NAME_MAX`] bytes, or not ASCII) is refused with an error naming it.
pub fn node_named(name: &str, handle_signals: bool) -> Result<Node<ipc::Service>, IpcError> {
    let node_name = NodeName::new(name).map_err(|e| IpcError {
        context: "use the node name",
        message: format!(
            "{name:?} is not a node name ({e:?}): at most {NODE_NAME_MAX} ASCII characters \
             (a group's node names are its service prefix and the process's role: shorten \
             the service prefix)"
        ),
    })?;
    let mode = if handle_signals {
        SignalHandlingMode::HandleTerminationRequests
    } else {
        SignalHandlingMode::Disabled
    };
    NodeBuilder::new()
        .name(&node_name)
        .config(config())
        .signal_handling_mode(mode)
        .create::<ipc::Service>()
        .map_err(ipc_err("create the node"))
}

/// The node of the process playing `role` in the group whose services are `names`: named
/// [`group_node_name`]`(prefix, role)` so that `tes status` finds the group and the role.
pub fn group_node(
    names: &ServiceNames,
    role: Role,
    handle_signals: bool,
) -> Result<Node<ipc::Service>, IpcError> {
    node_named(
        &group_node_name(prefix_of(names), Member::Process(role)),
        handle_signals,
    )
}

/// The longest node name iceoryx2 takes, in bytes (ASCII only).
pub const NODE_NAME_MAX: usize = iceoryx2::constants::MAX_NODE_NAME_LENGTH;

/// A member of a group, as its node's name says it: one of the three processes, or the
/// launcher.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Member {
    /// A process of the group, by its role.
    Process(Role),
    /// The group's launcher.
    Launcher,
}

impl Member {
    /// Every member, in the order the data flows, the launcher last.
    pub const ALL: [Member; 4] = [
        Member::Process(Role::Perception),
        Member::Process(Role::Controller),
        Member::Process(Role::Bridge),
        Member::Launcher,
    ];

    /// Its name in a node name: a process's [`Role::name`], or `launcher`.
    pub fn name(self) -> &'static str {
        match self {
            Member::Process(role) => role.name(),
            Member::Launcher => "launcher",
        }
    }

    /// The role of a process member; `None` for the launcher.
    pub fn role(self) -> Option<Role> {
        match self {
            Member::Process(role) => Some(role),
            Member::Launcher => None,
        }
    }
}

impl std::fmt::Display for Member {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // `pad`, so that a width (`{:<14}`) lines members up in tables.
        f.pad(self.name())
    }
}

/// What stands between a group's service prefix and the member in a node name: a group's
/// node names look like its service names (`tes-41-0badcafe/tes/controller` beside the
/// service `tes-41-0badcafe/tes/progress/controller`).
const MEMBER_MARK: &str = "tes/";

/// The node name of `member` of the group with service prefix `prefix`;
/// [`parse_group_node_name`] reads it back.
pub fn group_node_name(prefix: &str, member: Member) -> String {
    format!("{prefix}{MEMBER_MARK}{}", member.name())
}

/// The (service prefix, member) a node name made by [`group_node_name`] says; `None` for a
/// name that is not a TES group member's (an unnamed node, another program's node).
pub fn parse_group_node_name(name: &str) -> Option<(&str, Member)> {
    Member::ALL.into_iter().find_map(|member| {
        let prefix = name
            .strip_suffix(member.name())?
            .strip_suffix(MEMBER_MARK)?;
        Some((prefix, member))
    })
}

/// The service prefix of the group whose services are `names` (empty for names not made by
/// [`ServiceNames::with_prefix`]).
pub fn prefix_of(names: &ServiceNames) -> &str {
    let role = Role::Perception;
    let progress = names.progress_of(role);
    progress
        .strip_suffix(role.name())
        .and_then(|p| p.strip_suffix('/'))
        .and_then(|p| p.strip_suffix(tes_topics::service::PROGRESS))
        .unwrap_or("")
}

/// Whether a listed node's process is alive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeLiveness {
    /// Its process runs.
    Alive,
    /// Its process died without removing the node's resources: stale, for
    /// [`clean_stale_resources`].
    Dead,
    /// This process may not tell (another user's node).
    Inaccessible,
    /// The node's files are incomplete (being created or removed right now).
    Undefined,
}

/// One iceoryx2 node of this machine, as [`list_nodes`] sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeEntry {
    /// The node's name (empty for an unnamed node); `None` when its details cannot be read.
    pub name: Option<String>,
    /// Its process's id, when its details can be read.
    pub pid: Option<i32>,
    /// Whether its process is alive.
    pub liveness: NodeLiveness,
}

/// Every iceoryx2 node of this machine (of the default config), alive or dead.
pub fn list_nodes() -> Result<Vec<NodeEntry>, IpcError> {
    use iceoryx2::node::NodeView;
    let mut nodes = Vec::new();
    Node::<ipc::Service>::list(config(), |state| {
        let (details, liveness) = match &state {
            NodeState::Alive(view) => (view.details().as_ref(), NodeLiveness::Alive),
            NodeState::Dead(view) => (view.details().as_ref(), NodeLiveness::Dead),
            NodeState::Inaccessible(_) => (None, NodeLiveness::Inaccessible),
            NodeState::Undefined(_) => (None, NodeLiveness::Undefined),
        };
        nodes.push(NodeEntry {
            name: details.map(|d| d.name().as_str().to_owned()),
            pid: details.map(|d| d.process_id().value()),
            liveness,
        });
        CallbackProgression::Continue
    })
    .map_err(ipc_err("list the nodes"))?;
    Ok(nodes)
}

/// What a clean-up removed, and what it could not remove (each named, with why).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Cleanup {
    /// How many dead nodes (or domains) were removed.
    pub removed: usize,
    /// What could not be removed: "node NAME (pid N): why", "domain NAME: why".
    pub not_removed: Vec<String>,
}

/// [`clean_stale_resources`], going on past a dead node it cannot clean: every other one is
/// cleaned, and each failure is named in [`Cleanup::not_removed`]. Fails only when the node
/// registry cannot be listed.
pub fn clean_every_stale_resource() -> Result<Cleanup, IpcError> {
    use iceoryx2::node::NodeView;
    let mut cleanup = Cleanup::default();
    Node::<ipc::Service>::list(config(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            let who = match view.details() {
                Some(d) => format!(
                    "node {:?} (pid {})",
                    d.name().as_str(),
                    d.process_id().value()
                ),
                None => "a node whose details cannot be read".to_owned(),
            };
            match view.try_remove_stale_resources() {
                Ok(()) => cleanup.removed += 1,
                Err(e) => cleanup.not_removed.push(format!("{who}: {e:?}")),
            }
        }
        CallbackProgression::Continue
    })
    .map_err(ipc_err("list the nodes"))?;
    Ok(cleanup)
}

/// [`clean_stale_domains`], going on past a domain it cannot remove: every other one is
/// removed, and each failure is named in [`Cleanup::not_removed`].
pub fn clean_every_stale_domain() -> Cleanup {
    let mut cleanup = Cleanup::default();
    for domain in domains_on_machine() {
        if recently_changed(&domain) {
            continue;
        }
        match remove_domain(&domain) {
            Ok(removed) => cleanup.removed += usize::from(removed),
            Err(e) => cleanup.not_removed.push(format!("domain {domain:?}: {e}")),
        }
    }
    cleanup
}

/// Removes the iceoryx2 resources (shared memory, event and service files) left behind by
/// nodes whose process died without cleaning up; returns how many dead nodes were cleaned.
pub fn clean_stale_resources() -> Result<usize, IpcError> {
    let mut cleaned = 0;
    let mut failures = Vec::new();
    Node::<ipc::Service>::list(config(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(()) => cleaned += 1,
                Err(e) => failures.push(format!("{e:?}")),
            }
        }
        CallbackProgression::Continue
    })
    .map_err(ipc_err("list the nodes"))?;
    if let Some(first) = failures.first() {
        return Err(IpcError {
            context: "remove a dead node's stale resources",
            message: format!("{first} ({} failures)", failures.len()),
        });
    }
    Ok(cleaned)
}

/// Opens (or creates) a publish–subscribe service with the settings every TES process uses
/// (subscriber buffer [`BUFFER`], `history` samples for late subscribers). Every opener of a
/// service must use these, since iceoryx2 refuses to open a service with other settings.
pub fn pubsub<T: ZeroCopySend + Copy + fmt::Debug + 'static, S: Service>(
    node: &Node<S>,
    name: &str,
    history: usize,
) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, T, ()>, IpcError> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .history_size(history)
        .subscriber_max_buffer_size(max_buffer_of(name, history))
        .open_or_create()
        .map_err(ipc_err("open a publish-subscribe service"))
}

/// Samples a recorder's subscriber to a small payload's service holds
/// ([`RECORDED_BUFFER_SERVICES`]), so that a recorder that polls now and then misses nothing:
/// at the fastest pace the bridge publishes about 17 motor states per action, 8 000 a second,
/// so this rides out half a second in which a busy machine gives the (`SCHED_IDLE`) recorder
/// no time (and the observations and world poses, one an action each, far longer).
pub const RECORDER_BUFFER: usize = 4096;

/// The services (by the end of their names) whose subscribers may hold up to
/// [`RECORDER_BUFFER`] samples: small payloads published every action. Subscribers of the
/// group itself still ask for [`BUFFER`].
pub const RECORDED_BUFFER_SERVICES: [&str; 3] = [
    tes_topics::service::OBSERVATION,
    tes_topics::service::MOTOR_STATE,
    tes_topics::service::WORLD_POSE,
];

/// The most samples a subscriber of the service `name` may hold.
fn max_buffer_of(name: &str, history: usize) -> usize {
    if RECORDED_BUFFER_SERVICES.iter().any(|s| name.ends_with(s)) {
        history.max(RECORDER_BUFFER)
    } else {
        history.max(BUFFER)
    }
}

/// The names of the iceoryx2 services that exist now and start with `prefix` (to check that a
/// stopped group left nothing behind).
pub fn services_with_prefix(prefix: &str) -> Result<Vec<String>, IpcError> {
    let mut names = Vec::new();
    ipc::Service::list(config(), |service| {
        let name = service.static_details.name().to_string();
        if name.starts_with(prefix) {
            names.push(name);
        }
        CallbackProgression::Continue
    })
    .map_err(ipc_err("list the services"))?;
    Ok(names)
}

/// A notifier on the event service `event` (opened or created).
pub(crate) fn notifier<S: Service>(
    node: &Node<S>,
    event: &str,
) -> Result<iceoryx2::port::notifier::Notifier<S>, IpcError> {
    node.service_builder(&service_name(event)?)
        .event()
        .open_or_create()
        .map_err(ipc_err("open an event service"))?
        .notifier_builder()
        .create()
        .map_err(ipc_err("create a notifier"))
}

/// A listener on the event service `event` (opened or created).
pub(crate) fn listener<S: Service>(node: &Node<S>, event: &str) -> Result<Listener<S>, IpcError> {
    node.service_builder(&service_name(event)?)
        .event()
        .open_or_create()
        .map_err(ipc_err("open an event service"))?
        .listener_builder()
        .create()
        .map_err(ipc_err("create a listener"))
}

pub(crate) fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).map_err(ipc_err("use the service name"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn files_of(domain: &str) -> Vec<std::path::PathBuf> {
        let prefix = domain_prefix(domain);
        files_under(&iceoryx2_dirs())
            .into_iter()
            .filter(|p| {
                p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with(&prefix))
            })
            .collect()
    }

    /// A domain keeps its files while a node of it lives; once none does, `remove_domain`
    /// leaves nothing of it, not even the segment iceoryx2 keeps per domain.
    #[test]
    fn a_domain_is_removed_whole_once_its_processes_end() {
        let domain = format!("tesunit{}", std::process::id());
        let config = domain_config(&domain).expect("a domain name");
        let node = NodeBuilder::new()
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .expect("a node in the domain");
        let service = node
            .service_builder(&"tes/unit".try_into().expect("a service name"))
            .publish_subscribe::<u64>()
            .open_or_create()
            .expect("a service");
        assert!(!files_of(&domain).is_empty());
        assert!(domains_on_machine().contains(&domain));
        assert!(
            !remove_domain(&domain).expect("listed"),
            "a live node keeps it"
        );
        assert!(!files_of(&domain).is_empty());
        drop(service);
        drop(node);
        assert!(remove_domain(&domain).expect("removed"));
        assert_eq!(files_of(&domain), Vec::<std::path::PathBuf>::new());
        assert!(!domains_on_machine().contains(&domain));
    }

    #[test]
    fn only_domain_names_are_domains() {
        assert!(domain_config("bench42").is_some());
        assert!(domain_config("t1-2host").is_some());
        for bad in ["", "a_b", "../x", "a b"] {
            assert!(domain_config(bad).is_none(), "{bad:?}");
            assert!(remove_domain(bad).is_err(), "{bad:?}");
        }
    }

    /// Every member's node name reads back as its group's prefix and the member, whatever
    /// the prefix holds (nothing, slashes, even a member's name).
    #[test]
    fn a_group_node_name_reads_back_as_its_prefix_and_member() {
        for prefix in [
            "",
            "g/",
            "tes-41-0badcafe/",
            "tes-test/7/x/",
            "a/tes/controller/",
        ] {
            for member in Member::ALL {
                let name = group_node_name(prefix, member);
                assert_eq!(
                    parse_group_node_name(&name),
                    Some((prefix, member)),
                    "{name}"
                );
            }
        }
        assert_eq!(
            group_node_name("tes-41-0badcafe/", Member::Process(Role::Controller)),
            "tes-41-0badcafe/tes/controller"
        );
    }

    /// An unnamed node, another program's node, or a name that only looks like a member's is
    /// no group member.
    #[test]
    fn other_node_names_are_no_group_member() {
        for name in [
            "",
            "controller",
            "x/controller",
            "x/tes/",
            "x/tes/planner",
            "x/tes/controllers",
            "x/tes-controller",
            "x/tes/Controller",
        ] {
            assert_eq!(parse_group_node_name(name), None, "{name}");
        }
    }

    #[test]
    fn the_process_members_are_the_roles() {
        let roles = Role::ALL.map(Member::Process);
        assert_eq!(Member::ALL[..3], roles);
        assert_eq!(Member::ALL.map(Member::role)[..3], Role::ALL.map(Some));
    }

    #[test]
    fn the_prefix_of_a_groups_names_is_the_one_they_were_made_with() {
        for prefix in ["", "g/", "tes-41-0badcafe/", "run-42/"] {
            assert_eq!(prefix_of(&ServiceNames::with_prefix(prefix)), prefix);
        }
    }

    /// A name iceoryx2 cannot take is refused with a typed error naming it, before any node
    /// exists.
    #[test]
    fn a_node_name_iceoryx2_cannot_take_is_refused() {
        for name in [
            "x".repeat(NODE_NAME_MAX + 1),
            "prefix-é/tes/bridge".to_owned(),
        ] {
            let err = node_named(&name, false).expect_err("refused");
            assert_eq!(err.context, "use the node name");
            assert!(err.message.contains(&format!("{name:?}")), "{err}");
        }
        assert!(node_named(&"x".repeat(NODE_NAME_MAX), false).is_ok());
    }

    /// A named node is listed alive with its name and this process's id.
    #[test]
    fn a_named_node_is_listed_alive_with_its_name_and_pid() {
        let name = group_node_name(
            &format!("tes-unit/{}/", std::process::id()),
            Member::Process(Role::Controller),
        );
        let node = node_named(&name, false).expect("node");
        let listed = list_nodes().expect("list");
        let ours: Vec<&NodeEntry> = listed
            .iter()
            .filter(|n| n.name.as_deref() == Some(name.as_str()))
            .collect();
        assert_eq!(
            ours,
            [&NodeEntry {
                name: Some(name.clone()),
                pid: Some(std::process::id() as i32),
                liveness: NodeLiveness::Alive,
            }]
        );
        drop(node);
        let listed = list_nodes().expect("list");
        assert!(
            !listed
                .iter()
                .any(|n| n.name.as_deref() == Some(name.as_str()))
        );
    }
}
