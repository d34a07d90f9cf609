//! ARIS frame → the model's polar input image, through the library's one resampler.

use anyhow::{anyhow, ensure, Result};
use epssn::config;
use epssn::geometry::{resample_to_grid, Grid, SampleRanges};
use epssn::ping_average::{IntensityTable, PingAverager};

use crate::aris::{ArisReader, Frame};

/// The model's input grid (the compiled configuration's).
pub fn model_grid() -> Grid<'static> {
    Grid {
        r_min: config::R_MIN_M,
        r_max: config::R_MAX_M,
        half_elevation: config::HALF_ELEVATION_RAD,
        column_azimuths: &config::INPUT_COLUMN_AZIMUTH_RAD,
    }
}

/// Resamples `frame` onto the model's R × B polar grid (`img[i · B + k]`, u8), through the
/// frame's own beam table and range geometry.
pub fn frame_to_polar(frame: &Frame) -> Result<Vec<u8>> {
    let ranges = frame.range_geometry()?;
    let beams = frame.beam_centres_rad()?;
    let mut out = vec![0u8; config::INPUT_LEN];
    resample_to_grid(
        &frame.data,
        ranges,
        &beams,
        &model_grid(),
        config::INPUT_RANGE_BINS,
        &mut out,
    )
    .map_err(|e| anyhow!("resampling frame {}: {e:?}", frame.index))?;
    Ok(out)
}

/// Why samples at `r` do not cover the model's range window (within one sample), if they do not:
/// the one rule for every recording format.
pub fn range_window_mismatch(r: &SampleRanges) -> Option<String> {
    let end = r.start + r.step * r.samples.saturating_sub(1) as f64;
    (r.start > config::R_MIN_M + r.step || end < config::R_MAX_M - r.step).then(|| {
        format!(
            "range window {:.3}–{:.3} m does not cover the model's {:.3}–{:.3} m",
            r.start,
            end,
            config::R_MIN_M,
            config::R_MAX_M
        )
    })
}

/// Why a recording's sonar cannot feed the model (system, lens, beam count), or `None` when it
/// can; each frame's range window is [`range_window_mismatch`]'s.
pub fn sensor_mismatch(reader: &ArisReader) -> Option<String> {
    let mut why = Vec::new();
    let system = reader.system();
    if system.name() != config::SONAR_SYSTEM {
        why.push(format!(
            "sonar is {}, the model is for {}",
            system.name(),
            config::SONAR_SYSTEM
        ));
    }
    if reader.telephoto() {
        why.push("telephoto lens (narrower beams than the model's table)".to_string());
    }
    if reader.beams() != config::BEAMS {
        why.push(format!(
            "{} beams, the model needs {}",
            reader.beams(),
            config::BEAMS
        ));
    }
    (!why.is_empty()).then(|| why.join("; "))
}

/// The frames `pings` of a recording (a view's pings at one roll) averaged in intensity
/// (`epssn::ping_average`) into one frame with the first's header: what `host-sim run
/// --pings-per-view` feeds [`frame_to_polar`].
pub fn average_pings(
    reader: &ArisReader,
    pings: &[usize],
    table: &IntensityTable,
) -> Result<Frame> {
    let (&head, rest) = pings
        .split_first()
        .ok_or_else(|| anyhow!("no frames to average"))?;
    let mut first = reader.frame(head)?;
    if rest.is_empty() {
        return Ok(first);
    }
    let mut sum = vec![0f32; first.data.len()];
    let mut avg = PingAverager::new(table, &mut sum);
    avg.add(&first.data)
        .map_err(|e| anyhow!("frame {head}: {e:?}"))?;
    for &p in rest {
        let f = reader.frame(p)?;
        ensure!(
            (f.beams, f.samples_per_beam) == (first.beams, first.samples_per_beam),
            "frames {head} and {p} differ in geometry: their pings cannot be averaged"
        );
        avg.add(&f.data).map_err(|e| anyhow!("frame {p}: {e:?}"))?;
    }
    avg.finish(&mut first.data)
        .map_err(|e| anyhow!("averaging frames {pings:?}: {e:?}"))?;
    Ok(first)
}
