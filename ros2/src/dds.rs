//! The ROS 2 node: a DDS participant (RustDDS, through `ros2-client`) in the domain of
//! `ROS_DOMAIN_ID`, named `/tes/<name>`, with a publisher per [`Topic`] at the QoS ROS 2's
//! own publishers of those topics use.
//!
//! What it reaches: RustDDS (0.11) discovers peers by UDP multicast and answers them on every
//! network interface of the host that has multicast, never on loopback
//! (`rustdds::network::util` leaves loopback out, and its participant builder's
//! `only_networks` is a placeholder that nothing reads), so it cannot be confined to the host
//! as ROS 2's `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` confines rclcpp. [`Reach`] says which
//! interfaces carry it, for the launch to say at start; a launch whose environment asks for
//! localhost only ([`DiscoveryRange`]) is refused rather than published wider.

use ros2_client::ros2::{QosPolicies, QosPolicyBuilder, policy};
use ros2_client::{Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions};

use crate::msg::{Definition, Float64, Log, MarkerArray, Path, Text, TfMessage, UInt32};
use crate::scene::{Delivery, RosMessage, Sink, Topic};

/// The highest domain id ROS 2 allows on Linux (its ports must fit in 16 bits).
pub const DOMAIN_MAX: u16 = 232;

/// Why the node cannot start or publish.
#[derive(Debug, thiserror::Error)]
pub enum DdsError {
    /// `ROS_DOMAIN_ID` is not a domain id.
    #[error("ROS_DOMAIN_ID={0:?} is not a ROS 2 domain id (0 to {DOMAIN_MAX})")]
    Domain(String),
    /// `ROS_AUTOMATIC_DISCOVERY_RANGE` is not one of ROS 2's values.
    #[error(
        "ROS_AUTOMATIC_DISCOVERY_RANGE={0:?} is not one of ROS 2's ranges (SYSTEM_DEFAULT, \
         SUBNET, LOCALHOST, OFF)"
    )]
    Range(String),
    /// The environment asks for this host only, which RustDDS cannot keep to.
    #[error(
        "{asked} asks to keep ROS 2 on this host, but TES's DDS (RustDDS) discovers and \
         answers on every multicast interface and never on loopback, so it would be seen on \
         {interfaces}; unset it to publish with that reach, or run in a network namespace \
         without those interfaces"
    )]
    CannotKeepLocal {
        /// The setting, as the environment has it.
        asked: String,
        /// The interfaces beyond loopback.
        interfaces: String,
    },
    /// The DDS participant, node, topic or publisher cannot be created.
    #[error("cannot create the ROS 2 {what}: {reason}")]
    Create {
        /// What.
        what: String,
        /// Why, as RustDDS says it.
        reason: String,
    },
}

/// The domain of `ROS_DOMAIN_ID` (0 when unset or empty, as in ROS 2).
pub fn domain_from_env() -> Result<u16, DdsError> {
    match std::env::var("ROS_DOMAIN_ID") {
        Ok(text) if !text.trim().is_empty() => parse_domain(&text),
        _ => Ok(0),
    }
}

/// How far ROS 2 discovery may reach, as ROS 2's environment says it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub enum DiscoveryRange {
    /// ROS 2's default (`SUBNET` since Iron, the whole network before): RustDDS's own reach.
    #[default]
    Default,
    /// This host only (`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` or `OFF`, or Humble's
    /// `ROS_LOCALHOST_ONLY=1`); the setting as given.
    HostOnly(String),
}

/// The range ROS 2's environment asks for: `ROS_AUTOMATIC_DISCOVERY_RANGE`, else
/// `ROS_LOCALHOST_ONLY`.
pub fn range_from_env() -> Result<DiscoveryRange, DdsError> {
    let var = |name| {
        std::env::var(name)
            .ok()
            .filter(|v: &String| !v.trim().is_empty())
    };
    parse_range(
        var("ROS_AUTOMATIC_DISCOVERY_RANGE").as_deref(),
        var("ROS_LOCALHOST_ONLY").as_deref(),
    )
}

