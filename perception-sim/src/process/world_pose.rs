//! Where the simulated world has the robot, for viewers: a [`WorldPose`] after each
//! observation (the recorder reads it when it drains the group's services; no process of the
//! group listens to it). Published after the observation, while the controller decides, so
//! it is never on the observation-to-command path.

use tes_runtime::channel::{IpcError, Outbox};
use tes_runtime::clock::monotonic_ns;
use tes_topics::WorldPose;

use crate::arena::Pose;

/// The publisher of the world's pose.
pub(crate) struct WorldPoseOut {
    outbox: Outbox<WorldPose>,
}

impl WorldPoseOut {
    /// Publishes on `outbox` (the group's world-pose service).
    pub(crate) fn new(outbox: Outbox<WorldPose>) -> Self {
        Self { outbox }
    }

    /// Publishes that observation `observation` of `episode` saw the robot at `to`, moved
    /// there from `from` by command `after_command` (0 at an episode's start).
    pub(crate) fn send(
        &self,
        observation: u64,
        episode: u32,
        after_command: u64,
        from: Pose,
        to: Pose,
    ) -> Result<(), IpcError> {
        let triple = |p: Pose| [p.position.x, p.position.y, p.heading];
        let pose = WorldPose {
            observation,
            stamp_ns: monotonic_ns(),
            after_command,
            episode,
            reserved: 0,
            from: triple(from),
            to: triple(to),
        };
        self.outbox.send(pose)
    }

    /// Connects subscribers that appeared since the last call.
    pub(crate) fn update_connections(&self) -> Result<(), IpcError> {
        self.outbox.update_connections()
    }
}
