//! The group's ROS 2 topics as a rosbag2 bag: a directory `NAME/` holding `NAME_0.mcap` (MCAP
//! profile `ros2`, each topic's schema its `ros2msg` definition, its messages CDR, its QoS in
//! the channel's `offered_qos_profiles`) and `metadata.yaml` (rosbag2 format version 5, which
//! Humble writes and every later release reads), as `ros2 bag record -s mcap` leaves it.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use crate::scene::{Delivery, RosMessage, Sink, Topic};

/// The bag's format version in `metadata.yaml`.
pub const BAG_VERSION: u32 = 5;

/// Why a bag could not be written.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// Its directory exists: a bag is never overwritten.
    #[error("{} exists already: a bag is written to a new directory", .0.display())]
    Exists(PathBuf),
    /// A file of it cannot be created or written.
    #[error("cannot write the bag {}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        error: std::io::Error,
    },
    /// The MCAP file refused a record.
    #[error("cannot write the bag {}: {error}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        error: mcap::McapError,
    },
    /// A message could not be encoded.
    #[error(transparent)]
    Encode(#[from] crate::msg::EncodeError),
}

/// What a finished bag holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagSummary {
    /// The bag's directory.
    pub dir: PathBuf,
    /// Messages per topic.
    pub counts: BTreeMap<Topic, u64>,
}

impl BagSummary {
    /// Messages in all.
    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }
}

/// A rosbag2 bag being written.
pub struct BagWriter {
    dir: PathBuf,
    file: PathBuf,
    mcap: mcap::Writer<BufWriter<File>>,
    channels: BTreeMap<Topic, u16>,
    counts: BTreeMap<Topic, u64>,
    first_ns: Option<u64>,
    last_ns: u64,
    sequence: u32,
}

impl std::fmt::Debug for BagWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BagWriter")
            .field("dir", &self.dir)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

/// A topic's QoS as rosbag2 writes `offered_qos_profiles` (Humble's numeric form; the
/// durations are ROS 2's "infinite").
fn offered_qos(topic: Topic) -> String {
    let q = topic.qos();
    let infinite = "\n    sec: 2147483647\n    nsec: 4294967295";
    format!(
        "- history: 1\n  depth: {}\n  reliability: 1\n  durability: {}\n  deadline:{infinite}\n  \
         lifespan:{infinite}\n  liveliness: 1\n  liveliness_lease_duration:{infinite}\n  \
         avoid_ros_namespace_conventions: false",
        q.depth,
        if q.transient_local { 1 } else { 2 }
    )
}

