//! Loss-curve PNG drawn with the `image` crate and the shared helpers of `epssn_sim::draw`
//! (text in its 8 × 8 bitmap font: no font file needed).
//!
//! Two curves, the first blue and the second orange, on linear axes whose end values are
//! written at the axes' ends, with the axes' titles and a legend: the loss curves of training
//! (train and validation loss per epoch) and docs/POSE.md's accuracy against pose error.

use std::path::Path;

use anyhow::Result;
use epssn_sim::draw::{draw_text, line, put, text_width};
use image::{Rgb, RgbImage};

const W: u32 = 640;
const H: u32 = 400;
const LEFT: i64 = 60;
const RIGHT: i64 = 20;
// Room above the plot for the y axis's title and the legend.
const TOP: i64 = 36;
const BOTTOM: i64 = 30;

/// What the axes and the two curves are called, and an optional marked x value.
pub struct Labels<'a> {
    /// Title of the x axis.
    pub x: &'a str,
    /// Title of the y axis.
    pub y: &'a str,
    /// Legend names of the first (blue) and second (orange) curve.
    pub curves: [&'a str; 2],
    /// A vertical line at this x value with its caption (e.g. a chosen threshold).
    pub marker: Option<(f64, &'a str)>,
}

/// Draws the training curves (x = epoch; NaN points skipped) to a PNG.
pub fn plot_losses(path: &Path, train: &[(f64, f64)], val: &[(f64, f64)]) -> Result<()> {
    let labels = Labels {
        x: "epoch",
        y: "loss",
        curves: ["train", "validation"],
        marker: None,
    };
    plot_two(path, train, val, &labels)
}

/// Draws two curves `(x, y)` (NaN points skipped) with axis titles and a legend to a PNG.
pub fn plot_two(
    path: &Path,
    first: &[(f64, f64)],
    second: &[(f64, f64)],
    labels: &Labels,
) -> Result<()> {
    let mut img = RgbImage::from_pixel(W, H, Rgb([255, 255, 255]));
    let (x0, x1, y0, y1) = bounds(first, second);
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
    let x_digits = if x1 - x0 < 5.0 { 2 } else { 0 };
    let x_end = format!("{x1:.x_digits$}");
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
        &format!("{x0:.x_digits$}"),
        black,
    );
    let x_title_at = LEFT + (pw as i64 - text_width(labels.x) as i64) / 2;
    draw_text(&mut img, x_title_at, H as i64 - BOTTOM + 8, labels.x, black);
    draw_text(&mut img, 4, 6, labels.y, black);
    let blue = Rgb([31, 119, 180]);
    let orange = Rgb([255, 127, 14]);
    // The legend in one row above the plot, right-aligned, so it never covers a curve.
    let entry = |name: &str| 26 + text_width(name) as i64 + 12;
    let mut x = W as i64 - RIGHT - labels.curves.iter().map(|n| entry(n)).sum::<i64>();
    for (name, c) in labels.curves.iter().zip([blue, orange]) {
        line(&mut img, (x, 10), (x + 20, 10), c);
        line(&mut img, (x, 11), (x + 20, 11), c);
        draw_text(&mut img, x + 26, 7, name, black);
        x += entry(name);
    }
    if let Some((mx, caption)) = labels.marker {
        if (x0..=x1).contains(&mx) {
            draw_marker(&mut img, map((mx, y0)).0, caption);
        }
    }
    draw_text(
        &mut img,
        W as i64 - RIGHT - text_width(&x_end) as i64,
        H as i64 - BOTTOM + 8,
        &x_end,
        black,
    );
    for (pts, c) in [(first, blue), (second, orange)] {
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

/// The plot's x and y ranges `(x0, x1, y0, y1)` over both curves' finite points: y from 0 at
/// most, neither range empty.
fn bounds(first: &[(f64, f64)], second: &[(f64, f64)]) -> (f64, f64, f64, f64) {
    let all = first.iter().chain(second).filter(|p| p.1.is_finite());
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
    (x0, x1, y0, y1)
}

/// A vertical marker at pixel column `px` with its caption.
fn draw_marker(img: &mut RgbImage, px: i64, caption: &str) {
    let grey_dark = Rgb([120, 120, 120]);
    // Dashed, so that it does not read as a third curve.
    let mut y = TOP;
    while y < H as i64 - BOTTOM {
        line(
            img,
            (px, y),
            (px, (y + 4).min(H as i64 - BOTTOM)),
            grey_dark,
        );
        y += 8;
    }
    draw_text(img, px + 4, TOP + 40, caption, grey_dark);
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

    #[test]
    fn marker_is_drawn_only_inside_the_x_range() {
        let dir = tempfile::tempdir().unwrap();
        let a: Vec<(f64, f64)> = (0..5).map(|i| (i as f64 * 0.25, i as f64)).collect();
        let b: Vec<(f64, f64)> = (0..5).map(|i| (i as f64 * 0.25, 2.0 * i as f64)).collect();
        let dark = |marker| {
            let path = dir.path().join("p.png");
            let labels = Labels {
                x: "x",
                y: "y",
                curves: ["a", "b"],
                marker,
            };
            plot_two(&path, &a, &b, &labels).unwrap();
            let img = image::open(&path).unwrap().to_rgb8();
            img.pixels().filter(|p| p.0 == [120, 120, 120]).count()
        };
        assert!(dark(Some((0.5, "m"))) > 100, "marker line and caption");
        assert_eq!(
            dark(Some((2.0, "m"))),
            0,
            "a marker outside the range is left out"
        );
        assert_eq!(dark(None), 0);
    }
}
