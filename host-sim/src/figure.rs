//! Labelled depth-map figures: panels side by side, each with its title, azimuth and
//! elevation axes in degrees and a colour bar in metres (depth) or millimetres (error). Text is
//! drawn with the 8 × 8 bitmap font of `epssn_sim::draw`, so no font file is needed.

use epssn::config::{
    DEPTH_COLUMNS, DEPTH_ROWS, DEPTH_ROW_ELEVATION_RAD, INPUT_COLUMN_AZIMUTH_RAD, R_MAX_M, R_MIN_M,
};
use image::{Rgb, RgbImage};

use epssn_sim::draw::{draw_text, fill, text_width};
use epssn_sim::preview::turbo;

/// What a panel shows and how it is coloured.
pub enum Panel<'a> {
    /// A depth map `[E][A]`, metres, coloured over the range window.
    Depth {
        /// Title above the panel.
        title: &'a str,
        /// The map.
        depth: &'a [f32],
    },
    /// A per-pixel absolute error `[E][A]`, metres, shown in millimetres over `0..=max_mm`.
    Error {
        /// Title above the panel.
        title: &'a str,
        /// `|prediction − label|` per pixel, metres.
        error: &'a [f32],
        /// Top of the colour scale, mm (larger errors saturate).
        max_mm: f32,
    },
}

