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
    /// The key directory exists and someone other than its owner may open it or replace the
    /// files in it (or it is not a directory, or not this user's).
    #[error("{}: {reason}", path.display())]
    OpenDirectory {
        /// The directory.
        path: PathBuf,
        /// Why, with the fix.
        reason: String,
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
        if let Some(address) = &address
            && !is_address(address)
        {
            return Err(bad(&format!(
                "{address:?} is not an address: give an IP address (192.168.1.20, fd00::20) or \
                 a DNS name (robot.local: letters, digits and '-' in dot-separated labels)"
            )));
        }
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

/// Whether `text` is an IP address or a DNS name (labels of ASCII letters, digits and `-`,
/// neither first nor last, 1 to 63 bytes each, 253 in all): what an endpoint and a
/// certificate's subject alternative name may hold, and nothing that could end the quoted
/// string it is printed into.
pub fn is_address(text: &str) -> bool {
    if text.parse::<std::net::IpAddr>().is_ok() {
        return true;
    }
    let label_ok = |label: &str| {
        (1..=63).contains(&label.len())
            && label
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-')
            && !label.starts_with('-')
            && !label.ends_with('-')
    };
    text.len() <= 253
        && text.split('.').all(label_ok)
        // All digits and dots is a mistyped IPv4 address, not a name.
        && !text.bytes().all(|b| b.is_ascii_digit() || b == b'.')
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

/// The largest TLS file read, in bytes: a certificate or key is a few kilobytes, a bundle of
/// authorities a few hundred.
pub const MAX_PEM_BYTES: u64 = 1 << 20;

/// The first PEM block of the file at `path`, read as every TES file is
/// ([`tes_files::read_capped`]: a regular file of at most [`MAX_PEM_BYTES`]; a FIFO or a
/// device is refused without blocking or reading).
fn read_pem(path: &Path) -> Result<x509_parser::pem::Pem, String> {
    let bytes = tes_files::read_capped(path, MAX_PEM_BYTES)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let (_, pem) = x509_parser::pem::parse_x509_pem(&bytes)
        .map_err(|e| format!("{} is not a PEM file: {e}", path.display()))?;
    Ok(pem)
}

/// What a certificate says, for the checks at launch.
struct Certificate {
    facts: CertificateFacts,
    is_ca: bool,
    subject: String,
    issuer: String,
    /// The certificate itself (DER), to check signatures with.
    der: Vec<u8>,
}

impl Certificate {
    /// Whether `authority`'s key signed this certificate.
    fn signed_by(&self, authority: &Certificate) -> bool {
        let parse = |der| x509_parser::parse_x509_certificate(der).map(|(_, cert)| cert);
        match (parse(&self.der), parse(&authority.der)) {
            (Ok(cert), Ok(ca)) => cert.verify_signature(Some(ca.public_key())).is_ok(),
            _ => false,
        }
    }
}

/// Reads and parses the first certificate of a PEM file.
fn read_cert(path: &Path) -> Result<Certificate, String> {
    let pem = read_pem(path)?;
    let not_a_certificate = |e: String| format!("{} is not a PEM certificate: {e}", path.display());
    if pem.label != "CERTIFICATE" {
        return Err(not_a_certificate(format!("it holds a {:?}", pem.label)));
    }
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
    Ok(Certificate {
        facts: CertificateFacts {
            common_name,
            not_after: cert.validity().not_after.to_string(),
            valid_now: cert.validity().is_valid(),
        },
        is_ca: cert.is_ca(),
        subject: cert.subject().to_string(),
        issuer: cert.issuer().to_string(),
        der: pem.contents.clone(),
    })
}

/// Reads the first certificate of a PEM file.
pub fn read_certificate(path: &Path) -> Result<CertificateFacts, String> {
    read_cert(path).map(|c| c.facts)
}

/// Which of a host's three TLS files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TlsFile {
    /// The group's authority (`tls_ca`).
    Authority,
    /// This host's certificate (`tls_cert`).
    Certificate,
    /// This host's private key (`tls_key`).
    Key,
}

impl TlsFile {
    /// Its key in the launch file, within `[launch]`.
    pub fn setting(self) -> &'static str {
        match self {
            TlsFile::Authority => "link.tls_ca",
            TlsFile::Certificate => "link.tls_cert",
            TlsFile::Key => "link.tls_key",
        }
    }
}

