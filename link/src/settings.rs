//! The `[launch.link]` table: how a launch with roles reaches its peers.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use tes_runtime::settings::SettingError;
use tes_topics::Role;

use crate::{LinkError, Topic, keys};

/// The longest group name, in bytes (as a launch's `service_prefix`).
pub const GROUP_NAME_MAX: usize = tes_runtime::settings::SERVICE_PREFIX_MAX;

/// The process whose settings the table belongs to, for [`SettingError`].
const PROCESS: &str = "launch";

/// Zenoh's session mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Every launch a peer: they connect to each other directly.
    #[default]
    Peer,
    /// This launch reaches the others through a Zenoh router it connects to.
    Client,
}

/// The `[launch.link]` table: how a launch with roles reaches its peers. Each field's doc is
/// its key's entry in the launch file's reference (`tes launch --print-config`): what it does,
/// then its unit or values on a `Values:` line; the defaults are this struct's `Default`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LinkSection {
    /// The group's name on Zenoh, the first part of every key: the launches of one group give
    /// the same, two groups on one network different ones.
    ///
    /// Values: text: ASCII letters, digits, `-`, `_`, `.`, parts separated by `/`; at most
    /// [`GROUP_NAME_MAX`] bytes.
    pub group: String,
    /// `peer`: the launches connect to each other directly; `client`: through a Zenoh router
    /// that `connect` names.
    ///
    /// Values: `peer` | `client`.
    pub mode: Mode,
    /// Where this launch accepts its peers' connections. Empty, with `connect` empty too and
    /// no TLS keys (the default), the launches of one host meet on a Unix socket in a
    /// directory only this user can enter (`socket_dir`): the first to start listens, the
    /// others connect. A host that other machines connect to listens with QUIC (TLS 1.3,
    /// both sides authenticated) on an address of its own, e.g. `["quic/0.0.0.0:7447"]`
    /// (`tes link keygen` prints the lines to use).
    ///
    /// Values: list of endpoints: `quic/ADDRESS:PORT` (UDP), or, only with `insecure =
    /// true`, plain `tcp/ADDRESS:PORT` (every local user reaches loopback, and anyone on the
    /// network any other address).
    pub listen: Vec<String>,
    /// The peers (or the router) this launch connects to.
    ///
    /// Values: list of endpoints, as `listen`.
    pub connect: Vec<String>,
    /// Where the launches of one host meet when `listen` and `connect` are empty and no TLS
    /// keys are given: a directory of this user's, made if missing and refused unless only
    /// its owner may enter it; the socket in it is named after the group. Unset:
    /// `$XDG_RUNTIME_DIR/tes`, else `/tmp/tes-UID`.
    ///
    /// Values: path, or unset.
    ///
    /// Example: `"/run/user/1000/tes"`.
    pub socket_dir: Option<PathBuf>,
    /// The group's certificate authority (PEM): a peer is accepted only with a certificate
    /// it signed. Set with `tls_cert` and `tls_key` for `quic/` endpoints.
    ///
    /// Values: path, or unset.
    ///
    /// Example: `"keys/ca.pem"`.
    pub tls_ca: Option<PathBuf>,
    /// This host's certificate (PEM), signed by `tls_ca`; its common name says which roles
    /// the host plays, and so what it may publish.
    ///
    /// Values: path, or unset.
    ///
    /// Example: `"keys/robot.pem"`.
    pub tls_cert: Option<PathBuf>,
    /// This host's private key (PEM), readable only by its owner.
    ///
    /// Values: path, or unset.
    ///
    /// Example: `"keys/robot.key"`.
    pub tls_key: Option<PathBuf>,
    /// How long a peer may go unheard before its link is dropped (and its launch taken as
    /// gone: the group stops). Each side sends four keep-alives per lease. Over QUIC (UDP) a
    /// killed host or a pulled cable sends nothing, so this is how soon it is noticed.
    ///
    /// Values: ms, at least [`MIN_LEASE_MS`].
    pub lease_ms: u64,
    /// Allow plain TCP (loopback included): anyone who reaches the port — every local user
    /// on loopback — can then join the group, read every observation and drive the robot.
    /// Said at every start.
    ///
    /// Values: `true` | `false`.
    pub insecure: bool,
    /// Find peers on the local network by UDP multicast (224.0.0.224:7446). Unset: on when
    /// the link has TLS keys and `connect` is empty, otherwise off (without keys, only with
    /// `insecure = true`: a launch would connect to whoever answers).
    ///
    /// Values: `true` | `false`.
    ///
    /// Example: `false`.
    pub multicast_scouting: Option<bool>,
    /// How long a launch waits for the launches of the other roles before it gives up
    /// (non-zero exit; it names the roles it waited for). Nothing starts before they are all
    /// there.
    ///
    /// Values: ms, at least [`MIN_PEER_TIMEOUT_MS`].
    pub peer_timeout_ms: u64,
    /// Stamp observations and commands that arrive from a peer with this host's clock,
    /// keeping the differences between their stamps (hosts' monotonic clocks differ);
    /// `false` keeps the sender's stamps, for launches on one machine (tests, `tes bench
    /// latency --via zenoh`).
    ///
    /// Values: `true` | `false`.
    pub restamp: bool,
}

