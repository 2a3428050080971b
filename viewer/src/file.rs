//! Drawings in an MCAP file of their own ([`DrawingFile`]): a world drawn away from the
//! process group, such as a grid task's run in `tes experiment grid --draw`. A recording of
//! the group writes its drawings beside its own channels instead, through the same
//! [`ChannelIds`].

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use crate::canvas::{Canvas, Channel, Drawing};

/// Why a drawing file cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum DrawingFileError {
    /// The file cannot be created.
    #[error("cannot create {}: {source}", path.display())]
    Create {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The MCAP writer failed.
    #[error("cannot write {}: {source}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: mcap::McapError,
    },
}

/// The MCAP channel of each drawn topic, added to the file the first time it is drawn on.
#[derive(Debug, Default, Clone)]
pub struct ChannelIds(BTreeMap<&'static str, u16>);

impl ChannelIds {
    /// The id of `channel` in `mcap`, adding its schema and channel on first use.
    pub fn id<W: Write + Seek>(
        &mut self,
        mcap: &mut mcap::Writer<W>,
        channel: &Channel,
    ) -> Result<u16, mcap::McapError> {
        if let Some(&id) = self.0.get(channel.topic) {
            return Ok(id);
        }
        let schema = &channel.schema;
        let schema_id = mcap.add_schema(&schema.name, &schema.encoding, &schema.data)?;
        let id = mcap.add_channel(
            schema_id,
            channel.topic,
            &channel.encoding,
            &BTreeMap::new(),
        )?;
        self.0.insert(channel.topic, id);
        Ok(id)
    }
}

/// An MCAP file holding only drawings.
pub struct DrawingFile {
    path: PathBuf,
    mcap: mcap::Writer<BufWriter<File>>,
    channels: ChannelIds,
    sequence: u32,
    written: u64,
}

impl std::fmt::Debug for DrawingFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DrawingFile")
            .field("path", &self.path)
            .field("written", &self.written)
            .finish_non_exhaustive()
    }
}

impl DrawingFile {
    /// Creates `path` (replacing a file there) with `metadata` as its `tes.drawing` record.
    pub fn create(
        path: &Path,
        metadata: BTreeMap<String, String>,
    ) -> Result<Self, DrawingFileError> {
        let file = File::create(path).map_err(|source| DrawingFileError::Create {
            path: path.to_owned(),
            source,
        })?;
        let err = |source| DrawingFileError::Mcap {
            path: path.to_owned(),
            source,
        };
        let mut mcap = mcap::WriteOptions::new()
            .compression(None)
            .profile("")
            .library(format!("tes-viewer {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(err)?;
        mcap.write_metadata(&mcap::records::Metadata {
            name: "tes.drawing".to_owned(),
            metadata,
        })
        .map_err(err)?;
        Ok(Self {
            path: path.to_owned(),
            mcap,
            channels: ChannelIds::default(),
            sequence: 0,
            written: 0,
        })
    }

    /// Messages written so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Writes the summary and the footer: the file is complete.
    pub fn finish(mut self) -> Result<u64, DrawingFileError> {
        let finished = self.mcap.finish();
        finished.map_err(|source| DrawingFileError::Mcap {
            path: self.path.clone(),
            source,
        })?;
        Ok(self.written)
    }
}

impl Canvas for DrawingFile {
    type Error = DrawingFileError;

    fn draw(&mut self, d: Drawing<'_>) -> Result<(), DrawingFileError> {
        let err = |source| DrawingFileError::Mcap {
            path: self.path.clone(),
            source,
        };
        let channel_id = self.channels.id(&mut self.mcap, d.channel).map_err(err)?;
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: d.wall_ns,
            publish_time: d.stamp_ns,
        };
        self.mcap
            .write_to_known_channel(&header, d.data)
            .map_err(err)?;
        self.written += 1;
        Ok(())
    }
}
