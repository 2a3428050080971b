//! The `[launch.link]` table: how a launch with roles reaches its peers.

use serde::{Deserialize, Serialize};
use tes_runtime::settings::SettingError;

use crate::LinkError;

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
    /// only; a host that other machines connect to names an address of its own, e.g.
    /// `["tcp/192.168.1.20:7447"]`.
    ///
    /// Values: list of TCP endpoints (`tcp/ADDRESS:PORT`).
    pub listen: Vec<String>,
    /// The peers (or the router) this launch connects to.
    ///
    /// Values: list of TCP endpoints (`tcp/ADDRESS:PORT`).
    pub connect: Vec<String>,
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

/// Whether `endpoint` is a Zenoh TCP endpoint.
fn is_tcp_endpoint(endpoint: &str) -> bool {
    endpoint.parse::<zenoh::config::EndPoint>().is_ok() && endpoint.starts_with("tcp/")
}

impl LinkSection {
    /// Checks the table: a usable group name, TCP endpoints, a way to reach a peer, a peer
    /// timeout of at least 100 ms. The error names the key within `[launch]`
    /// (`link.group`, `link.listen`, `link.connect`, `link.peer_timeout_ms`).
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
        for (key, endpoints) in [
            ("link.listen", &self.listen),
            ("link.connect", &self.connect),
        ] {
            if let Some(bad_one) = endpoints.iter().find(|e| !is_tcp_endpoint(e)) {
                return bad(
                    key,
                    format!("{bad_one:?} is not a TCP endpoint such as \"tcp/192.168.1.20:7447\""),
                );
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

    /// The Zenoh configuration: mode, endpoints, scouting.
    pub fn zenoh_config(&self) -> Result<zenoh::Config, LinkError> {
        let mut config = zenoh::Config::default();
        let json = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
        let mode = match self.mode {
            Mode::Peer => "\"peer\"",
            Mode::Client => "\"client\"",
        };
        let multicast = self.multicast_scouting.unwrap_or(self.connect.is_empty());
        for (key, value) in [
            ("mode", mode.to_owned()),
            ("listen/endpoints", json(&self.listen)),
            ("connect/endpoints", json(&self.connect)),
            ("scouting/multicast/enabled", multicast.to_string()),
            // Peers a peer learns of from another are connected to as well.
            ("scouting/gossip/enabled", "true".into()),
        ] {
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
        assert!(reason.contains("is not a TCP endpoint"), "{reason}");
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
}
