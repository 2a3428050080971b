//! Where a drawing goes: a recording's file or the live server, both behind [`Canvas`].
//!
//! A [`Channel`] is one topic with its schema, built once from the message type's own
//! description (Foxglove's `Encode`); the scene encodes each message once into its own buffer
//! and hands every canvas the same bytes.

use foxglove::{Encode, Schema};

/// One topic of the drawing: its name, schema and message encoding.
#[derive(Debug, Clone)]
pub struct Channel {
    /// The topic, e.g. `/arena`.
    pub topic: &'static str,
    /// The schema its messages follow (a Protobuf file descriptor set).
    pub schema: Schema,
    /// The message encoding (`protobuf`).
    pub encoding: String,
}

impl Channel {
    /// The channel `topic` carrying messages of type `T`.
    pub fn of<T: Encode>(topic: &'static str) -> Self {
        Self {
            topic,
            // Foxglove's schemas and our derived messages all describe themselves.
            schema: T::get_schema().unwrap_or_else(|| Schema::new("", "", Vec::new())),
            encoding: T::get_message_encoding(),
        }
    }
}

/// One encoded message on its way to a canvas.
#[derive(Debug, Clone, Copy)]
pub struct Drawing<'a> {
    /// Its channel.
    pub channel: &'a Channel,
    /// The encoded message.
    pub data: &'a [u8],
    /// Monotonic clock (ns) of the event it draws: the publish time of the sample it comes
    /// from.
    pub stamp_ns: u64,
    /// The same instant on the wall clock (ns since the Unix epoch), as viewers show it.
    pub wall_ns: u64,
    /// A picture of the robot's motion that the next one on its channel supersedes (a
    /// transform, its pose, path and scene at an observation): a live view may skip it.
    /// Everything else (the arena, decisions, episode ends, log lines) is always delivered.
    pub motion: bool,
}

/// Something a drawing can be put on: a recording, the live server, or both.
pub trait Canvas {
    /// Why a drawing could not be put.
    type Error;
    /// Puts one message.
    fn draw(&mut self, drawing: Drawing<'_>) -> Result<(), Self::Error>;
}

/// Drawings collected in memory: for tests and for a caller that forwards them itself.
#[derive(Debug, Default, Clone)]
pub struct Collected {
    /// Each drawing's topic, bytes and wall-clock time, in order.
    pub drawings: Vec<(&'static str, Vec<u8>, u64)>,
}

impl Collected {
    /// The drawings on `topic`, in order.
    pub fn on<'a>(&'a self, topic: &'a str) -> impl Iterator<Item = &'a [u8]> + 'a {
        self.drawings
            .iter()
            .filter(move |(t, ..)| *t == topic)
            .map(|(_, d, _)| d.as_slice())
    }
}

impl Canvas for Collected {
    type Error = std::convert::Infallible;
    fn draw(&mut self, d: Drawing<'_>) -> Result<(), Self::Error> {
        self.drawings
            .push((d.channel.topic, d.data.to_vec(), d.wall_ns));
        Ok(())
    }
}
