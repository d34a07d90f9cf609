//! ROS 2 bags as sonar recordings (docs/ROS2.md): an MCAP reader (`header`, `record`,
//! `decode`: chunks uncompressed, LZ4 or zstd), CDR (`cdr`) of
//! `marine_acoustic_msgs/ProjectedSonarImage` and `tf2_msgs/TFMessage` (`msgs`), the transform
//! tree (`tf`), a ping as a native frame (`ping`, `frame`) and the check that its fan covers
//! the model's grid (`fit`), a bag's pings with their attitudes and rolls (`bag`), and the
//! recording that is an ARIS file or a bag behind one type (`recording`), and `host-sim
//! inspect` of a bag (`inspect`). `encode` writes
//! small bags (one chunk, any compression) for the tests and the fuzz target's seeds.

#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod bag;
pub mod cdr;
pub mod decode;
pub mod encode;
pub mod fit;
pub mod frame;
pub mod header;
pub mod inspect;
pub mod msgs;
pub mod ping;
pub mod record;
pub mod recording;
pub mod tf;

pub use frame::SonarFrame;
pub use recording::{OpenOptions, Recording};

/// Why an MCAP file or a CDR message cannot be read.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum McapError {
    /// The file does not start with MCAP's magic.
    #[error("not an MCAP file (no magic)")]
    Magic,
    /// A record or field runs past the end of its bytes.
    #[error("truncated record at byte {0}")]
    Truncated(usize),
    /// A string is not UTF-8.
    #[error("string at byte {0} is not UTF-8")]
    Utf8(usize),
    /// A message names a channel not (yet) defined.
    #[error("message on unknown channel {0}")]
    UnknownChannel(u16),
    /// A chunk holds a chunk.
    #[error("a chunk inside a chunk")]
    NestedChunk,
    /// A chunk declares more bytes than this reader decompresses.
    #[error("chunk of {0} bytes uncompressed is larger than the reader's limit")]
    ChunkTooLarge(u64),
    /// A compression this reader does not know.
    #[error("chunk compression {0:?} (known: none, lz4, zstd)")]
    Compression(String),
    /// Decompression failed.
    #[error("decompressing a chunk: {0}")]
    Decompress(String),
    /// A chunk decompressed to another size than it declares.
    #[error("chunk declares {declared} bytes and holds {actual}")]
    ChunkSize {
        /// Declared.
        declared: u64,
        /// Decompressed (at most one more than declared).
        actual: u64,
    },
    /// A CDR message that cannot be decoded.
    #[error("CDR: {0}")]
    Cdr(&'static str),
    /// A record declares more bytes than this reader reads into memory.
    #[error("record of {0} bytes is larger than the reader's limit")]
    RecordTooLarge(u64),
    /// Reading the file failed.
    #[error("reading the bag: {0}")]
    Io(String),
    /// A message is not where the first pass found it: the file changed since.
    #[error("the bag changed since it was opened: {0}")]
    Changed(&'static str),
}
