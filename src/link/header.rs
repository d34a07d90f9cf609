//! The JSON header of a link message and the error codes it carries.

use serde::{Deserialize, Serialize};

use super::MAX_SOURCES;

/// The JSON header as on the wire: every field but `t` and `seq` is optional and only the
/// fields of the message type are written.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header<'a> {
    /// Message type, one of [`kind`](super::kind).
    pub t: &'a str,
    /// Sequence number: strictly increasing per direction.
    pub seq: u32,
    /// Frame: roll of the sonar, degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roll: Option<f32>,
    /// Frame: the sonar's attitude quaternion (docs/POSE.md), `w`; absent = roll-only
    /// pairing. Four scalar fields rather than an array: a JSON array parser costs the
    /// firmware 4 KiB of flash it does not have.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub qw: Option<f32>,
    /// Frame: attitude, `x`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub qx: Option<f32>,
    /// Frame: attitude, `y`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub qy: Option<f32>,
    /// Frame: attitude, `z`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub qz: Option<f32>,
    /// Frame: range bins of the polar image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub r: Option<u32>,
    /// Frame: beam columns of the polar image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub b: Option<u32>,
    /// Payload bytes (absent = 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub len: Option<u32>,
    /// Depth: `seq` of the reference frame.
    #[serde(default, rename = "ref", skip_serializing_if = "Option::is_none")]
    pub reference: Option<u32>,
    /// Depth: `seq`s of the source frames, view 1 first.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub src: Option<heapless::Vec<u32, MAX_SOURCES>>,
    /// Depth: instructions spent computing the map.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instr: Option<u32>,
    /// Status: frames accepted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<u32>,
    /// Status: depth maps sent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depths: Option<u32>,
    /// Status: errors replied.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub errors: Option<u32>,
    /// Status: stack high-water mark, bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stack: Option<u32>,
    /// Status: feature maps cached for pairing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cached: Option<u32>,
    /// Status, depth: `seq` of the reference of the last candidate pair checked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub pref: Option<u32>,
    /// Status, depth: `seq` of its source the figures are of.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub psrc: Option<u32>,
    /// Status, depth: its relative roll, degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub proll: Option<f32>,
    /// Status, depth: its residual tilt, degrees (absent without attitude).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub pres: Option<f32>,
    /// Status, depth: the verdict, [`Verdict::reason`](crate::attitude::Verdict::reason).
    // The device only sends these five (it refuses status and depth messages), so its build
    // does not parse them: 1 KiB of flash.
    #[serde(default, borrow, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub why: Option<&'a str>,
    /// Hello (device → host): why the device last reset,
    /// [`ResetCause::code`](crate::fault::ResetCause::code). The device sends it, never parses
    /// it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub reset: Option<u8>,
    /// Hello (host → device): the [`id`](crate::fault::Record::id) of the fault record the
    /// host read; the device forgets that record.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ack: Option<u32>,
    /// Chunk: the chunk's offset in the update image, bytes. The host sends it, the device
    /// never does (its build does not serialise it: flash).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_serializing))]
    pub off: Option<u32>,
    /// Chunk: CRC-32 (IEEE) of the chunk's bytes, checked before they are written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_serializing))]
    pub crc: Option<u32>,
    /// Upload: the slot uploads go to. Status, hello: the slot the serving model lies in
    /// (absent: the model compiled into the image). The device sends it, never parses it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub slot: Option<u8>,
    /// Upload: which upload the slot holds (CRC-32 of the image's header).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub id: Option<u32>,
    /// Upload: the held image's model version. Status, hello: the serving model's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub ver: Option<u32>,
    /// Upload: bytes of the whole image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub total: Option<u32>,
    /// Upload: bytes held from the image's start; the upload resumes there.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[cfg_attr(target_os = "none", serde(skip_deserializing))]
    pub held: Option<u32>,
    /// Error: [`ErrorCode`] number.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub code: Option<u16>,
    /// Error: short text.
    #[serde(default, borrow, skip_serializing_if = "Option::is_none")]
    pub msg: Option<&'a str>,
}

