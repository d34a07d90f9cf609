//! Loss-curve PNG drawn with the `image` crate (no font files needed: a 3×5 digit font).
//!
//! Train loss is blue, validation loss orange; x = epoch, y = loss (linear). The y-axis labels
//! give the top and bottom values.

use std::path::Path;

use anyhow::Result;
use image::{Rgb, RgbImage};

const W: u32 = 640;
const H: u32 = 400;
const LEFT: i64 = 60;
const RIGHT: i64 = 20;
const TOP: i64 = 20;
const BOTTOM: i64 = 30;

/// 3×5 glyphs of `0-9 . - e`, rows top to bottom, bit 2 = left column.
fn glyph(c: char) -> Option<[u8; 5]> {
    Some(match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        'e' => [7, 5, 7, 4, 7],
        _ => return None,
    })
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

fn text(img: &mut RgbImage, x: i64, y: i64, s: &str, c: Rgb<u8>) {
    let scale = 2;
    for (i, ch) in s.chars().enumerate() {
        if let Some(g) = glyph(ch) {
            for (row, bits) in g.iter().enumerate() {
                for col in 0..3 {
                    if bits & (4 >> col) != 0 {
                        for dy in 0..scale {
                            for dx in 0..scale {
                                put(
                                    img,
                                    x + (i as i64 * 4 + col) * scale + dx,
                                    y + row as i64 * scale + dy,
                                    c,
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}

fn line(img: &mut RgbImage, (x0, y0): (i64, i64), (x1, y1): (i64, i64), c: Rgb<u8>) {
    let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
    let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
    let (mut x, mut y, mut err) = (x0, y0, dx + dy);
    loop {
        put(img, x, y, c);
        put(img, x, y + 1, c);
        if x == x1 && y == y1 {
            break;
        }
        let e2 = 2 * err;
        if e2 >= dy {
            err += dy;
            x += sx;
        }
        if e2 <= dx {
            err += dx;
            y += sy;
        }
    }
}

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
    text(&mut img, 4, TOP - 4, &format!("{y1:.3}"), black);
    text(
        &mut img,
        4,
        H as i64 - BOTTOM - 6,
        &format!("{y0:.3}"),
        black,
    );
    text(
        &mut img,
        LEFT,
        H as i64 - BOTTOM + 8,
        &format!("{x0:.0}"),
        black,
    );
    text(
        &mut img,
        W as i64 - RIGHT - 40,
        H as i64 - BOTTOM + 8,
        &format!("{x1:.0}"),
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