impl BagWriter {
    /// Creates the bag directory `dir` (which must not exist) and its MCAP file, with a
    /// channel for every [`Topic`].
    pub fn create(dir: &Path) -> Result<Self, BagError> {
        if dir.exists() {
            return Err(BagError::Exists(dir.to_owned()));
        }
        let io = |path: &Path| {
            let path = path.to_owned();
            move |error| BagError::Io { path, error }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let name = dir
            .file_name()
            .map_or_else(|| "bag".into(), |n| n.to_string_lossy().into_owned());
        let file = dir.join(format!("{name}_0.mcap"));
        let out = File::create(&file).map_err(io(&file))?;
        let err = |error| BagError::Mcap {
            path: file.clone(),
            error,
        };
        let mut mcap = mcap::WriteOptions::new()
            .compression(None)
            .profile("ros2")
            .library(format!("tes-ros2 {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(out))
            .map_err(err)?;
        let mut channels = BTreeMap::new();
        for topic in Topic::ALL {
            let d = topic.definition();
            let schema = mcap
                .add_schema(&d.full_name(), "ros2msg", d.ros2msg().as_bytes())
                .map_err(err)?;
            let metadata =
                BTreeMap::from([("offered_qos_profiles".to_owned(), offered_qos(topic))]);
            let id = mcap
                .add_channel(schema, topic.name(), "cdr", &metadata)
                .map_err(err)?;
            channels.insert(topic, id);
        }
        Ok(Self {
            dir: dir.to_owned(),
            file,
            mcap,
            channels,
            counts: BTreeMap::new(),
            first_ns: None,
            last_ns: 0,
            sequence: 0,
        })
    }

    /// Writes `message` at `wall_ns`.
    pub fn write(&mut self, message: &RosMessage, wall_ns: u64) -> Result<(), BagError> {
        let topic = message.topic();
        let data = message.encode()?;
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: self.channels[&topic],
            sequence: self.sequence,
            log_time: wall_ns,
            publish_time: wall_ns,
        };
        self.mcap
            .write_to_known_channel(&header, &data)
            .map_err(|error| BagError::Mcap {
                path: self.file.clone(),
                error,
            })?;
        *self.counts.entry(topic).or_default() += 1;
        self.first_ns = Some(self.first_ns.map_or(wall_ns, |f| f.min(wall_ns)));
        self.last_ns = self.last_ns.max(wall_ns);
        Ok(())
    }

    /// Finishes the MCAP file (its summary and index) and writes `metadata.yaml`.
    pub fn finish(mut self) -> Result<BagSummary, BagError> {
        self.mcap.finish().map_err(|error| BagError::Mcap {
            path: self.file.clone(),
            error,
        })?;
        let yaml = self.metadata_yaml();
        let path = self.dir.join("metadata.yaml");
        std::fs::write(&path, yaml).map_err(|error| BagError::Io { path, error })?;
        Ok(BagSummary {
            dir: self.dir.clone(),
            counts: self.counts.clone(),
        })
    }

    fn metadata_yaml(&self) -> String {
        let start = self.first_ns.unwrap_or(0);
        let duration = self.last_ns.saturating_sub(start);
        let total: u64 = self.counts.values().sum();
        let file_name = self
            .file
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        let mut topics = String::new();
        for topic in Topic::ALL {
            let qos = offered_qos(topic).replace('"', "\\\"").replace('\n', "\\n");
            topics.push_str(&format!(
                "    - topic_metadata:\n        name: {}\n        type: {}\n        \
                 serialization_format: cdr\n        offered_qos_profiles: \"{qos}\"\n      \
                 message_count: {}\n",
                topic.name(),
                topic.definition().full_name(),
                self.counts.get(&topic).copied().unwrap_or(0)
            ));
        }
        format!(
            "rosbag2_bagfile_information:\n  version: {BAG_VERSION}\n  storage_identifier: mcap\n  \
             duration:\n    nanoseconds: {duration}\n  starting_time:\n    \
             nanoseconds_since_epoch: {start}\n  message_count: {total}\n  \
             topics_with_message_count:\n{topics}  compression_format: \"\"\n  \
             compression_mode: \"\"\n  relative_file_paths:\n    - {file_name}\n  files:\n    \
             - path: {file_name}\n      starting_time:\n        nanoseconds_since_epoch: {start}\n      \
             duration:\n        nanoseconds: {duration}\n      message_count: {total}\n"
        )
    }
}

impl Sink for BagWriter {
    type Error = BagError;
    fn put(&mut self, m: &RosMessage, wall_ns: u64, _: Delivery) -> Result<(), BagError> {
        self.write(m, wall_ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::Float64;

    #[test]
    fn a_bag_is_never_written_over() {
        let dir = tempfile::tempdir().unwrap();
        let e = BagWriter::create(dir.path()).unwrap_err();
        assert!(matches!(e, BagError::Exists(_)), "{e}");
    }

    #[test]
    fn a_bag_holds_its_messages_and_says_so_in_its_metadata() {
        let dir = tempfile::tempdir().unwrap();
        let bag = dir.path().join("run");
        let mut w = BagWriter::create(&bag).unwrap();
        w.write(&RosMessage::Reward(Float64 { data: 1.0 }), 10)
            .unwrap();
        w.write(&RosMessage::Latency(Float64 { data: 2.0 }), 30)
            .unwrap();
        let summary = w.finish().unwrap();
        assert_eq!(summary.total(), 2);
        let yaml = std::fs::read_to_string(bag.join("metadata.yaml")).unwrap();
        assert!(yaml.contains("nanoseconds_since_epoch: 10"), "{yaml}");
        assert!(yaml.contains("nanoseconds: 20"), "{yaml}");
        assert!(yaml.contains("name: /tes/episode/reward\n        type: std_msgs/msg/Float64"));
        let bytes = std::fs::read(bag.join("run_0.mcap")).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let topics: Vec<_> = summary.channels.values().map(|c| c.topic.clone()).collect();
        assert_eq!(topics.len(), Topic::ALL.len());
        assert!(
            summary
                .channels
                .values()
                .all(|c| c.message_encoding == "cdr"
                    && c.schema.as_ref().is_some_and(|s| s.encoding == "ros2msg"))
        );
    }
}
