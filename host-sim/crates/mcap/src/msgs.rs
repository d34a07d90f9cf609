//! The ROS 2 messages written, as serde structs whose fields are in the order of their
//! `.msg` definitions ([`crate::schemas`]): CDR has no field names, only that order.

use anyhow::{ensure, Context, Result};
use serde::Serialize;

use crate::cdr::Bytes;
use crate::schemas::Schema;

/// A message type: its schema (name and definition) goes with it.
pub trait Message: Serialize {
    /// The type's schema.
    const SCHEMA: Schema;
}

/// `builtin_interfaces/Time`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Time {
    /// Seconds since the Unix epoch.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// The time `ns` nanoseconds after the Unix epoch; refused past the message's 2038 limit
    /// (`sec` is an int32).
    pub fn from_ns(ns: u64) -> Result<Self> {
        let sec = i32::try_from(ns / 1_000_000_000)
            .ok()
            .with_context(|| format!("time {ns} ns is past what builtin_interfaces/Time holds"))?;
        Ok(Self {
            sec,
            nanosec: (ns % 1_000_000_000) as u32,
        })
    }
}

/// `std_msgs/Header`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Header {
    /// When the data was taken.
    pub stamp: Time,
    /// The coordinate frame of the data (a TF frame id).
    pub frame_id: String,
}

/// `sensor_msgs/Image`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Image {
    /// Stamp and frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`mono8`, `32FC1`).
    pub encoding: String,
    /// 0: little endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// Row-major pixels, row 0 first.
    pub data: Bytes,
}

impl Message for Image {
    const SCHEMA: Schema = Schema::Image;
}

/// Rows and columns as the message's u32, checked against the pixel count.
fn shape(width: usize, height: usize, pixels: usize) -> Result<(u32, u32)> {
    ensure!(
        width.checked_mul(height) == Some(pixels),
        "{pixels} pixels are not {height} rows of {width}"
    );
    Ok((
        u32::try_from(width).context("image width")?,
        u32::try_from(height).context("image height")?,
    ))
}

impl Image {
    /// An 8-bit grey image (`mono8`) of `height` rows of `width` pixels.
    pub fn mono8(header: Header, width: usize, height: usize, pixels: Vec<u8>) -> Result<Self> {
        let (w, h) = shape(width, height, pixels.len())?;
        Ok(Self {
            header,
            height: h,
            width: w,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: w,
            data: Bytes(pixels),
        })
    }

    /// A 32-bit float image (`32FC1`, little endian) of `height` rows of `width` pixels.
    pub fn float32(header: Header, width: usize, height: usize, pixels: &[f32]) -> Result<Self> {
        let (w, h) = shape(width, height, pixels.len())?;
        Ok(Self {
            header,
            height: h,
            width: w,
            encoding: "32FC1".into(),
            is_bigendian: 0,
            step: w.checked_mul(4).context("image row too long")?,
            data: Bytes(pixels.iter().flat_map(|v| v.to_le_bytes()).collect()),
        })
    }
}

/// `sensor_msgs/PointField`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PointField {
    /// Field name.
    pub name: String,
    /// Byte offset within a point.
    pub offset: u32,
    /// Type code (`FLOAT32` = 7, `UINT32` = 6).
    pub datatype: u8,
    /// Elements.
    pub count: u32,
}

/// `PointField::FLOAT32`.
pub const FLOAT32: u8 = 7;
/// `PointField::UINT32`.
pub const UINT32: u8 = 6;

/// `sensor_msgs/PointCloud2`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PointCloud2 {
    /// Stamp and frame.
    pub header: Header,
    /// 1: an unordered cloud.
    pub height: u32,
    /// Points.
    pub width: u32,
    /// Layout of a point.
    pub fields: Vec<PointField>,
    /// false: little endian.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row (all points).
    pub row_step: u32,
    /// The points.
    pub data: Bytes,
    /// No invalid (NaN) points.
    pub is_dense: bool,
}

impl Message for PointCloud2 {
    const SCHEMA: Schema = Schema::PointCloud2;
}

