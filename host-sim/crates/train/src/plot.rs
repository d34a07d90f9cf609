//! Loss-curve PNG drawn with the `image` crate and the shared helpers of `epssn_sim::draw`
//! (text in its 8 × 8 bitmap font: no font file needed).
//!
//! Train loss is blue, validation loss orange; x = epoch, y = loss (linear). The y-axis labels
//! give the top and bottom values.

use std::path::Path;

use anyhow::Result;
use epssn_sim::draw::{draw_text, line, put, text_width};
use image::{Rgb, RgbImage};

const W: u32 = 640;
const H: u32 = 400;
const LEFT: i64 = 60;
const RIGHT: i64 = 20;
const TOP: i64 = 20;
const BOTTOM: i64 = 30;

/// Draws the curves `(x, y)` (NaN points skipped) to a PNG.
pub fn plot_losses(path: &Path, train: &[(f64, f64)], val: &[(f64, f64)]) -> Result<()> {
    let mut img = RgbImage::from_pixel(W, H, Rgb([255, 255, 255]));
    let all = train.iter().chain(val).filter(|p| p.1.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in all {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    y0 = y0.min(0.0);
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    if y1 <= y0 {
        y1 = y0 + 1.0;
    }
    let (pw, ph) = (
        (W as i64 - LEFT - RIGHT) as f64,
        (H as i64 - TOP - BOTTOM) as f64,
    );
    let map = |(x, y): (f64, f64)| {
        (
            LEFT + ((x - x0) / (x1 - x0) * pw).round() as i64,
            TOP + ((1.0 - (y - y0) / (y1 - y0)) * ph).round() as i64,
        )
    };
    let black = Rgb([0, 0, 0]);
    let grey = Rgb([220, 220, 220]);
    for i in 1..4 {
        let y = TOP + (ph * i as f64 / 4.0) as i64;
        line(&mut img, (LEFT, y), (W as i64 - RIGHT, y), grey);
    }
    line(&mut img, (LEFT, TOP), (LEFT, H as i64 - BOTTOM), black);
    line(
        &mut img,
        (LEFT, H as i64 - BOTTOM),
        (W as i64 - RIGHT, H as i64 - BOTTOM),
        black,
    );
    let x_end = format!("{x1:.0}");
    draw_text(&mut img, 4, TOP - 4, &format!("{y1:.3}"), black);
    draw_text(
        &mut img,
        4,
        H as i64 - BOTTOM - 4,
        &format!("{y0:.3}"),
        black,
    );
    draw_text(
        &mut img,
        LEFT,
        H as i64 - BOTTOM + 8,
        &format!("{x0:.0}"),
        black,
    );
    draw_text(
        &mut img,
        W as i64 - RIGHT - text_width(&x_end) as i64,
        H as i64 - BOTTOM + 8,
        &x_end,
        black,
    );
    for (pts, c) in [(train, Rgb([31, 119, 180])), (val, Rgb([255, 127, 14]))] {
        let mut prev: Option<(i64, i64)> = None;
        for &p in pts {
            if !p.1.is_finite() {
                prev = None;
                continue;
            }
            let q = map(p);
            if let Some(pp) = prev {
                line(&mut img, pp, q, c);
            } else {
                put(&mut img, q.0, q.1, c);
            }
            prev = Some(q);
        }
    }
    img.save(path)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_has_curves_and_labels() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("loss.png");
        let train: Vec<(f64, f64)> = (0..10)
            .map(|e| (e as f64, 1.0 / (1.0 + e as f64)))
            .collect();
        let val: Vec<(f64, f64)> = (0..10)
            .map(|e| {
                (
                    e as f64,
                    if e == 3 {
                        f64::NAN
                    } else {
                        0.8 / (1.0 + e as f64)
                    },
                )
            })
            .collect();
        plot_losses(&path, &train, &val).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (W, H));
        let count = |c: [u8; 3]| img.pixels().filter(|p| p.0 == c).count();
        assert!(count([31, 119, 180]) > 100, "train curve");
        assert!(count([255, 127, 14]) > 100, "validation curve");
        // The top y label "1.000" in the left margin: black text pixels left of the axis.
        let label = (0..LEFT as u32 - 2)
            .flat_map(|x| (0..TOP as u32 + 8).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0 == [0, 0, 0])
            .count();
        assert!(label > 20, "y label drawn ({label} pixels)");
    }
}
