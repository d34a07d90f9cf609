//! PNG previews: polar images drawn as a fan in Cartesian coordinates, depth maps in the turbo
//! colour map.

use std::path::Path;

use anyhow::{Context, Result};
use epssn::config::{
    DEPTH_COLUMNS, DEPTH_ROWS, INPUT_COLUMNS, INPUT_COLUMN_AZIMUTH_RAD, INPUT_RANGE_BINS, R_MAX_M,
    R_MIN_M,
};
use epssn::geometry::fractional_index;
use image::{Rgb, RgbImage};

/// Turbo colour map (Google's polynomial approximation), `x` in [0, 1].
pub fn turbo(x: f64) -> [u8; 3] {
    let x = x.clamp(0.0, 1.0);
    let (x2, x3) = (x * x, x * x * x);
    let (x4, x5) = (x2 * x2, x2 * x3);
    let r = 0.13572138 + 4.61539260 * x - 42.66032258 * x2 + 132.13108234 * x3 - 152.94239396 * x4
        + 59.28637943 * x5;
    let g = 0.09140261 + 2.19418839 * x + 4.84296658 * x2 - 14.18503333 * x3
        + 4.27729857 * x4
        + 2.82956604 * x5;
    let b = 0.10667330 + 12.64194608 * x - 60.58204836 * x2 + 110.36276771 * x3 - 89.90310912 * x4
        + 27.34824973 * x5;
    let q = |v: f64| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    [q(r), q(g), q(b)]
}

/// A sonar-style palette for intensities: black, copper, yellow, white.
pub fn sonar_palette(v: u8) -> [u8; 3] {
    let x = v as f64 / 255.0;
    let r = (x * 1.6).min(1.0);
    let g = (x * 1.25 - 0.15).clamp(0.0, 1.0);
    let b = (x * 1.8 - 0.9).clamp(0.0, 1.0);
    [
        (r * 255.0) as u8,
        (g * 255.0).round() as u8,
        (b * 255.0).round() as u8,
    ]
}

/// Pixel size of the fan drawing, metres.
const FAN_RES_M: f64 = 0.008;

/// Draws a polar image (R × B, `img[i × B + k]`) as a fan seen from above: forward is up, the
/// sonar's left is left.
pub fn fan_image(polar: &[u8]) -> RgbImage {
    let az = &INPUT_COLUMN_AZIMUTH_RAD[..INPUT_COLUMNS];
    let half = az[0].abs().max(az[INPUT_COLUMNS - 1].abs());
    let y_max = R_MAX_M * half.sin();
    let x_min = R_MIN_M * half.cos();
    let w = (2.0 * y_max / FAN_RES_M).ceil() as u32 + 1;
    let h = ((R_MAX_M - x_min) / FAN_RES_M).ceil() as u32 + 1;
    let bin = (R_MAX_M - R_MIN_M) / INPUT_RANGE_BINS as f64;
    let mut img = RgbImage::from_pixel(w, h, Rgb([24, 24, 32]));
    for py in 0..h {
        for px in 0..w {
            let y = y_max - px as f64 * FAN_RES_M;
            let x = R_MAX_M - py as f64 * FAN_RES_M;
            let r = (x * x + y * y).sqrt();
            if !(R_MIN_M..R_MAX_M).contains(&r) {
                continue;
            }
            let Some((k, f)) = fractional_index(az, y.atan2(x)) else {
                continue;
            };
            let i = (((r - R_MIN_M) / bin) as usize).min(INPUT_RANGE_BINS - 1);
            let a = polar.get(i * INPUT_COLUMNS + k).copied().unwrap_or(0) as f64;
            let b = polar.get(i * INPUT_COLUMNS + k + 1).copied().unwrap_or(0) as f64;
            let v = (a * (1.0 - f) + b * f).round() as u8;
            img.put_pixel(px, py, Rgb(sonar_palette(v)));
        }
    }
    img
}

