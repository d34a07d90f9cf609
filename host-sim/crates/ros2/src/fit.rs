//! Whether a frame's fan covers the model's polar grid, and what does not fit when it does
//! not: the aperture (the outermost input columns lie beyond the outermost beams), the range
//! window (the ranges do not reach from `r_min` to `r_max`, within one sample), too few beams
//! (fewer beams inside the model's aperture than it has input columns: each column would be
//! interpolated between beams, finer than the sonar resolves).

use epssn::config;

use crate::frame::SonarFrame;

/// Every reason `frame` cannot feed the model, joined; `None` when it fits.
pub fn misfit(frame: &SonarFrame) -> Option<String> {
    let mut why = Vec::new();
    let cols = &config::INPUT_COLUMN_AZIMUTH_RAD;
    let (col_lo, col_hi) = (cols[0], cols[cols.len() - 1]);
    let beams = &frame.beam_centres_rad;
    if let (Some(&lo), Some(&hi)) = (beams.first(), beams.last()) {
        if lo > col_lo || hi < col_hi {
            why.push(format!(
                "aperture {:.2}°…{:.2}° does not cover the model's {:.2}°…{:.2}°",
                lo.to_degrees(),
                hi.to_degrees(),
                col_lo.to_degrees(),
                col_hi.to_degrees()
            ));
        }
    }
    let inside = beams
        .iter()
        .filter(|&&a| (col_lo..=col_hi).contains(&a))
        .count();
    if inside < cols.len() {
        why.push(format!(
            "too few beams: {inside} inside the model's aperture, it has {} input columns",
            cols.len()
        ));
    }
    why.extend(epssn_aris::polar::range_window_mismatch(&frame.ranges));
    (!why.is_empty()).then(|| why.join("; "))
}