/// Error codes of error messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorCode {
    /// Bytes before a sync pattern were skipped.
    BadSync = 1,
    /// Header length over [`MAX_HEADER_LEN`](super::MAX_HEADER_LEN) (or zero).
    HeaderTooLong = 2,
    /// The header is not valid JSON of the expected shape, or a field is missing or invalid.
    BadJson = 3,
    /// CRC mismatch.
    BadCrc = 4,
    /// Payload length over [`MAX_PAYLOAD_LEN`](super::MAX_PAYLOAD_LEN).
    Oversized = 5,
    /// Unknown message type.
    UnknownType = 6,
    /// Frame dimensions differ from the compiled configuration.
    WrongGeometry = 7,
    /// `seq` not greater than the previous message's.
    OutOfOrder = 8,
    /// Payload length inconsistent with the message type.
    BadLength = 9,
    /// A valid message the receiver does not accept (e.g. a depth map sent to the device).
    Unexpected = 10,
    /// Inference failed on the device.
    Model = 11,
    /// The line went idle inside a message.
    Truncated = 12,
    /// A chunk not on a page, past the image, short of a page before its end, beyond what is
    /// held, or after offset 0 with no upload begun.
    UploadRange = 13,
    /// A chunk's bytes do not match its `crc`.
    UploadCrc = 14,
    /// The slot held bytes of another upload, cut short: it was erased; resend from 0.
    UploadConflict = 15,
    /// The update image's header was refused (magic, version 0, length).
    UpdateHeader = 16,
    /// `commit` before the whole image is held.
    UpdateIncomplete = 17,
    /// The blob was refused: format, length or CRC.
    UpdateBlob = 18,
    /// The blob was quantised for another model spec.
    UpdateSpec = 19,
    /// The signature is not by the key compiled into the firmware.
    UpdateSignature = 20,
    /// The version is not above the serving model's.
    UpdateVersion = 21,
    /// The boot self-test failed on the new model.
    UpdateSelfTest = 22,
    /// The update partition's flash failed.
    UpdateFlash = 23,
}

impl Header<'_> {
    /// The attitude fields as `[w, x, y, z]`: `None` when all are absent, `Some(None)` when
    /// only some are (a malformed frame).
    pub fn q(&self) -> Option<Option<[f32; 4]>> {
        match (self.qw, self.qx, self.qy, self.qz) {
            (None, None, None, None) => None,
            (Some(w), Some(x), Some(y), Some(z)) => Some(Some([w, x, y, z])),
            _ => Some(None),
        }
    }

    /// Sets the attitude fields.
    pub fn set_q(&mut self, q: Option<[f32; 4]>) {
        let [w, x, y, z] = q.map_or([None; 4], |q| q.map(Some));
        (self.qw, self.qx, self.qy, self.qz) = (w, x, y, z);
    }
}

impl ErrorCode {
    /// Every code, for lookups.
    pub const ALL: [ErrorCode; 23] = [
        ErrorCode::BadSync,
        ErrorCode::HeaderTooLong,
        ErrorCode::BadJson,
        ErrorCode::BadCrc,
        ErrorCode::Oversized,
        ErrorCode::UnknownType,
        ErrorCode::WrongGeometry,
        ErrorCode::OutOfOrder,
        ErrorCode::BadLength,
        ErrorCode::Unexpected,
        ErrorCode::Model,
        ErrorCode::Truncated,
        ErrorCode::UploadRange,
        ErrorCode::UploadCrc,
        ErrorCode::UploadConflict,
        ErrorCode::UpdateHeader,
        ErrorCode::UpdateIncomplete,
        ErrorCode::UpdateBlob,
        ErrorCode::UpdateSpec,
        ErrorCode::UpdateSignature,
        ErrorCode::UpdateVersion,
        ErrorCode::UpdateSelfTest,
        ErrorCode::UpdateFlash,
    ];

    /// The number on the wire.
    pub fn code(self) -> u16 {
        self as u16
    }

    /// The code of a wire number.
    pub fn from_code(code: u16) -> Option<Self> {
        Self::ALL.iter().copied().find(|c| c.code() == code)
    }
}