/// Colour of depth-map pixel `i`.
type Colouring<'a> = Box<dyn Fn(usize) -> [u8; 3] + 'a>;
/// A colour bar's low and high values, unit and decimals.
type ColourBar = (f64, f64, &'static str, usize);

/// Pixels per depth-map cell.
const SCALE: u32 = 4;
const LEFT: u32 = 44;
const TOP: u32 = 16;
const BOTTOM: u32 = 30;
const BAR_GAP: u32 = 6;
const BAR_W: u32 = 10;
const BAR_LABELS: u32 = 44;
const GAP: u32 = 8;
const INK: Rgb<u8> = Rgb([20, 20, 20]);
const PAPER: Rgb<u8> = Rgb([255, 255, 255]);

/// Horizontal pixel (from the map's left edge) of azimuth `deg`: columns are drawn with the
/// sonar's left (positive azimuth, the last column) on the left; `None` outside the fan.
fn azimuth_x(deg: f64) -> Option<f64> {
    let az = &INPUT_COLUMN_AZIMUTH_RAD[..DEPTH_COLUMNS];
    let t = deg.to_radians();
    let k = epssn::geometry::fractional_index(az, t)
        .map(|(k, f)| k as f64 + f)
        .or_else(|| ((t - az[0]).abs() < 1e-9).then_some(0.0))?;
    let column_from_left = (DEPTH_COLUMNS - 1) as f64 - k;
    Some((column_from_left + 0.5) * SCALE as f64)
}

/// Vertical pixel (from the map's top edge) of elevation `deg` (up on top).
fn elevation_y(deg: f64) -> f64 {
    let lo = DEPTH_ROW_ELEVATION_RAD[0].to_degrees();
    let hi = DEPTH_ROW_ELEVATION_RAD[DEPTH_ROWS - 1].to_degrees();
    let row_from_bottom = (deg - lo) / (hi - lo) * (DEPTH_ROWS - 1) as f64;
    ((DEPTH_ROWS - 1) as f64 - row_from_bottom + 0.5) * SCALE as f64
}

fn panel_width() -> u32 {
    LEFT + DEPTH_COLUMNS as u32 * SCALE + BAR_GAP + BAR_W + BAR_LABELS
}

/// Draws one panel with its top-left corner at `x0`.
fn draw_panel(img: &mut RgbImage, x0: u32, panel: &Panel<'_>) {
    let (mw, mh) = (DEPTH_COLUMNS as u32 * SCALE, DEPTH_ROWS as u32 * SCALE);
    let (mx, my) = (x0 + LEFT, TOP);
    let (title, colour, bar): (&str, Colouring<'_>, ColourBar) = match panel {
        Panel::Depth { title, depth } => (
            title,
            Box::new(|i| {
                let d = depth.get(i).copied().unwrap_or(f32::NAN) as f64;
                if d.is_finite() {
                    turbo((d - R_MIN_M) / (R_MAX_M - R_MIN_M))
                } else {
                    [60, 60, 60]
                }
            }),
            (R_MIN_M, R_MAX_M, "m", 2),
        ),
        Panel::Error {
            title,
            error,
            max_mm,
        } => (
            title,
            Box::new(|i| {
                let e = error.get(i).copied().unwrap_or(f32::NAN) as f64 * 1000.0;
                if e.is_finite() {
                    turbo(e / *max_mm as f64)
                } else {
                    [60, 60, 60]
                }
            }),
            (0.0, *max_mm as f64, "mm", 0),
        ),
    };
    draw_text(
        img,
        (mx + mw / 2) as i64 - text_width(title) as i64 / 2,
        2,
        title,
        INK,
    );
    for py in 0..mh {
        for px in 0..mw {
            let a = DEPTH_COLUMNS - 1 - (px / SCALE) as usize;
            let e = DEPTH_ROWS - 1 - (py / SCALE) as usize;
            img.put_pixel(mx + px, my + py, Rgb(colour(e * DEPTH_COLUMNS + a)));
        }
    }
    // Azimuth ticks every 5°, elevation ticks every 3.5°, in degrees.
    for deg in (-15..=15).step_by(5) {
        if let Some(x) = azimuth_x(deg as f64) {
            let x = mx + x.round() as u32;
            fill(img, x, my + mh, 1, 4, INK);
            let label = format!("{deg}");
            draw_text(
                img,
                x as i64 - text_width(&label) as i64 / 2,
                (my + mh + 5) as i64,
                &label,
                INK,
            );
        }
    }
    let label = "azimuth (deg)";
    draw_text(
        img,
        (mx + mw / 2) as i64 - text_width(label) as i64 / 2,
        (my + mh + 16) as i64,
        label,
        INK,
    );
    let half = DEPTH_ROW_ELEVATION_RAD[DEPTH_ROWS - 1].to_degrees();
    for k in -2i32..=2 {
        let deg = half * k as f64 / 2.0;
        let y = my + elevation_y(deg).round() as u32;
        fill(img, mx - 4, y, 4, 1, INK);
        let label = format!("{deg:.1}");
        draw_text(
            img,
            (mx - 5 - text_width(&label)) as i64,
            y as i64 - 4,
            &label,
            INK,
        );
    }
    draw_text(img, x0 as i64, (my + mh + 16) as i64, "elev", INK);
    // Colour bar with its scale at both ends and the middle.
    let (lo, hi, unit, decimals) = bar;
    let bx = mx + mw + BAR_GAP;
    for py in 0..mh {
        let x = 1.0 - py as f64 / (mh - 1) as f64;
        fill(img, bx, my + py, BAR_W, 1, Rgb(turbo(x)));
    }
    for (k, x) in [(0, 1.0), (1, 0.5), (2, 0.0)] {
        let v = lo + (hi - lo) * x;
        let y = my as i64 + (k * (mh - 1) / 2) as i64 - 4;
        let label = format!("{v:.decimals$}");
        draw_text(img, (bx + BAR_W + 2) as i64, y.max(0), &label, INK);
    }
    draw_text(
        img,
        (bx + BAR_W + 2) as i64,
        (my + mh + 5) as i64,
        unit,
        INK,
    );
}

/// The panels side by side on a white page.
pub fn depth_figure(panels: &[Panel<'_>]) -> RgbImage {
    let pw = panel_width();
    let w = pw * panels.len() as u32 + GAP * (panels.len() as u32).saturating_sub(1);
    let h = TOP + DEPTH_ROWS as u32 * SCALE + BOTTOM;
    let mut img = RgbImage::from_pixel(w.max(1), h, PAPER);
    for (n, p) in panels.iter().enumerate() {
        draw_panel(&mut img, n as u32 * (pw + GAP), p);
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panels_are_laid_out_and_coloured_by_value() {
        let near = vec![R_MIN_M as f32; DEPTH_ROWS * DEPTH_COLUMNS];
        let far = vec![R_MAX_M as f32; DEPTH_ROWS * DEPTH_COLUMNS];
        let err = vec![0.05f32; DEPTH_ROWS * DEPTH_COLUMNS];
        let img = depth_figure(&[
            Panel::Depth {
                title: "int8",
                depth: &near,
            },
            Panel::Depth {
                title: "ground truth",
                depth: &far,
            },
            Panel::Error {
                title: "|int8 - truth|",
                error: &err,
                max_mm: 100.0,
            },
        ]);
        assert_eq!(img.width(), 3 * panel_width() + 2 * GAP);
        // The centre of each map shows its value's colour.
        let centre = |n: u32| {
            *img.get_pixel(
                n * (panel_width() + GAP) + LEFT + DEPTH_COLUMNS as u32 * SCALE / 2,
                TOP + DEPTH_ROWS as u32 * SCALE / 2,
            )
        };
        assert_eq!(centre(0), Rgb(turbo(0.0)));
        assert_eq!(centre(1), Rgb(turbo(1.0)));
        assert_eq!(centre(2), Rgb(turbo(0.5)));
        // Titles and tick labels put ink on the page outside the maps.
        let ink = img.pixels().filter(|p| **p == INK).count();
        assert!(ink > 500, "{ink}");
    }

    #[test]
    fn axes_follow_the_geometry() {
        // 0° azimuth lies between the two middle columns, the sonar's left on the left.
        let x0 = azimuth_x(0.0).unwrap();
        let mid = DEPTH_COLUMNS as f64 * SCALE as f64 / 2.0;
        assert!((x0 - mid).abs() < 2.0 * SCALE as f64, "{x0} vs {mid}");
        assert!(azimuth_x(10.0).unwrap() < azimuth_x(-10.0).unwrap());
        assert!(azimuth_x(40.0).is_none());
        // Top elevation at the top row's centre.
        let half = DEPTH_ROW_ELEVATION_RAD[DEPTH_ROWS - 1].to_degrees();
        assert!((elevation_y(half) - SCALE as f64 / 2.0).abs() < 1e-9);
    }
}
