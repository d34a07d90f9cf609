//! What `run --mcap` and `sil --mcap` write alike: the TF frames, headers at an ARIS
//! FrameTime, the sonar's transform and a depth map's returns as points.

use anyhow::{Context, Result};
use epssn::attitude::Attitude;
use epssn::config;
use epssn_sim::metrics;

use crate::fan::fan;
use crate::msgs::{
    Header, Image, Quaternion, SonarPoint, TfMessage, Time, Transform, TransformStamped, Vector3,
};
use crate::Bag;

/// The TF frame of everything measured in the sonar's own frame (x forward, y left, z up).
pub const SONAR_FRAME: &str = "sonar";
/// The TF frame the sonar is placed in (the attitude's level frame; the site's with poses).
pub const WORLD_FRAME: &str = "world";

/// Polar image (range bins × beam columns), mono8, every frame.
pub const POLAR_TOPIC: &str = "/sonar/polar";
/// The polar image as the Cartesian fan seen from above, mono8, every frame.
pub const FAN_TOPIC: &str = "/sonar/fan";
/// world ← sonar per frame with attitude.
pub const TF_TOPIC: &str = "/tf";

/// One sonar frame's messages at FrameTime `time_us`: its polar image, the fan drawn from it
/// and, when the frame is placed (its attitude and position), world ← sonar.
pub fn write_sonar_frame(
    bag: &mut Bag,
    time_us: u64,
    polar: &[u8],
    placed: Option<(&Attitude, [f64; 3])>,
) -> Result<()> {
    let time = ns(time_us)?;
    let fan = fan(polar)?;
    bag.write(
        FAN_TOPIC,
        time,
        &Image::mono8(
            header(time_us, SONAR_FRAME)?,
            fan.width,
            fan.height,
            fan.pixels,
        )?,
    )?;
    bag.write(
        POLAR_TOPIC,
        time,
        &Image::mono8(
            header(time_us, SONAR_FRAME)?,
            config::INPUT_COLUMNS,
            config::INPUT_RANGE_BINS,
            polar.to_vec(),
        )?,
    )?;
    if let Some((attitude, position)) = placed {
        bag.write(TF_TOPIC, time, &tf(time_us, attitude, position)?)?;
    }
    Ok(())
}

/// An ARIS FrameTime (µs) in nanoseconds, refused when it overflows.
pub fn ns(time_us: u64) -> Result<u64> {
    time_us
        .checked_mul(1000)
        .with_context(|| format!("FrameTime {time_us} µs overflows nanoseconds"))
}

/// A header at FrameTime `time_us`.
pub fn header(time_us: u64, frame_id: &str) -> Result<Header> {
    Ok(Header {
        stamp: Time::from_ns(ns(time_us)?)?,
        frame_id: frame_id.into(),
    })
}

/// world ← sonar at a frame.
pub fn tf(time_us: u64, attitude: &Attitude, position_m: [f64; 3]) -> Result<TfMessage> {
    let [w, x, y, z] = attitude.to_array().map(f64::from);
    let [tx, ty, tz] = position_m;
    Ok(TfMessage {
        transforms: vec![TransformStamped {
            header: header(time_us, WORLD_FRAME)?,
            child_frame_id: SONAR_FRAME.into(),
            transform: Transform {
                translation: Vector3 {
                    x: tx,
                    y: ty,
                    z: tz,
                },
                rotation: Quaternion { x, y, z, w },
            },
        }],
    })
}

/// A depth map's returns (its own mask, `metrics::prediction_mask`: the points of its PLY),
/// each with its range and the reference view's echo intensity at that range and azimuth.
pub fn sonar_points(depth: &[f32], polar: &[u8]) -> Result<Vec<SonarPoint>> {
    let mask = metrics::prediction_mask(depth);
    let xyz = metrics::depth_points(depth, &mask)?;
    let bin = (config::R_MAX_M - config::R_MIN_M) / config::INPUT_RANGE_BINS as f64;
    // depth_points walks the map row by row as this does, so the i-th set pixel is xyz[i].
    let returns = (0..depth.len()).filter(|&i| mask[i]);
    Ok(returns
        .zip(xyz)
        .map(|(i, p)| {
            let range = depth[i];
            let b = ((f64::from(range) - config::R_MIN_M) / bin) as usize;
            let column = i % config::DEPTH_COLUMNS;
            let intensity = polar
                .get(b.min(config::INPUT_RANGE_BINS - 1) * config::INPUT_COLUMNS + column)
                .map_or(0.0, |&v| f32::from(v));
            SonarPoint {
                xyz: p.map(|v| v as f32),
                range,
                intensity,
                pair: None,
            }
        })
        .collect())
}