/// The default `lease_ms`: a lost host is noticed within 4 s (Zenoh's own default is 10 s;
/// the bridge's watchdog has braked the robot long before either).
pub const DEFAULT_LEASE_MS: u64 = 4_000;

/// The least `lease_ms`.
pub const MIN_LEASE_MS: u64 = 1_000;

/// The least `peer_timeout_ms`.
pub const MIN_PEER_TIMEOUT_MS: u64 = 100;

impl Default for LinkSection {
    fn default() -> Self {
        Self {
            group: "tes".into(),
            mode: Mode::Peer,
            listen: Vec::new(),
            connect: Vec::new(),
            socket_dir: None,
            multicast_scouting: None,
            peer_timeout_ms: 30_000,
            restamp: true,
            tls_ca: None,
            tls_cert: None,
            tls_key: None,
            lease_ms: DEFAULT_LEASE_MS,
            insecure: false,
        }
    }
}

/// Whether `name` is a group name: at most [`GROUP_NAME_MAX`] bytes of ASCII letters,
/// digits, `-`, `_`, `.`, in non-empty parts separated by `/`.
fn is_group_name(name: &str) -> bool {
    let part_ok = |c: &str| {
        !c.is_empty()
            && c.bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_' || b == b'.')
    };
    name.len() <= GROUP_NAME_MAX && name.split('/').all(part_ok)
}

/// How a launch's link is protected ([`LinkSection::security`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Security {
    /// The launches of this host only, on a Unix socket in a directory only this user may
    /// enter.
    Private {
        /// The socket.
        socket: PathBuf,
    },
    /// Mutual TLS against the group's authority, with access control by role.
    Tls {
        /// This host's certificate's common name (the roles it may publish for).
        common_name: String,
    },
    /// Plain TCP or a Unix socket others may reach (`insecure = true`).
    Insecure {
        /// Those endpoints.
        exposed: Vec<String>,
    },
}

/// How an endpoint carries the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Carrier {
    /// Plain TCP.
    Tcp,
    /// QUIC: TLS 1.3 with both sides' certificates checked, over UDP.
    Quic,
    /// Zenoh's TLS-over-TCP link, refused (see [`TLS_OVER_TCP_REFUSED`]).
    TlsOverTcp,
    /// A Unix stream socket: this host only, whoever may enter its directory.
    Unix,
}

/// Why `tls/` endpoints are refused.
const TLS_OVER_TCP_REFUSED: &str = "Zenoh 1.10's TLS-over-TCP link reads and writes one TLS \
     stream from two tasks at once, which rustls does not support: with traffic both ways it \
     drops the link within seconds (the launches then stop, each saying the other left) and \
     can corrupt memory. Use quic/ endpoints, which carry TLS 1.3 with the same keys";

/// The scheme of a Unix socket endpoint.
pub(crate) const UNIX_SCHEME: &str = "unixsock-stream";

/// The longest path of a Unix socket, in bytes (`sun_path` less its final NUL).
const SOCKET_PATH_MAX: usize = 107;

/// The carrier of a Zenoh endpoint, if it is one the link takes.
fn carrier(endpoint: &str) -> Option<Carrier> {
    endpoint.parse::<zenoh::config::EndPoint>().ok()?;
    let (scheme, _) = endpoint.split_once('/')?;
    match scheme {
        "tcp" => Some(Carrier::Tcp),
        "quic" => Some(Carrier::Quic),
        "tls" => Some(Carrier::TlsOverTcp),
        UNIX_SCHEME => Some(Carrier::Unix),
        _ => None,
    }
}

/// An endpoint's address: what follows the scheme, without Zenoh's `?…` and `#…` parts.
fn address(endpoint: &str) -> &str {
    endpoint
        .split_once('/')
        .map_or(endpoint, |(_, rest)| rest)
        .split(['?', '#'])
        .next()
        .unwrap_or("")
}

/// Whether an endpoint is one others than this user could reach without the group's keys:
/// plain TCP anywhere (every local user reaches loopback), a Unix socket in a directory
/// others may enter.
fn exposed_without_keys(endpoint: &str) -> bool {
    match carrier(endpoint) {
        Some(Carrier::Tcp) => true,
        Some(Carrier::Unix) => std::path::Path::new(address(endpoint))
            .parent()
            .is_none_or(|dir| private_dir(dir).is_err()),
        _ => false,
    }
}

/// Whether an endpoint's address is loopback (`127.0.0.0/8`, `::1`, `localhost`).
pub(crate) fn is_loopback(endpoint: &str) -> bool {
    let address = address(endpoint);
    if let Ok(socket) = address.parse::<std::net::SocketAddr>() {
        return socket.ip().is_loopback();
    }
    address
        .rsplit_once(':')
        .is_some_and(|(host, _)| host.eq_ignore_ascii_case("localhost"))
}

/// Checks that `dir` is a directory (not a link to one) of this user's that no one else
/// may enter; the reason when it is not.
pub(crate) fn private_dir(dir: &std::path::Path) -> Result<(), String> {
    use std::os::unix::fs::MetadataExt;
    let meta = std::fs::symlink_metadata(dir)
        .map_err(|e| format!("cannot look at {}: {e}", dir.display()))?;
    let me = nix::unistd::geteuid().as_raw();
    if !meta.is_dir() {
        Err(format!("{} is not a directory", dir.display()))
    } else if meta.uid() != me {
        Err(format!(
            "{} belongs to user {}, not to this one ({me})",
            dir.display(),
            meta.uid()
        ))
    } else if meta.mode() & 0o077 != 0 {
        Err(format!(
            "{} may be entered by other users (mode {:o}): `chmod 700` it",
            dir.display(),
            meta.mode() & 0o777
        ))
    } else {
        Ok(())
    }
}

