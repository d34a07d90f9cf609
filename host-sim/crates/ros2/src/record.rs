//! The MCAP records this reader uses, parsed from one record's body (opcode and length already
//! read by [`crate::decode`]): schemas, channels, messages and chunks. Their layouts are those
//! of the MCAP specification; fields this reader does not need are skipped.

use crate::header::{op, Cursor};
use crate::McapError;

/// A schema record: how a channel's messages are defined.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Schema {
    /// Id, unique in the file (0 is invalid).
    pub id: u16,
    /// Type name, e.g. `marine_acoustic_msgs/msg/ProjectedSonarImage`.
    pub name: String,
    /// Encoding of `data`, e.g. `ros2msg`.
    pub encoding: String,
}

/// A channel record: a topic and its schema.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Channel {
    /// Id, unique in the file.
    pub id: u16,
    /// The schema's id (0: no schema).
    pub schema_id: u16,
    /// Topic, e.g. `/sonar/image`.
    pub topic: String,
    /// Encoding of the messages, `cdr` for ROS 2.
    pub message_encoding: String,
}

/// A message record.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Message {
    /// Its channel's id.
    pub channel_id: u16,
    /// Log time, ns.
    pub log_time: u64,
    /// The serialised message.
    pub data: Vec<u8>,
}

/// A chunk record: its compression and its (compressed) records.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Chunk<'a> {
    /// Size of the records once decompressed, bytes.
    pub uncompressed_size: u64,
    /// `""` (none), `lz4` or `zstd`.
    pub compression: String,
    /// The records, compressed as `compression` says.
    pub records: &'a [u8],
}

/// One record this reader uses, or `Other` (skipped).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Record<'a> {
    /// A schema.
    Schema(Schema),
    /// A channel.
    Channel(Channel),
    /// A message.
    Message(Message),
    /// A chunk.
    Chunk(Chunk<'a>),
    /// The footer: the data section ends.
    Footer,
    /// Any other record.
    Other,
}

/// Parses the body of a record of opcode `opcode`.
pub fn parse(opcode: u8, body: &[u8]) -> Result<Record<'_>, McapError> {
    let mut c = Cursor::new(body);
    Ok(match opcode {
        op::SCHEMA => {
            let id = c.u16()?;
            let name = c.string()?;
            let encoding = c.string()?;
            c.bytes_u32()?;
            Record::Schema(Schema { id, name, encoding })
        }
        op::CHANNEL => {
            let id = c.u16()?;
            let schema_id = c.u16()?;
            let topic = c.string()?;
            let message_encoding = c.string()?;
            Record::Channel(Channel {
                id,
                schema_id,
                topic,
                message_encoding,
            })
        }
        op::MESSAGE => {
            let channel_id = c.u16()?;
            let _sequence = c.u32()?;
            let log_time = c.u64()?;
            let _publish_time = c.u64()?;
            let data = c.take(c.remaining() as u64)?.to_vec();
            Record::Message(Message {
                channel_id,
                log_time,
                data,
            })
        }
        op::CHUNK => {
            let _start = c.u64()?;
            let _end = c.u64()?;
            let uncompressed_size = c.u64()?;
            let _crc = c.u32()?;
            let compression = c.string()?;
            let len = c.u64()?;
            let records = c.take(len)?;
            Record::Chunk(Chunk {
                uncompressed_size,
                compression,
                records,
            })
        }
        op::FOOTER => Record::Footer,
        _ => Record::Other,
    })
}
