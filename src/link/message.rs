//! Link messages as typed values: status, depth data, [`Message`], payloads.

use core::fmt;

use fixed::types::U16F16;

use crate::attitude::{Attitude, Verdict};
use crate::config;
use crate::fault::ResetCause;
use crate::pairing::PairCheck;

use super::header::Header;
use super::{kind, MAX_ERROR_TEXT, MAX_SOURCES};

/// Short error text for an error message: `Display` of `e`, cut to [`MAX_ERROR_TEXT`].
pub fn error_text(e: &impl fmt::Display) -> heapless::String<MAX_ERROR_TEXT> {
    struct Cut(heapless::String<MAX_ERROR_TEXT>);
    impl fmt::Write for Cut {
        fn write_str(&mut self, s: &str) -> fmt::Result {
            for c in s.chars() {
                // Full: drop the rest rather than fail the whole message.
                if self.0.push(c).is_err() {
                    break;
                }
            }
            Ok(())
        }
    }
    let mut cut = Cut(heapless::String::new());
    let _ = fmt::write(&mut cut, format_args!("{e}"));
    cut.0
}

/// Device counters carried by a status message, and the last pairing decision.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// Frames accepted.
    pub frames: u32,
    /// Depth maps sent.
    pub depth_maps: u32,
    /// Error replies sent.
    pub errors: u32,
    /// Stack high-water mark, bytes.
    pub stack_high_water: u32,
    /// Feature maps cached for pairing.
    pub cached: u32,
    /// The candidate pair the last frame formed and the gate's verdict on it (a status reply
    /// after a frame carries a rejection; none when the frame formed no candidate).
    pub pair: Option<PairCheck>,
    /// The model that serves (`slot`, `ver` on the wire): in a device's hello and the reply
    /// to a `commit`; none in a plain status.
    pub model: Option<Serving>,
}

/// Which model serves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Serving {
    /// The slot it lies in; `None` for the model compiled into the image.
    pub slot: Option<u8>,
    /// Its version (0: the compiled-in model).
    pub version: u32,
}

/// What the upload slot holds of an upload: the device's reply to `chunk` and `upload?`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Held {
    /// Which upload: CRC-32 of the image's header.
    pub id: u32,
    /// The model version it carries.
    pub version: u32,
    /// Bytes of the whole image.
    pub total: u32,
    /// Bytes held from the start: the upload resumes here.
    pub held: u32,
}

/// Writes a pair check into a header. Not inlined: one copy for its two callers (flash).
#[inline(never)]
fn put_pair(h: &mut Header<'_>, pair: &Option<PairCheck>) {
    if let Some(p) = pair {
        h.pref = Some(p.reference);
        h.psrc = Some(p.source);
        h.proll = Some(p.roll_deg);
        // JSON has no NaN: a missing residual (roll-only) is an absent field.
        h.pres = p.residual_deg.is_finite().then_some(p.residual_deg);
        h.why = Some(p.verdict.reason());
    }
}

/// Writes the counters and the pair check of a status or a device's hello.
fn put_status(h: &mut Header<'_>, status: &Status) {
    h.frames = Some(status.frames);
    h.depths = Some(status.depth_maps);
    h.errors = Some(status.errors);
    h.stack = Some(status.stack_high_water);
    h.cached = Some(status.cached);
    put_pair(h, &status.pair);
    if let Some(m) = status.model {
        h.slot = m.slot;
        h.ver = Some(m.version);
    }
}

