//! The group's keys (`tes link keygen`): a certificate authority of the group's own, and a
//! certificate and key per host, whose common name says which roles the host plays.
//!
//! Every host of a TLS group holds the authority's certificate, its own certificate and its
//! own key. A connection is accepted only when both sides show a certificate the group's
//! authority signed (mutual TLS), and what a peer may publish follows from the roles its
//! certificate names ([`common_name`]): only a certificate naming the controller may send
//! commands, so a stolen robot-host key cannot drive the robot.
//!
//! ```
//! use tes_link::keys::{Host, common_name};
//! use tes_topics::Role;
//!
//! let robot: Host = "robot=perception-sim,bridge@192.168.1.20".parse()?;
//! assert_eq!(robot.roles, [Role::Perception, Role::Bridge]);
//! assert_eq!(common_name(&robot.roles), "perception-sim+bridge");
//! # Ok::<(), tes_link::keys::KeyError>(())
//! ```

use std::fmt::Write as _;
use std::fs;
use std::io::Write as _;
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::SystemTime;

use rcgen::{
    BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair,
    KeyUsagePurpose,
};
use tes_topics::Role;

/// The (UDP) port the printed settings listen on and connect to.
pub const DEFAULT_PORT: u16 = 7447;

/// Years a host's certificate is valid from the start of the year it was made.
pub const HOST_YEARS: i32 = 3;

/// Years the group's authority is valid from the start of the year it was made.
pub const AUTHORITY_YEARS: i32 = 10;

/// The authority's files in the key directory.
pub const AUTHORITY_CERT: &str = "ca.pem";
/// The authority's signing key: kept with the keys to sign more hosts later, never copied to
/// a host.
pub const AUTHORITY_KEY: &str = "ca.key";

/// Why the keys could not be made.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    /// A `--host` value is not `NAME=ROLE[,ROLE…][@ADDRESS]`.
    #[error("--host {text:?}: {reason}")]
    BadHost {
        /// The value given.
        text: String,
        /// What is wrong with it.
        reason: String,
    },
    /// The hosts do not play every role exactly once.
    #[error("{0}")]
    Roles(String),
    /// A file of the key set exists already: keys are never overwritten.
    #[error(
        "{} exists: keys are never overwritten (to rotate them, make a new authority in a new \
         directory)",
        path.display()
    )]
    Exists {
        /// The file.
        path: PathBuf,
    },
    /// A file or the directory could not be written.
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The certificate library refused.
    #[error("cannot make a certificate: {0}")]
    Certificate(#[from] rcgen::Error),
}

/// A host of the group: its name (the file names of its certificate and key), the roles it
/// plays and, when known, the address the other hosts reach it at.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Host {
    /// A name for the files: ASCII letters, digits, `-`, `_`.
    pub name: String,
    /// The roles it plays, in the order of [`Role::ALL`].
    pub roles: Vec<Role>,
    /// Where the other hosts reach it (an IP address or a host name), if given.
    pub address: Option<String>,
}

/// `NAME=ROLE[,ROLE…][@ADDRESS]`, e.g. `robot=perception-sim,bridge@192.168.1.20`.
impl FromStr for Host {
    type Err = KeyError;

    fn from_str(text: &str) -> Result<Self, KeyError> {
        let bad = |reason: &str| KeyError::BadHost {
            text: text.to_owned(),
            reason: reason.to_owned(),
        };
        let (name, rest) = text
            .split_once('=')
            .ok_or_else(|| bad("expected NAME=ROLE[,ROLE…][@ADDRESS]"))?;
        let name_ok = !name.is_empty()
            && name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
        if !name_ok || name == "ca" {
            return Err(bad(
                "the name must be ASCII letters, digits, '-' or '_' (and not \"ca\")",
            ));
        }
        let (roles_text, address) = match rest.split_once('@') {
            Some((roles, address)) if !address.is_empty() => (roles, Some(address.to_owned())),
            Some(_) => return Err(bad("nothing after '@': give the host's address")),
            None => (rest, None),
        };
        let mut roles = Vec::new();
        for part in roles_text.split(',') {
            let role = Role::ALL
                .into_iter()
                .find(|r| r.name() == part)
                .ok_or_else(|| {
                    bad(&format!(
                        "{part:?} is not a role (perception-sim, controller, bridge)"
                    ))
                })?;
            if !roles.contains(&role) {
                roles.push(role);
            }
        }
        roles.sort_by_key(|r| Role::ALL.iter().position(|a| a == r));
        Ok(Self {
            name: name.to_owned(),
            roles,
            address,
        })
    }
}

