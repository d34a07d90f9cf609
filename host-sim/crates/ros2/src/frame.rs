//! One native sonar frame, whichever file it came from: u8 samples range-major with the beams
//! in ascending azimuth, their ranges and each beam's azimuth. The model's polar input is
//! resampled from it by the library's one resampler, and pings are averaged in it, exactly as
//! for an ARIS frame (whose numbers it carries unchanged).

use anyhow::{anyhow, ensure, Result};
use epssn::config;
use epssn::geometry::{resample_to_grid, SampleRanges};
use epssn::ping_average::{IntensityTable, PingAverager};
use epssn_aris::aris::Frame;
use epssn_aris::polar::model_grid;

/// A native frame.
#[derive(Clone, Debug, PartialEq)]
pub struct SonarFrame {
    /// Position in the recording (0-based).
    pub index: usize,
    /// Time of the ping, µs since the epoch.
    pub time_us: u64,
    /// Beams per range row.
    pub beams: usize,
    /// `data[sample × beams + beam]`, beam 0 the right-most (most negative azimuth).
    pub data: Vec<u8>,
    /// Range of each sample.
    pub ranges: SampleRanges,
    /// Beam azimuths, radians, ascending (positive to port, as the ARIS tables).
    pub beam_centres_rad: Vec<f64>,
}

impl SonarFrame {
    /// An ARIS frame, with the range geometry and beam table docs/ARIS.md gives it.
    pub fn of_aris(frame: Frame) -> Result<Self> {
        Ok(Self {
            index: frame.index,
            time_us: frame.header.frame_time_us,
            beams: frame.beams,
            ranges: frame.range_geometry()?,
            beam_centres_rad: frame.beam_centres_rad()?,
            data: frame.data,
        })
    }

    /// Resampled onto the model's R × B polar grid (`img[i · B + k]`, u8).
    pub fn to_polar(&self) -> Result<Vec<u8>> {
        let mut out = vec![0u8; config::INPUT_LEN];
        resample_to_grid(
            &self.data,
            self.ranges,
            &self.beam_centres_rad,
            &model_grid(),
            config::INPUT_RANGE_BINS,
            &mut out,
        )
        .map_err(|e| anyhow!("resampling frame {}: {e:?}", self.index))?;
        Ok(out)
    }
}

/// `frames` (a view's pings at one roll) averaged in intensity (`epssn::ping_average`) into
/// one frame with the first's geometry and time.
pub fn average(mut frames: Vec<SonarFrame>, table: &IntensityTable) -> Result<SonarFrame> {
    ensure!(!frames.is_empty(), "no frames to average");
    if frames.len() == 1 {
        return Ok(frames.remove(0));
    }
    let mut first = frames.remove(0);
    let mut sum = vec![0f32; first.data.len()];
    let mut avg = PingAverager::new(table, &mut sum);
    avg.add(&first.data)
        .map_err(|e| anyhow!("frame {}: {e:?}", first.index))?;
    for f in &frames {
        ensure!(
            f.beams == first.beams
                && f.data.len() == first.data.len()
                && f.ranges == first.ranges
                && f.beam_centres_rad == first.beam_centres_rad,
            "frames {} and {} differ in geometry: their pings cannot be averaged",
            first.index,
            f.index
        );
        avg.add(&f.data)
            .map_err(|e| anyhow!("frame {}: {e:?}", f.index))?;
    }
    avg.finish(&mut first.data)
        .map_err(|e| anyhow!("averaging from frame {}: {e:?}", first.index))?;
    Ok(first)
}
