//! ARIS frame → the model's polar input image, through the library's one resampler.

use anyhow::{anyhow, Result};
use epssn::config;
use epssn::geometry::{resample_to_grid, Grid};

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

/// Explains why a recording cannot feed the model, or `None` when it fits.
pub fn geometry_mismatch(reader: &ArisReader) -> Result<Option<String>> {
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
    if let Ok(frame) = reader.frame(0) {
        if let Ok(r) = frame.range_geometry() {
            let end = r.start + r.step * (r.samples.saturating_sub(1)) as f64;
            // The recording must cover the model's window (within one sample).
            if r.start > config::R_MIN_M + r.step || end < config::R_MAX_M - r.step {
                why.push(format!(
                    "range window {:.3}–{:.3} m does not cover the model's {:.3}–{:.3} m",
                    r.start,
                    end,
                    config::R_MIN_M,
                    config::R_MAX_M
                ));
            }
        }
    }
    Ok((!why.is_empty()).then(|| why.join("; ")))
}
