#![doc = r#"
The link: a launch that starts only some of the group's processes (`tes launch --roles`,
`[launch] roles`) reaches the others, on other hosts, through one Zenoh session.

The link runs in the launcher. It forwards each local service a remote process reads —
a process's payload as the fixed-size bytes of its `#[repr(C)]` struct
([`tes_topics::wire`]), one Zenoh key per service under `[launch.link] group` — and, on
receipt, checks each payload ([`tes_topics::wire::Checker`]), republishes what passes into
the local iceoryx2 service and notifies its event, so the processes themselves are
unchanged and never see a raw network sample. What it refuses it counts and reports.

Each launch declares a Zenoh liveliness token per local role (`GROUP/member/ROLE/ZID`):
that is how a launch knows its peers are there, that a role is played twice, and that a
peer's host is gone (its session ended). Every payload it forwards carries its session's id
as an attachment, and a launch takes a service only from the session whose token claims the
role that writes it: another session's samples are dropped before the checks, so they
cannot move the checker's state (a sequence number far ahead) and shut the writer out. A launch that stops tells its peers why
(`GROUP/stop`), so they stop too.

Which services cross, by who writes and who reads them (each a [`Topic`]):

| service | writer → readers | key |
|---|---|---|
| observation (publish–subscribe) | perception → controller | `GROUP/observation` |
| world map (publish–subscribe, history 1) | perception → controller (and every host, to check commands) | `GROUP/world-map` |
| command (blackboard) | controller → bridge | `GROUP/command` |
| motor state (publish–subscribe) | bridge → perception | `GROUP/motor-state` |
| progress of each role (publish–subscribe, history 1) | the role → everyone | `GROUP/progress/ROLE` |

# Overview

- [`LinkSection`] is the `[launch.link]` table; [`LinkSection::check`] refuses a bad key
  with a [`SettingError`](tes_runtime::settings::SettingError).
- [`Link::open`] opens the session, announces the local roles and starts forwarding;
  [`Link::events`] says what happened since the last look ([`LinkEvent`]: a peer joined or
  left, a role played twice, a peer stopped the group, a payload refused);
  [`Link::send_stop`] tells the peers this launch stops; [`Link::counts`] says what crossed.
- [`Topic`] names the services that cross, their keys, writers and readers.
- [`LinkError`] says why the link could not be opened.
- [`keys`] makes the group's own authority and host certificates (`tes link keygen`); with
  them the link runs over QUIC with mutual TLS 1.3, and [`access_control`] lets a peer
  publish only what the roles in its certificate write ([`LinkSection::security`] says how a
  launch's link is protected).
- [`refusals`] picks the connections and messages Zenoh refused out of its log, for
  [`LinkEvent::Denied`].

Which topics a robot host (perception and the bridge) and a learning host (the controller)
exchange:

```
use tes_link::{LinkSection, Topic};
use tes_topics::Role;

let settings = LinkSection::default();
settings.check()?;
let robot = [Role::Perception, Role::Bridge];
let sent: Vec<&str> = Topic::ALL.into_iter().filter(|t| t.goes_out(&robot)).map(Topic::key).collect();
assert_eq!(sent, ["observation", "world-map", "progress/perception-sim", "progress/bridge"]);
let taken: Vec<Topic> = Topic::ALL.into_iter().filter(|t| t.comes_in(&robot)).collect();
assert_eq!(taken, [Topic::Command, Topic::Progress(Role::Controller)]);
# Ok::<(), Box<dyn std::error::Error>>(())
```

The launcher's side (it needs the peers, so it is not run here):

```no_run
use std::time::Duration;
use tes_link::{Link, LinkEvent, LinkSection};
use tes_topics::{Role, ServiceNames};

// No endpoints and no keys: the launches of this host meet on a Unix socket only this
// user can reach.
let settings = LinkSection::default();
let mut link = Link::open(&settings, &[Role::Perception, Role::Bridge], &ServiceNames::with_prefix("tes/"))?;
while !link.missing().is_empty() {
    std::thread::sleep(Duration::from_millis(100));
}
// … start the local processes, then watch:
for event in link.events() {
    if let LinkEvent::Stop { clean, reason } = event {
        println!("a peer stopped the group (clean: {clean}): {reason}");
    }
}
link.send_stop(true, "episodes done");
println!("link: {}", link.counts());
link.close();
# Ok::<(), Box<dyn std::error::Error>>(())
```
"#]

mod error;
mod inbound;
pub mod keys;
mod link;
mod outbound;
pub mod refusals;
mod settings;
mod shared;
mod topic;

pub use error::LinkError;
pub use link::{Endpoints, Link, LinkCounts};
pub use settings::{
    DEFAULT_LEASE_MS, GROUP_NAME_MAX, LinkSection, MIN_LEASE_MS, MIN_PEER_TIMEOUT_MS, Mode,
    Security, access_control,
};
pub use shared::LinkEvent;
pub use topic::Topic;
