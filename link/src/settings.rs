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
    /// Where this launch accepts its peers' connections. The default listens on loopback
    /// only; a host that other machines connect to listens with QUIC (TLS 1.3, both sides
    /// authenticated) on an address of its own, e.g. `["quic/0.0.0.0:7447"]` (`tes link
    /// keygen` prints the lines to use).
    ///
    /// Values: list of endpoints: `quic/ADDRESS:PORT` (UDP), or `tcp/ADDRESS:PORT` on
    /// loopback (any other address only with `insecure = true`).
    pub listen: Vec<String>,
    /// The peers (or the router) this launch connects to.
    ///
    /// Values: list of endpoints, as `listen`.
    pub connect: Vec<String>,
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
    /// Allow plain TCP on an address other hosts can reach: anyone who reaches the port can
    /// then join the group, read every observation and drive the robot. Said at every start.
    ///
    /// Values: `true` | `false`.
    pub insecure: bool,
    /// Find peers on the local network by UDP multicast (224.0.0.224:7446). Unset: on when
    /// `connect` is empty, off when it names peers.
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
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: Vec::new(),
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
    /// Plain TCP, on loopback only: no other host can connect.
    Loopback,
    /// Mutual TLS against the group's authority, with access control by role.
    Tls {
        /// This host's certificate's common name (the roles it may publish for).
        common_name: String,
    },
    /// Plain TCP on addresses other hosts can reach (`insecure = true`).
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
}

/// Why `tls/` endpoints are refused.
const TLS_OVER_TCP_REFUSED: &str = "Zenoh 1.10's TLS-over-TCP link reads and writes one TLS \
     stream from two tasks at once, which rustls does not support: with traffic both ways it \
     drops the link within seconds (the launches then stop, each saying the other left) and \
     can corrupt memory. Use quic/ endpoints, which carry TLS 1.3 with the same keys";

/// The carrier of a Zenoh endpoint, if it is one the link takes.
fn carrier(endpoint: &str) -> Option<Carrier> {
    endpoint.parse::<zenoh::config::EndPoint>().ok()?;
    let (scheme, _) = endpoint.split_once('/')?;
    match scheme {
        "tcp" => Some(Carrier::Tcp),
        "quic" => Some(Carrier::Quic),
        "tls" => Some(Carrier::TlsOverTcp),
        _ => None,
    }
}

/// Whether an endpoint is plain TCP that other hosts could reach.
fn exposes_plain_tcp(endpoint: &str) -> bool {
    carrier(endpoint) == Some(Carrier::Tcp) && !is_loopback(endpoint)
}

/// Whether an endpoint's address is loopback (`127.0.0.0/8`, `::1`, `localhost`): only this
/// host can reach it.
fn is_loopback(endpoint: &str) -> bool {
    let address = endpoint
        .split_once('/')
        .map_or(endpoint, |(_, rest)| rest)
        .split(['?', '#'])
        .next()
        .unwrap_or("");
    if let Ok(socket) = address.parse::<std::net::SocketAddr>() {
        return socket.ip().is_loopback();
    }
    address
        .rsplit_once(':')
        .is_some_and(|(host, _)| host.eq_ignore_ascii_case("localhost"))
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
        if self.listen.is_empty()
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
    /// only on loopback (unless `insecure`).
    fn check_endpoint(&self, key: &str, endpoint: &str) -> Result<(), SettingError> {
        let refused = match carrier(endpoint) {
            None => format!(
                "{endpoint:?} is not a QUIC or TCP endpoint such as \"quic/192.168.1.20:7447\""
            ),
            Some(Carrier::TlsOverTcp) => format!("{endpoint:?}: {TLS_OVER_TCP_REFUSED}"),
            Some(Carrier::Tcp) if !self.insecure && exposes_plain_tcp(endpoint) => format!(
                "{endpoint:?} is plain TCP on an address other hosts can reach: anyone who \
                 reaches it could join the group, read its observations and drive the robot. \
                 Use QUIC with the group's keys: `tes link keygen DIR` makes them and prints \
                 the `quic/` endpoints and the link.tls_ca, link.tls_cert and link.tls_key \
                 lines for each host (or set link.insecure = true to take that risk)"
            ),
            Some(Carrier::Quic) if !self.has_tls() => format!(
                "{endpoint:?} is a QUIC endpoint, but link.tls_ca, link.tls_cert and \
                 link.tls_key are not all set (`tes link keygen DIR` makes them)"
            ),
            Some(_) => return Ok(()),
        };
        Err(SettingError::new(PROCESS, key, refused))
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
        if !facts.valid_now {
            return bad(format!(
                "{} is not valid now (it runs to {}): make new keys with `tes link keygen`",
                cert.display(),
                facts.not_after
            ));
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
        let exposed: Vec<String> = self
            .listen
            .iter()
            .chain(&self.connect)
            .filter(|e| exposes_plain_tcp(e))
            .cloned()
            .collect();
        if exposed.is_empty() {
            Security::Loopback
        } else {
            Security::Insecure { exposed }
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
        let mut config = zenoh::Config::default();
        let json = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
        let mode = match self.mode {
            Mode::Peer => "\"peer\"",
            Mode::Client => "\"client\"",
        };
        let multicast = self.multicast_scouting.unwrap_or(self.connect.is_empty());
        let mut entries = vec![
            ("mode", mode.to_owned()),
            ("listen/endpoints", json(&self.listen)),
            ("connect/endpoints", json(&self.connect)),
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
        assert!(reason.contains("is not a QUIC or TCP endpoint"), "{reason}");
        let (key, _) = refused(&LinkSection {
            connect: vec!["192.168.1.20:7447".into()],
            ..LinkSection::default()
        });
        assert_eq!(key, "link.connect");
        let (key, reason) = refused(&LinkSection {
            listen: Vec::new(),
            multicast_scouting: Some(false),
            ..LinkSection::default()
        });
        assert_eq!(key, "link.connect");
        assert!(reason.contains("no peer can be reached"), "{reason}");
        let (key, reason) = refused(&LinkSection {
            peer_timeout_ms: 99,
            ..LinkSection::default()
        });
        assert_eq!(key, "link.peer_timeout_ms");
        assert!(reason.contains("at least 100"), "{reason}");
    }

    /// Plain TCP is refused wherever another host could connect, naming the fix, unless
    /// `insecure`; loopback is fine.
    #[test]
    fn plain_tcp_is_only_for_loopback() {
        for endpoint in [
            "tcp/192.168.1.20:7447",
            "tcp/0.0.0.0:7447",
            "tcp/robot.local:7447",
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
                assert!(reason.contains("plain TCP on an address other hosts can reach"));
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
        for endpoint in [
            "tcp/127.0.0.1:7447",
            "tcp/127.3.2.1:1",
            "tcp/[::1]:7447",
            "tcp/localhost:7447",
        ] {
            let section = LinkSection {
                connect: vec![endpoint.into()],
                ..LinkSection::default()
            };
            section.check().expect(endpoint);
            assert_eq!(section.security(), Security::Loopback, "{endpoint}");
        }
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