/// One point of a sonar cloud: position (metres, the header's frame), the slant range it was
/// measured at, the echo intensity there, and for a merged cloud the pair it came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SonarPoint {
    /// x, y, z, metres.
    pub xyz: [f32; 3],
    /// Slant range from the sonar, metres.
    pub range: f32,
    /// Echo intensity, 0–255 counts of the reference view's polar image.
    pub intensity: f32,
    /// Index of the depth map in the run (a merged cloud's only).
    pub pair: Option<u32>,
}

impl PointCloud2 {
    /// An unordered cloud of fields `x y z range intensity` (FLOAT32) and, when every point
    /// has one, `pair` (UINT32).
    pub fn of_points(header: Header, points: &[SonarPoint]) -> Result<Self> {
        let with_pair = !points.is_empty() && points.iter().all(|p| p.pair.is_some());
        let mut fields: Vec<PointField> = ["x", "y", "z", "range", "intensity"]
            .iter()
            .enumerate()
            .map(|(i, name)| PointField {
                name: (*name).into(),
                offset: 4 * i as u32,
                datatype: FLOAT32,
                count: 1,
            })
            .collect();
        if with_pair {
            fields.push(PointField {
                name: "pair".into(),
                offset: 20,
                datatype: UINT32,
                count: 1,
            });
        }
        let point_step: u32 = if with_pair { 24 } else { 20 };
        let mut data = Vec::with_capacity(points.len() * point_step as usize);
        for p in points {
            for v in p.xyz.iter().chain([&p.range, &p.intensity]) {
                data.extend(v.to_le_bytes());
            }
            if let (true, Some(pair)) = (with_pair, p.pair) {
                data.extend(pair.to_le_bytes());
            }
        }
        let width = u32::try_from(points.len()).context("too many points for one cloud")?;
        Ok(Self {
            header,
            height: 1,
            width,
            fields,
            is_bigendian: false,
            point_step,
            row_step: width
                .checked_mul(point_step)
                .context("too many points for one cloud")?,
            data: Bytes(data),
            is_dense: points.iter().all(|p| p.xyz.iter().all(|v| v.is_finite())),
        })
    }
}

/// `geometry_msgs/Vector3`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/Quaternion` (x, y, z, w in that order).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `geometry_msgs/Transform`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Transform {
    /// The child frame's origin in the parent frame, metres.
    pub translation: Vector3,
    /// The child frame's axes in the parent frame.
    pub rotation: Quaternion,
}

/// `geometry_msgs/TransformStamped`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// The frame the transform places.
    pub child_frame_id: String,
    /// Child → parent.
    pub transform: Transform,
}

/// `tf2_msgs/TFMessage`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

impl Message for TfMessage {
    const SCHEMA: Schema = Schema::TfMessage;
}

/// `std_msgs/String`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StringMsg {
    /// The text (here JSON).
    pub data: String,
}

impl Message for StringMsg {
    const SCHEMA: Schema = Schema::String;
}

/// `marine_acoustic_msgs/PingInfo`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PingInfo {
    /// Centre frequency, Hz (0: not given).
    pub frequency: f32,
    /// Speed of sound of the ranges, m/s (0: not given).
    pub sound_speed: f32,
    /// −3 dB transmit (vertical) beam widths, radians.
    pub tx_beamwidths: Vec<f32>,
    /// −3 dB receive (horizontal) beam widths, radians.
    pub rx_beamwidths: Vec<f32>,
}

/// `marine_acoustic_msgs/SonarImageData`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SonarImageData {
    /// false: little endian.
    pub is_bigendian: bool,
    /// `DTYPE_UINT8` (0) here.
    pub dtype: u32,
    /// Beams per range row.
    pub beam_count: u32,
    /// Range-major: `(range r, beam b)` at `r · beam_count + b`.
    pub data: Bytes,
}

/// `marine_acoustic_msgs/ProjectedSonarImage`: Z forward, X up, each beam's direction.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ProjectedSonarImage {
    /// Stamp and frame.
    pub header: Header,
    /// Frequency, sound speed, beam widths.
    pub ping_info: PingInfo,
    /// Each beam's unit direction in the message's axes.
    pub beam_directions: Vec<Vector3>,
    /// Centre of each range bin, metres.
    pub ranges: Vec<f32>,
    /// The image.
    pub image: SonarImageData,
}

impl Message for ProjectedSonarImage {
    const SCHEMA: Schema = Schema::ProjectedSonarImage;
}
