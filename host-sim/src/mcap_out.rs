//! `run --mcap FILE`: the run as ROS 2 messages in one MCAP file (docs/MCAP.md lists the
//! topics, frames and types). Every message is stamped with its ARIS frame's FrameTime (a depth
//! map, its clouds and its pair check with the reference frame's), and messages are written in
//! frame order, each frame's after the one before, so a file cut short holds a prefix of the
//! recording; the merged sweep and the run's summary close the file at the last frame's time.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result};
use epssn::attitude::Attitude;
use epssn::config;
use epssn_mcap::msgs::{Image, PointCloud2, SonarPoint, StringMsg};
use epssn_mcap::sonar::{header, ns, write_sonar_frame};
use epssn_mcap::sonar_image::{image_frame_tf, sonar_image, SONAR_IMAGE_TOPIC, TF_STATIC_TOPIC};
use epssn_mcap::Bag;
use epssn_ros2::{Recording, SonarFrame};

use crate::pairing::CandidateReport;

pub use epssn_mcap::sonar::{sonar_points, SONAR_FRAME, WORLD_FRAME};

/// The topics, in one place for the docs and the tests.
pub mod topic {
    pub use epssn_mcap::sonar::{FAN_TOPIC as FAN, POLAR_TOPIC as POLAR, TF_TOPIC as TF};
    pub use epssn_mcap::sonar_image::{
        SONAR_IMAGE_TOPIC as SONAR_IMAGE, TF_STATIC_TOPIC as TF_STATIC,
    };
    /// The pose gate's verdict on each candidate pair, JSON.
    pub const PAIR_CHECK: &str = "/pairing/check";
    /// Depth maps, 32FC1 metres, elevation rows × azimuth columns.
    pub const DEPTH_INT8: &str = "/depth/int8";
    /// The float model's depth map.
    pub const DEPTH_FLOAT: &str = "/depth/float";
    /// The ground truth's depth map.
    pub const DEPTH_TRUTH: &str = "/depth/ground_truth";
    /// The int8 map's returns, sonar frame.
    pub const POINTS_INT8: &str = "/points/int8";
    /// The float map's returns, sonar frame.
    pub const POINTS_FLOAT: &str = "/points/float";
    /// Every pair's int8 returns merged in the world frame (`--frame world`).
    pub const SWEEP: &str = "/sweep/points";
    /// The run's summary (`run --json`'s), JSON.
    pub const SUMMARY: &str = "/run/summary";
}

/// One depth map of the run, as the MCAP file needs it.
pub struct PairMessages<'a> {
    /// Frames, reference first.
    pub frames: &'a [usize],
    /// The library's int8 depth map.
    pub int8: &'a [f32],
    /// The float model's.
    pub float: &'a [f32],
    /// Ground truth, when there is some.
    pub truth: Option<&'a [f32]>,
    /// The reference view's polar image (pings averaged), for the points' intensity.
    pub polar: &'a [u8],
}

/// What the file holds beyond the recording's frames.
pub struct RunMessages<'a> {
    /// Every candidate with the pose gate's verdict.
    pub candidates: &'a [CandidateReport],
    /// Every depth map.
    pub pairs: &'a [PairMessages<'a>],
    /// Each frame's attitude (`None`: no transform for it).
    pub attitudes: &'a [Option<Attitude>],
    /// Positions from the poses file, by frame (else the origin).
    pub positions: &'a BTreeMap<usize, [f64; 3]>,
    /// The merged cloud, world frame, when one was made.
    pub sweep: Option<&'a [SonarPoint]>,
    /// The run's summary, JSON.
    pub summary_json: &'a str,
}

/// Writes the run's MCAP file.
pub fn write(path: &Path, reader: &Recording, run: &RunMessages) -> Result<()> {
    let mut bag = Bag::create(path)?;
    let mut last_us = 0;
    for f in 0..reader.frame_count() {
        let frame = reader.frame(f)?;
        let t = frame.time_us;
        if f == 0 {
            // The ProjectedSonarImage's own axes in the sonar frame, once.
            bag.write(TF_STATIC_TOPIC, ns(t)?, &image_frame_tf(t)?)?;
        }
        last_us = last_us.max(t);
        write_frame(&mut bag, f, &frame, run).with_context(|| format!("frame {f}"))?;
    }
    let end = ns(last_us)?;
    if let Some(points) = run.sweep {
        let cloud = PointCloud2::of_points(header(last_us, WORLD_FRAME)?, points)?;
        bag.write(topic::SWEEP, end, &cloud)?;
    }
    bag.write(
        topic::SUMMARY,
        end,
        &StringMsg {
            data: run.summary_json.to_string(),
        },
    )?;
    bag.finish()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// One frame's messages: its images and transform, and the pair checks and depth maps whose
/// reference it is.
fn write_frame(bag: &mut Bag, f: usize, frame: &SonarFrame, run: &RunMessages) -> Result<()> {
    let t = frame.time_us;
    let time = ns(t)?;
    let polar = frame.to_polar()?;
    let placed = run.attitudes.get(f).copied().flatten().map(|a| {
        let position = run.positions.get(&f).copied().unwrap_or([0.0; 3]);
        (a, position)
    });
    write_sonar_frame(bag, t, &polar, placed.as_ref().map(|(a, p)| (a, *p)))?;
    bag.write(SONAR_IMAGE_TOPIC, time, &sonar_image(t, &polar)?)?;
    for c in run
        .candidates
        .iter()
        .filter(|c| c.frames.first() == Some(&f))
    {
        let json = serde_json::to_string(c)?;
        bag.write(topic::PAIR_CHECK, time, &StringMsg { data: json })?;
    }
    for p in run.pairs.iter().filter(|p| p.frames.first() == Some(&f)) {
        write_pair(bag, t, p)?;
    }
    Ok(())
}

/// A depth map's images and clouds.
fn write_pair(bag: &mut Bag, t: u64, p: &PairMessages) -> Result<()> {
    let time = ns(t)?;
    let (w, h) = (config::DEPTH_COLUMNS, config::DEPTH_ROWS);
    let maps = [
        (topic::DEPTH_INT8, Some(p.int8)),
        (topic::DEPTH_FLOAT, Some(p.float)),
        (topic::DEPTH_TRUTH, p.truth),
    ];
    for (name, map) in maps {
        if let Some(d) = map {
            bag.write(
                name,
                time,
                &Image::float32(header(t, SONAR_FRAME)?, w, h, d)?,
            )?;
        }
    }
    for (name, d) in [(topic::POINTS_INT8, p.int8), (topic::POINTS_FLOAT, p.float)] {
        let points = sonar_points(d, p.polar)?;
        bag.write(
            name,
            time,
            &PointCloud2::of_points(header(t, SONAR_FRAME)?, &points)?,
        )?;
    }
    Ok(())
}