/// [`range_from_env`] on given values.
pub fn parse_range(
    automatic: Option<&str>,
    localhost_only: Option<&str>,
) -> Result<DiscoveryRange, DdsError> {
    match automatic.map(str::trim) {
        Some(r @ ("LOCALHOST" | "OFF")) => Ok(DiscoveryRange::HostOnly(format!(
            "ROS_AUTOMATIC_DISCOVERY_RANGE={r}"
        ))),
        Some("SUBNET" | "SYSTEM_DEFAULT") => Ok(DiscoveryRange::Default),
        Some(other) => Err(DdsError::Range(other.to_owned())),
        None if localhost_only.map(str::trim) == Some("1") => {
            Ok(DiscoveryRange::HostOnly("ROS_LOCALHOST_ONLY=1".to_owned()))
        }
        None => Ok(DiscoveryRange::Default),
    }
}

/// A domain id as `ROS_DOMAIN_ID` gives it.
pub fn parse_domain(text: &str) -> Result<u16, DdsError> {
    text.trim()
        .parse::<u16>()
        .ok()
        .filter(|d| *d <= DOMAIN_MAX)
        .ok_or_else(|| DdsError::Domain(text.to_owned()))
}

/// Where the node's DDS traffic goes: the host's interfaces that are up, by name and address.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reach {
    /// The domain.
    pub domain: u16,
    /// Interfaces other than loopback that are up, with an address (`eth0 192.0.2.2`).
    pub beyond_loopback: Vec<String>,
}

impl Reach {
    /// The interfaces of this host, as the kernel lists them now.
    pub fn of_this_host(domain: u16) -> Self {
        Self {
            domain,
            beyond_loopback: interfaces_beyond_loopback(),
        }
    }

    /// Whether peers on other hosts can reach the node.
    pub fn is_local(&self) -> bool {
        self.beyond_loopback.is_empty()
    }

    /// Refuses a reach wider than `range` allows.
    pub fn allowed_by(&self, range: &DiscoveryRange) -> Result<(), DdsError> {
        match range {
            DiscoveryRange::HostOnly(asked) if !self.is_local() => Err(DdsError::CannotKeepLocal {
                asked: asked.clone(),
                interfaces: self.beyond_loopback.join(", "),
            }),
            _ => Ok(()),
        }
    }
}

impl std::fmt::Display for Reach {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ROS 2 domain {}", self.domain)?;
        if self.is_local() {
            write!(
                f,
                ", no interface but loopback is up (RustDDS never uses loopback: no peer may \
                 hear it)"
            )
        } else {
            write!(
                f,
                ", reachable beyond this host on {} (DDS discovery by multicast; RustDDS cannot \
                 be held to loopback)",
                self.beyond_loopback.join(", ")
            )
        }
    }
}

/// The non-loopback IPv4 interfaces that are up, from `/proc/net/route`'s view of the host's
/// addresses (`ip -brief addr` says the same): read through `getifaddrs`.
fn interfaces_beyond_loopback() -> Vec<String> {
    let Ok(addrs) = nix::ifaddrs::getifaddrs() else {
        return Vec::new();
    };
    let mut found: Vec<String> = addrs
        .filter(|a| {
            a.flags.contains(nix::net::if_::InterfaceFlags::IFF_UP)
                && !a
                    .flags
                    .contains(nix::net::if_::InterfaceFlags::IFF_LOOPBACK)
        })
        .filter_map(|a| {
            let ip = a.address?.as_sockaddr_in()?.ip();
            Some(format!("{} {ip}", a.interface_name))
        })
        .collect();
    found.sort();
    found.dedup();
    found
}

/// The ROS 2 node and its publishers.
pub struct RosNode {
    // Dropped after the publishers (declared first, dropped first): the node, then the
    // participant.
    tf: ros2_client::Publisher<TfMessage>,
    arena: ros2_client::Publisher<MarkerArray>,
    path: ros2_client::Publisher<Path>,
    action: ros2_client::Publisher<UInt32>,
    latency: ros2_client::Publisher<Float64>,
    reward: ros2_client::Publisher<Float64>,
    episode_end: ros2_client::Publisher<Text>,
    rosout: ros2_client::Publisher<Log>,
    _node: ros2_client::Node,
    _context: Context,
    reach: Reach,
}

