//! An MCAP file of ROS 2 messages: profile `ros2`, schemas `ros2msg`, message encoding `cdr`,
//! one channel per topic registered on its first message.
//!
//! Chunked (1 MiB, uncompressed: the crate is built without zstd and lz4, which are C
//! libraries) with message and chunk indexes; the summary is written by [`Bag::finish`], and,
//! should the run stop on an error, when the bag is dropped. A file cut short (a full disk, a
//! killed process) keeps every complete chunk, which MCAP readers recover without the summary.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::Path;

use anyhow::{bail, Context, Result};

use crate::cdr;
use crate::msgs::Message;
use crate::schemas::Schema;

/// Bytes of messages per chunk.
pub const CHUNK_BYTES: u64 = 1 << 20;

/// An open MCAP file.
pub struct Bag<W: Write + Seek = BufWriter<File>> {
    writer: mcap::Writer<W>,
    schemas: BTreeMap<Schema, u16>,
    channels: BTreeMap<String, (u16, Schema)>,
    sequence: BTreeMap<u16, u32>,
}

impl Bag {
    /// Creates (or truncates) `path`.
    pub fn create(path: &Path) -> Result<Self> {
        let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
        Self::new(BufWriter::new(file)).with_context(|| format!("writing {}", path.display()))
    }
}

impl<W: Write + Seek> Bag<W> {
    /// A bag written to `sink`.
    pub fn new(sink: W) -> Result<Self> {
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("epssn-mcap ", env!("CARGO_PKG_VERSION")))
            .compression(None)
            .chunk_size(Some(CHUNK_BYTES))
            .create(sink)
            .context("starting the MCAP file")?;
        Ok(Self {
            writer,
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            sequence: BTreeMap::new(),
        })
    }

    /// The channel of `topic` for messages of `schema`, registered (with its schema) the
    /// first time; a topic keeps the type it was first written with.
    fn channel(&mut self, topic: &str, schema: Schema) -> Result<u16> {
        if let Some(&(id, known)) = self.channels.get(topic) {
            if known != schema {
                bail!(
                    "topic {topic} carries {}, not {}",
                    known.name(),
                    schema.name()
                );
            }
            return Ok(id);
        }
        let schema_id = match self.schemas.get(&schema) {
            Some(&id) => id,
            None => {
                let id = self
                    .writer
                    .add_schema(schema.name(), "ros2msg", schema.definition().as_bytes())
                    .with_context(|| format!("schema {}", schema.name()))?;
                self.schemas.insert(schema, id);
                id
            }
        };
        let id = self
            .writer
            .add_channel(schema_id, topic, "cdr", &BTreeMap::new())
            .with_context(|| format!("channel {topic}"))?;
        self.channels.insert(topic.to_string(), (id, schema));
        Ok(id)
    }

    /// Writes `msg` on `topic`, logged (and published) at `time_ns` since the Unix epoch.
    pub fn write<M: Message>(&mut self, topic: &str, time_ns: u64, msg: &M) -> Result<()> {
        let channel_id = self.channel(topic, M::SCHEMA)?;
        let data = cdr::encode(msg).with_context(|| format!("a message on {topic}"))?;
        let seq = self.sequence.entry(channel_id).or_insert(0);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: *seq,
            log_time: time_ns,
            publish_time: time_ns,
        };
        *seq = seq.wrapping_add(1);
        self.writer
            .write_to_known_channel(&header, &data)
            .with_context(|| format!("writing a message on {topic}"))
    }

    /// Writes the last chunk, the summary and the footer, and flushes the sink.
    pub fn finish(mut self) -> Result<W> {
        self.writer.finish().context("finishing the MCAP file")?;
        let mut sink = self.writer.into_inner();
        sink.flush().context("flushing the MCAP file")?;
        Ok(sink)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::StringMsg;
    use std::io::Cursor;

    #[test]
    fn a_topic_keeps_its_type_and_the_file_reads_back() {
        let mut bag = Bag::new(Cursor::new(Vec::new())).unwrap();
        let msg = StringMsg { data: "{}".into() };
        bag.write("/a", 5, &msg).unwrap();
        bag.write("/a", 6, &msg).unwrap();
        let tf = crate::msgs::TfMessage { transforms: vec![] };
        assert!(bag.write("/a", 7, &tf).is_err());
        let bytes = bag.finish().unwrap().into_inner();
        let times: Vec<u64> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap().log_time)
            .collect();
        assert_eq!(times, vec![5, 6]);
    }
}