/// The directory the launches of this host meet in by default: `$XDG_RUNTIME_DIR/tes`
/// (the user's own runtime directory), else `/tmp/tes-UID`.
fn default_socket_dir() -> PathBuf {
    match std::env::var_os("XDG_RUNTIME_DIR") {
        Some(runtime) if !runtime.is_empty() => PathBuf::from(runtime).join("tes"),
        _ => std::env::temp_dir().join(format!("tes-{}", nix::unistd::geteuid())),
    }
}

impl LinkSection {
    /// Checks the table: a usable group name, QUIC or TCP endpoints, QUIC wherever another
    /// host could connect (unless `insecure`), the three TLS files together and readable, a
    /// way to reach a peer, a peer timeout of at least 100 ms. The error names the key within
    /// `[launch]` (`link.group`, `link.listen`, `link.connect`, `link.tls_ca`, …).
    pub fn check(&self) -> Result<(), SettingError> {
        let bad = |key: &str, reason: String| Err(SettingError::new(PROCESS, key, reason));
        if !is_group_name(&self.group) {
            return bad(
                "link.group",
                format!(
                    "{:?} is not a group name: at most {GROUP_NAME_MAX} bytes of ASCII letters, \
                     digits, '-', '_', '.', in parts separated by '/'",
                    self.group
                ),
            );
        }
        self.check_tls_files()?;
        for (key, endpoints) in [
            ("link.listen", &self.listen),
            ("link.connect", &self.connect),
        ] {
            for endpoint in endpoints {
                self.check_endpoint(key, endpoint)?;
            }
        }
        if self.has_tls()
            && self.listen.is_empty()
            && self.connect.is_empty()
            && self.multicast_scouting == Some(false)
        {
            return bad(
                "link.connect",
                "with nothing to listen on, nothing to connect to and no scouting, no peer can \
                 be reached"
                    .into(),
            );
        }
        if self.multicast_scouting == Some(true) && !self.has_tls() && !self.insecure {
            return bad(
                "link.multicast_scouting",
                "without the group's TLS keys, scouting would connect this launch to whoever \
                 answers on the network: give the keys (`tes link keygen DIR`), or set \
                 link.insecure = true to take that risk"
                    .into(),
            );
        }
        if let Some(dir) = &self.socket_dir
            && self.is_private()
        {
            self.socket_path_in(dir)
                .map_err(|reason| SettingError::new(PROCESS, "link.socket_dir", reason))?;
        }
        if self.lease_ms < MIN_LEASE_MS {
            return bad(
                "link.lease_ms",
                format!("must be at least {MIN_LEASE_MS}, got {}", self.lease_ms),
            );
        }
        if self.peer_timeout_ms < MIN_PEER_TIMEOUT_MS {
            return bad(
                "link.peer_timeout_ms",
                format!(
                    "must be at least {MIN_PEER_TIMEOUT_MS}, got {}",
                    self.peer_timeout_ms
                ),
            );
        }
        Ok(())
    }

    /// One endpoint of `key`: a carrier the link takes, QUIC only with the keys, plain TCP
    /// or a Unix socket others may reach only with `insecure`.
    fn check_endpoint(&self, key: &str, endpoint: &str) -> Result<(), SettingError> {
        let refused = match carrier(endpoint) {
            None => format!(
                "{endpoint:?} is not a QUIC, TCP or Unix socket endpoint such as \
                 \"quic/192.168.1.20:7447\""
            ),
            Some(Carrier::TlsOverTcp) => format!("{endpoint:?}: {TLS_OVER_TCP_REFUSED}"),
            Some(Carrier::Tcp) if !self.insecure => {
                let who = if is_loopback(endpoint) {
                    "every user of this host reaches loopback"
                } else {
                    "it is reachable from other hosts"
                };
                format!(
                    "{endpoint:?} is plain TCP, with no authentication: {who}, and anyone who \
                     reaches it could join the group, read its observations and drive the \
                     robot. On one host leave link.listen and link.connect empty (the \
                     launches meet on a Unix socket only this user can reach); across hosts \
                     use QUIC with the group's keys: `tes link keygen DIR` makes them and \
                     prints the `quic/` endpoints and the link.tls_ca, link.tls_cert and \
                     link.tls_key lines for each host (or set link.insecure = true to take \
                     that risk)"
                )
            }
            Some(Carrier::Unix) if !self.insecure && exposed_without_keys(endpoint) => format!(
                "{endpoint:?} is a Unix socket in a directory other users may enter or that \
                 is not this user's: put it in a directory of mode 700, or leave link.listen \
                 and link.connect empty for the default one (or set link.insecure = true)"
            ),
            Some(Carrier::Quic) if !self.has_tls() => format!(
                "{endpoint:?} is a QUIC endpoint, but link.tls_ca, link.tls_cert and \
                 link.tls_key are not all set (`tes link keygen DIR` makes them)"
            ),
            Some(_) => return Ok(()),
        };
        Err(SettingError::new(PROCESS, key, refused))
    }

