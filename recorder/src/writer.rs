//! Writing a recording: one MCAP file, a channel per [`Topic`], the run's facts as metadata
//! and its starting library as an attachment. The container is the `mcap` crate's.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use tes_topics::{Command, KEEP_ALIVE_ACTION, MotorState, Observation, WorldMap};

use crate::schema::{self, FORMAT_VERSION, MESSAGE_ENCODING, SCHEMA_ENCODING, Topic, VERSION_KEY};

/// Name of the metadata record with the run's facts ([`RunInfo`]).
pub const RUN_METADATA: &str = "tes.run";
/// Name of the metadata record the recorder writes when it finishes ([`RecordCounts`]).
pub const END_METADATA: &str = "tes.recorder";
/// Name of the attachment holding the view library the run started from.
pub const LIBRARY_ATTACHMENT: &str = "library.tesl";

/// Target size of a chunk: a recorder killed mid-run loses at most the open chunk (and what
/// it wrote since its last flush).
const CHUNK_SIZE: u64 = 64 * 1024;

/// Why a recording cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// The file cannot be created.
    #[error("cannot create the recording {}: {error}", path.display())]
    Create {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// The MCAP writer failed (the disk is full, the file went away, …).
    #[error("cannot write the recording {}: {error}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// Why.
        error: mcap::McapError,
    },
}

/// What a recording says about its run, written when it starts.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunInfo {
    /// The TES version that ran (`CARGO_PKG_VERSION`).
    pub tes_version: String,
    /// The launch's seed (world and agent).
    pub seed: u64,
    /// The group's service prefix.
    pub service_prefix: String,
    /// The controller's settings, as the TOML the controller read.
    pub controller_toml: String,
    /// The whole launch's settings (every table), as TOML.
    pub launch_toml: String,
    /// The view library file the controller loads.
    pub library_path: String,
    /// Its bytes when the run started; `None` when there was none (an empty start).
    pub library: Option<Vec<u8>>,
    /// Wall clock minus the monotonic clock at the start, ns: added to a message's publish
    /// time (monotonic) for its log time, so viewers show wall-clock dates.
    pub wall_offset_ns: i128,
}

/// What a recorder wrote and what it knows it missed, written when it finishes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RecordCounts {
    /// Messages written per [`Topic`], in [`Topic::ALL`] order.
    pub written: [u64; 5],
    /// Observations missed (gaps in their sequence numbers).
    pub missed_observations: u64,
    /// Commands missed (gaps in their sequence numbers not explained by keep-alives).
    pub missed_commands: u64,
    /// Motor states missed (gaps in their sequence numbers).
    pub missed_motor_states: u64,
    /// Messages written in Foxglove's schemas for viewers (the scene of the run).
    pub drawings: u64,
}

/// An open recording.
pub struct RunWriter {
    path: PathBuf,
    mcap: mcap::Writer<BufWriter<File>>,
    channels: BTreeMap<Topic, u16>,
    /// The viewers' channels, added as the scene first draws on each.
    drawn_channels: tes_viewer::file::ChannelIds,
    sequence: u32,
    wall_offset_ns: i128,
    counts: RecordCounts,
}

impl std::fmt::Debug for RunWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunWriter")
            .field("path", &self.path)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

impl RunWriter {
    /// Creates `path` (replacing a file there) and writes the header, the channels, the
    /// run's metadata and its starting library.
    pub fn create(path: &Path, info: &RunInfo) -> Result<Self, WriteError> {
        let file = File::create(path).map_err(|error| WriteError::Create {
            path: path.to_owned(),
            error,
        })?;
        let err = |error| WriteError::Mcap {
            path: path.to_owned(),
            error,
        };
        let mut mcap = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(CHUNK_SIZE))
            .profile("")
            .library(format!("tes-recorder {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(err)?;
        let mut channels = BTreeMap::new();
        let channel_metadata =
            BTreeMap::from([(VERSION_KEY.to_owned(), FORMAT_VERSION.to_string())]);
        for topic in Topic::ALL {
            let schema = mcap
                .add_schema(
                    topic.schema_name(),
                    SCHEMA_ENCODING,
                    topic.schema().as_bytes(),
                )
                .map_err(err)?;
            let id = mcap
                .add_channel(schema, topic.name(), MESSAGE_ENCODING, &channel_metadata)
                .map_err(err)?;
            channels.insert(topic, id);
        }
        let metadata = BTreeMap::from([
            ("format_version".to_owned(), FORMAT_VERSION.to_string()),
            ("tes_version".to_owned(), info.tes_version.clone()),
            ("seed".to_owned(), info.seed.to_string()),
            ("service_prefix".to_owned(), info.service_prefix.clone()),
            ("controller_toml".to_owned(), info.controller_toml.clone()),
            ("launch_toml".to_owned(), info.launch_toml.clone()),
            ("library_path".to_owned(), info.library_path.clone()),
            (
                "library".to_owned(),
                if info.library.is_some() {
                    LIBRARY_ATTACHMENT.to_owned()
                } else {
                    "none (started empty)".to_owned()
                },
            ),
        ]);
        mcap.write_metadata(&mcap::records::Metadata {
            name: RUN_METADATA.to_owned(),
            metadata,
        })
        .map_err(err)?;
        if let Some(bytes) = &info.library {
            mcap.attach(&mcap::Attachment {
                log_time: 0,
                create_time: 0,
                name: LIBRARY_ATTACHMENT.to_owned(),
                media_type: "application/octet-stream".to_owned(),
                data: std::borrow::Cow::Borrowed(bytes),
            })
            .map_err(err)?;
        }
        let mut writer = Self {
            path: path.to_owned(),
            mcap,
            channels,
            drawn_channels: tes_viewer::file::ChannelIds::default(),
            sequence: 0,
            wall_offset_ns: info.wall_offset_ns,
            counts: RecordCounts::default(),
        };
        writer.flush()?;
        Ok(writer)
    }

    fn err(&self) -> impl Fn(mcap::McapError) -> WriteError + '_ {
        move |error| WriteError::Mcap {
            path: self.path.clone(),
            error,
        }
    }

