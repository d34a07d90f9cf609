//! The polar image (range bins × beam columns) drawn as the sonar's fan in Cartesian
//! coordinates, seen from above: what a sonar viewer shows, for an image panel.
//!
//! Row 0 is the far edge (x = r_max, forward up), column 0 the sonar's left (+y); every pixel
//! is [`metres_per_pixel`] square in the sonar frame's x–y plane (x forward, y left) and takes
//! the polar pixel of its range and azimuth (nearest bin and column); pixels outside the fan
//! are 0.

use anyhow::{ensure, Result};
use epssn::config::{INPUT_COLUMNS, INPUT_COLUMN_AZIMUTH_RAD, INPUT_LEN, INPUT_RANGE_BINS};
use epssn::config::{R_MAX_M, R_MIN_M};
use epssn::geometry::fractional_index;

/// Side of a fan pixel, metres: one polar range bin, so the fan keeps the range resolution.
pub fn metres_per_pixel() -> f64 {
    (R_MAX_M - R_MIN_M) / INPUT_RANGE_BINS as f64
}

/// A fan image.
#[derive(Clone, Debug, PartialEq)]
pub struct Fan {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major grey pixels.
    pub pixels: Vec<u8>,
}

/// Azimuths of the fan's edges: the outer columns' centres widened by half a column.
fn edges() -> (f64, f64) {
    let a = &INPUT_COLUMN_AZIMUTH_RAD;
    let n = a.len();
    let half = |i: usize, j: usize| (a[j] - a[i]).abs() / 2.0;
    (a[0] - half(0, 1), a[n - 1] + half(n - 2, n - 1))
}

/// The polar column nearest azimuth `az`, if it is inside the fan.
fn column_of(az: f64, lo: f64, hi: f64) -> Option<usize> {
    let a = &INPUT_COLUMN_AZIMUTH_RAD;
    if !(lo..=hi).contains(&az) {
        return None;
    }
    if az < a[0] {
        return Some(0);
    }
    match fractional_index(a, az) {
        Some((i, f)) => Some(if f > 0.5 { i + 1 } else { i }),
        None => Some(a.len() - 1),
    }
}

/// Draws `polar` (`INPUT_RANGE_BINS` rows of `INPUT_COLUMNS`, row 0 nearest) as the fan.
pub fn fan(polar: &[u8]) -> Result<Fan> {
    ensure!(
        polar.len() == INPUT_LEN,
        "a polar image has {INPUT_RANGE_BINS} × {INPUT_COLUMNS} = {INPUT_LEN} pixels, not {}",
        polar.len()
    );
    let m = metres_per_pixel();
    let (lo, hi) = edges();
    let x_near = R_MIN_M * lo.abs().max(hi.abs()).cos();
    let (y_left, y_right) = (R_MAX_M * hi.sin(), R_MAX_M * lo.sin());
    let width = ((y_left - y_right) / m).ceil() as usize;
    let height = ((R_MAX_M - x_near) / m).ceil() as usize;
    let bin = (R_MAX_M - R_MIN_M) / INPUT_RANGE_BINS as f64;
    let mut pixels = vec![0u8; width * height];
    for (row, line) in pixels.chunks_exact_mut(width).enumerate() {
        let x = R_MAX_M - (row as f64 + 0.5) * m;
        for (col, px) in line.iter_mut().enumerate() {
            let y = y_left - (col as f64 + 0.5) * m;
            let r = x.hypot(y);
            if !(R_MIN_M..R_MAX_M).contains(&r) {
                continue;
            }
            let b = (((r - R_MIN_M) / bin) as usize).min(INPUT_RANGE_BINS - 1);
            if let Some(c) = column_of(y.atan2(x), lo, hi) {
                *px = polar[b * INPUT_COLUMNS + c];
            }
        }
    }
    Ok(Fan {
        width,
        height,
        pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bright spot at one range bin and column lands where its range and azimuth put it.
    #[test]
    fn a_polar_pixel_lands_at_its_range_and_azimuth() {
        let (b, c) = (200, 10);
        let mut polar = vec![0u8; INPUT_LEN];
        polar[b * INPUT_COLUMNS + c] = 255;
        let f = fan(&polar).unwrap();
        let m = metres_per_pixel();
        let (lo, hi) = edges();
        let y_left = R_MAX_M * hi.sin();
        let lit: Vec<(usize, usize)> = f
            .pixels
            .iter()
            .enumerate()
            .filter(|(_, &v)| v == 255)
            .map(|(i, _)| (i / f.width, i % f.width))
            .collect();
        assert!(!lit.is_empty());
        let bin = (R_MAX_M - R_MIN_M) / INPUT_RANGE_BINS as f64;
        let half_col = (INPUT_COLUMN_AZIMUTH_RAD[c + 1] - INPUT_COLUMN_AZIMUTH_RAD[c]) / 2.0;
        for (row, col) in lit {
            let x = R_MAX_M - (row as f64 + 0.5) * m;
            let y = y_left - (col as f64 + 0.5) * m;
            let r = x.hypot(y);
            assert!(r >= R_MIN_M + b as f64 * bin && r < R_MIN_M + (b + 1) as f64 * bin);
            assert!((y.atan2(x) - INPUT_COLUMN_AZIMUTH_RAD[c]).abs() <= half_col * 1.0001);
        }
        // Column 10 is right of centre (ascending azimuth, column 0 right-most): y < 0.
        assert!(INPUT_COLUMN_AZIMUTH_RAD[c] < 0.0 && lo < 0.0);
        assert!(fan(&polar[1..]).is_err());
    }
}