/// A TLS file refused at start.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{reason}")]
pub struct TlsFileError {
    /// Which file.
    pub file: TlsFile,
    /// Why, naming the file and the fix.
    pub reason: String,
}

/// Checks a host's three TLS files before anything else uses them (Zenoh reads them only
/// once the link opens, and blocks on a FIFO or reads `/dev/zero` until memory runs out):
/// each a regular file of at most [`MAX_PEM_BYTES`] holding PEM; the key and its directory
/// owner-only, the others' directories writable by their owner alone; `ca` the certificate
/// of an authority, and `cert` a host certificate it issued.
pub fn check_tls_files(ca: &Path, cert: &Path, key: &Path) -> Result<(), TlsFileError> {
    fn refuse<T>(file: TlsFile, reason: String) -> Result<T, TlsFileError> {
        Err(TlsFileError { file, reason })
    }
    let authority = read_cert(ca).or_else(|r| refuse(TlsFile::Authority, r))?;
    let host = read_cert(cert).or_else(|r| refuse(TlsFile::Certificate, r))?;
    let key_pem = read_pem(key).or_else(|r| refuse(TlsFile::Key, r))?;
    check_key_privacy(key).or_else(|r| refuse(TlsFile::Key, r))?;
    for (file, path) in [(TlsFile::Authority, ca), (TlsFile::Certificate, cert)] {
        let dir = tes_files::parent_dir(path);
        if let Err(e) = tes_files::check_dir_not_writable_by_others(&dir) {
            return refuse(
                file,
                format!("{} (holding {}) {e}", dir.display(), path.display()),
            );
        }
    }
    if !authority.is_ca {
        return refuse(
            TlsFile::Authority,
            format!(
                "{} is not an authority's certificate but a host's (common name {:?}): set \
                 link.tls_ca to the group's authority, the {AUTHORITY_CERT} that `tes link \
                 keygen` made beside the host files",
                ca.display(),
                authority.facts.common_name
            ),
        );
    }
    if host.is_ca {
        return refuse(
            TlsFile::Certificate,
            format!(
                "{} is an authority's certificate, not a host's: set link.tls_cert to this \
                 host's certificate (NAME.pem of `tes link keygen`)",
                cert.display()
            ),
        );
    }
    if host.issuer != authority.subject || !host.signed_by(&authority) {
        return refuse(
            TlsFile::Certificate,
            format!(
                "{} was not issued by the authority in {} (it names {:?} as its issuer): \
                 give every host the files of one `tes link keygen`",
                cert.display(),
                ca.display(),
                host.issuer,
            ),
        );
    }
    if !key_pem.label.ends_with("PRIVATE KEY") {
        return refuse(
            TlsFile::Key,
            format!(
                "{} holds a {:?}, not a private key: set link.tls_key to this host's key \
                 (NAME.key of `tes link keygen`)",
                key.display(),
                key_pem.label
            ),
        );
    }
    Ok(())
}

