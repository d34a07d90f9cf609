//! A minimal MCAP writer of ROS 2 messages whose chunks are uncompressed, LZ4 or zstd: the
//! reader's tests and the fuzz target's seeds build bags with it (`host-sim run --mcap`
//! writes its files with the `mcap` crate, whose chunks are uncompressed). One chunk holds
//! every record; no summary section (the reader does not need one).

use std::io::Write;

use crate::header::{op, MAGIC};
use crate::msgs::{Header, PingInfo, ProjectedSonarImage, SonarImageData};

/// A chunk's compression.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Stored as is.
    None,
    /// An LZ4 frame.
    Lz4,
    /// A zstd frame.
    Zstd,
}

/// One message: topic, schema name, log time (ns), CDR bytes.
pub struct Entry<'a> {
    /// Topic.
    pub topic: &'a str,
    /// Schema name, e.g. `tf2_msgs/msg/TFMessage`.
    pub schema: &'a str,
    /// Log time, ns.
    pub log_time: u64,
    /// The CDR message.
    pub data: &'a [u8],
}

fn string(out: &mut Vec<u8>, s: &str) {
    out.extend((s.len() as u32).to_le_bytes());
    out.extend(s.as_bytes());
}

fn record(out: &mut Vec<u8>, opcode: u8, body: &[u8]) {
    out.push(opcode);
    out.extend((body.len() as u64).to_le_bytes());
    out.extend(body);
}

/// The schema, channel and message records of `entries` (a schema and a channel per
/// distinct schema and topic, ids from 1, written before their first message; `schemas` and
/// `topics` hold those already written).
fn records<'e>(
    entries: &[Entry<'e>],
    schemas: &mut Vec<&'e str>,
    topics: &mut Vec<&'e str>,
) -> Vec<u8> {
    let mut out = Vec::new();
    for e in entries {
        let schema_id = match schemas.iter().position(|s| *s == e.schema) {
            Some(i) => i + 1,
            None => {
                schemas.push(e.schema);
                let mut body = (schemas.len() as u16).to_le_bytes().to_vec();
                string(&mut body, e.schema);
                string(&mut body, "ros2msg");
                body.extend(0u32.to_le_bytes());
                record(&mut out, op::SCHEMA, &body);
                schemas.len()
            }
        };
        let channel_id = match topics.iter().position(|t| *t == e.topic) {
            Some(i) => i + 1,
            None => {
                topics.push(e.topic);
                let mut body = (topics.len() as u16).to_le_bytes().to_vec();
                body.extend((schema_id as u16).to_le_bytes());
                string(&mut body, e.topic);
                string(&mut body, "cdr");
                body.extend(0u32.to_le_bytes());
                record(&mut out, op::CHANNEL, &body);
                topics.len()
            }
        };
        let mut body = (channel_id as u16).to_le_bytes().to_vec();
        body.extend(0u32.to_le_bytes());
        body.extend(e.log_time.to_le_bytes());
        body.extend(e.log_time.to_le_bytes());
        body.extend(e.data);
        record(&mut out, op::MESSAGE, &body);
    }
    out
}