impl std::fmt::Debug for RosNode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RosNode")
            .field("reach", &self.reach)
            .finish_non_exhaustive()
    }
}

/// `r`, or the DDS entity `what` that could not be created, and why.
pub(crate) fn create<T, E: std::fmt::Display>(what: &str, r: Result<T, E>) -> Result<T, DdsError> {
    r.map_err(|e| DdsError::Create {
        what: what.to_owned(),
        reason: e.to_string(),
    })
}

/// The QoS of `topic` in DDS terms.
pub fn qos_of(topic: Topic) -> QosPolicies {
    let q = topic.qos();
    let durability = if q.transient_local {
        policy::Durability::TransientLocal
    } else {
        policy::Durability::Volatile
    };
    QosPolicyBuilder::new()
        .history(policy::History::KeepLast { depth: q.depth })
        .reliability(policy::Reliability::Reliable {
            max_blocking_time: ros2_client::ros2::Duration::from_millis(100),
        })
        .durability(durability)
        .build()
}

/// A node of TES in a domain: the DDS participant, the node, and where they reach. (A
/// node's publishers and subscriptions must be dropped before it: the structs that hold them
/// declare these after them.)
pub(crate) struct Joined {
    pub(crate) node: ros2_client::Node,
    pub(crate) context: Context,
    pub(crate) reach: Reach,
}

impl Joined {
    /// Joins `domain` as node `/tes/<name>`, unless `range` asks for less reach than
    /// RustDDS has here.
    pub(crate) fn start(domain: u16, range: &DiscoveryRange, name: &str) -> Result<Self, DdsError> {
        let reach = Reach::of_this_host(domain);
        reach.allowed_by(range)?;
        let context = create(
            "DDS participant",
            Context::with_options(ContextOptions::new().domain_id(domain)),
        )?;
        let node_name = create("node name", NodeName::new("/tes", name))?;
        let node = create(
            "node",
            context.new_node(node_name, NodeOptions::new().enable_rosout(false)),
        )?;
        Ok(Self {
            node,
            context,
            reach,
        })
    }
}

impl RosNode {
    /// Joins `domain` as node `/tes/<name>` and creates its publishers, unless `range` asks
    /// for less reach than RustDDS has here. RustDDS starts its own threads here, with the
    /// calling thread's priority and CPU placement.
    pub fn start(domain: u16, range: &DiscoveryRange, name: &str) -> Result<Self, DdsError> {
        let Joined {
            mut node,
            context,
            reach,
        } = Joined::start(domain, range, name)?;
        macro_rules! publisher {
            ($topic:expr) => {{
                let of: Topic = $topic;
                let t = topic(&mut node, of.name(), of.definition(), &qos_of(of))?;
                create(of.name(), node.create_publisher(&t, Some(qos_of(of))))?
            }};
        }
        Ok(Self {
            tf: publisher!(Topic::Tf),
            arena: publisher!(Topic::Arena),
            path: publisher!(Topic::Path),
            action: publisher!(Topic::Action),
            latency: publisher!(Topic::Latency),
            reward: publisher!(Topic::Reward),
            episode_end: publisher!(Topic::EpisodeEnd),
            rosout: publisher!(Topic::Rosout),
            _node: node,
            _context: context,
            reach,
        })
    }

    /// Where it is reachable.
    pub fn reach(&self) -> &Reach {
        &self.reach
    }
}

/// A ROS 2 topic of `node` named `ros_name` (`/tes/world/map`), of type `d`.
pub(crate) fn topic(
    node: &mut ros2_client::Node,
    ros_name: &str,
    d: &Definition,
    qos: &QosPolicies,
) -> Result<ros2_client::rustdds::Topic, DdsError> {
    let (ns, base) = ros_name.rsplit_once('/').unwrap_or(("/", ros_name));
    let ns = if ns.is_empty() { "/" } else { ns };
    let name = create(ros_name, Name::new(ns, base))?;
    create(
        ros_name,
        node.create_topic(&name, MessageTypeName::new(d.package, d.name), qos),
    )
}