    /// Whether the link is the default one of this host: no endpoints, no keys, so the
    /// launches meet on [`private_socket`](Self::private_socket).
    pub fn is_private(&self) -> bool {
        self.listen.is_empty() && self.connect.is_empty() && !self.has_tls()
    }

    /// The Unix socket the launches of this host meet on when the link
    /// [is private](Self::is_private): `socket_dir` (or its default) and the group's name.
    pub fn private_socket(&self) -> Result<PathBuf, String> {
        let dir = self.socket_dir.clone().unwrap_or_else(default_socket_dir);
        self.socket_path_in(&dir)
    }

    /// `DIR/link-GROUP.sock`, each `/` of the group a `~` (no group name has one), if short
    /// enough for a Unix socket.
    fn socket_path_in(&self, dir: &std::path::Path) -> Result<PathBuf, String> {
        let path = dir.join(format!("link-{}.sock", self.group.replace('/', "~")));
        let length = path.as_os_str().len();
        if length > SOCKET_PATH_MAX {
            return Err(format!(
                "the link's socket {} would be {length} bytes, more than a Unix socket's \
                 {SOCKET_PATH_MAX}: set link.socket_dir to a shorter directory, or give the \
                 group a shorter name",
                path.display()
            ));
        }
        Ok(path)
    }

    /// Makes the directory of the [private socket](Self::private_socket) if missing (mode
    /// 700) and checks that only this user may enter it; the socket's endpoint.
    pub(crate) fn prepare_private_socket(&self) -> Result<String, String> {
        use std::os::unix::fs::DirBuilderExt;
        let socket = self.private_socket()?;
        let dir = socket.parent().unwrap_or(std::path::Path::new("/"));
        if let Err(e) = std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(dir)
        {
            return Err(format!("cannot make {}: {e}", dir.display()));
        }
        private_dir(dir).map_err(|reason| {
            format!(
                "the link's socket directory is not private: {reason} (set [launch.link] \
                 socket_dir to a directory only this user may enter)"
            )
        })?;
        Ok(format!("{UNIX_SCHEME}/{}", socket.display()))
    }

    /// [`check`](Self::check), and for a launch playing `roles` with TLS, that this host's
    /// certificate names exactly those roles (a peer takes from it only what they write) and
    /// is valid now.
    pub fn check_for(&self, roles: &[Role]) -> Result<(), SettingError> {
        self.check()?;
        let Some(cert) = &self.tls_cert else {
            return Ok(());
        };
        let bad = |reason: String| Err(SettingError::new(PROCESS, "link.tls_cert", reason));
        let facts = match keys::read_certificate(cert) {
            Ok(facts) => facts,
            Err(reason) => return bad(reason),
        };
        let want = keys::common_name(roles);
        if facts.common_name != want {
            return bad(format!(
                "{} is the certificate of a host playing {:?}, but this launch plays {want:?}: \
                 give this host its own certificate and key",
                cert.display(),
                facts.common_name
            ));
        }
        if !facts.valid_now
            && let Some(why) = certificate_problem(cert, None)
        {
            return bad(why);
        }
        if let Some(ca) = &self.tls_ca
            && let Some(why) = certificate_problem(cert, Some(ca.as_path()))
        {
            return bad(why);
        }
        Ok(())
    }

    /// How this launch's link is protected, as said at its start.
    pub fn security(&self) -> Security {
        if let Some(cert) = &self.tls_cert {
            return Security::Tls {
                common_name: keys::read_certificate(cert)
                    .map(|facts| facts.common_name)
                    .unwrap_or_default(),
            };
        }
        if self.is_private() {
            return Security::Private {
                socket: self.private_socket().unwrap_or_default(),
            };
        }
        Security::Insecure {
            exposed: self
                .listen
                .iter()
                .chain(&self.connect)
                .filter(|e| exposed_without_keys(e))
                .cloned()
                .collect(),
        }
    }

    /// Links with the group's keys: `[authority, this host's certificate, its key]`.
    pub fn set_keys(&mut self, [ca, cert, key]: [PathBuf; 3]) {
        self.tls_ca = Some(ca);
        self.tls_cert = Some(cert);
        self.tls_key = Some(key);
    }

    /// Whether the three TLS files are given.
    pub fn has_tls(&self) -> bool {
        self.tls_ca.is_some() && self.tls_cert.is_some() && self.tls_key.is_some()
    }

    /// The TLS files: none or all three, as [`keys::check_tls_files`] wants them.
    fn check_tls_files(&self) -> Result<(), SettingError> {
        let files = [
            ("link.tls_ca", &self.tls_ca),
            ("link.tls_cert", &self.tls_cert),
            ("link.tls_key", &self.tls_key),
        ];
        if files.iter().all(|(_, f)| f.is_none()) {
            return Ok(());
        }
        let (Some(ca), Some(cert), Some(key)) = (&self.tls_ca, &self.tls_cert, &self.tls_key)
        else {
            let (key, _) = files.iter().find(|(_, f)| f.is_none()).unwrap_or(&files[0]);
            return Err(SettingError::new(
                PROCESS,
                *key,
                "link.tls_ca, link.tls_cert and link.tls_key go together: set all three \
                 (`tes link keygen DIR` prints them)"
                    .to_owned(),
            ));
        };
        keys::check_tls_files(ca, cert, key)
            .map_err(|e| SettingError::new(PROCESS, e.file.setting(), e.reason))
    }

