//! The ROS 2 messages a bag's sonar is read from, decoded from CDR field by field in the order
//! of their `.msg` definitions (marine_msgs 2.x, `common_interfaces`):
//!
//! ```text
//! marine_acoustic_msgs/ProjectedSonarImage: std_msgs/Header header, PingInfo ping_info,
//!     geometry_msgs/Vector3[] beam_directions, float32[] ranges, SonarImageData image
//! marine_acoustic_msgs/PingInfo: float32 frequency, float32 sound_speed,
//!     float32[] tx_beamwidths, float32[] rx_beamwidths
//! marine_acoustic_msgs/SonarImageData: bool is_bigendian, uint32 dtype, uint32 beam_count,
//!     uint8[] data
//! std_msgs/Header: builtin_interfaces/Time stamp (int32 sec, uint32 nanosec), string frame_id
//! tf2_msgs/TFMessage: geometry_msgs/TransformStamped[] transforms
//! geometry_msgs/TransformStamped: Header header, string child_frame_id,
//!     Transform transform (Vector3 translation, Quaternion rotation x y z w), all float64
//! ```

use crate::cdr::CdrReader;
use crate::McapError;

/// Schema name of the sonar image.
pub const PROJECTED_SONAR_IMAGE: &str = "marine_acoustic_msgs/msg/ProjectedSonarImage";
/// Schema name of the transforms (`/tf`, `/tf_static`).
pub const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";

/// `std_msgs/Header`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Header {
    /// Stamp, ns since the epoch (sec · 1e9 + nanosec).
    pub stamp_ns: i64,
    /// The frame the data is in.
    pub frame_id: String,
}

/// `marine_acoustic_msgs/PingInfo`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PingInfo {
    /// Centre frequency, Hz (0: unknown).
    pub frequency: f32,
    /// Speed of sound the ranges were computed with, m/s (0: unknown).
    pub sound_speed: f32,
    /// −3 dB transmit beam widths, radians.
    pub tx_beamwidths: Vec<f32>,
    /// −3 dB receive beam widths, radians.
    pub rx_beamwidths: Vec<f32>,
}

/// `marine_acoustic_msgs/SonarImageData`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SonarImageData {
    /// The elements are big-endian.
    pub is_bigendian: bool,
    /// `DTYPE_*`: 0 uint8, 1 int8, 2 uint16, 3 int16, 4 uint32, 5 int32, 6 uint64, 7 int64,
    /// 8 float32, 9 float64.
    pub dtype: u32,
    /// Beams per range row.
    pub beam_count: u32,
    /// The elements, range-major: element `(range r, beam b)` at `r · beam_count + b`.
    pub data: Vec<u8>,
}

/// `marine_acoustic_msgs/ProjectedSonarImage`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProjectedSonarImage {
    /// Stamp (the ping's transmit time) and frame.
    pub header: Header,
    /// Frequency, sound speed, beam widths.
    pub ping_info: PingInfo,
    /// Each beam's direction `[x, y, z]` in the message's axes (Z forward, X up).
    pub beam_directions: Vec<[f64; 3]>,
    /// Centre of each range bin, metres.
    pub ranges: Vec<f32>,
    /// The image.
    pub image: SonarImageData,
}

/// `geometry_msgs/TransformStamped`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TransformStamped {
    /// Stamp, and the parent frame.
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// Translation of the child in the parent, metres.
    pub translation: [f64; 3],
    /// Rotation child → parent, `[x, y, z, w]`.
    pub rotation: [f64; 4],
}

fn header(r: &mut CdrReader<'_>) -> Result<Header, McapError> {
    let sec = r.i32()?;
    let nanosec = r.u32()?;
    Ok(Header {
        stamp_ns: i64::from(sec) * 1_000_000_000 + i64::from(nanosec),
        frame_id: r.string()?,
    })
}

fn vector3(r: &mut CdrReader<'_>) -> Result<[f64; 3], McapError> {
    Ok([r.f64()?, r.f64()?, r.f64()?])
}

/// Decodes a ProjectedSonarImage from a CDR message.
pub fn decode_sonar_image(bytes: &[u8]) -> Result<ProjectedSonarImage, McapError> {
    let mut r = CdrReader::new(bytes)?;
    let header = header(&mut r)?;
    let ping_info = PingInfo {
        frequency: r.f32()?,
        sound_speed: r.f32()?,
        tx_beamwidths: r.f32_seq()?,
        rx_beamwidths: r.f32_seq()?,
    };
    let n = r.count(24)?;
    let beam_directions = (0..n).map(|_| vector3(&mut r)).collect::<Result<_, _>>()?;
    let ranges = r.f32_seq()?;
    let image = SonarImageData {
        is_bigendian: r.bool()?,
        dtype: r.u32()?,
        beam_count: r.u32()?,
        data: r.byte_seq()?.to_vec(),
    };
    Ok(ProjectedSonarImage {
        header,
        ping_info,
        beam_directions,
        ranges,
        image,
    })
}

/// Decodes a TFMessage from a CDR message.
pub fn decode_tf_message(bytes: &[u8]) -> Result<Vec<TransformStamped>, McapError> {
    let mut r = CdrReader::new(bytes)?;
    // Each transform: at least a stamp, two string lengths and seven f64s.
    let n = r.count(72)?;
    (0..n)
        .map(|_| {
            let header = header(&mut r)?;
            let child_frame_id = r.string()?;
            let translation = vector3(&mut r)?;
            let rotation = [r.f64()?, r.f64()?, r.f64()?, r.f64()?];
            Ok(TransformStamped {
                header,
                child_frame_id,
                translation,
                rotation,
            })
        })
        .collect()
}