    fn write(&mut self, topic: Topic, stamp_ns: u64, data: &[u8]) -> Result<(), WriteError> {
        let log_time = (i128::from(stamp_ns) + self.wall_offset_ns).clamp(0, i128::from(u64::MAX));
        self.write_to(self.channels[&topic], log_time as u64, stamp_ns, data)?;
        if let Some(i) = Topic::ALL.iter().position(|t| *t == topic) {
            self.counts.written[i] += 1;
        }
        Ok(())
    }

    fn write_to(
        &mut self,
        channel_id: u16,
        log_time: u64,
        publish_time: u64,
        data: &[u8],
    ) -> Result<(), WriteError> {
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time,
            publish_time,
        };
        let written = self.mcap.write_to_known_channel(&header, data);
        written.map_err(self.err())
    }

    /// Writes the world map.
    pub fn world_map(&mut self, map: &WorldMap, stamp_ns: u64) -> Result<(), WriteError> {
        self.write(Topic::WorldMap, stamp_ns, &schema::encode_world_map(map))
    }

    /// Writes an observation.
    pub fn observation(&mut self, o: &Observation) -> Result<(), WriteError> {
        self.write(
            Topic::Observation,
            o.stamp_ns,
            &schema::encode_observation(o),
        )
    }

    /// Writes a command: a decision, or a keep-alive on its own channel.
    pub fn command(&mut self, c: &Command) -> Result<(), WriteError> {
        let topic = if c.action == KEEP_ALIVE_ACTION {
            Topic::KeepAlive
        } else {
            Topic::Command
        };
        self.write(topic, c.stamp_ns, &schema::encode_command(c))
    }

    /// Writes a motor state.
    pub fn motor_state(&mut self, m: &MotorState) -> Result<(), WriteError> {
        self.write(
            Topic::MotorState,
            m.stamp_ns,
            &schema::encode_motor_state(m),
        )
    }

    /// Writes a drawing of the run's scene (Foxglove's schemas) on its own channel.
    pub fn drawing(&mut self, d: tes_viewer::canvas::Drawing<'_>) -> Result<(), WriteError> {
        let id = self.drawn_channels.id(&mut self.mcap, d.channel);
        let id = id.map_err(self.err())?;
        self.write_to(id, d.wall_ns, d.stamp_ns, d.data)?;
        self.counts.drawings += 1;
        Ok(())
    }

    /// What was written so far.
    pub fn counts(&self) -> RecordCounts {
        self.counts
    }

    /// Closes the open chunk and writes what is buffered to the file: a recorder killed after
    /// this leaves a file readable up to here.
    pub fn flush(&mut self) -> Result<(), WriteError> {
        let flushed = self.mcap.flush();
        flushed.map_err(self.err())
    }

    /// Writes what the recorder missed, the summary and the footer: the file is complete.
    pub fn finish(mut self, missed: RecordCounts) -> Result<RecordCounts, WriteError> {
        let mut counts = self.counts;
        counts.missed_observations = missed.missed_observations;
        counts.missed_commands = missed.missed_commands;
        counts.missed_motor_states = missed.missed_motor_states;
        let mut metadata: BTreeMap<String, String> = Topic::ALL
            .iter()
            .zip(counts.written)
            .map(|(t, n)| (format!("written {}", t.name()), n.to_string()))
            .collect();
        metadata.insert(
            "missed_observations".into(),
            counts.missed_observations.to_string(),
        );
        metadata.insert("missed_commands".into(), counts.missed_commands.to_string());
        metadata.insert("drawings".into(), counts.drawings.to_string());
        metadata.insert(
            "missed_motor_states".into(),
            counts.missed_motor_states.to_string(),
        );
        let written = self.mcap.write_metadata(&mcap::records::Metadata {
            name: END_METADATA.to_owned(),
            metadata,
        });
        written.map_err(self.err())?;
        let finished = self.mcap.finish();
        finished.map_err(self.err())?;
        Ok(counts)
    }
}

impl tes_viewer::canvas::Canvas for RunWriter {
    type Error = WriteError;
    fn draw(&mut self, d: tes_viewer::canvas::Drawing<'_>) -> Result<(), WriteError> {
        self.drawing(d)
    }
}