/// The hosts `tes link keygen` makes keys for when none is given: the robot's host
/// (perception and the bridge) and the learning host (the controller).
pub fn default_hosts() -> Vec<Host> {
    vec![
        Host {
            name: "robot".into(),
            roles: vec![Role::Perception, Role::Bridge],
            address: None,
        },
        Host {
            name: "learner".into(),
            roles: vec![Role::Controller],
            address: None,
        },
    ]
}

/// The common name of the certificate of a host playing `roles`: their names in the order of
/// [`Role::ALL`], joined by `+` (`perception-sim+bridge`, `controller`). What a peer may
/// publish is decided from it ([`common_names_playing`]).
pub fn common_name(roles: &[Role]) -> String {
    Role::ALL
        .into_iter()
        .filter(|r| roles.contains(r))
        .map(Role::name)
        .collect::<Vec<_>>()
        .join("+")
}

/// Every common name a certificate of a host playing `role` (among others) can have.
pub fn common_names_playing(role: Role) -> Vec<String> {
    role_sets()
        .filter(|roles| roles.contains(&role))
        .map(|roles| common_name(&roles))
        .collect()
}

/// Every common name a host certificate of the group can have.
pub fn every_common_name() -> Vec<String> {
    role_sets().map(|roles| common_name(&roles)).collect()
}

/// The non-empty sets of roles.
fn role_sets() -> impl Iterator<Item = Vec<Role>> {
    (1u8..1 << Role::ALL.len()).map(|mask| {
        Role::ALL
            .into_iter()
            .enumerate()
            .filter(|(i, _)| mask & (1 << i) != 0)
            .map(|(_, r)| r)
            .collect()
    })
}

/// What a host certificate says, read at launch to catch a host given another's files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CertificateFacts {
    /// Its common name (for a group certificate, the roles: see [`common_name`]).
    pub common_name: String,
    /// Its last day of validity, as the certificate writes it.
    pub not_after: String,
    /// Whether it is valid now.
    pub valid_now: bool,
}

/// Reads the first certificate of a PEM file.
pub fn read_certificate(path: &Path) -> Result<CertificateFacts, String> {
    let bytes = fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let not_a_certificate = |e: String| format!("{} is not a PEM certificate: {e}", path.display());
    let (_, pem) =
        x509_parser::pem::parse_x509_pem(&bytes).map_err(|e| not_a_certificate(e.to_string()))?;
    let cert = pem
        .parse_x509()
        .map_err(|e| not_a_certificate(e.to_string()))?;
    let common_name = cert
        .subject()
        .iter_common_name()
        .next()
        .and_then(|cn| cn.as_str().ok())
        .unwrap_or("")
        .to_owned();
    Ok(CertificateFacts {
        common_name,
        not_after: cert.validity().not_after.to_string(),
        valid_now: cert.validity().is_valid(),
    })
}

/// The files of one host.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostFiles {
    /// The host.
    pub host: Host,
    /// Its certificate (PEM).
    pub cert: PathBuf,
    /// Its private key (PEM, PKCS #8), readable only by its owner.
    pub key: PathBuf,
}

/// A key set as written by [`keygen`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KeySet {
    /// The authority's certificate, which every host needs.
    pub authority: PathBuf,
    /// The authority's signing key, which no host needs.
    pub authority_key: PathBuf,
    /// Each host's files, in the order given.
    pub hosts: Vec<HostFiles>,
    /// The port the printed settings use.
    pub port: u16,
}

/// Makes the group's authority and a certificate and key per host in `dir` (created, readable
/// only by its owner, if missing). Refuses before writing anything when the hosts do not play
/// each role exactly once, or when any of the files exists.
pub fn keygen(dir: &Path, hosts: &[Host], port: u16) -> Result<KeySet, KeyError> {
    check_roles(hosts)?;
    let set = KeySet {
        authority: dir.join(AUTHORITY_CERT),
        authority_key: dir.join(AUTHORITY_KEY),
        hosts: hosts
            .iter()
            .map(|host| HostFiles {
                host: host.clone(),
                cert: dir.join(format!("{}.pem", host.name)),
                key: dir.join(format!("{}.key", host.name)),
            })
            .collect(),
        port,
    };
    for path in set.paths() {
        if path.exists() {
            return Err(KeyError::Exists { path });
        }
    }
    fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .map_err(|source| KeyError::Write {
            path: dir.to_owned(),
            source,
        })?;
    let year = this_year();
    let authority_key = KeyPair::generate()?;
    let authority_params = authority_params(year);
    let authority = authority_params.self_signed(&authority_key)?;
    write_private(&set.authority_key, &authority_key.serialize_pem())?;
    write_private(&set.authority, &authority.pem())?;
    let issuer = Issuer::new(authority_params, authority_key);
    for files in &set.hosts {
        let key = KeyPair::generate()?;
        let cert = host_params(&files.host, year)?.signed_by(&key, &issuer)?;
        write_private(&files.key, &key.serialize_pem())?;
        write_private(&files.cert, &cert.pem())?;
    }
    Ok(set)
}