/// Reliable, keep-last `depth`, transient-local when `latched`.
pub(crate) fn reliable(depth: i32, latched: bool) -> QosPolicies {
    let durability = if latched {
        policy::Durability::TransientLocal
    } else {
        policy::Durability::Volatile
    };
    QosPolicyBuilder::new()
        .history(policy::History::KeepLast { depth })
        .reliability(policy::Reliability::Reliable {
            max_blocking_time: ros2_client::ros2::Duration::from_millis(100),
        })
        .durability(durability)
        .build()
}

/// A message the node could not hand to DDS (a reader that keeps a reliable writer waiting
/// past its blocking time); counted, never fatal.
#[derive(Debug, Clone, Copy)]
pub struct NotPublished;

impl Sink for RosNode {
    type Error = NotPublished;

    fn put(&mut self, m: &RosMessage, _wall_ns: u64, _: Delivery) -> Result<(), NotPublished> {
        let sent = match m.clone() {
            RosMessage::Tf(x) => self.tf.publish(x).is_ok(),
            RosMessage::Arena(x) => self.arena.publish(x).is_ok(),
            RosMessage::Path(x) => self.path.publish(x).is_ok(),
            RosMessage::Action(x) => self.action.publish(x).is_ok(),
            RosMessage::Latency(x) => self.latency.publish(x).is_ok(),
            RosMessage::Reward(x) => self.reward.publish(x).is_ok(),
            RosMessage::EpisodeEnd(x) => self.episode_end.publish(x).is_ok(),
            RosMessage::Rosout(x) => self.rosout.publish(x).is_ok(),
        };
        if sent { Ok(()) } else { Err(NotPublished) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_domain_id_is_0_to_232() {
        assert_eq!(parse_domain(" 7 ").unwrap(), 7);
        assert_eq!(parse_domain("232").unwrap(), 232);
        for bad in ["233", "-1", "x", "70000"] {
            let e = parse_domain(bad).unwrap_err();
            assert!(e.to_string().contains("0 to 232"), "{e}");
        }
    }

    #[test]
    fn the_reach_says_whether_other_hosts_see_the_node() {
        let local = Reach {
            domain: 3,
            beyond_loopback: vec![],
        };
        assert!(
            local
                .to_string()
                .starts_with("ROS 2 domain 3, no interface but loopback is up"),
            "{local}"
        );
        let wide = Reach {
            domain: 0,
            beyond_loopback: vec!["eth0 192.0.2.2".into()],
        };
        assert!(
            wide.to_string()
                .contains("reachable beyond this host on eth0 192.0.2.2")
        );
    }

    #[test]
    fn localhost_only_is_refused_when_other_interfaces_are_up() {
        let host_only = parse_range(Some("LOCALHOST"), None).unwrap();
        assert_eq!(
            host_only,
            DiscoveryRange::HostOnly("ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST".into())
        );
        assert_eq!(
            parse_range(None, Some("1")).unwrap(),
            DiscoveryRange::HostOnly("ROS_LOCALHOST_ONLY=1".into())
        );
        // The newer setting wins over the older, as in ROS 2.
        assert_eq!(
            parse_range(Some("SUBNET"), Some("1")).unwrap(),
            DiscoveryRange::Default
        );
        assert_eq!(
            parse_range(None, Some("0")).unwrap(),
            DiscoveryRange::Default
        );
        assert!(
            parse_range(Some("LAN"), None)
                .unwrap_err()
                .to_string()
                .contains("LAN")
        );
        let wide = Reach {
            domain: 0,
            beyond_loopback: vec!["eth0 192.0.2.2".into()],
        };
        let e = wide.allowed_by(&host_only).unwrap_err().to_string();
        assert!(
            e.contains("LOCALHOST") && e.contains("eth0 192.0.2.2"),
            "{e}"
        );
        assert!(wide.allowed_by(&DiscoveryRange::Default).is_ok());
        let local = Reach {
            domain: 0,
            beyond_loopback: vec![],
        };
        assert!(local.allowed_by(&host_only).is_ok());
    }
}
