//! The launch's side of ROS 2 (`[launch] ros2`, `tes launch --ros2`; `[launch] rosbag`,
//! `--rosbag`): the group's ROS 2 side (`tes_ros2::group`), a thread of the launcher reading
//! the group's services, is started before any child and stopped after they all have. Built
//! only with the `ros2` cargo feature; without it, asking for ROS 2 is refused at start with
//! how to build it in. A launch that asks for neither starts nothing of it.

use std::path::PathBuf;

use crate::file::LaunchFile;

/// The ROS 2 side cannot start, or did not end whole.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    /// This `tes` was built without the `ros2` feature.
    #[error(
        "this tes was built without ROS 2 (`[launch] ros2`, `rosbag`); build it in with \
         `cargo install --locked --path tes --features ros2`; nothing was started"
    )]
    NotBuiltIn,
    /// The ROS 2 side cannot start.
    #[cfg(feature = "ros2")]
    #[error("cannot start the group on ROS 2; nothing was started")]
    Start(#[source] tes_ros2::group::GroupError),
    /// The ROS 2 side failed on the way.
    #[cfg(feature = "ros2")]
    #[error("the group's ROS 2 side failed")]
    Incomplete(#[source] tes_ros2::group::GroupError),
}

/// What the ROS 2 side is doing, said at start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ros2Started {
    /// Where the node is reachable (`None`: no node, a bag only).
    pub reach: Option<String>,
    /// Whether peers beyond this host can reach it.
    pub beyond_this_host: bool,
    /// The bag being written.
    pub bag: Option<PathBuf>,
}

/// What the ROS 2 side did, said at the end.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ros2Done {
    /// Messages published on ROS 2.
    pub published: u64,
    /// Messages DDS did not take.
    pub not_published: u64,
    /// The bag and its messages.
    pub bag: Option<(PathBuf, u64)>,
}

impl std::fmt::Display for Ros2Done {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "published {} ROS 2 messages", self.published)?;
        if self.not_published > 0 {
            write!(f, " ({} not taken by DDS)", self.not_published)?;
        }
        if let Some((dir, n)) = &self.bag {
            write!(f, "; wrote {n} to the rosbag2 bag {}", dir.display())?;
        }
        Ok(())
    }
}

/// Whether the launch asks for ROS 2 at all.
fn asked(file: &LaunchFile) -> bool {
    file.launch.ros2 || file.launch.rosbag.is_some()
}

#[cfg(feature = "ros2")]
pub use built_in::*;

#[cfg(feature = "ros2")]
mod built_in {
    use tes_ros2::group::{GroupOnRos2, LogLines, Outputs};
    use tes_ros2::scene::SceneSettings;

    use super::*;

    /// The running ROS 2 side.
    pub type Running = GroupOnRos2;
    /// Where the processes' log lines go for `/rosout`.
    pub type Lines = LogLines;

    /// Starts the group's ROS 2 side if the launch asks for it: subscribed to the services
    /// of `prefix` before any child starts; the domain is `ROS_DOMAIN_ID`'s.
    pub fn start(
        file: &LaunchFile,
        prefix: &str,
    ) -> Result<Option<(Running, Ros2Started)>, Ros2Error> {
        if !asked(file) {
            return Ok(None);
        }
        let domain = if file.launch.ros2 {
            Some(tes_ros2::dds::domain_from_env().map_err(|e| Ros2Error::Start(e.into()))?)
        } else {
            None
        };
        let range = if file.launch.ros2 {
            tes_ros2::dds::range_from_env().map_err(|e| Ros2Error::Start(e.into()))?
        } else {
            tes_ros2::dds::DiscoveryRange::Default
        };
        let outputs = Outputs {
            domain,
            range,
            bag: file.launch.rosbag.clone(),
            scene: SceneSettings::from_now([file.perception.left_port, file.perception.right_port]),
        };
        let running = GroupOnRos2::start(prefix, outputs).map_err(Ros2Error::Start)?;
        let started = Ros2Started {
            reach: running.reach().map(ToString::to_string),
            beyond_this_host: running.reach().is_some_and(|r| !r.is_local()),
            bag: file.launch.rosbag.clone(),
        };
        Ok(Some((running, started)))
    }

    /// Hands a process's log line to `/rosout`.
    pub fn send_line(lines: &Lines, role: tes_topics::Role, text: &str) {
        lines.send(role.name(), text);
    }

    /// The log lines' way in.
    pub fn lines(running: &Running) -> Lines {
        running.log_lines()
    }

    /// Stops the ROS 2 side (the group has stopped): the bag is finished.
    pub fn finish(running: Running) -> Result<Ros2Done, Ros2Error> {
        let p = running.stop().map_err(Ros2Error::Incomplete)?;
        Ok(Ros2Done {
            published: p.published,
            not_published: p.not_published,
            bag: p.bag.map(|b| (b.dir.clone(), b.total())),
        })
    }
}

#[cfg(not(feature = "ros2"))]
pub use left_out::*;

#[cfg(not(feature = "ros2"))]
mod left_out {
    use super::*;

    /// Never made: this build has no ROS 2 side.
    #[derive(Debug)]
    pub enum Running {}
    /// Never made.
    #[derive(Debug, Clone)]
    pub enum Lines {}

    /// Refuses a launch that asks for ROS 2; starts nothing otherwise.
    pub fn start(
        file: &LaunchFile,
        _prefix: &str,
    ) -> Result<Option<(Running, Ros2Started)>, Ros2Error> {
        if asked(file) {
            return Err(Ros2Error::NotBuiltIn);
        }
        Ok(None)
    }

    /// Nothing to hand to.
    pub fn send_line(lines: &Lines, _role: tes_topics::Role, _text: &str) {
        match *lines {}
    }

    /// Nothing to take from.
    pub fn lines(running: &Running) -> Lines {
        match *running {}
    }

    /// Nothing to stop.
    pub fn finish(running: Running) -> Result<Ros2Done, Ros2Error> {
        match running {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A launch that asks for neither `ros2` nor `rosbag` starts nothing of ROS 2, with the
    /// feature or without: no thread, no DDS participant, no socket.
    #[test]
    fn a_launch_that_does_not_ask_starts_nothing() {
        let file = LaunchFile::default();
        assert!(!asked(&file));
        assert!(matches!(start(&file, "tes-never-opened/"), Ok(None)));
    }

    #[cfg(not(feature = "ros2"))]
    #[test]
    fn without_the_feature_asking_is_refused_saying_how_to_build_it_in() {
        for ask in [
            |f: &mut LaunchFile| f.launch.ros2 = true,
            |f: &mut LaunchFile| f.launch.rosbag = Some("bag".into()),
        ] {
            let mut file = LaunchFile::default();
            ask(&mut file);
            let e = start(&file, "tes-never-opened/").unwrap_err();
            assert!(e.to_string().contains("--features ros2"), "{e}");
        }
    }

    #[test]
    fn the_end_says_what_was_published_and_written() {
        let done = Ros2Done {
            published: 120,
            not_published: 2,
            bag: Some(("run-bag".into(), 300)),
        };
        assert_eq!(
            done.to_string(),
            "published 120 ROS 2 messages (2 not taken by DDS); wrote 300 to the rosbag2 bag run-bag"
        );
    }
}