    /// The Zenoh configuration: mode, endpoints, scouting; with TLS, mutual authentication
    /// against the group's authority and access control by the roles in the peers'
    /// certificates ([`access_control`]).
    pub fn zenoh_config(&self) -> Result<zenoh::Config, LinkError> {
        self.zenoh_config_for(&self.listen, &self.connect)
    }

    /// [`zenoh_config`](Self::zenoh_config) listening on `listen` and connecting to
    /// `connect` (the private socket's, or the table's own).
    pub(crate) fn zenoh_config_for(
        &self,
        listen: &[String],
        connect: &[String],
    ) -> Result<zenoh::Config, LinkError> {
        let mut config = zenoh::Config::default();
        let json = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
        let mode = match self.mode {
            Mode::Peer => "\"peer\"",
            Mode::Client => "\"client\"",
        };
        let multicast = self
            .multicast_scouting
            .unwrap_or(self.has_tls() && self.connect.is_empty());
        let mut entries = vec![
            ("mode", mode.to_owned()),
            ("listen/endpoints", json(listen)),
            ("connect/endpoints", json(connect)),
            ("scouting/multicast/enabled", multicast.to_string()),
            // Peers a peer learns of from another are connected to as well.
            ("scouting/gossip/enabled", "true".into()),
            ("transport/link/tx/lease", self.lease_ms.to_string()),
        ];
        if let (Some(ca), Some(cert), Some(key)) = (&self.tls_ca, &self.tls_cert, &self.tls_key) {
            let path = |p: &PathBuf| {
                serde_json::to_string(&p.display().to_string()).unwrap_or_else(|_| "\"\"".into())
            };
            entries.extend([
                ("transport/link/tls/root_ca_certificate", path(ca)),
                ("transport/link/tls/listen_certificate", path(cert)),
                ("transport/link/tls/listen_private_key", path(key)),
                ("transport/link/tls/connect_certificate", path(cert)),
                ("transport/link/tls/connect_private_key", path(key)),
                ("transport/link/tls/enable_mtls", "true".into()),
                // The group's own authority signs only its hosts: a certificate it signed is
                // a member wherever it connects from, so host names are not checked.
                ("transport/link/tls/verify_name_on_connect", "false".into()),
                ("access_control", access_control(&self.group).to_string()),
            ]);
        }
        for (key, value) in entries {
            if let Err(e) = config.insert_json5(key, &value) {
                return Err(LinkError::Config {
                    key,
                    value,
                    message: e.to_string(),
                });
            }
        }
        Ok(config)
    }
}

/// The first certificate of a PEM file, as DER.
fn certificate_der(path: &std::path::Path) -> Result<Vec<u8>, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let (_, pem) = x509_parser::pem::parse_x509_pem(&bytes)
        .map_err(|e| format!("{} is not a PEM certificate: {e}", path.display()))?;
    Ok(pem.contents)
}

/// What is wrong with the certificate `cert`, in the words a person fixes it by: not valid
/// yet (this host's clock, or the keys', is off), expired, or — given the group's authority
/// `ca` — issued by another authority. `None` when nothing is.
fn certificate_problem(cert: &std::path::Path, ca: Option<&std::path::Path>) -> Option<String> {
    use x509_parser::prelude::{FromDer, X509Certificate};
    let der = match certificate_der(cert) {
        Ok(der) => der,
        Err(why) => return Some(why),
    };
    let parsed = match X509Certificate::from_der(&der) {
        Ok((_, parsed)) => parsed,
        Err(e) => return Some(format!("{} is not a certificate: {e}", cert.display())),
    };
    let validity = parsed.validity();
    let now = x509_parser::time::ASN1Time::now();
    if now < validity.not_before {
        return Some(format!(
            "{} is not valid yet: it starts {}, and this host's clock says {now}. Is this \
             host's clock (or the one of the host that made the keys) wrong?",
            cert.display(),
            validity.not_before
        ));
    }
    if now > validity.not_after {
        return Some(format!(
            "{} expired {}: make new keys with `tes link keygen` (docs/multi-host.md, \
             rotation)",
            cert.display(),
            validity.not_after
        ));
    }
    let ca = ca?;
    let authority_der = match certificate_der(ca) {
        Ok(der) => der,
        Err(why) => return Some(why),
    };
    let authority = match X509Certificate::from_der(&authority_der) {
        Ok((_, authority)) => authority,
        Err(e) => return Some(format!("{} is not a certificate: {e}", ca.display())),
    };
    (!issued_by(&parsed, &authority)).then(|| {
        format!(
            "{} was not issued by the group's authority {} (it names {} as its issuer): \
             give this host the certificate made with that authority, or the authority that \
             made it",
            cert.display(),
            ca.display(),
            parsed.issuer()
        )
    })
}

