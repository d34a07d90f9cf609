//! `host-sim inspect BAG.mcap`: a bag's sonar topic summarised as the model sees it: pings,
//! beams and their azimuths, ranges, dtype, each ping's time and roll, and whether its fan
//! covers the model's grid (docs/ROS2.md).

use std::io::Write;
use std::path::Path;

use anyhow::Result;
use serde::Serialize;

use crate::bag::BagRecording;
use crate::fit::misfit;

/// One ping.
#[derive(Clone, Debug, Serialize)]
pub struct PingSummary {
    /// Position in the recording.
    pub index: usize,
    /// Stamp, µs since the epoch.
    pub time_us: u64,
    /// Roll from /tf, degrees (null without a transform).
    pub roll_deg: Option<f64>,
    /// Attitude `[w, x, y, z]` (docs/POSE.md; null without a transform).
    pub attitude_q: Option<[f32; 4]>,
}

/// The bag's sonar topic.
#[derive(Clone, Debug, Serialize)]
pub struct BagSummary {
    /// The file.
    pub file: String,
    /// The ProjectedSonarImage topic read.
    pub topic: String,
    /// Its frame.
    pub frame_id: String,
    /// Pings.
    pub pings: usize,
    /// Beams of the first ping.
    pub beams: usize,
    /// Its azimuth span, degrees (positive to port).
    pub azimuth_deg: [f64; 2],
    /// Range bins.
    pub range_bins: usize,
    /// First and last bin's range, metres.
    pub range_m: [f64; 2],
    /// SonarImageData dtype (0 uint8 … 9 float64).
    pub dtype: u32,
    /// `None` when the fan covers the model's grid, else what does not fit.
    pub misfit: Option<String>,
    /// Every ping.
    pub frames: Vec<PingSummary>,
    /// What reading noticed.
    pub warnings: Vec<String>,
}

/// Summarises the bag at `file` (`topic`: its ProjectedSonarImage topic, default the only one).
pub fn summarise(file: &Path, topic: Option<&str>) -> Result<BagSummary> {
    let bag = BagRecording::open(file, topic)?;
    anyhow::ensure!(
        bag.frame_count() > 0,
        "{}: no pings on {}",
        file.display(),
        bag.topic
    );
    let first = bag.message(0)?;
    let frame = bag.frame(0)?;
    let az = &frame.beam_centres_rad;
    let r = frame.ranges;
    let frames = (0..bag.frame_count())
        .map(|i| {
            Ok(PingSummary {
                index: i,
                time_us: bag.message(i)?.header.stamp_ns.max(0) as u64 / 1000,
                roll_deg: bag.roll_deg(i),
                attitude_q: bag.attitude(i).map(|a| a.to_array()),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(BagSummary {
        file: file.display().to_string(),
        topic: bag.topic.clone(),
        frame_id: first.header.frame_id.clone(),
        pings: bag.frame_count(),
        beams: frame.beams,
        azimuth_deg: [az[0].to_degrees(), az[az.len() - 1].to_degrees()],
        range_bins: r.samples,
        range_m: [r.start, r.start + r.step * (r.samples - 1) as f64],
        dtype: first.image.dtype,
        misfit: misfit(&frame),
        frames,
        warnings: bag.warnings().to_vec(),
    })
}

/// Prints the summary, as text or JSON.
pub fn run(file: &Path, topic: Option<&str>, json: bool, out: &mut impl Write) -> Result<()> {
    let s = summarise(file, topic)?;
    if json {
        writeln!(out, "{}", serde_json::to_string_pretty(&s)?)?;
        return Ok(());
    }
    writeln!(out, "file:     {} (ROS 2 bag)", s.file)?;
    writeln!(
        out,
        "topic:    {} (frame {}), {} pings",
        s.topic, s.frame_id, s.pings
    )?;
    writeln!(
        out,
        "beams:    {}, azimuth {:.2}° … {:.2}°",
        s.beams, s.azimuth_deg[0], s.azimuth_deg[1]
    )?;
    writeln!(
        out,
        "ranges:   {} bins, {:.3} – {:.3} m",
        s.range_bins, s.range_m[0], s.range_m[1]
    )?;
    writeln!(out, "dtype:    {}", s.dtype)?;
    match &s.misfit {
        None => writeln!(out, "model:    fits ({})", epssn::config::SPEC_NAME)?,
        Some(why) => writeln!(
            out,
            "model:    does not fit ({}): {why}",
            epssn::config::SPEC_NAME
        )?,
    }
    for p in &s.frames {
        writeln!(
            out,
            "  ping {:4}  t {} µs  roll {}",
            p.index,
            p.time_us,
            p.roll_deg.map_or("n/a".into(), |r| format!("{r:.3}°"))
        )?;
    }
    for w in &s.warnings {
        writeln!(out, "warning: {w}")?;
    }
    Ok(())
}
