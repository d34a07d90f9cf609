//! The link protocol between the vehicle's host and the co-processor (UART), shared by the
//! firmware and the host tools. Wire format (see `docs/LINK.md`):
//!
//! ```text
//! SYNC (4 bytes: A5 5A 45 50) | header length H (u16 LE) | H bytes JSON header
//!     | payload (`len` bytes from the header, 0 when absent) | CRC-32 (u32 LE) over header+payload
//! ```
//!
//! The JSON header always has `t` (type) and `seq`; the other fields depend on the type
//! ([`Header`]). [`Decoder`] is a streaming decoder that never panics, resynchronises on
//! garbage and reports every rejected message with a [`DecodeError`].
//!
//! ```
//! use epssn::link::{encode_to_slice, Decoder, Message, MAX_MESSAGE_LEN};
//!
//! let mut wire = [0u8; 64];
//! let n = encode_to_slice(&Message::StatusRequest { seq: 7 }, &mut wire).unwrap();
//! let mut decoder = Decoder::new();
//! let mut got = None;
//! for &byte in &wire[..n] {
//!     decoder.push(byte);
//!     while let Some(event) = decoder.poll() {
//!         got = Some(event.map(|m| m.seq()));
//!     }
//! }
//! assert_eq!(got, Some(Ok(7)));
//! ```
//!
//! Modules, as smoltcp splits a wire format: `header` (the JSON header, error codes),
//! `message` (typed messages and payloads), `encode` and `decode` (the streaming decoder);
//! everything is re-exported here.

use crate::config;

mod decode;
mod encode;
mod header;
mod message;

pub use decode::*;
pub use encode::*;
pub use header::*;
pub use message::*;

/// Start of every message. Two bytes unlikely in text, then "EP".
pub const SYNC: [u8; 4] = [0xA5, 0x5A, b'E', b'P'];
/// Sync bytes plus the u16 header length.
pub const PREAMBLE_LEN: usize = SYNC.len() + 2;
/// Longest JSON header accepted.
pub const MAX_HEADER_LEN: usize = 192;
/// Bytes of the trailing CRC-32.
pub const CRC_LEN: usize = 4;
/// Payload of a frame message: one u8 polar image, R × B.
pub const FRAME_PAYLOAD_LEN: usize = config::INPUT_LEN;
/// Payload of a depth message: the depth map as U16F16 bits, u32 LE each.
pub const DEPTH_PAYLOAD_LEN: usize = config::DEPTH_LEN * 4;
/// Largest payload of any message type.
pub const MAX_PAYLOAD_LEN: usize = if FRAME_PAYLOAD_LEN > DEPTH_PAYLOAD_LEN {
    FRAME_PAYLOAD_LEN
} else {
    DEPTH_PAYLOAD_LEN
};
/// Largest message on the wire.
pub const MAX_MESSAGE_LEN: usize = PREAMBLE_LEN + MAX_HEADER_LEN + MAX_PAYLOAD_LEN + CRC_LEN;
/// Longest error text in an error message.
pub const MAX_ERROR_TEXT: usize = 48;
/// Longest chunk of an update image in one `chunk` message.
pub const MAX_CHUNK_LEN: usize = 4096;
const _: () = assert!(MAX_CHUNK_LEN <= MAX_PAYLOAD_LEN);
/// Source views of a depth map at most.
pub const MAX_SOURCES: usize = config::MAX_VIEWS - 1;

/// Message types (`t` in the header).
pub mod kind {
    /// Host → device: one polar image and its roll.
    pub const FRAME: &str = "frame";
    /// Device → host: a depth map.
    pub const DEPTH: &str = "depth";
    /// Host → device: asks for a status reply.
    pub const STATUS_REQUEST: &str = "status?";
    /// Device → host: counters.
    pub const STATUS: &str = "status";
    /// Device → host: a message was rejected.
    pub const ERROR: &str = "error";
    /// Host → device: stop serving (the device answers with a status first).
    pub const SHUTDOWN: &str = "shutdown";
    /// Host → device, test builds only (feature `fault-injection`): provoke a fault,
    /// [`fault::inject`](crate::fault::inject) in `code`.
    #[cfg(feature = "fault-injection")]
    pub const INJECT: &str = "inject";
    /// Either direction: starts a session; accepted whatever its `seq` (docs/LINK.md).
    pub const HELLO: &str = "hello";
    /// Host → device: a chunk of a signed update image, at `off`, with its `crc`.
    pub const CHUNK: &str = "chunk";
    /// Host → device: asks what the device holds of an upload.
    pub const UPLOAD_REQUEST: &str = "upload?";
    /// Device → host: what the upload slot holds (the reply to `chunk` and `upload?`).
    pub const UPLOAD: &str = "upload";
    /// Host → device: check the held upload and make it the serving model.
    pub const COMMIT: &str = "commit";
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attitude::{Attitude, Verdict};
    use crate::crc32::Crc32;
    use crate::pairing::PairCheck;
    use core::fmt;
    use fixed::types::U16F16;
    use std::vec::Vec;

