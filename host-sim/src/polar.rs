//! ARIS frame → the model's polar input image, through the library's one resampler.

use anyhow::{anyhow, Result};
use epssn::config;
use epssn::geometry::{resample_to_grid, Grid};

use crate::aris::Frame;

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
