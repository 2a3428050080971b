//! Reading a recording back: the typed messages of our channels, the run's metadata and its
//! starting library. A truncated file (a recorder killed mid-run) is read up to its last
//! complete record and says so; anything that is not a TES recording of a version this
//! build knows is refused with the file and the problem named.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use tes_topics::{Command, MotorState, Observation, WorldMap};

use crate::schema::{self, DecodeError, FORMAT_VERSION, Topic, VERSION_KEY};
use crate::writer::{END_METADATA, LIBRARY_ATTACHMENT, RUN_METADATA};

/// Why a file cannot be read as a recording.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file cannot be read.
    #[error("cannot read {}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// Not an MCAP file at all.
    #[error("{} is not an MCAP file ({why})", path.display())]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// What the MCAP reader said.
        why: String,
    },
    /// An MCAP file, but not one `tes launch --record` wrote.
    #[error("{} is an MCAP file but not a TES recording (no {RUN_METADATA:?} metadata{})", path.display(), topics_note(.topics))]
    NotTes {
        /// The file.
        path: PathBuf,
        /// The topics it has.
        topics: Vec<String>,
    },
    /// A recording of a later format than this build reads.
    #[error("{} is a TES recording of format version {found}; this build reads version {FORMAT_VERSION} (use a newer tes)", path.display())]
    FutureVersion {
        /// The file.
        path: PathBuf,
        /// The version it says.
        found: String,
    },
    /// A message of one of our channels that does not decode.
    #[error("{}: message {index} of {topic}: {error}", path.display())]
    BadMessage {
        /// The file.
        path: PathBuf,
        /// The channel.
        topic: &'static str,
        /// Its index on the channel, from 0.
        index: usize,
        /// Why.
        error: DecodeError,
    },
}

fn topics_note(topics: &[String]) -> String {
    if topics.is_empty() {
        String::new()
    } else {
        format!("; its topics: {}", topics.join(", "))
    }
}

/// A recording, read.
#[derive(Debug, Clone)]
pub struct Recording {
    /// The file.
    pub path: PathBuf,
    /// The run's metadata ([`RUN_METADATA`]).
    pub run: BTreeMap<String, String>,
    /// What the recorder wrote at its end ([`END_METADATA`]); `None` if it never finished.
    pub end: Option<BTreeMap<String, String>>,
    /// The world map (the first, if several).
    pub world_map: Option<Box<WorldMap>>,
    /// Every observation, in file order.
    pub observations: Vec<Observation>,
    /// Every decision, in file order.
    pub commands: Vec<Command>,
    /// Every keep-alive, in file order.
    pub keepalives: Vec<Command>,
    /// Every motor state, in file order.
    pub motor_states: Vec<MotorState>,
    /// The library the run started from (`None`: it started empty).
    pub library: Option<Vec<u8>>,
    /// `None` for a complete file; for a truncated one, where reading stopped and why.
    pub truncated: Option<String>,
}