/// Whether `authority` issued `cert`: the issuer's name is the authority's, and so is the
/// key identifier, where both certificates give one (two runs of `keygen` make authorities
/// of the same name with different keys).
fn issued_by(
    cert: &x509_parser::certificate::X509Certificate<'_>,
    authority: &x509_parser::certificate::X509Certificate<'_>,
) -> bool {
    use x509_parser::extensions::ParsedExtension;
    let key_of_issuer = cert
        .extensions()
        .iter()
        .find_map(|e| match e.parsed_extension() {
            ParsedExtension::AuthorityKeyIdentifier(aki) => {
                aki.key_identifier.as_ref().map(|k| k.0)
            }
            _ => None,
        });
    let own_key = authority
        .extensions()
        .iter()
        .find_map(|e| match e.parsed_extension() {
            ParsedExtension::SubjectKeyIdentifier(ski) => Some(ski.0),
            _ => None,
        });
    let same_key = match (key_of_issuer, own_key) {
        (Some(a), Some(b)) => a == b,
        _ => true,
    };
    cert.issuer() == authority.subject() && same_key
}

/// Zenoh's access control for a TLS group: nothing is allowed but what follows from the
/// peers' certificates. Every member (a certificate of the group's authority, whatever its
/// roles) may subscribe, query, stop the group, and is sent what this host publishes; a
/// sample of a topic, or a member token of a role, is taken only from a peer whose
/// certificate names the role that writes it ([`keys::common_names_playing`]).
pub fn access_control(group: &str) -> serde_json::Value {
    use serde_json::json;
    let mut subjects = vec![json!({
        "id": "members",
        "cert_common_names": keys::every_common_name(),
    })];
    let mut rules = vec![
        json!({
            "id": "members-listen",
            "messages": ["declare_subscriber", "declare_liveliness_subscriber",
                         "liveliness_query", "query", "declare_queryable", "reply"],
            "flows": ["ingress", "egress"],
            "permission": "allow",
            "key_exprs": [format!("{group}/**")],
        }),
        json!({
            "id": "members-stop",
            "messages": ["put"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": [format!("{group}/stop")],
        }),
        json!({
            "id": "members-hear",
            "messages": ["put", "liveliness_token"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [format!("{group}/**")],
        }),
    ];
    let mut policies = vec![json!({
        "rules": ["members-listen", "members-stop", "members-hear"],
        "subjects": ["members"],
    })];
    for role in Role::ALL {
        let name = role.name();
        subjects.push(json!({
            "id": format!("plays-{name}"),
            "cert_common_names": keys::common_names_playing(role),
        }));
        let written: Vec<String> = Topic::ALL
            .into_iter()
            .filter(|t| t.writer() == role)
            .map(|t| format!("{group}/{t}"))
            .collect();
        rules.push(json!({
            "id": format!("{name}-writes"),
            "messages": ["put"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": written,
        }));
        rules.push(json!({
            "id": format!("{name}-is-there"),
            "messages": ["liveliness_token"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": [format!("{group}/member/{name}/*")],
        }));
        policies.push(json!({
            "rules": [format!("{name}-writes"), format!("{name}-is-there")],
            "subjects": [format!("plays-{name}")],
        }));
    }
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refused(section: &LinkSection) -> (String, String) {
        let e = section.check().expect_err("refused");
        assert_eq!(e.process, "launch");
        (e.key, e.reason)
    }

    #[test]
    fn the_defaults_pass_and_make_a_config() {
        LinkSection::default().check().expect("defaults");
        LinkSection::default().zenoh_config().expect("config");
    }

    #[test]
    fn each_bad_key_is_named_with_its_reason() {
        for group in ["", "a//b", "a b", "/a", &"g".repeat(GROUP_NAME_MAX + 1)] {
            let (key, reason) = refused(&LinkSection {
                group: group.into(),
                ..LinkSection::default()
            });
            assert_eq!(key, "link.group");
            assert!(reason.contains("is not a group name"), "{reason}");
        }
        for group in ["tes", "lab-1/robot_2.a", &"g".repeat(GROUP_NAME_MAX)] {
            let section = LinkSection {
                group: group.into(),
                ..LinkSection::default()
            };
            assert!(section.check().is_ok(), "{group:?}");
        }
        let (key, reason) = refused(&LinkSection {
            listen: vec!["udp/127.0.0.1:7447".into()],
            ..LinkSection::default()
        });
        assert_eq!(key, "link.listen");
        assert!(
            reason.contains("is not a QUIC, TCP or Unix socket endpoint"),
            "{reason}"
        );
        let (key, _) = refused(&LinkSection {
            connect: vec!["192.168.1.20:7447".into()],
            ..LinkSection::default()
        });
        assert_eq!(key, "link.connect");
        let (key, reason) = refused(&LinkSection {
            multicast_scouting: Some(true),
            ..LinkSection::default()
        });
        assert_eq!(key, "link.multicast_scouting");
        assert!(reason.contains("whoever answers"), "{reason}");
        let (key, reason) = refused(&LinkSection {
            peer_timeout_ms: 99,
            ..LinkSection::default()
        });
        assert_eq!(key, "link.peer_timeout_ms");
        assert!(reason.contains("at least 100"), "{reason}");
    }

    /// Plain TCP is refused everywhere, loopback included (every local user reaches it),
    /// naming the fix, unless `insecure`; the default is the private socket.
    #[test]
    fn plain_tcp_needs_insecure_even_on_loopback() {
        for (endpoint, who) in [
            ("tcp/192.168.1.20:7447", "reachable from other hosts"),
            ("tcp/0.0.0.0:7447", "reachable from other hosts"),
            ("tcp/robot.local:7447", "reachable from other hosts"),
            (
                "tcp/127.0.0.1:7447",
                "every user of this host reaches loopback",
            ),
            ("tcp/[::1]:7447", "every user of this host reaches loopback"),
            (
                "tcp/localhost:7447",
                "every user of this host reaches loopback",
            ),
        ] {
            for (key, listen, connect) in [
                ("link.listen", vec![endpoint.to_owned()], vec![]),
                ("link.connect", vec![], vec![endpoint.to_owned()]),
            ] {
                let section = LinkSection {
                    listen,
                    connect,
                    ..LinkSection::default()
                };
                let (got, reason) = refused(&section);
                assert_eq!(got, key);
                assert!(reason.contains("plain TCP, with no authentication"));
                assert!(reason.contains(who), "{reason}");
                assert!(reason.contains("tes link keygen DIR"), "{reason}");
                assert!(reason.contains("link.insecure = true"), "{reason}");
                let insecure = LinkSection {
                    insecure: true,
                    ..section
                };
                insecure.check().expect("insecure is allowed");
                assert!(matches!(insecure.security(), Security::Insecure { .. }));
            }
        }
        let default = LinkSection::default();
        assert!(default.is_private());
        assert!(matches!(default.security(), Security::Private { .. }));
    }

    /// The default link's socket: in `socket_dir`, named after the group, made private
    /// (mode 700) when missing; a directory others may enter, or too long a path, refused.
    #[test]
    fn the_private_socket_is_in_a_directory_only_this_user_enters() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().expect("temp dir");
        let section = LinkSection {
            group: "lab/robot-1".into(),
            socket_dir: Some(dir.path().join("run/tes")),
            ..LinkSection::default()
        };
        section.check().expect("a private socket");
        let endpoint = section.prepare_private_socket().expect("made");
        let socket = dir.path().join("run/tes/link-lab~robot-1.sock");
        assert_eq!(endpoint, format!("unixsock-stream/{}", socket.display()));
        let mode =
            |p: &std::path::Path| std::fs::metadata(p).expect("made").permissions().mode() & 0o777;
        assert_eq!(mode(&dir.path().join("run/tes")), 0o700);
        assert_eq!(
            section.security(),
            Security::Private {
                socket: socket.clone()
            }
        );
        std::fs::set_permissions(
            dir.path().join("run/tes"),
            std::fs::Permissions::from_mode(0o755),
        )
        .expect("chmod");
        let why = section
            .prepare_private_socket()
            .expect_err("open to others");
        assert!(why.contains("may be entered by other users"), "{why}");
        assert!(why.contains("socket_dir"), "{why}");
        // An explicit socket in such a directory needs `insecure` too.
        let explicit = LinkSection {
            listen: vec![format!("unixsock-stream/{}", socket.display())],
            ..LinkSection::default()
        };
        let (key, reason) = refused(&explicit);
        assert_eq!(key, "link.listen");
        assert!(reason.contains("other users may enter"), "{reason}");
        let long = LinkSection {
            socket_dir: Some(dir.path().join("d".repeat(120))),
            ..section
        };
        let (key, reason) = refused(&long);
        assert_eq!(key, "link.socket_dir");
        assert!(reason.contains("shorter directory"), "{reason}");
    }

    /// `quic/` endpoints need the three files, which go together and must be readable;
    /// `tls/` endpoints are refused, saying why.
    #[test]
    fn tls_needs_its_three_files() {
        let dir = tempfile::tempdir().expect("temp dir");
        let keys = crate::keys::keygen(
            &dir.path().join("k"),
            &crate::keys::default_hosts(),
            crate::keys::DEFAULT_PORT,
        )
        .expect("keys");
        let tls = LinkSection {
            listen: vec!["quic/0.0.0.0:7447".into()],
            ..LinkSection::default()
        };
        let (key, reason) = refused(&tls);
        assert_eq!(key, "link.listen");
        assert!(reason.contains("link.tls_ca, link.tls_cert"), "{reason}");
        let with_files = LinkSection {
            tls_ca: Some(keys.authority.clone()),
            tls_cert: Some(keys.hosts[0].cert.clone()),
            tls_key: Some(keys.hosts[0].key.clone()),
            ..tls
        };
        with_files.check().expect("all three");
        with_files
            .check_for(&[Role::Perception, Role::Bridge])
            .expect("the robot's certificate on the robot's host");
        let (key, reason) = {
            let e = with_files
                .check_for(&[Role::Controller])
                .expect_err("the robot's certificate on the learning host");
            (e.key, e.reason)
        };
        assert_eq!(key, "link.tls_cert");
        assert!(
            reason.contains("playing \"perception-sim+bridge\""),
            "{reason}"
        );
        let config = with_files.zenoh_config().expect("config");
        let acl = config.get_json("access_control").expect("acl");
        assert!(acl.contains("\"default_permission\":\"deny\""), "{acl}");
        let (key, reason) = refused(&LinkSection {
            tls_key: None,
            ..with_files.clone()
        });
        assert_eq!(key, "link.tls_key");
        assert!(reason.contains("go together"), "{reason}");
        let (key, reason) = refused(&LinkSection {
            tls_ca: Some(dir.path().join("missing.pem")),
            ..with_files
        });
        assert_eq!(key, "link.tls_ca");
        assert!(reason.contains("cannot read"), "{reason}");
        let (key, reason) = refused(&LinkSection {
            connect: vec!["tls/192.168.1.20:7447".into()],
            ..LinkSection::default()
        });
        assert_eq!(key, "link.connect");
        assert!(reason.contains("Use quic/ endpoints"), "{reason}");
    }

    /// A controller's certificate made by rcgen: by the authority `issuer`, valid from
    /// `from` to `to` (years), written to `dir/NAME.pem`.
    fn controller_cert(
        dir: &std::path::Path,
        name: &str,
        issuer: &rcgen::Issuer<'_, rcgen::KeyPair>,
        (from, to): (i32, i32),
    ) -> PathBuf {
        let mut params = rcgen::CertificateParams::new(vec!["learner".into()]).expect("params");
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, "controller");
        params.use_authority_key_identifier_extension = true;
        params.not_before = rcgen::date_time_ymd(from, 1, 1);
        params.not_after = rcgen::date_time_ymd(to, 1, 1);
        let key = rcgen::KeyPair::generate().expect("key");
        let cert = params.signed_by(&key, issuer).expect("signed");
        let path = dir.join(format!("{name}.pem"));
        std::fs::write(&path, cert.pem()).expect("written");
        path
    }

    /// An authority made by rcgen, as `tes link keygen` makes one, written to `dir/NAME.pem`.
    fn authority(
        dir: &std::path::Path,
        name: &str,
    ) -> (PathBuf, rcgen::Issuer<'static, rcgen::KeyPair>) {
        let mut params = rcgen::CertificateParams::default();
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, "TES group authority");
        params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Constrained(0));
        params.key_usages = vec![rcgen::KeyUsagePurpose::KeyCertSign];
        let key = rcgen::KeyPair::generate().expect("key");
        let cert = params.self_signed(&key).expect("self-signed");
        let path = dir.join(format!("{name}.pem"));
        std::fs::write(&path, cert.pem()).expect("written");
        (path, rcgen::Issuer::new(params, key))
    }

    /// A certificate not valid yet, one expired and one of another authority are each
    /// refused at start with that cause, not a generic "not valid".
    #[test]
    fn certificate_faults_are_named_by_their_cause() {
        let dir = tempfile::tempdir().expect("temp dir");
        let (ca, issuer) = authority(dir.path(), "ca");
        let (_, stranger) = authority(dir.path(), "other-ca");
        // A private key, owner-only in an owner-only directory, so that the key's own checks
        // pass and the certificate's cause is what is said.
        use std::os::unix::fs::PermissionsExt as _;
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o700))
            .expect("chmod 700");
        let key = dir.path().join("host.key");
        let pem = rcgen::KeyPair::generate().expect("key").serialize_pem();
        std::fs::write(&key, pem).expect("key");
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).expect("chmod 600");
        let year: i32 = humantime::format_rfc3339_seconds(std::time::SystemTime::now())
            .to_string()
            .get(..4)
            .and_then(|y| y.parse().ok())
            .expect("this year");
        let cases = [
            (
                controller_cert(dir.path(), "future", &issuer, (year + 50, year + 60)),
                "is not valid yet: it starts",
            ),
            (
                controller_cert(dir.path(), "expired", &issuer, (year - 20, year - 10)),
                "expired",
            ),
            (
                controller_cert(dir.path(), "foreign", &stranger, (year - 1, year + 50)),
                "was not issued by the",
            ),
        ];
        for (cert, cause) in cases {
            let section = LinkSection {
                listen: vec!["quic/127.0.0.1:7447".into()],
                tls_ca: Some(ca.clone()),
                tls_cert: Some(cert.clone()),
                tls_key: Some(key.clone()),
                ..LinkSection::default()
            };
            let e = section.check_for(&[Role::Controller]).expect_err("refused");
            assert_eq!(e.key, "link.tls_cert");
            assert!(e.reason.contains(cause), "{cert:?}: {}", e.reason);
            assert!(!e.reason.contains("not valid now"), "{}", e.reason);
        }
        let good = controller_cert(dir.path(), "good", &issuer, (year - 1, year + 50));
        LinkSection {
            listen: vec!["quic/127.0.0.1:7447".into()],
            tls_ca: Some(ca),
            tls_cert: Some(good),
            tls_key: Some(key),
            ..LinkSection::default()
        }
        .check_for(&[Role::Controller])
        .expect("a good certificate of the group's authority");
    }

    /// Commands are taken only from a certificate naming the controller; members may stop the
    /// group; nothing else is allowed by default.
    #[test]
    fn access_control_follows_the_roles() {
        let acl = access_control("lab");
        assert_eq!(acl["default_permission"], "deny");
        let rule = |id: &str| {
            acl["rules"]
                .as_array()
                .and_then(|rules| rules.iter().find(|r| r["id"] == id))
                .cloned()
                .unwrap_or_default()
        };
        assert_eq!(
            rule("controller-writes")["key_exprs"],
            serde_json::json!(["lab/command", "lab/progress/controller"])
        );
        assert_eq!(
            rule("members-stop")["key_exprs"],
            serde_json::json!(["lab/stop"])
        );
        let subject = acl["subjects"]
            .as_array()
            .and_then(|s| s.iter().find(|s| s["id"] == "plays-controller"))
            .cloned()
            .unwrap_or_default();
        let names = subject["cert_common_names"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        assert!(!names.contains(&serde_json::json!("perception-sim+bridge")));
        assert!(names.contains(&serde_json::json!("controller")));
    }
}