    fn raw_bytes(h: &Header<'_>, payload: &[u8]) -> Vec<u8> {
        let mut v = Vec::new();
        encode_raw(h, message::Payload::Bytes(payload), &mut |b: &[u8]| {
            v.extend_from_slice(b);
            Ok::<(), ()>(())
        })
        .unwrap();
        v
    }

    fn wire(msg: &Message<'_>) -> Vec<u8> {
        let mut v = Vec::new();
        encode(msg, &mut |b: &[u8]| {
            v.extend_from_slice(b);
            Ok::<(), ()>(())
        })
        .unwrap();
        v
    }

    fn raw(h: &Header<'_>, payload: &[u8]) -> Vec<u8> {
        let mut v = Vec::new();
        encode_raw(h, Payload::Bytes(payload), &mut |b: &[u8]| {
            v.extend_from_slice(b);
            Ok::<(), ()>(())
        })
        .unwrap();
        v
    }

    /// Everything the decoder reports for `bytes`, as owned summaries.
    #[derive(Debug, PartialEq)]
    enum Ev {
        Msg(u32, &'static str, usize),
        Err(DecodeError),
    }

    fn feed(d: &mut Decoder, bytes: &[u8]) -> Vec<Ev> {
        let mut out = drain(d);
        for &b in bytes {
            d.push(b);
            out.extend(drain(d));
        }
        out
    }

    fn drain(d: &mut Decoder) -> Vec<Ev> {
        let mut out = Vec::new();
        {
            while let Some(e) = d.poll() {
                out.push(match e {
                    Ok(m) => {
                        let payload = match &m {
                            Message::Frame { image, .. } => image.len(),
                            Message::Depth { depth, .. } => depth.len(),
                            Message::Chunk { data, .. } => data.len(),
                            _ => 0,
                        };
                        Ev::Msg(m.seq(), m.kind(), payload)
                    }
                    Err(e) => Ev::Err(e),
                });
            }
        }
        out
    }