/// Draws an E × A depth map, `scale` pixels per cell, with the sonar's left on the left and
/// up on top; pixels outside the mask are grey.
pub fn depth_image(depth: &[f32], mask: &[f32], scale: u32) -> RgbImage {
    let (w, h) = (DEPTH_COLUMNS as u32 * scale, DEPTH_ROWS as u32 * scale);
    let mut img = RgbImage::new(w, h);
    for py in 0..h {
        for px in 0..w {
            let a = DEPTH_COLUMNS - 1 - (px / scale) as usize;
            let e = DEPTH_ROWS - 1 - (py / scale) as usize;
            let i = e * DEPTH_COLUMNS + a;
            let c = match (depth.get(i), mask.get(i)) {
                (Some(d), Some(m)) if *m > 0.5 => {
                    turbo((*d as f64 - R_MIN_M) / (R_MAX_M - R_MIN_M))
                }
                _ => [60, 60, 60],
            };
            img.put_pixel(px, py, Rgb(c));
        }
    }
    img
}

/// One preview: the views' fans side by side, the depth map below.
pub fn sample_preview(polar_views: &[Vec<u8>], depth: &[f32], mask: &[f32]) -> RgbImage {
    let fans: Vec<RgbImage> = polar_views.iter().map(|p| fan_image(p)).collect();
    let fw = fans.first().map_or(0, |f| f.width());
    let fh = fans.first().map_or(0, |f| f.height());
    let gap = 4;
    let dimg = depth_image(depth, mask, 4);
    let w =
        (fw * fans.len() as u32 + gap * (fans.len() as u32).saturating_sub(1)).max(dimg.width());
    let h = fh + gap + dimg.height();
    let mut out = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    for (n, f) in fans.iter().enumerate() {
        image::imageops::replace(&mut out, f, (n as u32 * (fw + gap)) as i64, 0);
    }
    image::imageops::replace(
        &mut out,
        &dimg,
        ((w - dimg.width()) / 2) as i64,
        (fh + gap) as i64,
    );
    out
}

/// Images side by side with a 4-pixel white gap, top-aligned.
pub fn hstack(images: &[RgbImage]) -> RgbImage {
    let gap = 4;
    let w = images.iter().map(|i| i.width()).sum::<u32>()
        + gap * (images.len() as u32).saturating_sub(1);
    let h = images.iter().map(|i| i.height()).max().unwrap_or(0);
    let mut out = RgbImage::from_pixel(w.max(1), h.max(1), Rgb([255, 255, 255]));
    let mut x = 0;
    for img in images {
        image::imageops::replace(&mut out, img, x as i64, 0);
        x += img.width() + gap;
    }
    out
}

/// Writes a PNG.
pub fn save_png(img: &RgbImage, path: &Path) -> Result<()> {
    img.save_with_format(path, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turbo_ends() {
        // Dark at 0, blue, then green in the middle, red near the top.
        assert!(turbo(0.0).iter().all(|c| *c < 60), "{:?}", turbo(0.0));
        let blue = turbo(0.15);
        assert!(blue[2] > 200 && blue[0] < blue[2], "{blue:?}");
        let mid = turbo(0.5);
        assert!(mid[1] > 200, "{mid:?}");
        let red = turbo(0.9);
        assert!(
            red[0] > 150 && red[0] > 3 * red[2] && red[0] > 3 * red[1],
            "{red:?}"
        );
    }

    #[test]
    fn fan_puts_a_left_target_on_the_left() {
        let mut polar = vec![0u8; INPUT_RANGE_BINS * INPUT_COLUMNS];
        // Column 60 is on the sonar's left (positive azimuth).
        for i in 100..110 {
            polar[i * INPUT_COLUMNS + 60] = 255;
        }
        let img = fan_image(&polar);
        let (mut left, mut right) = (0, 0);
        for (x, _, p) in img.enumerate_pixels() {
            if p.0[0] == 255 {
                if x < img.width() / 2 {
                    left += 1;
                } else {
                    right += 1;
                }
            }
        }
        assert!(left > 0 && right == 0, "left {left} right {right}");
    }
}
