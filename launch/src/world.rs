//! The launch's side of a ROS 2 robot as the world (`[ros2_world]`, docs/ros2.md): the
//! table checked as the ROS 2 world reads it, the settings file the perception role is given,
//! and that role run (`tes_ros2::world`). Built only with the `ros2` cargo feature; without
//! it, the table is read as any table and refused, saying how to build it in.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use tes_runtime::settings::SettingError;

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

#[cfg(feature = "ros2")]
pub use built_in::*;

#[cfg(feature = "ros2")]
mod built_in {
    use super::*;

    pub use tes_ros2::world::WorldSettings;

    /// Refuses `[ros2_world]` settings the group cannot carry.
    pub fn check_world(world: &WorldSettings) -> Result<(), SettingError> {
        world
            .check()
            .map_err(|e| SettingError::new(WORLD, e.key, e.reason))
    }

    /// The ROS 2 world's settings file: `[ros2_world]` and the run's (`episodes`, the
    /// services' `prefix`, the report in the run folder `run_dir`).
    pub fn world_file(
        world: &WorldSettings,
        episodes: u32,
        prefix: &str,
        run_dir: &Path,
    ) -> Result<String, toml::ser::Error> {
        use tes_ros2::world::{WorldFile, WorldRun};
        toml::to_string(&WorldFile {
            ros2_world: world.clone(),
            run: WorldRun {
                episodes,
                service_prefix: prefix.to_owned(),
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
}

#[cfg(not(feature = "ros2"))]
pub use left_out::*;

#[cfg(not(feature = "ros2"))]
mod left_out {
    use super::*;

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
        _episodes: u32,
        _prefix: &str,
        _run_dir: &Path,
    ) -> Result<String, toml::ser::Error> {
        toml::to_string(world)
    }

    /// Never called: [`check_world`] refuses every world first.
    pub fn run_world(
        _text: &str,
        _stop: &AtomicBool,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        Err(
            "this tes was built without ROS 2; build it in with `cargo install --locked \
             --path tes --features ros2`"
                .into(),
        )
    }
}
