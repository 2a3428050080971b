//! Reading a recording back: the typed messages of our channels, the run's metadata and its
//! starting library. A truncated file (a recorder killed mid-run) is read up to its last
//! complete record and says so; anything that is not a TES recording of a version this
//! build knows is refused with the file and the problem named.
//!
//! [`Recording::open`] opens the file as every TES file is opened
//! ([`tes_files::open_regular`]: a FIFO, a device or a directory is refused without being
//! read), reads its first 8 bytes and refuses a file that does not start with the MCAP magic
//! before reading on, and refuses one larger than [`MAX_RECORDING_BYTES`] before reserving
//! memory for it. Every checksum the writer stored is checked — each chunk's before its
//! records are read, each attachment's, the data section's — and a mismatch is
//! [`ReadError::Corrupt`], as is a break in a file that ends as a complete one does: a
//! damaged file is never mistaken for one cut short.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use tes_files::{FileProblem, Opened};
use tes_topics::{Command, MotorState, Observation, WorldMap};

use crate::schema::{self, DecodeError, FORMAT_VERSION, Topic, VERSION_KEY};
use crate::writer::{END_METADATA, LIBRARY_ATTACHMENT, RUN_METADATA};

/// The largest recording read, in bytes (1 GiB). A recording is read whole and its
/// messages decoded into memory; a run records a few kilobytes per step, so this is hundreds
/// of thousands of steps.
pub const MAX_RECORDING_BYTES: u64 = 1 << 30;

/// Why a file cannot be read as a recording.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file cannot be read: missing, unreadable, not a regular file (a FIFO, a device, a
    /// directory: refused without reading from it) or larger than [`MAX_RECORDING_BYTES`].
    #[error("cannot read {}: {problem}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        problem: FileProblem,
    },
    /// A checksum does not match, or the file breaks although it ends as a complete file
    /// does: it was damaged (a flipped bit, a bad copy), and none of it is trusted.
    #[error("{} is corrupt: {why}", path.display())]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Where and how.
        why: String,
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
    /// An MCAP file cut short before the run's metadata (the recorder's first record) was
    /// written whole: it may have been a TES recording, but nothing of the run is readable.
    #[error("{} was cut short before its run metadata ({why}): nothing of the run is readable", path.display())]
    CutBeforeRun {
        /// The file.
        path: PathBuf,
        /// Where and how it breaks.
        why: String,
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
    /// Reads the recording at `path` (see the module docs for what is refused).
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let bytes = read_recording_file(path)?;
        Self::from_bytes(path, &bytes)
    }

    /// Reads a recording from its bytes (`path` names it in errors).
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Self, ReadError> {
        check_magic(path, bytes)?;
        // Read up to where the framing breaks, if it does: the mcap crate trusts the lengths.
        let broken = crate::framing::check(bytes).err();
        if let Some(b) = broken.as_ref().filter(|b| b.corrupt) {
            return Err(ReadError::Corrupt {
                path: path.to_owned(),
                why: b.why.clone(),
            });
        }
        let bytes = broken.as_ref().map_or(bytes, |b| &bytes[..b.offset]);
        let records = Records::read(path, bytes)?;
        if let Some(why) = records.corrupt {
            return Err(ReadError::Corrupt {
                path: path.to_owned(),
                why,
            });
        }
        let truncated = records.truncation(broken.as_ref());
        if records.run.is_empty() {
            if let Some(why) = truncated {
                return Err(ReadError::CutBeforeRun {
                    path: path.to_owned(),
                    why,
                });
            }
            return Err(ReadError::NotTes {
                path: path.to_owned(),
                topics: records.channels.values().map(|c| c.name.clone()).collect(),
            });
        }
        records.check_versions(path)?;
        let mut rec = Recording {
            path: path.to_owned(),
            run: records.run,
            end: records.end,
            world_map: None,
            observations: Vec::new(),
            commands: Vec::new(),
            keepalives: Vec::new(),
            motor_states: Vec::new(),
            library: records.library,
            truncated,
        };
        rec.decode(records.messages)?;
        Ok(rec)
    }

    /// Decodes the messages of our channels into their lists, in file order.
    fn decode(&mut self, messages: Vec<(Topic, Vec<u8>)>) -> Result<(), ReadError> {
        let mut index: BTreeMap<Topic, usize> = BTreeMap::new();
        for (topic, data) in messages {
            let i = index.entry(topic).or_default();
            let bad = |error| ReadError::BadMessage {
                path: self.path.clone(),
                topic: topic.name(),
                index: *i,
                error,
            };
            match topic {
                Topic::WorldMap => {
                    let map = schema::decode_world_map(&data).map_err(bad)?;
                    self.world_map.get_or_insert(map);
                }
                Topic::Observation => self
                    .observations
                    .push(schema::decode_observation(&data).map_err(bad)?),
                Topic::Command => self
                    .commands
                    .push(schema::decode_command(&data).map_err(bad)?),
                Topic::KeepAlive => self
                    .keepalives
                    .push(schema::decode_command(&data).map_err(bad)?),
                Topic::MotorState => self
                    .motor_states
                    .push(schema::decode_motor_state(&data).map_err(bad)?),
            }
            *i += 1;
        }
        Ok(())
    }

    /// A value of the run's metadata, or "" if it has none.
    pub fn run_value(&self, key: &str) -> &str {
        self.run.get(key).map_or("", String::as_str)
    }
}