impl Recording {
    /// Reads the recording at `path`.
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let bytes = std::fs::read(path).map_err(|error| ReadError::Io {
            path: path.to_owned(),
            error,
        })?;
        Self::from_bytes(path, &bytes)
    }

    /// Reads a recording from its bytes (`path` names it in errors).
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Self, ReadError> {
        let path_buf = path.to_owned();
        if bytes.len() < 8 || &bytes[..8] != mcap::MAGIC {
            return Err(ReadError::NotMcap {
                path: path_buf,
                why: if bytes.is_empty() {
                    "the file is empty".into()
                } else {
                    "it does not start with the MCAP magic bytes".into()
                },
            });
        }
        // Read up to where the framing breaks, if it does: the mcap crate trusts the lengths.
        let broken = crate::framing::check(bytes).err();
        let bytes = broken.as_ref().map_or(bytes, |b| &bytes[..b.offset]);
        let records = mcap::read::ChunkFlattener::new_with_options(
            bytes,
            mcap::read::Options::IgnoreEndMagic.into(),
        )
        .map_err(|e| ReadError::NotMcap {
            path: path_buf.clone(),
            why: e.to_string(),
        })?;
        let mut channels: BTreeMap<u16, (String, Option<Topic>, Option<String>)> = BTreeMap::new();
        let mut rec = Recording {
            path: path_buf.clone(),
            run: BTreeMap::new(),
            end: None,
            world_map: None,
            observations: Vec::new(),
            commands: Vec::new(),
            keepalives: Vec::new(),
            motor_states: Vec::new(),
            library: None,
            truncated: None,
        };
        let mut raw: Vec<(Topic, Vec<u8>)> = Vec::new();
        let mut complete = false;
        let mut records_read = 0usize;
        for record in records {
            let record = match record {
                Ok(r) => r,
                Err(e) => {
                    rec.truncated = Some(format!(
                        "the file ends or breaks after {records_read} records ({e})"
                    ));
                    break;
                }
            };
            records_read += 1;
            use mcap::records::Record;
            match record {
                Record::Channel(c) => {
                    let topic = Topic::from_name(&c.topic);
                    channels.insert(c.id, (c.topic, topic, c.metadata.get(VERSION_KEY).cloned()));
                }
                Record::Message { header, data } => {
                    if let Some((_, Some(topic), _)) = channels.get(&header.channel_id) {
                        raw.push((*topic, data.into_owned()));
                    }
                }
                Record::Metadata(m) if m.name == RUN_METADATA => rec.run = m.metadata,
                Record::Metadata(m) if m.name == END_METADATA => rec.end = Some(m.metadata),
                Record::Attachment { header, data, .. } if header.name == LIBRARY_ATTACHMENT => {
                    rec.library = Some(data.into_owned());
                }
                Record::Footer(_) | Record::DataEnd(_) => complete = true,
                _ => {}
            }
        }
        if let Some(b) = &broken {
            rec.truncated = Some(format!(
                "the file breaks after {records_read} records: {}",
                b.why
            ));
        }
        if rec.truncated.is_none() && !complete {
            rec.truncated = Some(format!(
                "the file ends after {records_read} records, without its summary and footer"
            ));
        }
        if rec.run.is_empty() {
            return Err(ReadError::NotTes {
                path: path_buf,
                topics: channels.values().map(|(name, ..)| name.clone()).collect(),
            });
        }
        let version = rec.run.get("format_version").cloned().unwrap_or_default();
        let versions = std::iter::once(Some(version.clone())).chain(
            channels
                .values()
                .filter(|c| c.1.is_some())
                .map(|c| c.2.clone()),
        );
        for v in versions {
            let v = v.unwrap_or_default();
            if v != FORMAT_VERSION.to_string() {
                return Err(ReadError::FutureVersion {
                    path: path_buf,
                    found: if v.is_empty() { "(none)".into() } else { v },
                });
            }
        }
        let mut index: BTreeMap<Topic, usize> = BTreeMap::new();
        for (topic, data) in raw {
            let i = index.entry(topic).or_default();
            let bad = |error| ReadError::BadMessage {
                path: path_buf.clone(),
                topic: topic.name(),
                index: *i,
                error,
            };
            match topic {
                Topic::WorldMap => {
                    let map = schema::decode_world_map(&data).map_err(bad)?;
                    rec.world_map.get_or_insert(map);
                }
                Topic::Observation => rec
                    .observations
                    .push(schema::decode_observation(&data).map_err(bad)?),
                Topic::Command => rec
                    .commands
                    .push(schema::decode_command(&data).map_err(bad)?),
                Topic::KeepAlive => rec
                    .keepalives
                    .push(schema::decode_command(&data).map_err(bad)?),
                Topic::MotorState => rec
                    .motor_states
                    .push(schema::decode_motor_state(&data).map_err(bad)?),
            }
            *i += 1;
        }
        Ok(rec)
    }

    /// A value of the run's metadata, or "" if it has none.
    pub fn run_value(&self, key: &str) -> &str {
        self.run.get(key).map_or("", String::as_str)
    }
}