/// A whole MCAP file of `entries`, in one chunk compressed as `compression`.
pub fn bag(entries: &[Entry<'_>], compression: Compression) -> Vec<u8> {
    bag_in_chunks(entries, compression, entries.len().max(1))
}

/// A whole MCAP file of `entries`, `per_chunk` entries to a chunk compressed as `compression`.
pub fn bag_in_chunks(entries: &[Entry<'_>], compression: Compression, per_chunk: usize) -> Vec<u8> {
    let mut out = MAGIC.to_vec();
    let mut header = Vec::new();
    string(&mut header, "ros2");
    string(&mut header, "epssn-ros2 test writer");
    record(&mut out, op::HEADER, &header);
    let (mut schemas, mut topics) = (Vec::new(), Vec::new());
    for part in entries.chunks(per_chunk.max(1)) {
        let inner = records(part, &mut schemas, &mut topics);
        record(&mut out, op::CHUNK, &chunk(part, &inner, compression));
    }
    record(&mut out, op::FOOTER, &[0u8; 20]);
    out.extend(MAGIC);
    out
}

/// A chunk record's body: `entries`' records `inner`, compressed.
fn chunk(entries: &[Entry<'_>], inner: &[u8], compression: Compression) -> Vec<u8> {
    let (name, packed) = match compression {
        Compression::None => ("", inner.to_vec()),
        Compression::Lz4 => {
            let mut enc = lz4_flex::frame::FrameEncoder::new(Vec::new());
            // Writing to a Vec does not fail.
            let _ = enc.write_all(inner);
            ("lz4", enc.finish().unwrap_or_default())
        }
        Compression::Zstd => (
            "zstd",
            ruzstd::encoding::compress_to_vec(inner, ruzstd::encoding::CompressionLevel::Fastest),
        ),
    };
    let mut chunk = Vec::new();
    let first = entries.iter().map(|e| e.log_time).min().unwrap_or(0);
    let last = entries.iter().map(|e| e.log_time).max().unwrap_or(0);
    chunk.extend(first.to_le_bytes());
    chunk.extend(last.to_le_bytes());
    chunk.extend((inner.len() as u64).to_le_bytes());
    chunk.extend(0u32.to_le_bytes()); // CRC 0: not checked
    string(&mut chunk, name);
    chunk.extend((packed.len() as u64).to_le_bytes());
    chunk.extend(&packed);
    chunk
}

/// A ping of a sonar whose beams lie at `azimuths` (rad, in the message's Y-Z plane: Z forward,
/// positive azimuth to -Y) and samples at `ranges` (m), in frame `sonar_image`, with image
/// bytes `data` of `dtype` (sonar_image_proc's layout: range-major, beam fastest).
pub fn level_ping(
    stamp_ns: i64,
    azimuths: &[f64],
    ranges: &[f32],
    sound_speed: f32,
    dtype: u32,
    data: Vec<u8>,
) -> ProjectedSonarImage {
    ProjectedSonarImage {
        header: Header {
            stamp_ns,
            frame_id: "sonar_image".into(),
        },
        ping_info: PingInfo {
            frequency: 3e6,
            sound_speed,
            tx_beamwidths: vec![],
            rx_beamwidths: vec![],
        },
        beam_directions: azimuths.iter().map(|&a| [0.0, -a.sin(), a.cos()]).collect(),
        ranges: ranges.to_vec(),
        image: SonarImageData {
            is_bigendian: false,
            dtype,
            beam_count: azimuths.len() as u32,
            data,
        },
    }
}

/// `n` azimuths evenly spread over `width` (rad), centred on the forward axis.
pub fn even_azimuths(n: usize, width: f64) -> Vec<f64> {
    (0..n)
        .map(|b| (b as f64 / (n.max(2) - 1) as f64 - 0.5) * width)
        .collect()
}

/// CDR encoding of the two message types, little endian, for tests and seeds.
pub mod cdr {
    use crate::msgs::{ProjectedSonarImage, TransformStamped};

    /// A CDR body being written (alignment from the first byte after the header).
    struct W(Vec<u8>);

    impl W {
        fn align(&mut self, n: usize) {
            while !(self.0.len() - 4).is_multiple_of(n) {
                self.0.push(0);
            }
        }
        fn u32(&mut self, v: u32) {
            self.align(4);
            self.0.extend(v.to_le_bytes());
        }
        fn f32(&mut self, v: f32) {
            self.align(4);
            self.0.extend(v.to_le_bytes());
        }
        fn f64(&mut self, v: f64) {
            self.align(8);
            self.0.extend(v.to_le_bytes());
        }
        fn string(&mut self, s: &str) {
            self.u32(s.len() as u32 + 1);
            self.0.extend(s.as_bytes());
            self.0.push(0);
        }
        fn header(&mut self, stamp_ns: i64, frame: &str) {
            self.u32(stamp_ns.div_euclid(1_000_000_000) as i32 as u32);
            self.u32(stamp_ns.rem_euclid(1_000_000_000) as u32);
            self.string(frame);
        }
        fn f32s(&mut self, v: &[f32]) {
            self.u32(v.len() as u32);
            v.iter().for_each(|&x| self.f32(x));
        }
    }

    /// A ProjectedSonarImage.
    pub fn sonar_image(m: &ProjectedSonarImage) -> Vec<u8> {
        let mut w = W(vec![0, 1, 0, 0]);
        w.header(m.header.stamp_ns, &m.header.frame_id);
        w.f32(m.ping_info.frequency);
        w.f32(m.ping_info.sound_speed);
        w.f32s(&m.ping_info.tx_beamwidths);
        w.f32s(&m.ping_info.rx_beamwidths);
        w.u32(m.beam_directions.len() as u32);
        m.beam_directions.iter().flatten().for_each(|&c| w.f64(c));
        w.f32s(&m.ranges);
        w.0.push(u8::from(m.image.is_bigendian));
        w.u32(m.image.dtype);
        w.u32(m.image.beam_count);
        w.u32(m.image.data.len() as u32);
        w.0.extend(&m.image.data);
        w.0
    }

    /// A TFMessage.
    pub fn tf_message(transforms: &[TransformStamped]) -> Vec<u8> {
        let mut w = W(vec![0, 1, 0, 0]);
        w.u32(transforms.len() as u32);
        for t in transforms {
            w.header(t.header.stamp_ns, &t.header.frame_id);
            w.string(&t.child_frame_id);
            t.translation.iter().for_each(|&c| w.f64(c));
            t.rotation.iter().for_each(|&c| w.f64(c));
        }
        w.0
    }
}
