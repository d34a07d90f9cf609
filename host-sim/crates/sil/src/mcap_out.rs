//! `sil --mcap FILE`: what the device returned, as ROS 2 messages in one MCAP file (the same
//! types and TF frames as `run --mcap`, docs/MCAP.md): every frame streamed, as the device got
//! it, and every depth map the device sent back with its points, stamped with the reference
//! frame's ARIS FrameTime; the SIL report closes the file.

use std::path::Path;

use anyhow::{Context, Result};
use epssn::config;
use epssn_mcap::msgs::{Image, PointCloud2, StringMsg};
use epssn_mcap::sonar::{header, ns, sonar_points, write_sonar_frame, SONAR_FRAME};
use epssn_mcap::Bag;
use fixed::types::U16F16;
use serde::Serialize;

/// The topics, in one place for the docs and the tests.
pub mod topic {
    /// The image sent to the device (polar, mono8), its fan and world ← sonar, every frame.
    pub use epssn_mcap::sonar::{FAN_TOPIC as FAN, POLAR_TOPIC as POLAR, TF_TOPIC as TF};
    /// Each depth map the device returned, 32FC1 metres, elevation rows × azimuth columns.
    pub const DEPTH: &str = "/device/depth";
    /// Its returns (the map's own mask), sonar frame.
    pub const POINTS: &str = "/device/points";
    /// The reply's pair, cost and bit-exactness against the host library, JSON.
    pub const REPLY: &str = "/device/reply";
    /// The SIL report (`sil --json`'s), JSON.
    pub const SUMMARY: &str = "/sil/summary";
}

/// One frame as streamed.
pub struct StreamedFrame<'a> {
    /// ARIS FrameTime, µs.
    pub time_us: u64,
    /// Its attitude, when the header has one.
    pub attitude: Option<epssn::attitude::Attitude>,
    /// The polar image the device got.
    pub image: &'a [u8],
}

/// One depth map the device returned.
#[derive(Serialize, Clone, Debug)]
pub struct DeviceMap {
    /// Reference frame's seq (frame seq − 1 of the recording).
    pub reference: u32,
    /// Source frames' seqs.
    pub sources: Vec<u32>,
    /// The device's cost figure for it (instructions in QEMU, cycles on a board).
    pub instructions: u32,
    /// Every value equals the host library's.
    pub bit_exact: bool,
    /// The depth values, U16F16 bits.
    #[serde(skip)]
    pub bits: Vec<u32>,
}

/// Writes the file: per frame its images and transform, then the maps whose reference it is.
pub fn write(
    path: &Path,
    frames: &[StreamedFrame],
    maps: &[DeviceMap],
    report: &impl Serialize,
) -> Result<()> {
    let mut bag = Bag::create(path)?;
    let mut last_us = 0;
    for (i, f) in frames.iter().enumerate() {
        last_us = last_us.max(f.time_us);
        write_frame(&mut bag, f)?;
        let seq = i as u32 + 1;
        for m in maps.iter().filter(|m| m.reference == seq) {
            write_map(&mut bag, f, m).with_context(|| format!("depth map of frame {i}"))?;
        }
    }
    let summary = StringMsg {
        data: serde_json::to_string(report)?,
    };
    bag.write(topic::SUMMARY, ns(last_us)?, &summary)?;
    bag.finish()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

fn write_frame(bag: &mut Bag, f: &StreamedFrame) -> Result<()> {
    let placed = f.attitude.as_ref().map(|a| (a, [0.0; 3]));
    write_sonar_frame(bag, f.time_us, f.image, placed)
}

fn write_map(bag: &mut Bag, reference: &StreamedFrame, m: &DeviceMap) -> Result<()> {
    let (t, time) = (reference.time_us, ns(reference.time_us)?);
    let depth: Vec<f32> = m
        .bits
        .iter()
        .map(|&b| U16F16::from_bits(b).to_num::<f32>())
        .collect();
    let (w, h) = (config::DEPTH_COLUMNS, config::DEPTH_ROWS);
    bag.write(
        topic::DEPTH,
        time,
        &Image::float32(header(t, SONAR_FRAME)?, w, h, &depth)?,
    )?;
    let points = sonar_points(&depth, reference.image)?;
    bag.write(
        topic::POINTS,
        time,
        &PointCloud2::of_points(header(t, SONAR_FRAME)?, &points)?,
    )?;
    bag.write(
        topic::REPLY,
        time,
        &StringMsg {
            data: serde_json::to_string(m)?,
        },
    )?;
    Ok(())
}
