//! Why the link could not be opened.

use tes_runtime::channel::IpcError;

/// Why [`Link::open`](crate::Link::open) (or [`LinkSection::zenoh_config`](crate::LinkSection::zenoh_config))
/// failed. Each message says the whole of it, the cause included, so none has a
/// [`source`](std::error::Error::source) to print again.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// A value of the table Zenoh's configuration refused.
    #[error("zenoh config {key} = {value}: {message}")]
    Config {
        /// The configuration key.
        key: &'static str,
        /// The value given, as JSON5.
        value: String,
        /// Zenoh's reason.
        message: String,
    },
    /// The Zenoh session could not be opened.
    #[error("cannot open the link (listen {listen:?}, connect {connect:?}): {reason}")]
    Open {
        /// The endpoints to listen on.
        listen: Vec<String>,
        /// The endpoints to connect to.
        connect: Vec<String>,
        /// Zenoh's error in the link's words, with the fix where one is known.
        reason: String,
    },
    /// The directory of the private socket could not be made, or others may enter it.
    #[error("cannot open the link on this host's private socket: {0}")]
    PrivateSocket(String),
    /// The liveliness subscriber that watches the group's members could not be declared.
    #[error("cannot watch the group's members on Zenoh: {0}")]
    WatchMembers(zenoh::Error),
    /// The subscriber to the group's stop key could not be declared.
    #[error("cannot subscribe on Zenoh: {0}")]
    WatchStops(zenoh::Error),
    /// The publisher of the group's stop key could not be declared.
    #[error("cannot publish on Zenoh: {0}")]
    StopPublisher(zenoh::Error),
    /// A subscriber to a service of a peer could not be declared.
    #[error("cannot subscribe to {key} on Zenoh: {error}")]
    Subscribe {
        /// The full key, `GROUP/TOPIC`.
        key: String,
        /// Zenoh's error.
        error: zenoh::Error,
    },
    /// A publisher of a local service could not be declared.
    #[error("cannot publish {key} on Zenoh: {error}")]
    Publish {
        /// The full key, `GROUP/TOPIC`.
        key: String,
        /// Zenoh's error.
        error: zenoh::Error,
    },
    /// A local iceoryx2 service (or the node) could not be opened.
    #[error("the link cannot open the local services: {0}")]
    LocalServices(IpcError),
    /// The forwarding threads did not say they had their ports within 30 s.
    #[error("the link's threads did not open the local services")]
    NotReady,
    /// A thread of the link could not be started.
    #[error("cannot start the link's thread: {0}")]
    Thread(std::io::Error),
    /// The liveliness token of a local role could not be declared.
    #[error("cannot announce this launch on Zenoh: {0}")]
    Announce(zenoh::Error),
}
