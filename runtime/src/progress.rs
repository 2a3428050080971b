//! Each process's [`Progress`] report: published a few times a second by the process
//! ([`ProgressOutbox`]), read by whoever watches the group ([`ProgressWatch`]: the launcher's
//! stall detector, `tes` tools).
//!
//! A report is published off the acting path — after a command is out, or while the process
//! waits — and at most once per [`ProgressOutbox::PERIOD`], so it costs the loop one clock
//! comparison per step. A process that stops publishing (stopped, wedged, or dead) is the
//! watcher's first clue; the sequence numbers in the reports tell which process holds the loop
//! up when every process still reports.

use std::time::Duration;

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use tes_topics::{Progress, Role, ServiceNames};

use crate::clock::monotonic_ns;
use crate::ipc::{IpcError, ipc_err, pubsub};

/// A process's progress publisher.
pub struct ProgressOutbox {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, Progress, ()>,
    report: Progress,
    last_ns: u64,
}

impl std::fmt::Debug for ProgressOutbox {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProgressOutbox")
            .field("report", &self.report)
            .finish_non_exhaustive()
    }
}

impl ProgressOutbox {
    /// How often a report is published at most.
    pub const PERIOD: Duration = Duration::from_millis(250);

    /// Opens `role`'s progress service of the group `names` and publishes a first report.
    pub fn open(
        node: &Node<ipc::Service>,
        names: &ServiceNames,
        role: Role,
    ) -> Result<Self, IpcError> {
        let service = pubsub::<Progress, _>(node, names.progress_of(role), 1)?;
        let publisher = service
            .publisher_builder()
            .create()
            .map_err(ipc_err("create a progress publisher"))?;
        let now = monotonic_ns();
        let mut outbox = Self {
            publisher,
            report: Progress {
                started_ns: now,
                pid: std::process::id(),
                role: role as u32,
                ..Progress::default()
            },
            last_ns: 0,
        };
        outbox.publish(now)?;
        Ok(outbox)
    }

    /// The report to fill in; published by the next [`publish_due`](Self::publish_due).
    pub fn report_mut(&mut self) -> &mut Progress {
        &mut self.report
    }

    /// Publishes the report if [`PERIOD`](Self::PERIOD) has passed since the last one.
    pub fn publish_due(&mut self, now_ns: u64) -> Result<bool, IpcError> {
        if now_ns.saturating_sub(self.last_ns) < Self::PERIOD.as_nanos() as u64 {
            return Ok(false);
        }
        self.publish(now_ns)?;
        Ok(true)
    }

    /// Publishes the report now.
    pub fn publish(&mut self, now_ns: u64) -> Result<(), IpcError> {
        self.report.stamp_ns = now_ns;
        self.last_ns = now_ns;
        self.publisher
            .send_copy(self.report)
            .map_err(ipc_err("publish a progress report"))?;
        Ok(())
    }
}

/// The latest progress report of each process of a group.
pub struct ProgressWatch {
    subscribers: Vec<iceoryx2::port::subscriber::Subscriber<ipc::Service, Progress, ()>>,
    latest: [Option<Progress>; 3],
}

impl std::fmt::Debug for ProgressWatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProgressWatch")
            .field("latest", &self.latest)
            .finish_non_exhaustive()
    }
}

impl ProgressWatch {
    /// Subscribes to the progress of every process of the group `names`.
    pub fn open(node: &Node<ipc::Service>, names: &ServiceNames) -> Result<Self, IpcError> {
        let mut subscribers = Vec::with_capacity(Role::ALL.len());
        for role in Role::ALL {
            let service = pubsub::<Progress, _>(node, names.progress_of(role), 1)?;
            let subscriber = service
                .subscriber_builder()
                .create()
                .map_err(ipc_err("create a progress subscriber"))?;
            subscriber
                .update_connections()
                .map_err(ipc_err("connect a progress subscriber"))?;
            subscribers.push(subscriber);
        }
        Ok(Self {
            subscribers,
            latest: [None; 3],
        })
    }

    /// Takes every report published since the last call; returns whether any came.
    pub fn poll(&mut self) -> Result<bool, IpcError> {
        let mut any = false;
        for (i, subscriber) in self.subscribers.iter().enumerate() {
            while let Some(sample) = subscriber
                .receive()
                .map_err(ipc_err("receive a progress report"))?
            {
                self.latest[i] = Some(*sample);
                any = true;
            }
        }
        Ok(any)
    }

    /// `role`'s latest report, if it sent one.
    pub fn latest(&self, role: Role) -> Option<&Progress> {
        self.latest[role as usize - 1].as_ref()
    }

    /// Forgets `role`'s reports (after it was respawned: its successor reports afresh).
    pub fn forget(&mut self, role: Role) {
        self.latest[role as usize - 1] = None;
    }
}

/// Which process holds a stalled group up, and why, from the latest reports.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holdup {
    /// The process.
    pub role: Role,
    /// What it has not done, for the launcher's message.
    pub why: String,
}