#[cfg_attr(target_os = "none", allow(dead_code))]
/// The pair check of a received header: `None` when it carries none, `Err` when it is
/// incomplete or its reason unknown.
pub(super) fn pair_of(h: &Header<'_>) -> Result<Option<PairCheck>, &'static str> {
    let Some(why) = h.why else {
        return Ok(None);
    };
    let verdict = Verdict::ALL
        .iter()
        .copied()
        .find(|v| v.reason() == why)
        .ok_or("why")?;
    match (h.pref, h.psrc, h.proll) {
        (Some(reference), Some(source), Some(roll_deg)) => Ok(Some(PairCheck {
            reference,
            source,
            roll_deg,
            residual_deg: h.pres.unwrap_or(f32::NAN),
            verdict,
        })),
        _ => Err("pref/psrc/proll"),
    }
}

/// A depth map payload: values to send, or received little-endian bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DepthData<'a> {
    /// `config::DEPTH_LEN` values, to encode.
    Values(&'a [U16F16]),
    /// Received payload, `config::DEPTH_LEN` × u32 LE.
    Bytes(&'a [u8]),
}

impl DepthData<'_> {
    /// Values in the payload.
    pub fn len(&self) -> usize {
        match self {
            DepthData::Values(v) => v.len(),
            DepthData::Bytes(b) => b.len() / 4,
        }
    }

    /// True without values.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i`, if present.
    pub fn get(&self, i: usize) -> Option<U16F16> {
        match self {
            DepthData::Values(v) => v.get(i).copied(),
            DepthData::Bytes(b) => {
                let at = i.checked_mul(4)?;
                let w = b.get(at..at.checked_add(4)?)?;
                Some(U16F16::from_bits(u32::from_le_bytes([
                    w[0], w[1], w[2], w[3],
                ])))
            }
        }
    }

    /// Copies the values into `out` (same length), or returns false.
    pub fn copy_to(&self, out: &mut [U16F16]) -> bool {
        if out.len() != self.len() {
            return false;
        }
        for (i, o) in out.iter_mut().enumerate() {
            match self.get(i) {
                Some(v) => *o = v,
                None => return false,
            }
        }
        true
    }
}

/// A typed message.
#[derive(Clone, Debug, PartialEq)]
pub enum Message<'a> {
    /// Host → device: a polar image (`config::INPUT_LEN` bytes, `img[i · B + k]`).
    Frame {
        /// Sequence number.
        seq: u32,
        /// Sonar roll, degrees.
        roll_deg: f32,
        /// The sonar's attitude; `None` (an older host) pairs by the roll-only rule.
        attitude: Option<Attitude>,
        /// The image.
        image: &'a [u8],
    },
    /// Device → host: a depth map.
    Depth {
        /// Sequence number.
        seq: u32,
        /// `seq` of the reference frame.
        reference: u32,
        /// `seq`s of the source frames (view 1 first).
        sources: heapless::Vec<u32, MAX_SOURCES>,
        /// Instructions spent: the newest frame's features plus the depth map.
        instructions: u32,
        /// The map, `config::DEPTH_LEN` values, `[E][A]`, metres.
        depth: DepthData<'a>,
        /// The gate's figures for the pair (its residual, or the roll-only fallback).
        pair: Option<PairCheck>,
    },
    /// Host → device: status request.
    StatusRequest {
        /// Sequence number.
        seq: u32,
    },
    /// Device → host: status reply.
    Status {
        /// Sequence number.
        seq: u32,
        /// The counters.
        status: Status,
    },
    /// Device → host: a rejected message.
    Error {
        /// Sequence number.
        seq: u32,
        /// [`ErrorCode`](super::ErrorCode) number.
        code: u16,
        /// Short text.
        msg: &'a str,
    },
    /// Either direction: starts a session. Host → device without counters (any `seq`: it
    /// restarts the sequence); the device answers with one carrying its counters, why it last
    /// reset and, until a hello acknowledges it, its fault record.
    Hello {
        /// Sequence number (accepted whatever the previous one was).
        seq: u32,
        /// The device's counters (device → host only).
        status: Option<Status>,
        /// Why the device last reset (device → host only; `reset` on the wire).
        reset: Option<ResetCause>,
        /// The fault record, [`RECORD_LEN`](crate::fault::RECORD_LEN) bytes for
        /// [`Record::from_bytes`](crate::fault::Record::from_bytes) (device → host only, the
        /// payload; present until acknowledged).
        record: Option<&'a [u8]>,
        /// The [`id`](crate::fault::Record::id) of the record the host read (host → device
        /// only, `ack`): the device forgets that record.
        ack: Option<u32>,
    },
    /// Host → device: stop serving.
    Shutdown {
        /// Sequence number.
        seq: u32,
    },
    /// Host → device: bytes of a signed update image (1 to
    /// [`MAX_CHUNK_LEN`](super::MAX_CHUNK_LEN)).
    Chunk {
        /// Sequence number.
        seq: u32,
        /// Offset in the image (`off`).
        offset: u32,
        /// CRC-32 of `data`.
        crc: u32,
        /// The bytes.
        data: &'a [u8],
    },
    /// Host → device: what is held of an upload?
    UploadRequest {
        /// Sequence number.
        seq: u32,
    },
    /// Device → host: the upload slot and what it holds.
    Upload {
        /// Sequence number.
        seq: u32,
        /// The slot uploads go to.
        slot: u8,
        /// The upload it holds; `None` before one has begun.
        held: Option<Held>,
    },
    /// Host → device: check the held upload and make it serve (answered by a `status`
    /// carrying the serving model, or an error saying why not).
    Commit {
        /// Sequence number.
        seq: u32,
    },
    /// Host → device, test builds only: provoke the fault `what`
    /// ([`fault::inject`](crate::fault::inject); `code` on the wire).
    #[cfg(feature = "fault-injection")]
    Inject {
        /// Sequence number.
        seq: u32,
        /// Which fault.
        what: u16,
    },
}