/// A private key must be readable by its owner alone, in a directory only its owner may
/// open (anyone who may write there may replace the key or the authority beside it).
fn check_key_privacy(key: &Path) -> Result<(), String> {
    tes_files::check_private_file(key).map_err(|e| format!("{} {e}", key.display()))?;
    let dir = tes_files::parent_dir(key);
    tes_files::check_private_dir(&dir)
        .map_err(|e| format!("{} (holding {}) {e}", dir.display(), key.display()))
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
    prepare_dir(dir)?;
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
        let first_address = first.host.address.as_deref().map_or_else(
            || format!("{}-ADDRESS", first.host.name.to_uppercase()),
            endpoint_host,
        );
        for (i, files) in self.hosts.iter().enumerate() {
            let roles: Vec<String> = files
                .host
                .roles
                .iter()
                .map(|r| toml_string(r.name()))
                .collect();
            let (listen, connect) = if i == 0 {
                let listen = toml_string(&format!("quic/0.0.0.0:{}", self.port));
                (format!("[{listen}]"), "[]".to_owned())
            } else {
                let connect = toml_string(&format!("quic/{first_address}:{}", self.port));
                ("[]".to_owned(), format!("[{connect}]"))
            };
            let _ = write!(
                text,
                "# on {name} (copy {ca}, {cert} and {key} there)\n\
                 [launch]\n\
                 roles = [{roles}]\n\
                 [launch.link]\n\
                 listen = {listen}\n\
                 connect = {connect}\n\
                 tls_ca = {ca}\n\
                 tls_cert = {cert}\n\
                 tls_key = {key}\n\n",
                name = files.host.name,
                ca = toml_string(&self.authority.display().to_string()),
                cert = toml_string(&files.cert.display().to_string()),
                key = toml_string(&files.key.display().to_string()),
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

/// The key directory, created readable only by its owner if missing; an existing one must be
/// a directory of this user's that no one else may open, or the keys in it would not be
/// private (it is refused with the `chmod` that fixes it, not changed: it may hold more than
/// keys).
fn prepare_dir(dir: &Path) -> Result<(), KeyError> {
    let refuse = |reason: String| KeyError::OpenDirectory {
        path: dir.to_owned(),
        reason,
    };
    let meta = match fs::metadata(dir) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return fs::DirBuilder::new()
                .recursive(true)
                .mode(0o700)
                .create(dir)
                .map_err(|source| KeyError::Write {
                    path: dir.to_owned(),
                    source,
                });
        }
        Err(source) => {
            return Err(KeyError::Write {
                path: dir.to_owned(),
                source,
            });
        }
    };
    if !meta.is_dir() {
        return Err(refuse(format!(
            "is {}, not a directory",
            tes_files::kind_of(meta.file_type())
        )));
    }
    if !tes_files::owned_by_this_user(&meta) {
        return Err(refuse(
            "belongs to another user, who could read or replace the keys: give a directory \
             of your own"
                .into(),
        ));
    }
    tes_files::check_private_dir(dir).map_err(|e| refuse(e.to_string()))
}

/// `text` as a TOML basic string: quoted, with `"`, `\` and control characters escaped.
fn toml_string(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 2);
    out.push('"');
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => {
                let _ = write!(out, "\\u{:04X}", u32::from(c));
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// An address as an endpoint's host: an IPv6 address in brackets, anything else as is.
fn endpoint_host(address: &str) -> String {
    match address.parse::<std::net::IpAddr>() {
        Ok(std::net::IpAddr::V6(v6)) => format!("[{v6}]"),
        _ => address.to_owned(),
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
    use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};

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
            (
                "robot=controller@x\"]\ninsecure = true",
                "is not an address",
            ),
            ("robot=controller@-bad.local", "is not an address"),
            ("robot=controller@a..b", "is not an address"),
            ("robot=controller@192.168.1.300", "is not an address"),
            ("robot=controller@robot.local:7447", "is not an address"),
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
        let set = keygen(&dir.path().join("k"), &default_hosts(), DEFAULT_PORT).expect("keys");
        let facts = read_certificate(&set.hosts[0].cert).expect("certificate");
        assert_eq!(facts.common_name, "perception-sim+bridge");
        assert!(facts.valid_now, "{facts:?}");
        let e = read_certificate(&set.hosts[0].key).expect_err("a key is not a certificate");
        assert!(e.contains("is not a PEM certificate"), "{e}");
    }

    #[test]
    fn addresses_are_ip_addresses_or_dns_names() {
        for good in [
            "192.168.1.20",
            "fd00::20",
            "robot",
            "robot.local",
            "a-b.c1.example",
        ] {
            assert!(is_address(good), "{good}");
        }
        for bad in [
            "",
            "a b",
            "x\"]",
            "robot.local.",
            "-a",
            "a-",
            "1.2.3",
            "é.local",
        ] {
            assert!(!is_address(bad), "{bad}");
        }
    }

    #[test]
    fn printed_settings_quote_what_they_paste() {
        let dir = tempfile::tempdir().expect("temp dir");
        let keys = dir.path().join("odd \"dir\"\n");
        let hosts = vec![
            "robot=perception-sim,bridge@fd00::20"
                .parse()
                .expect("host"),
            "learner=controller".parse().expect("host"),
        ];
        let set = keygen(&keys, &hosts, DEFAULT_PORT).expect("keys");
        let lines = set.launch_lines();
        assert!(
            lines.contains("connect = [\"quic/[fd00::20]:7447\"]"),
            "{lines}"
        );
        assert!(lines.contains("odd \\\"dir\\\"\\u000A/ca.pem\""), "{lines}");
        // Every line is a comment, a table, a key, or empty: nothing a path or an address
        // holds starts a line of its own.
        for line in lines.lines() {
            let starts = [
                "#",
                "[launch]",
                "[launch.link]",
                "roles =",
                "listen =",
                "connect =",
            ];
            let tls = ["tls_ca =", "tls_cert =", "tls_key ="];
            assert!(
                line.is_empty() || starts.iter().chain(&tls).any(|s| line.starts_with(s)),
                "{line:?}"
            );
        }
    }

    #[test]
    fn keygen_refuses_a_directory_others_may_open() {
        let dir = tempfile::tempdir().expect("temp dir");
        let open = dir.path().join("open");
        fs::create_dir(&open).expect("dir");
        fs::set_permissions(&open, fs::Permissions::from_mode(0o777)).expect("chmod");
        let e = keygen(&open, &default_hosts(), DEFAULT_PORT).expect_err("open directory");
        let text = e.to_string();
        assert!(text.contains("mode 0777"), "{text}");
        assert!(
            text.contains(&format!("run `chmod 700 {}`", open.display())),
            "{text}"
        );
        assert_eq!(
            fs::read_dir(&open).expect("dir").count(),
            0,
            "nothing written"
        );
        let mode = fs::metadata(&open).expect("dir").permissions().mode();
        assert_eq!(mode & 0o777, 0o777, "left as it was");
        fs::set_permissions(&open, fs::Permissions::from_mode(0o700)).expect("chmod");
        keygen(&open, &default_hosts(), DEFAULT_PORT).expect("an owner-only directory");
        let file = dir.path().join("file");
        fs::write(&file, "").expect("file");
        let e = keygen(&file, &default_hosts(), DEFAULT_PORT).expect_err("a file");
        assert!(e.to_string().contains("not a directory"), "{e}");
    }

    /// The three TLS files of a fresh key set, in their own directory.
    fn tls_files(dir: &Path) -> (PathBuf, PathBuf, PathBuf, KeySet) {
        let set = keygen(dir, &default_hosts(), DEFAULT_PORT).expect("keys");
        let host = &set.hosts[0];
        (
            set.authority.clone(),
            host.cert.clone(),
            host.key.clone(),
            set.clone(),
        )
    }

    #[test]
    fn tls_files_as_keygen_makes_them_pass() {
        let dir = tempfile::tempdir().expect("temp dir");
        let (ca, cert, key, set) = tls_files(&dir.path().join("k"));
        check_tls_files(&ca, &cert, &key).expect("a fresh set");
        check_tls_files(&ca, &set.hosts[1].cert, &set.hosts[1].key).expect("either host");
    }

    #[test]
    fn open_keys_are_refused_with_the_chmod_to_run() {
        let dir = tempfile::tempdir().expect("temp dir");
        let keys = dir.path().join("k");
        let (ca, cert, key, _) = tls_files(&keys);
        fs::set_permissions(&key, fs::Permissions::from_mode(0o644)).expect("chmod");
        let e = check_tls_files(&ca, &cert, &key).expect_err("world-readable key");
        assert_eq!(e.file, TlsFile::Key);
        assert!(
            e.reason
                .contains(&format!("run `chmod 600 {}`", key.display())),
            "{e}"
        );
        fs::set_permissions(&key, fs::Permissions::from_mode(0o600)).expect("chmod");
        fs::set_permissions(&keys, fs::Permissions::from_mode(0o777)).expect("chmod");
        let e = check_tls_files(&ca, &cert, &key).expect_err("open directory");
        assert_eq!(e.file, TlsFile::Key);
        assert!(
            e.reason
                .contains(&format!("run `chmod 700 {}`", keys.display())),
            "{e}"
        );
        fs::set_permissions(&keys, fs::Permissions::from_mode(0o700)).expect("chmod");
    }

    #[test]
    fn fifos_and_devices_as_tls_files_are_refused_without_blocking() {
        let dir = tempfile::tempdir().expect("temp dir");
        let (ca, cert, key, _) = tls_files(&dir.path().join("k"));
        let fifo = dir.path().join("k").join("fifo.key");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
        let (tx, rx) = std::sync::mpsc::channel();
        let (c, k) = (ca.clone(), fifo.clone());
        let c2 = cert.clone();
        std::thread::spawn(move || {
            let _ = tx.send(check_tls_files(&c, &c2, &k));
        });
        let result = rx
            .recv_timeout(std::time::Duration::from_secs(20))
            .unwrap_or_else(|_| {
                let _ = fs::OpenOptions::new()
                    .write(true)
                    .custom_flags(nix::libc::O_NONBLOCK)
                    .open(&fifo);
                panic!("checking a FIFO key blocked")
            });
        let e = result.expect_err("a FIFO");
        assert_eq!(e.file, TlsFile::Key);
        assert!(e.reason.contains("is a FIFO, not a regular file"), "{e}");
        let zero = Path::new("/dev/zero");
        for (file, (a, c, k)) in [
            (TlsFile::Authority, (zero, &*cert, &*key)),
            (TlsFile::Certificate, (&*ca, zero, &*key)),
            (TlsFile::Key, (&*ca, &*cert, zero)),
        ] {
            let e = check_tls_files(a, c, k).expect_err("/dev/zero");
            assert_eq!(e.file, file);
            assert!(
                e.reason
                    .contains("is a character device, not a regular file"),
                "{e}"
            );
        }
        let big = dir.path().join("k").join("big.pem");
        fs::File::create(&big)
            .and_then(|f| f.set_len(2 << 30))
            .expect("a sparse file");
        let e = check_tls_files(&big, &cert, &key).expect_err("2 GiB");
        assert!(e.reason.contains("more than the 1048576 bytes"), "{e}");
    }

    #[test]
    fn a_host_certificate_as_the_authority_is_caught() {
        let dir = tempfile::tempdir().expect("temp dir");
        let (ca, cert, key, set) = tls_files(&dir.path().join("k"));
        let e = check_tls_files(&set.hosts[1].cert, &cert, &key).expect_err("host as CA");
        assert_eq!(e.file, TlsFile::Authority);
        assert!(
            e.reason
                .contains("is not an authority's certificate but a host's"),
            "{e}"
        );
        let e = check_tls_files(&ca, &ca, &key).expect_err("CA as host");
        assert_eq!(e.file, TlsFile::Certificate);
        let (other_ca, ..) = tls_files(&dir.path().join("other"));
        let e = check_tls_files(&other_ca, &cert, &key).expect_err("another group's CA");
        assert!(
            e.reason.contains("was not issued by the authority in"),
            "{e}"
        );
        let e = check_tls_files(&ca, &cert, &cert).expect_err("a certificate as the key");
        assert_eq!(e.file, TlsFile::Key);
        assert!(e.reason.contains("not a private key"), "{e}");
    }

    #[test]
    fn this_year_is_plausible() {
        assert!((2026..2200).contains(&this_year()));
    }
}