    fn image(seed: u8) -> Vec<u8> {
        (0..FRAME_PAYLOAD_LEN)
            .map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed))
            .collect()
    }

    fn frame_header(seq: u32) -> Header<'static> {
        Header {
            t: kind::FRAME,
            seq,
            roll: Some(7.0),
            r: Some(config::INPUT_RANGE_BINS as u32),
            b: Some(config::INPUT_COLUMNS as u32),
            len: Some(FRAME_PAYLOAD_LEN as u32),
            ..Header::default()
        }
    }

    #[test]
    fn attitude_and_pair_fields_are_checked() {
        let img = image(1);
        // One frame header; the cases below differ only in its attitude fields.
        let frame = frame_header(1);
        let decode = |h: &Header<'_>| {
            let mut d = Decoder::new();
            for b in raw_bytes(h, &img) {
                d.push(b);
            }
            match d.poll().unwrap() {
                Ok(Message::Frame { attitude, .. }) => Ok(attitude.map(|a| a.to_array())),
                Ok(m) => panic!("{m:?}"),
                Err(e) => Err(e),
            }
        };
        let frame_with = |q: Option<[f32; 4]>| {
            let mut h = frame.clone();
            h.set_q(q);
            decode(&h)
        };
        // An older host's frame (no `q`) decodes, without attitude: the roll-only rule.
        assert_eq!(frame_with(None), Ok(None));
        assert_eq!(
            frame_with(Some([0.0, 1.0, 0.0, 0.0])),
            Ok(Some([0.0, 1.0, 0.0, 0.0]))
        );
        for bad in [[0.0; 4], [2.0, 0.0, 0.0, 0.0], [f32::MAX, 0.0, 0.0, 0.0]] {
            assert_eq!(
                frame_with(Some(bad)),
                Err(DecodeError::BadField { field: "q" }),
                "{bad:?}"
            );
        }
        // Some of the four fields only: refused.
        let partial = Header {
            qw: Some(1.0),
            ..frame.clone()
        };
        assert_eq!(decode(&partial), Err(DecodeError::BadField { field: "q" }));
        // A status with an unknown reason or missing figures is refused.
        let status_with = |why: &'static str, proll: Option<f32>| {
            let h = Header {
                t: kind::STATUS,
                seq: 2,
                frames: Some(1),
                depths: Some(0),
                errors: Some(0),
                stack: Some(0),
                pref: Some(1),
                psrc: Some(2),
                proll,
                why: Some(why),
                ..Header::default()
            };
            let mut d = Decoder::new();
            for b in raw_bytes(&h, &[]) {
                d.push(b);
            }
            match d.poll().unwrap() {
                Ok(Message::Status { status, .. }) => Ok(status.pair),
                Ok(m) => panic!("{m:?}"),
                Err(e) => Err(e),
            }
        };
        assert_eq!(
            status_with("maybe", Some(7.0)),
            Err(DecodeError::BadField { field: "why" })
        );
        assert_eq!(
            status_with("roll", None),
            Err(DecodeError::BadField {
                field: "pref/psrc/proll"
            })
        );
        let p = status_with("roll_only", Some(7.0)).unwrap().unwrap();
        assert_eq!(p.verdict, Verdict::RollOnly);
        assert!(p.residual_deg.is_nan());
    }

    #[test]
    fn round_trip_every_type() {
        let img = image(3);
        let depth: Vec<U16F16> = (0..config::DEPTH_LEN)
            .map(|i| U16F16::from_bits(0x0002_0000 + i as u32 * 77))
            .collect();
        let mut srcs = heapless::Vec::new();
        srcs.push(11).unwrap();
        let record = crate::fault::Record::panic(&"boom", "src/x.rs", 1, 2).to_bytes();
        let msgs = [
            Message::Frame {
                seq: 1,
                roll_deg: -7.25,
                attitude: Attitude::from_header_deg(10.0, 1.0, -2.0, 0.0, 0.0, -7.25),
                image: &img,
            },
            Message::Depth {
                seq: 2,
                reference: 10,
                sources: srcs,
                instructions: 123_456_789,
                depth: DepthData::Values(&depth),
                pair: Some(PairCheck {
                    reference: 10,
                    source: 11,
                    roll_deg: 7.01,
                    residual_deg: 0.03,
                    verdict: Verdict::Accepted,
                }),
            },
            Message::StatusRequest { seq: 3 },
            Message::Status {
                seq: 4,
                status: Status {
                    frames: 5,
                    depth_maps: 4,
                    errors: 3,
                    stack_high_water: 2048,
                    cached: 2,
                    pair: Some(PairCheck {
                        reference: 3,
                        source: 4,
                        roll_deg: 6.9,
                        residual_deg: 1.5,
                        verdict: Verdict::Residual,
                    }),
                    model: None,
                },
            },
            Message::Error {
                seq: 5,
                code: ErrorCode::BadCrc.code(),
                msg: "crc 1 != 2",
            },
            Message::Shutdown { seq: 6 },
            Message::hello(7),
            Message::Hello {
                seq: 9,
                status: None,
                reset: None,
                record: None,
                ack: Some(0xDEAD_BEEF),
            },
            Message::Hello {
                seq: 8,
                status: Some(Status {
                    frames: 1,
                    depth_maps: 2,
                    errors: 3,
                    stack_high_water: 4,
                    cached: 5,
                    pair: None,
                    model: Some(Serving {
                        slot: Some(1),
                        version: u32::MAX,
                    }),
                }),
                reset: Some(crate::fault::ResetCause::PowerOn),
                record: None,
                ack: None,
            },
            Message::Hello {
                seq: 10,
                status: Some(Status::default()),
                reset: Some(crate::fault::ResetCause::Panic),
                record: Some(&record[..]),
                ack: None,
            },
            Message::Chunk {
                seq: 11,
                offset: 4096,
                crc: 0x1234_5678,
                data: &img[..MAX_CHUNK_LEN],
            },
            Message::UploadRequest { seq: 12 },
            Message::Upload {
                seq: 13,
                slot: 1,
                held: None,
            },
            Message::Upload {
                seq: 14,
                slot: 0,
                held: Some(Held {
                    id: u32::MAX,
                    version: u32::MAX,
                    total: u32::MAX,
                    held: u32::MAX,
                }),
            },
            Message::Commit { seq: 15 },
            Message::Status {
                seq: 16,
                status: Status {
                    model: Some(Serving {
                        slot: None,
                        version: 0,
                    }),
                    ..Status::default()
                },
            },
        ];
        let mut d = Decoder::new();
        for m in &msgs {
            let w = wire(m);
            let mut got = Vec::new();
            for &b in &w {
                d.push(b);
                while let Some(e) = d.poll() {
                    let e = e.unwrap();
                    // Compare through the depth values: bytes received vs values sent.
                    match (&e, m) {
                        (
                            Message::Depth {
                                depth: DepthData::Bytes(_),
                                ..
                            },
                            Message::Depth { depth: sent, .. },
                        ) => {
                            let Message::Depth { depth: got_d, .. } = &e else {
                                unreachable!()
                            };
                            let mut a = std::vec![U16F16::ZERO; config::DEPTH_LEN];
                            assert!(got_d.copy_to(&mut a));
                            for (i, v) in a.iter().enumerate() {
                                assert_eq!(Some(*v), sent.get(i));
                            }
                            let (h1, _) = e.to_parts();
                            let (h2, _) = m.to_parts();
                            assert_eq!(h1, h2);
                        }
                        _ => assert_eq!(&e, m),
                    }
                    got.push(e.seq());
                }
            }
            assert_eq!(got, std::vec![m.seq()]);
            assert_eq!(d.pending(), 0);
        }
    }

    #[test]
    fn update_messages_with_missing_or_wrong_fields_are_refused() {
        let chunk = |off: Option<u32>, crc: Option<u32>, len: usize| {
            let h = Header {
                t: kind::CHUNK,
                seq: 1,
                off,
                crc,
                len: (len > 0).then_some(len as u32),
                ..Header::default()
            };
            let payload = std::vec![7u8; len];
            feed(&mut Decoder::new(), &raw_bytes(&h, &payload))
        };
        assert_eq!(
            chunk(Some(0), Some(1), 1),
            std::vec![Ev::Msg(1, kind::CHUNK, 1)]
        );
        let field = |field| std::vec![Ev::Err(DecodeError::BadField { field })];
        assert_eq!(chunk(None, Some(1), 8), field("off"));
        assert_eq!(chunk(Some(0), None, 8), field("crc"));
        let bad_len = |len| {
            std::vec![Ev::Err(DecodeError::BadLength {
                len,
                expected: MAX_CHUNK_LEN as u32
            })]
        };
        assert_eq!(chunk(Some(0), Some(1), 0), bad_len(0));
        assert_eq!(
            chunk(Some(0), Some(1), MAX_CHUNK_LEN + 1),
            bad_len(MAX_CHUNK_LEN as u32 + 1)
        );
        let upload = |h: Header<'_>| feed(&mut Decoder::new(), &raw_bytes(&h, &[]));
        let base = Header {
            t: kind::UPLOAD,
            seq: 2,
            slot: Some(1),
            ..Header::default()
        };
        assert_eq!(upload(base.clone()), std::vec![Ev::Msg(2, kind::UPLOAD, 0)]);
        assert_eq!(
            upload(Header {
                slot: None,
                ..base.clone()
            }),
            field("slot")
        );
        let partial = Header {
            id: Some(1),
            ver: Some(2),
            ..base.clone()
        };
        assert_eq!(upload(partial), field("id/ver/total/held"));
        let over = Header {
            id: Some(1),
            ver: Some(2),
            total: Some(10),
            held: Some(11),
            ..base
        };
        assert_eq!(upload(over), field("held"));
        // A commit or an upload request carries nothing.
        let commit = Header {
            t: kind::COMMIT,
            seq: 3,
            len: Some(4),
            ..Header::default()
        };
        assert_eq!(
            feed(&mut Decoder::new(), &raw_bytes(&commit, &[0; 4])),
            std::vec![Ev::Err(DecodeError::BadLength {
                len: 4,
                expected: 0
            })]
        );
    }

    #[test]
    fn garbage_before_message_is_reported_then_message_decoded() {
        let mut bytes = std::vec![0x00, 0xA5, 0x11, 0xA5, 0x5A, b'E', 0x42];
        bytes.extend(wire(&Message::StatusRequest { seq: 1 }));
        let mut d = Decoder::new();
        assert_eq!(
            feed(&mut d, &bytes),
            std::vec![
                Ev::Err(DecodeError::BadSync { skipped: 7 }),
                Ev::Msg(1, kind::STATUS_REQUEST, 0)
            ]
        );
    }

    #[test]
    fn header_length_zero_or_too_long() {
        for len in [0usize, MAX_HEADER_LEN + 1, 0xFFFF] {
            let mut bytes = SYNC.to_vec();
            bytes.extend((len as u16).to_le_bytes());
            bytes.extend(wire(&Message::StatusRequest { seq: 9 }));
            let mut d = Decoder::new();
            assert_eq!(
                feed(&mut d, &bytes),
                std::vec![
                    Ev::Err(DecodeError::HeaderTooLong { len }),
                    Ev::Msg(9, kind::STATUS_REQUEST, 0)
                ]
            );
        }
    }

    fn with_json(json: &[u8], payload: &[u8]) -> Vec<u8> {
        let mut v = SYNC.to_vec();
        v.extend((json.len() as u16).to_le_bytes());
        v.extend_from_slice(json);
        v.extend_from_slice(payload);
        let mut c = Crc32::new();
        c.update(json);
        c.update(payload);
        v.extend(c.finish().to_le_bytes());
        v
    }

    #[test]
    fn bad_json_and_missing_fields() {
        let cases: [(&[u8], DecodeError); 6] = [
            (b"{\"t\":\"frame\",", DecodeError::BadJson),
            (b"not json at all", DecodeError::BadJson),
            (b"{\"seq\":1}", DecodeError::BadJson),
            (b"{\"t\":\"status?\",\"seq\":1} x", DecodeError::BadJson),
            (
                b"{\"t\":\"frame\",\"seq\":1,\"r\":256,\"b\":64,\"len\":16384}",
                DecodeError::BadField { field: "roll" },
            ),
            (
                b"{\"t\":\"error\",\"seq\":1}",
                DecodeError::BadField { field: "code" },
            ),
        ];
        for (json, err) in cases {
            let mut bytes = with_json(json, &[]);
            bytes.extend(wire(&Message::Shutdown { seq: 2 }));
            let mut d = Decoder::new();
            let ev = feed(&mut d, &bytes);
            assert_eq!(ev.first(), Some(&Ev::Err(err)), "{:?}", json);
            assert_eq!(ev.last(), Some(&Ev::Msg(2, kind::SHUTDOWN, 0)));
            assert!(ev[1..ev.len() - 1]
                .iter()
                .all(|e| matches!(e, Ev::Err(DecodeError::BadSync { .. }))));
        }
        assert_eq!(DecodeError::BadJson.code(), ErrorCode::BadJson);
    }

    #[test]
    fn bad_crc_then_resync() {
        let mut bytes = wire(&Message::StatusRequest { seq: 1 });
        let n = bytes.len();
        bytes[n - 1] ^= 0x01;
        bytes.extend(wire(&Message::StatusRequest { seq: 2 }));
        let mut d = Decoder::new();
        let ev = feed(&mut d, &bytes);
        assert!(matches!(ev[0], Ev::Err(DecodeError::BadCrc { .. })));
        assert_eq!(ev.last(), Some(&Ev::Msg(2, kind::STATUS_REQUEST, 0)));
        // Corrupt payload of a frame: same.
        let img = image(1);
        let mut bytes = wire(&Message::Frame {
            seq: 3,
            roll_deg: 0.0,
            attitude: None,
            image: &img,
        });
        bytes[100] ^= 0x80;
        bytes.extend(wire(&Message::StatusRequest { seq: 4 }));
        let ev = feed(&mut d, &bytes);
        assert!(matches!(ev[0], Ev::Err(DecodeError::BadCrc { .. })));
        assert_eq!(ev.last(), Some(&Ev::Msg(4, kind::STATUS_REQUEST, 0)));
    }

    #[test]
    fn oversized_unknown_geometry_length() {
        let img = image(2);
        let mut big = frame_header(1);
        big.len = Some(MAX_PAYLOAD_LEN as u32 + 1);
        // Twice the build's range bins: a geometry no spec of this build has.
        let (r, b) = (
            2 * config::INPUT_RANGE_BINS as u32,
            config::INPUT_COLUMNS as u32,
        );
        let mut geo = frame_header(1);
        geo.r = Some(r);
        geo.len = Some(r * b);
        let mut short = frame_header(1);
        short.len = Some(100);
        let unknown = Header {
            t: "reboot",
            seq: 1,
            ..Header::default()
        };
        let mut status_len = Header {
            t: kind::STATUS_REQUEST,
            seq: 1,
            ..Header::default()
        };
        status_len.len = Some(4);
        let cases = [
            (
                raw(&big, &[]),
                DecodeError::Oversized {
                    len: MAX_PAYLOAD_LEN as u32 + 1,
                },
            ),
            (raw(&geo, &img), DecodeError::WrongGeometry { r, b }),
            (
                raw(&short, &img[..100]),
                DecodeError::BadLength {
                    len: 100,
                    expected: FRAME_PAYLOAD_LEN as u32,
                },
            ),
            (raw(&unknown, &[]), DecodeError::UnknownType),
            (
                raw(&status_len, &[1, 2, 3, 4]),
                DecodeError::BadLength {
                    len: 4,
                    expected: 0,
                },
            ),
        ];
        for (mut bytes, err) in cases {
            bytes.extend(wire(&Message::StatusRequest { seq: 2 }));
            let mut d = Decoder::new();
            let ev = feed(&mut d, &bytes);
            assert_eq!(ev[0], Ev::Err(err));
            assert_eq!(ev.last(), Some(&Ev::Msg(2, kind::STATUS_REQUEST, 0)));
            assert!(ev.iter().filter(|e| matches!(e, Ev::Msg(..))).count() == 1);
        }
        assert_eq!(
            DecodeError::WrongGeometry { r: 1, b: 1 }.code(),
            ErrorCode::WrongGeometry
        );
    }

    #[test]
    fn out_of_order_is_rejected_and_does_not_advance() {
        let mut d = Decoder::new();
        let mut bytes = wire(&Message::StatusRequest { seq: 5 });
        bytes.extend(wire(&Message::StatusRequest { seq: 5 }));
        bytes.extend(wire(&Message::StatusRequest { seq: 3 }));
        bytes.extend(wire(&Message::StatusRequest { seq: 6 }));
        assert_eq!(
            feed(&mut d, &bytes),
            std::vec![
                Ev::Msg(5, kind::STATUS_REQUEST, 0),
                Ev::Err(DecodeError::OutOfOrder { last: 5, seq: 5 }),
                Ev::Err(DecodeError::OutOfOrder { last: 5, seq: 3 }),
                Ev::Msg(6, kind::STATUS_REQUEST, 0),
            ]
        );
        assert_eq!(d.last_seq(), Some(6));
    }

    fn hello(seq: u32) -> Message<'static> {
        Message::hello(seq)
    }

    #[test]
    fn seq_u32_max_blocks_until_hello_even_after_idle() {
        let mut d = Decoder::new();
        let sr = |seq| wire(&Message::StatusRequest { seq });
        let mut bytes = sr(u32::MAX);
        bytes.extend(sr(0));
        assert_eq!(
            feed(&mut d, &bytes),
            std::vec![
                Ev::Msg(u32::MAX, kind::STATUS_REQUEST, 0),
                Ev::Err(DecodeError::OutOfOrder {
                    last: u32::MAX,
                    seq: 0
                }),
            ]
        );
        // An idle line is not a session restart.
        assert_eq!(d.idle(), None);
        assert_eq!(
            feed(&mut d, &sr(1)),
            std::vec![Ev::Err(DecodeError::OutOfOrder {
                last: u32::MAX,
                seq: 1
            })]
        );
        // A hello is: accepted at any seq, and the sequence goes on from it.
        let mut bytes = wire(&hello(0));
        bytes.extend(sr(1));
        bytes.extend(sr(1));
        assert_eq!(
            feed(&mut d, &bytes),
            std::vec![
                Ev::Msg(0, kind::HELLO, 0),
                Ev::Msg(1, kind::STATUS_REQUEST, 0),
                Ev::Err(DecodeError::OutOfOrder { last: 1, seq: 1 }),
            ]
        );
        assert_eq!(d.last_seq(), Some(1));
    }

    #[test]
    fn restart_with_lower_seq_after_hello_and_hello_mid_stream() {
        let mut d = Decoder::new();
        let sr = |seq| wire(&Message::StatusRequest { seq });
        let mut bytes = sr(100);
        bytes.extend(sr(3)); // an old host restarted without hello: refused, as before
        bytes.extend(wire(&hello(3))); // with hello: served
        bytes.extend(sr(4));
        bytes.extend(wire(&hello(50))); // mid-stream, greater seq: also a restart
        bytes.extend(sr(51));
        bytes.extend(wire(&hello(50))); // a repeated hello, same seq: accepted
        bytes.extend(sr(50));
        assert_eq!(
            feed(&mut d, &bytes),
            std::vec![
                Ev::Msg(100, kind::STATUS_REQUEST, 0),
                Ev::Err(DecodeError::OutOfOrder { last: 100, seq: 3 }),
                Ev::Msg(3, kind::HELLO, 0),
                Ev::Msg(4, kind::STATUS_REQUEST, 0),
                Ev::Msg(50, kind::HELLO, 0),
                Ev::Msg(51, kind::STATUS_REQUEST, 0),
                Ev::Msg(50, kind::HELLO, 0),
                Ev::Err(DecodeError::OutOfOrder { last: 50, seq: 50 }),
            ]
        );
        // A corrupt hello restarts nothing.
        let mut bad = wire(&hello(0));
        let n = bad.len();
        bad[n - 1] ^= 1;
        let ev = feed(&mut d, &bad);
        assert!(matches!(ev[0], Ev::Err(DecodeError::BadCrc { .. })));
        assert_eq!(d.last_seq(), Some(50));
        // The host side: restart() forgets the sequence.
        d.restart();
        assert_eq!(
            feed(&mut d, &sr(0)),
            std::vec![Ev::Msg(0, kind::STATUS_REQUEST, 0)]
        );
    }

    #[test]
    fn message_hidden_behind_a_corrupt_length_is_found() {
        // A status request whose header length claims one byte too many swallows the next
        // message's first byte; the rescan must still find that message.
        let mut first = wire(&Message::StatusRequest { seq: 1 });
        let h = u16::from_le_bytes([first[4], first[5]]) + 1;
        first[4..6].copy_from_slice(&h.to_le_bytes());
        let mut bytes = first;
        bytes.extend(wire(&Message::StatusRequest { seq: 2 }));
        let mut d = Decoder::new();
        let ev = feed(&mut d, &bytes);
        assert!(matches!(ev[0], Ev::Err(_)));
        assert_eq!(ev.last(), Some(&Ev::Msg(2, kind::STATUS_REQUEST, 0)));
    }

    #[test]
    fn depth_data_access_is_bounded() {
        let bytes = [1u8, 0, 0, 0, 2, 0, 0];
        let d = DepthData::Bytes(&bytes);
        assert_eq!(d.len(), 1);
        assert_eq!(d.get(0), Some(U16F16::from_bits(1)));
        assert_eq!(d.get(1), None);
        assert_eq!(d.get(usize::MAX), None);
        let mut out = [U16F16::ZERO; 2];
        assert!(!d.copy_to(&mut out));
        let mut small = [0u8; 8];
        assert_eq!(
            encode_to_slice(&Message::Shutdown { seq: 1 }, &mut small),
            Err(EncodeError::Sink(SliceFull))
        );
    }

    #[test]
    fn error_text_is_cut_not_failed() {
        let t = error_text(&DecodeError::BadCrc {
            wire: 1,
            computed: 2,
        });
        assert_eq!(t.as_str(), "crc 00000001 != 00000002");
        struct Long;
        impl fmt::Display for Long {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                for _ in 0..100 {
                    f.write_str("ab")?;
                }
                Ok(())
            }
        }
        assert_eq!(error_text(&Long).len(), MAX_ERROR_TEXT);
        for c in ErrorCode::ALL {
            assert_eq!(ErrorCode::from_code(c.code()), Some(c));
        }
        assert_eq!(ErrorCode::from_code(0), None);
    }

    /// SplitMix64, for reproducible fuzzing without a dependency.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n.max(1) as u64) as usize
        }
    }

    #[test]
    fn fuzz_random_and_mutated_input_never_panics_and_resyncs() {
        let mut rng = Rng(0x5EED);
        let img = image(9);
        let mut d = Decoder::new();
        let mut seq = 0u32;
        for round in 0..400 {
            // A corrupted thing: random bytes, or a valid message with mutations.
            let mut junk: Vec<u8> = match rng.below(3) {
                0 => (0..rng.below(300)).map(|_| rng.next() as u8).collect(),
                _ => {
                    seq += 1;
                    let mut w = if rng.below(4) == 0 {
                        wire(&Message::Frame {
                            seq,
                            roll_deg: 14.0,
                            attitude: None,
                            image: &img,
                        })
                    } else {
                        wire(&Message::Error {
                            seq,
                            code: 3,
                            msg: "x",
                        })
                    };
                    let header_end = PREAMBLE_LEN + (w[4] as usize | (w[5] as usize) << 8);
                    for _ in 0..1 + rng.below(4) {
                        // Mostly in the preamble and header, where it matters for framing.
                        let at = if rng.below(2) == 0 {
                            rng.below(header_end)
                        } else {
                            rng.below(w.len())
                        };
                        w[at] ^= 1 << rng.below(8);
                    }
                    if rng.below(4) == 0 {
                        w.truncate(rng.below(w.len()));
                    }
                    w
                }
            };
            // Then a valid message, which must come out (with a fresh, larger seq).
            seq += 1;
            let valid = wire(&Message::StatusRequest { seq });
            junk.extend_from_slice(&valid);
            let mut ev = feed(&mut d, &junk);
            // A truncated frame can swallow the valid message while it waits for its
            // payload: the line then goes idle, which abandons it and rescans.
            while let Some(e) = d.idle() {
                ev.push(Ev::Err(e));
                ev.extend(drain(&mut d));
            }
            // Bit flips break the CRC, so the valid message is the only one.
            assert_eq!(
                ev.last(),
                Some(&Ev::Msg(seq, kind::STATUS_REQUEST, 0)),
                "round {round}: {ev:?}"
            );
            assert_eq!(
                ev.iter().filter(|e| matches!(e, Ev::Msg(..))).count(),
                1,
                "round {round}"
            );
            assert_eq!(d.pending(), 0, "round {round}");
        }
        assert_eq!(d.overflows(), 0);
    }

    #[test]
    fn never_panics_on_pure_noise_and_survives_overflow() {
        let mut rng = Rng(42);
        let mut d = Decoder::new();
        for _ in 0..200_000 {
            // Biased towards sync bytes so that headers get parsed.
            let b = match rng.below(8) {
                0 => SYNC[rng.below(4)],
                _ => rng.next() as u8,
            };
            d.push(b);
            while let Some(e) = d.poll() {
                let _ = e.map(|m| m.seq());
            }
        }
        // Pushing without polling fills the buffer; the decoder restarts instead of failing.
        let mut d = Decoder::new();
        for b in SYNC
            .iter()
            .copied()
            .chain(core::iter::repeat_n(0x20, MAX_MESSAGE_LEN))
        {
            d.push(b);
        }
        assert!(d.overflows() > 0);
        let mut n = 0;
        while d.poll().is_some() {
            n += 1;
            assert!(n < 10_000);
        }
        for &b in &wire(&Message::StatusRequest { seq: 77 }) {
            d.push(b);
        }
        let mut last = None;
        while let Some(e) = d.poll() {
            last = Some(e.map(|m| m.seq()));
        }
        assert_eq!(last, Some(Ok(77)));
    }
}
