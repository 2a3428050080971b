//! TES on ROS 2, with no ROS installation: the group's run published to ROS 2 and written as
//! a rosbag2 bag.
//!
//! * [`msg`] — ROS 2's standard messages as serde structs laid out as their IDL, with their
//!   names and `.msg` definitions;
//! * [`scene`] — the group's samples as those messages, on [`scene::Topic`]s (`/tf`, the
//!   arena's markers, the episode's path, decisions, rewards, `/rosout`);
//! * [`dds`] — the ROS 2 node (RustDDS through `ros2-client`) that publishes them;
//! * [`bag`] — the same topics as a rosbag2 bag (MCAP storage, `ros2msg` schemas, CDR);
//! * [`world`] — a ROS 2 robot as the group's world: its map and steps in, actions out;
//! * [`group`] — the thread that reads a running group's iceoryx2 services, off the acting
//!   path, into the node and the bag.
//!
//! ```
//! use tes_ros2::scene::{Collected, RosMessage, RosScene, SceneSettings, Topic};
//! use tes_topics::WorldMap;
//!
//! let mut scene = RosScene::new(SceneSettings::default());
//! let mut out = Collected::default();
//! let mut map = Box::new(WorldMap::EMPTY);
//! map.world = 3; // the paper's Env 3
//! scene.world_map(&map, 0, &mut out)?;
//! assert_eq!(out.0[0].topic(), Topic::Arena);
//! let bytes = out.0[0].encode()?; // CDR, as the DDS wire and a bag carry it
//! assert_eq!(&bytes[..4], &[0, 1, 0, 0]);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod bag;
pub mod dds;
pub mod group;
pub mod msg;
pub mod scene;
pub mod world;
