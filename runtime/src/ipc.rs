//! The iceoryx2 plumbing every TES process shares: its node, its error, the settings of every
//! publish–subscribe service, and the clean-up of resources dead processes left behind.

use std::fmt;

use iceoryx2::prelude::*;

use crate::channel::{BUFFER, Listener};

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

/// Creates a process's iceoryx2 node with an explicit default config (no "no config file"
/// warning); `handle_signals` lets iceoryx2 turn SIGINT/SIGTERM into a termination request
/// (a launcher that handles signals itself passes `false`).
pub fn node(handle_signals: bool) -> Result<Node<ipc::Service>, IpcError> {
    let mode = if handle_signals {
        SignalHandlingMode::HandleTerminationRequests
    } else {
        SignalHandlingMode::Disabled
    };
    NodeBuilder::new()
        .config(&Config::default())
        .signal_handling_mode(mode)
        .create::<ipc::Service>()
        .map_err(ipc_err("create the node"))
}

/// Removes the iceoryx2 resources (shared memory, event and service files) left behind by
/// nodes whose process died without cleaning up; returns how many dead nodes were cleaned.
pub fn clean_stale_resources() -> Result<usize, IpcError> {
    let mut cleaned = 0;
    let mut failures = Vec::new();
    Node::<ipc::Service>::list(&Config::default(), |state| {
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
pub fn pubsub<T: ZeroCopySend + Copy + fmt::Debug + 'static>(
    node: &Node<ipc::Service>,
    name: &str,
    history: usize,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>,
    IpcError,
> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .history_size(history)
        .subscriber_max_buffer_size(history.max(BUFFER))
        .open_or_create()
        .map_err(ipc_err("open a publish-subscribe service"))
}

/// The names of the iceoryx2 services that exist now and start with `prefix` (to check that a
/// stopped group left nothing behind).
pub fn services_with_prefix(prefix: &str) -> Result<Vec<String>, IpcError> {
    use iceoryx2::service::Service as _;
    let mut names = Vec::new();
    ipc::Service::list(&Config::default(), |service| {
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
pub(crate) fn notifier(
    node: &Node<ipc::Service>,
    event: &str,
) -> Result<iceoryx2::port::notifier::Notifier<ipc::Service>, IpcError> {
    node.service_builder(&service_name(event)?)
        .event()
        .open_or_create()
        .map_err(ipc_err("open an event service"))?
        .notifier_builder()
        .create()
        .map_err(ipc_err("create a notifier"))
}

/// A listener on the event service `event` (opened or created).
pub(crate) fn listener(node: &Node<ipc::Service>, event: &str) -> Result<Listener, IpcError> {
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