impl std::fmt::Display for Holdup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {}", self.role.name(), self.why)
    }
}

/// The process that holds a group up, judged from each process's latest report at `now_ns`
/// (`None` for a process that never reported): first a process whose reports stopped for
/// longer than `quiet`, then the first process along the loop observation → command → motion
/// that has not passed on what it was given.
pub fn holdup(latest: &[Option<Progress>; 3], now_ns: u64, quiet: Duration) -> Holdup {
    let quiet_ns = quiet.as_nanos() as u64;
    for role in Role::ALL {
        let silent_for = |stamp: u64| Duration::from_nanos(now_ns.saturating_sub(stamp));
        match &latest[role as usize - 1] {
            None => {
                return Holdup {
                    role,
                    why: "never reported its progress".into(),
                };
            }
            Some(p) if now_ns.saturating_sub(p.stamp_ns) > quiet_ns => {
                return Holdup {
                    role,
                    why: format!(
                        "stopped reporting {:.1} s ago (pid {})",
                        silent_for(p.stamp_ns).as_secs_f64(),
                        p.pid
                    ),
                };
            }
            Some(_) => {}
        }
    }
    let [Some(perception), Some(controller), Some(bridge)] = latest else {
        unreachable!("every role reported (checked above)")
    };
    if bridge.flags & tes_topics::progress_flags::LINK_DOWN != 0 {
        return Holdup {
            role: Role::Bridge,
            why: "has no link to the brick".into(),
        };
    }
    if perception.out_seq > controller.in_seq {
        return Holdup {
            role: Role::Controller,
            why: format!(
                "has not answered observation {} (its last answer was to {})",
                perception.out_seq, controller.in_seq
            ),
        };
    }
    if controller.out_seq > bridge.in_seq {
        return Holdup {
            role: Role::Bridge,
            why: format!(
                "has not executed command {} (it last executed {})",
                controller.out_seq, bridge.in_seq
            ),
        };
    }
    if bridge.out_seq < bridge.in_seq {
        return Holdup {
            role: Role::Bridge,
            why: format!(
                "has not reported the motion of command {} finished",
                bridge.in_seq
            ),
        };
    }
    Holdup {
        role: Role::Perception,
        why: format!(
            "has not published an observation after the motion of command {} (its last \
             observation followed command {})",
            bridge.out_seq, perception.in_seq
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    fn report(role: Role, stamp_s: u64, in_seq: u64, out_seq: u64) -> Option<Progress> {
        Some(Progress {
            stamp_ns: stamp_s * S,
            role: role as u32,
            pid: 100 + role as u32,
            in_seq,
            out_seq,
            ..Progress::default()
        })
    }

    /// Each process in turn holds the loop up, and is named for what it has not done.
    #[test]
    fn the_process_that_holds_the_loop_up_is_named() {
        let quiet = Duration::from_secs(2);
        let cases = [
            // perception published observation 8, the controller answered 7 with command 5.
            (
                [
                    report(Role::Perception, 10, 4, 8),
                    report(Role::Controller, 10, 7, 5),
                    report(Role::Bridge, 10, 4, 4),
                ],
                Role::Controller,
                "has not answered observation 8",
            ),
            (
                [
                    report(Role::Perception, 10, 4, 8),
                    report(Role::Controller, 10, 8, 5),
                    report(Role::Bridge, 10, 4, 4),
                ],
                Role::Bridge,
                "has not executed command 5",
            ),
            (
                [
                    report(Role::Perception, 10, 4, 8),
                    report(Role::Controller, 10, 8, 5),
                    report(Role::Bridge, 10, 5, 4),
                ],
                Role::Bridge,
                "has not reported the motion of command 5",
            ),
            (
                [
                    report(Role::Perception, 10, 4, 8),
                    report(Role::Controller, 10, 8, 5),
                    report(Role::Bridge, 10, 5, 5),
                ],
                Role::Perception,
                "has not published an observation after the motion of command 5",
            ),
            // A process whose reports stopped comes first, whatever the numbers say.
            (
                [
                    report(Role::Perception, 10, 4, 8),
                    report(Role::Controller, 10, 7, 5),
                    report(Role::Bridge, 5, 5, 5),
                ],
                Role::Bridge,
                "stopped reporting 6.0 s ago (pid 103)",
            ),
            (
                [report(Role::Perception, 10, 4, 8), None, None],
                Role::Controller,
                "never reported",
            ),
        ];
        for (latest, role, why) in cases {
            let h = holdup(&latest, 11 * S, quiet);
            assert_eq!(h.role, role, "{h}");
            assert!(h.why.contains(why), "{h}");
        }
        let mut down = [
            report(Role::Perception, 10, 4, 8),
            report(Role::Controller, 10, 8, 5),
            report(Role::Bridge, 10, 5, 4),
        ];
        if let Some(b) = down[2].as_mut() {
            b.flags = tes_topics::progress_flags::LINK_DOWN;
        }
        assert_eq!(
            holdup(&down, 11 * S, quiet).to_string(),
            "bridge has no link to the brick"
        );
    }
}
