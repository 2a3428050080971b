//! The launch's side of ROS 2 (`[launch] ros2`, `tes launch --ros2`; `[launch] rosbag`,
//! `--rosbag`): the group's ROS 2 side (`tes_ros2::group`), a thread of the launcher reading
//! the group's services, is started before any child and stopped after they all have. Built
//! only with the `ros2` cargo feature; without it, asking for ROS 2 is refused at start with
//! how to build it in. A launch that asks for neither starts nothing of it.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use tes_runtime::settings::SettingError;

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

/// The process name of errors about `[ros2_world]`.
pub const WORLD: &str = "ros2 world";

/// The summary the ROS 2 world writes in the run folder.
pub const WORLD_REPORT: &str = "ros2-world.json";

/// The world a perception settings file asks for: a ROS 2 robot's if it holds a
/// `ros2_world` table.
pub fn is_world_file(text: &str) -> bool {
    text.parse::<toml::Table>()
        .is_ok_and(|t| t.contains_key("ros2_world"))
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

    pub use tes_ros2::world::WorldSettings;

    /// Refuses `[ros2_world]` settings the group cannot carry.
    pub fn check_world(world: &WorldSettings) -> Result<(), SettingError> {
        world
            .check()
            .map_err(|e| SettingError::new(WORLD, e.key, e.reason))
    }

    /// The ROS 2 world's settings file: `[ros2_world]` and the run's (episodes, services,
    /// the report in the run folder).
    pub fn world_file(
        world: &WorldSettings,
        launch: &crate::file::LaunchSection,
        run_dir: &Path,
    ) -> Result<String, toml::ser::Error> {
        use tes_ros2::world::{WorldFile, WorldRun};
        toml::to_string(&WorldFile {
            ros2_world: world.clone(),
            run: WorldRun {
                episodes: launch.episodes,
                service_prefix: launch.service_prefix.clone(),
                report: Some(run_dir.join(WORLD_REPORT)),
            },
        })
    }

    /// Runs the ROS 2 world of a perception settings file `text` until its episodes are
    /// done or `stop` is raised.
    pub fn run_world(
        text: &str,
        stop: &AtomicBool,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let file: tes_ros2::world::WorldFile = toml::from_str(text)?;
        tes_ros2::world::run(&file, stop)?;
        Ok(())
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

    /// `[ros2_world]` as this build reads it: any table, refused by [`check_world`].
    pub type WorldSettings = toml::Table;

    /// Refuses a ROS 2 robot's world: this build cannot speak to it.
    pub fn check_world(_world: &WorldSettings) -> Result<(), SettingError> {
        Err(SettingError::new(
            WORLD,
            tes_runtime::settings::FILE_KEY,
            "this tes was built without ROS 2; build it in with `cargo install --locked \
             --path tes --features ros2`",
        ))
    }

    /// Never called: [`check_world`] refuses every world first.
    pub fn world_file(
        world: &WorldSettings,
        _launch: &crate::file::LaunchSection,
        _run_dir: &Path,
    ) -> Result<String, toml::ser::Error> {
        toml::to_string(world)
    }

    /// Never called: [`check_world`] refuses every world first.
    pub fn run_world(
        _text: &str,
        _stop: &AtomicBool,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        Err(Ros2Error::NotBuiltIn.into())
    }

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

    /// The launch file docs/ros2.md shows for a ROS 2 robot's world.
    fn documented_world() -> LaunchFile {
        let doc = include_str!("../../docs/ros2.md");
        let block = doc
            .split_once("<!-- launch file: ros2 world -->\n```toml\n")
            .and_then(|(_, rest)| rest.split_once("```"))
            .expect("docs/ros2.md shows the launch file")
            .0;
        LaunchFile::from_toml(block, tes_runtime::settings::Origin::Defaults)
            .expect("the documented launch file parses")
    }

    /// docs/ros2.md's launch file is taken as written by a `tes` with ROS 2, and it runs the
    /// ROS 2 world in perception's place with no bridge; without ROS 2 it is refused saying
    /// how to build it in.
    #[test]
    fn the_documented_ros2_world_is_taken_or_refused_by_how_tes_was_built() {
        let file = documented_world();
        let children = file.children();
        #[cfg(feature = "ros2")]
        {
            let children = children.expect("the documented world checks");
            let world = children.ros2_world.expect("a ROS 2 world");
            assert_eq!(world.cells, [20, 20]);
            assert_eq!(world.twist[0].seconds, 1.5);
            assert_eq!(
                file.world_name(),
                "the world of a ROS 2 robot ([ros2_world])"
            );
            let dir = tempfile::tempdir().expect("temp dir");
            let mut file = file;
            file.launch.run_dir = Some(dir.path().to_owned());
            let prepared = crate::file::prepare(&file).expect("prepared");
            let roles: Vec<_> = prepared.specs.iter().map(|s| s.role).collect();
            assert_eq!(
                roles,
                [tes_topics::Role::Controller, tes_topics::Role::Perception]
            );
            let text = std::fs::read_to_string(dir.path().join("perception-sim.toml"))
                .or_else(|_| std::fs::read_to_string(&prepared.specs[1].config))
                .expect("the world's settings");
            assert!(is_world_file(&text), "{text}");
            let back: tes_ros2::world::WorldFile = toml::from_str(&text).expect("its file");
            assert_eq!(back.run.episodes, 50);
            assert_eq!(
                back.run.report.as_deref(),
                Some(dir.path().join(WORLD_REPORT).as_path())
            );
        }
        #[cfg(not(feature = "ros2"))]
        {
            let e = children.unwrap_err().to_string();
            assert!(
                e.contains("built without ROS 2") && e.contains("--features ros2"),
                "{e}"
            );
        }
    }
}