impl KeySet {
    /// Every file of the set.
    fn paths(&self) -> Vec<PathBuf> {
        let mut paths = vec![self.authority.clone(), self.authority_key.clone()];
        for files in &self.hosts {
            paths.push(files.cert.clone());
            paths.push(files.key.clone());
        }
        paths
    }

    /// The launch-file lines for each host: its roles, its endpoints (the first host listens
    /// on every interface, the others connect to it) and its three files.
    pub fn launch_lines(&self) -> String {
        let mut text = String::new();
        let Some(first) = self.hosts.first() else {
            return text;
        };
        let first_address = first
            .host
            .address
            .clone()
            .unwrap_or_else(|| format!("{}-ADDRESS", first.host.name.to_uppercase()));
        for (i, files) in self.hosts.iter().enumerate() {
            let roles: Vec<String> = files
                .host
                .roles
                .iter()
                .map(|r| format!("{:?}", r.name()))
                .collect();
            let (listen, connect) = if i == 0 {
                (format!("[\"quic/0.0.0.0:{}\"]", self.port), "[]".to_owned())
            } else {
                (
                    "[]".to_owned(),
                    format!("[\"quic/{first_address}:{}\"]", self.port),
                )
            };
            let _ = write!(
                text,
                "# on {name} (copy {ca}, {cert} and {key} there)\n\
                 [launch]\n\
                 roles = [{roles}]\n\
                 [launch.link]\n\
                 listen = {listen}\n\
                 connect = {connect}\n\
                 tls_ca = {ca:?}\n\
                 tls_cert = {cert:?}\n\
                 tls_key = {key:?}\n\n",
                name = files.host.name,
                ca = self.authority.display().to_string(),
                cert = files.cert.display().to_string(),
                key = files.key.display().to_string(),
                roles = roles.join(", "),
            );
        }
        if first.host.address.is_none() {
            let _ = writeln!(
                text,
                "# Replace {first_address} with the address the other hosts reach {} at.",
                first.host.name
            );
        }
        text
    }
}

/// Each role played by exactly one host, and host names distinct.
fn check_roles(hosts: &[Host]) -> Result<(), KeyError> {
    for (i, host) in hosts.iter().enumerate() {
        if hosts[..i].iter().any(|h| h.name == host.name) {
            return Err(KeyError::Roles(format!(
                "two hosts are named {:?}",
                host.name
            )));
        }
    }
    for role in Role::ALL {
        let players: Vec<&str> = hosts
            .iter()
            .filter(|h| h.roles.contains(&role))
            .map(|h| h.name.as_str())
            .collect();
        match players.len() {
            1 => {}
            0 => {
                return Err(KeyError::Roles(format!(
                    "no host plays {}: give each role to one --host",
                    role.name()
                )));
            }
            _ => {
                return Err(KeyError::Roles(format!(
                    "{} is played by {}: a role is played by one host",
                    role.name(),
                    players.join(" and ")
                )));
            }
        }
    }
    Ok(())
}

/// The authority: a CA that signs host certificates only (no intermediate below it).
fn authority_params(year: i32) -> CertificateParams {
    let mut params = CertificateParams::default();
    params.distinguished_name = rcgen::DistinguishedName::new();
    params
        .distinguished_name
        .push(DnType::CommonName, "TES group authority");
    params.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    params.not_before = rcgen::date_time_ymd(year, 1, 1);
    params.not_after = rcgen::date_time_ymd(year + AUTHORITY_YEARS, 1, 1);
    params
}

/// A host: common name from its roles, its name (and address) as subject alternative names,
/// for both ends of a connection.
fn host_params(host: &Host, year: i32) -> Result<CertificateParams, KeyError> {
    let mut names = vec![host.name.clone()];
    names.extend(host.address.clone());
    let mut params = CertificateParams::new(names)?;
    params.distinguished_name = rcgen::DistinguishedName::new();
    params
        .distinguished_name
        .push(DnType::CommonName, common_name(&host.roles));
    params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
    params.extended_key_usages = vec![
        ExtendedKeyUsagePurpose::ServerAuth,
        ExtendedKeyUsagePurpose::ClientAuth,
    ];
    params.use_authority_key_identifier_extension = true;
    params.not_before = rcgen::date_time_ymd(year, 1, 1);
    params.not_after = rcgen::date_time_ymd(year + HOST_YEARS, 1, 1);
    Ok(params)
}

/// The current year (UTC), from the system clock (read off its RFC 3339 form, as the run
/// folders' names are made).
fn this_year() -> i32 {
    humantime::format_rfc3339_seconds(SystemTime::now())
        .to_string()
        .get(..4)
        .and_then(|year| year.parse().ok())
        .unwrap_or(2026)
}