/// The bytes of the recording at `path`: its magic checked before anything else is read, its
/// size checked against [`MAX_RECORDING_BYTES`] before memory is reserved for it.
fn read_recording_file(path: &Path) -> Result<Vec<u8>, ReadError> {
    let refused = |problem: FileProblem| ReadError::Io {
        path: path.to_owned(),
        problem,
    };
    let Opened { mut file, size } = tes_files::open_regular(path).map_err(refused)?;
    let mut bytes = Vec::with_capacity(mcap::MAGIC.len());
    Read::by_ref(&mut file)
        .take(mcap::MAGIC.len() as u64)
        .read_to_end(&mut bytes)
        .map_err(|e| refused(e.into()))?;
    check_magic(path, &bytes)?;
    let too_large = |size| {
        refused(FileProblem::TooLarge {
            size,
            limit: MAX_RECORDING_BYTES,
        })
    };
    if size > MAX_RECORDING_BYTES {
        return Err(too_large(size));
    }
    let rest = size.saturating_sub(bytes.len() as u64);
    bytes
        .try_reserve_exact(usize::try_from(rest).unwrap_or(usize::MAX))
        .map_err(|e| refused(std::io::Error::new(std::io::ErrorKind::OutOfMemory, e).into()))?;
    // One byte past the limit, so a file that grows while read is refused, not read on.
    file.take(MAX_RECORDING_BYTES + 1 - bytes.len() as u64)
        .read_to_end(&mut bytes)
        .map_err(|e| refused(e.into()))?;
    if bytes.len() as u64 > MAX_RECORDING_BYTES {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// Refuses bytes that do not start as an MCAP file.
fn check_magic(path: &Path, bytes: &[u8]) -> Result<(), ReadError> {
    if bytes.len() < 8 || &bytes[..8] != mcap::MAGIC {
        return Err(ReadError::NotMcap {
            path: path.to_owned(),
            why: if bytes.is_empty() {
                "the file is empty".into()
            } else {
                "it does not start with the MCAP magic bytes".into()
            },
        });
    }
    Ok(())
}

/// A channel of the file: its topic name, our topic if it is one of ours, and the format
/// version its metadata gives.
struct Channel {
    name: String,
    topic: Option<Topic>,
    version: Option<String>,
}

/// What the file's records hold, before our messages are decoded.
struct Records {
    channels: BTreeMap<u16, Channel>,
    /// The messages of our channels, undecoded, in file order.
    messages: Vec<(Topic, Vec<u8>)>,
    run: BTreeMap<String, String>,
    end: Option<BTreeMap<String, String>>,
    library: Option<Vec<u8>>,
    /// Records read before the end or the first unreadable one.
    read: usize,
    /// Why reading stopped early, if a record did not read.
    unreadable: Option<String>,
    /// Why reading stopped early, if a checksum did not match.
    corrupt: Option<String>,
    /// Whether the file's summary or footer was reached.
    complete: bool,
}

impl Records {
    /// Reads every record of `bytes` up to the end or the first that does not read.
    fn read(path: &Path, bytes: &[u8]) -> Result<Self, ReadError> {
        let records = mcap::read::ChunkFlattener::new_with_options(
            bytes,
            mcap::read::Options::IgnoreEndMagic | mcap::read::Options::ValidateChunkCrcs,
        )
        .map_err(|e| ReadError::NotMcap {
            path: path.to_owned(),
            why: e.to_string(),
        })?;
        let mut out = Records {
            channels: BTreeMap::new(),
            messages: Vec::new(),
            run: BTreeMap::new(),
            end: None,
            library: None,
            read: 0,
            unreadable: None,
            corrupt: None,
            complete: false,
        };
        for record in records {
            match record {
                Ok(record) => out.take(record),
                Err(
                    e @ (mcap::McapError::BadChunkCrc { .. }
                    | mcap::McapError::BadAttachmentCrc { .. }
                    | mcap::McapError::BadDataCrc { .. }),
                ) => {
                    out.corrupt = Some(format!("after {} records: {e}", out.read));
                    break;
                }
                Err(e) => {
                    out.unreadable = Some(format!(
                        "the file ends or breaks after {} records ({e})",
                        out.read
                    ));
                    break;
                }
            }
        }
        Ok(out)
    }

    /// Keeps what `record` says about the run.
    fn take(&mut self, record: mcap::records::Record<'_>) {
        use mcap::records::Record;
        self.read += 1;
        match record {
            Record::Channel(c) => {
                let channel = Channel {
                    topic: Topic::from_name(&c.topic),
                    version: c.metadata.get(VERSION_KEY).cloned(),
                    name: c.topic,
                };
                self.channels.insert(c.id, channel);
            }
            Record::Message { header, data } => {
                if let Some(Channel {
                    topic: Some(topic), ..
                }) = self.channels.get(&header.channel_id)
                {
                    self.messages.push((*topic, data.into_owned()));
                }
            }
            Record::Metadata(m) if m.name == RUN_METADATA => self.run = m.metadata,
            Record::Metadata(m) if m.name == END_METADATA => self.end = Some(m.metadata),
            Record::Attachment { header, data, .. } if header.name == LIBRARY_ATTACHMENT => {
                self.library = Some(data.into_owned());
            }
            Record::Footer(_) | Record::DataEnd(_) => self.complete = true,
            _ => {}
        }
    }

    /// `None` for a complete file; otherwise where reading stopped and why (`broken`: where
    /// the framing check found the file broken).
    fn truncation(&self, broken: Option<&crate::framing::Break>) -> Option<String> {
        if let Some(b) = broken {
            return Some(format!(
                "the file breaks after {} records: {}",
                self.read, b.why
            ));
        }
        if self.unreadable.is_some() {
            return self.unreadable.clone();
        }
        (!self.complete).then(|| {
            format!(
                "the file ends after {} records, without its summary and footer",
                self.read
            )
        })
    }

    /// Refuses a run, or a channel of ours, of another format version than this build's.
    fn check_versions(&self, path: &Path) -> Result<(), ReadError> {
        let version = self.run.get("format_version").cloned().unwrap_or_default();
        let versions = std::iter::once(Some(version)).chain(
            self.channels
                .values()
                .filter(|c| c.topic.is_some())
                .map(|c| c.version.clone()),
        );
        for v in versions {
            let v = v.unwrap_or_default();
            if v != FORMAT_VERSION.to_string() {
                return Err(ReadError::FutureVersion {
                    path: path.to_owned(),
                    found: if v.is_empty() { "(none)".into() } else { v },
                });
            }
        }
        Ok(())
    }
}
