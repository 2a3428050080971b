//! A TES run as robotics viewers draw it.
//!
//! Foxglove draws only its own schemas and Rerun decodes only Foxglove's and ROS 2's, so the
//! run's samples are turned into those ([`scene::Scene`]): the arena to scale in metres, the
//! robot's transform `arena → robot` at each observation and as its wheels turn, its body,
//! its episode's path and last decision, the processes' log lines, and each decision's latency
//! and each episode's reward as plain numbers. The same drawings go into a recording (beside
//! its `tes.*` channels) and to a live Foxglove WebSocket server ([`live::LiveServer`]),
//! through the [`canvas::Canvas`] they share.
//!
//! ```
//! use tes_viewer::canvas::Collected;
//! use tes_viewer::scene::{ARENA, Scene, SceneSettings};
//! use tes_topics::WorldMap;
//!
//! let mut scene = Scene::new(SceneSettings::default());
//! let mut drawn = Collected::default();
//! let mut map = Box::new(WorldMap::EMPTY);
//! map.world = 3; // the paper's Env 3
//! scene.world_map(&map, 0, &mut drawn)?;
//! assert_eq!(drawn.on(ARENA).count(), 1);
//! # Ok::<(), std::convert::Infallible>(())
//! ```

pub mod arena;
pub mod canvas;
pub mod file;
pub mod grid;
pub mod live;
pub mod robot;
pub mod scene;
pub mod series;