/// Writes `text` to a new file readable and writable only by its owner.
fn write_private(path: &Path, text: &str) -> Result<(), KeyError> {
    let failed = |source| KeyError::Write {
        path: path.to_owned(),
        source,
    };
    let mut file = fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)
        .map_err(failed)?;
    file.write_all(text.as_bytes()).map_err(failed)?;
    file.sync_all().map_err(failed)
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::PermissionsExt;

    use super::*;

    #[test]
    fn hosts_parse_and_bad_ones_say_why() {
        let host: Host = "learner=controller".parse().expect("host");
        assert_eq!(
            host,
            Host {
                name: "learner".into(),
                roles: vec![Role::Controller],
                address: None
            }
        );
        let host: Host = "r2=bridge,perception-sim@robot.local"
            .parse()
            .expect("host");
        assert_eq!(host.roles, [Role::Perception, Role::Bridge]);
        assert_eq!(host.address.as_deref(), Some("robot.local"));
        for (text, reason) in [
            ("robot", "expected NAME=ROLE"),
            ("=controller", "the name must be"),
            ("ca=controller", "not \"ca\""),
            ("a/b=controller", "the name must be"),
            ("robot=camera", "\"camera\" is not a role"),
            ("robot=controller@", "nothing after '@'"),
        ] {
            let e = text.parse::<Host>().expect_err(text).to_string();
            assert!(e.contains(reason), "{text}: {e}");
        }
    }

    #[test]
    fn common_names_follow_the_roles() {
        assert_eq!(
            common_name(&[Role::Bridge, Role::Perception]),
            "perception-sim+bridge"
        );
        assert_eq!(every_common_name().len(), 7);
        let controllers = common_names_playing(Role::Controller);
        assert_eq!(controllers.len(), 4);
        assert!(controllers.iter().all(|cn| cn.contains("controller")));
        assert!(!controllers.contains(&"perception-sim+bridge".to_owned()));
    }

    #[test]
    fn keygen_writes_private_files_and_never_overwrites() {
        let dir = tempfile::tempdir().expect("temp dir");
        let keys = dir.path().join("keys");
        let set = keygen(&keys, &default_hosts(), DEFAULT_PORT).expect("keys");
        assert_eq!(set.hosts.len(), 2);
        for path in set.paths() {
            let mode = fs::metadata(&path).expect("file").permissions().mode();
            assert_eq!(mode & 0o777, 0o600, "{}", path.display());
        }
        let dir_mode = fs::metadata(&keys).expect("dir").permissions().mode();
        assert_eq!(dir_mode & 0o777, 0o700);
        let cert = fs::read_to_string(&set.hosts[0].cert).expect("cert");
        assert!(cert.starts_with("-----BEGIN CERTIFICATE-----"));
        let lines = set.launch_lines();
        assert!(
            lines.contains("listen = [\"quic/0.0.0.0:7447\"]"),
            "{lines}"
        );
        assert!(
            lines.contains("connect = [\"quic/ROBOT-ADDRESS:7447\"]"),
            "{lines}"
        );
        assert!(lines.contains("roles = [\"controller\"]"), "{lines}");
        let again = keygen(&keys, &default_hosts(), DEFAULT_PORT).expect_err("exists");
        assert!(again.to_string().contains("never overwritten"), "{again}");
    }

    #[test]
    fn every_role_must_be_played_once() {
        let dir = tempfile::tempdir().expect("temp dir");
        let only_robot = vec![default_hosts().remove(0)];
        let e = keygen(dir.path(), &only_robot, DEFAULT_PORT).expect_err("no controller");
        assert!(e.to_string().contains("no host plays controller"), "{e}");
        let mut twice = default_hosts();
        twice.push("spare=controller".parse().expect("host"));
        let e = keygen(dir.path(), &twice, DEFAULT_PORT).expect_err("twice");
        assert!(
            e.to_string()
                .contains("controller is played by learner and spare"),
            "{e}"
        );
        assert_eq!(
            fs::read_dir(dir.path()).expect("dir").count(),
            0,
            "nothing written"
        );
    }

    #[test]
    fn a_certificate_says_its_roles() {
        let dir = tempfile::tempdir().expect("temp dir");
        let set = keygen(dir.path(), &default_hosts(), DEFAULT_PORT).expect("keys");
        let facts = read_certificate(&set.hosts[0].cert).expect("certificate");
        assert_eq!(facts.common_name, "perception-sim+bridge");
        assert!(facts.valid_now, "{facts:?}");
        let e = read_certificate(&set.hosts[0].key).expect_err("a key is not a certificate");
        assert!(e.contains("is not a PEM certificate"), "{e}");
    }

    #[test]
    fn this_year_is_plausible() {
        assert!((2026..2200).contains(&this_year()));
    }
}