impl Message<'_> {
    /// A host's hello: a new session, nothing acknowledged.
    pub fn hello(seq: u32) -> Self {
        Message::Hello {
            seq,
            status: None,
            reset: None,
            record: None,
            ack: None,
        }
    }

    /// The sequence number.
    pub fn seq(&self) -> u32 {
        match self {
            Message::Frame { seq, .. }
            | Message::Depth { seq, .. }
            | Message::StatusRequest { seq }
            | Message::Status { seq, .. }
            | Message::Error { seq, .. }
            | Message::Hello { seq, .. }
            | Message::Shutdown { seq }
            | Message::Chunk { seq, .. }
            | Message::UploadRequest { seq }
            | Message::Upload { seq, .. }
            | Message::Commit { seq } => *seq,
            #[cfg(feature = "fault-injection")]
            Message::Inject { seq, .. } => *seq,
        }
    }

    /// The type string on the wire.
    pub fn kind(&self) -> &'static str {
        match self {
            Message::Frame { .. } => kind::FRAME,
            Message::Depth { .. } => kind::DEPTH,
            Message::StatusRequest { .. } => kind::STATUS_REQUEST,
            Message::Status { .. } => kind::STATUS,
            Message::Error { .. } => kind::ERROR,
            Message::Hello { .. } => kind::HELLO,
            Message::Shutdown { .. } => kind::SHUTDOWN,
            Message::Chunk { .. } => kind::CHUNK,
            Message::UploadRequest { .. } => kind::UPLOAD_REQUEST,
            Message::Upload { .. } => kind::UPLOAD,
            Message::Commit { .. } => kind::COMMIT,
            #[cfg(feature = "fault-injection")]
            Message::Inject { .. } => kind::INJECT,
        }
    }

    /// Header and payload of the message.
    pub fn to_parts(&self) -> (Header<'_>, Payload<'_>) {
        let mut h = Header {
            t: self.kind(),
            seq: self.seq(),
            ..Header::default()
        };
        let payload = match self {
            Message::Frame {
                roll_deg,
                attitude,
                image,
                ..
            } => {
                h.roll = Some(*roll_deg);
                h.set_q(attitude.map(|a| a.to_array()));
                h.r = Some(config::INPUT_RANGE_BINS as u32);
                h.b = Some(config::INPUT_COLUMNS as u32);
                Payload::Bytes(image)
            }
            Message::Depth {
                reference,
                sources,
                instructions,
                depth,
                pair,
                ..
            } => {
                h.reference = Some(*reference);
                h.src = Some(sources.clone());
                h.instr = Some(*instructions);
                put_pair(&mut h, pair);
                match depth {
                    DepthData::Values(v) => Payload::Depth(v),
                    DepthData::Bytes(b) => Payload::Bytes(b),
                }
            }
            Message::Status { status, .. } => {
                put_status(&mut h, status);
                Payload::Bytes(&[])
            }
            Message::Hello {
                status: Some(status),
                reset,
                record,
                ..
            } => {
                put_status(&mut h, status);
                h.reset = reset.map(ResetCause::code);
                Payload::Bytes(record.unwrap_or(&[]))
            }
            Message::Error { code, msg, .. } => {
                h.code = Some(*code);
                h.msg = Some(msg);
                Payload::Bytes(&[])
            }
            Message::Hello {
                status: None,
                ack,
                record,
                ..
            } => {
                h.ack = *ack;
                Payload::Bytes(record.unwrap_or(&[]))
            }
            Message::Chunk {
                offset, crc, data, ..
            } => {
                h.off = Some(*offset);
                h.crc = Some(*crc);
                Payload::Bytes(data)
            }
            Message::Upload { slot, held, .. } => {
                h.slot = Some(*slot);
                if let Some(u) = held {
                    (h.id, h.ver, h.total, h.held) =
                        (Some(u.id), Some(u.version), Some(u.total), Some(u.held));
                }
                Payload::Bytes(&[])
            }
            Message::StatusRequest { .. }
            | Message::Shutdown { .. }
            | Message::UploadRequest { .. }
            | Message::Commit { .. } => Payload::Bytes(&[]),
            #[cfg(feature = "fault-injection")]
            Message::Inject { what, .. } => {
                h.code = Some(*what);
                Payload::Bytes(&[])
            }
        };
        if !payload.is_empty() {
            h.len = Some(u32::try_from(payload.len()).unwrap_or(u32::MAX));
        }
        (h, payload)
    }
}

/// A payload to encode.
#[derive(Clone, Copy, Debug)]
pub enum Payload<'a> {
    /// Raw bytes.
    Bytes(&'a [u8]),
    /// Depth values, written as u32 LE bits.
    Depth(&'a [U16F16]),
}

impl Payload<'_> {
    /// Bytes on the wire.
    pub fn len(&self) -> usize {
        match self {
            Payload::Bytes(b) => b.len(),
            Payload::Depth(v) => v.len() * 4,
        }
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
