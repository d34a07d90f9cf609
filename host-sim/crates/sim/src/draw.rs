//! Drawing on `image` buffers for the host tools' figures (the labelled depth figure of
//! `host-sim`, the training loss plot): text in the public-domain 8 × 8 bitmap font of
//! `font8x8` (no font file needed), filled rectangles and lines. Pixels outside the image are
//! skipped, so callers may draw across its edges.

use font8x8::{UnicodeFonts, BASIC_FONTS};
use image::{Rgb, RgbImage};

/// Width of a text in pixels (8 per character).
pub fn text_width(s: &str) -> u32 {
    8 * s.chars().count() as u32
}

/// Sets pixel `(x, y)` if it lies inside the image.
pub fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

/// Draws `s` with its top-left corner at `(x, y)`; characters without a glyph are left blank.
pub fn draw_text(img: &mut RgbImage, x: i64, y: i64, s: &str, colour: Rgb<u8>) {
    for (n, ch) in s.chars().enumerate() {
        let Some(glyph) = BASIC_FONTS.get(ch) else {
            continue;
        };
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits >> col & 1 == 1 {
                    put(img, x + 8 * n as i64 + col, y + row as i64, colour);
                }
            }
        }
    }
}

/// Fills the rectangle of width `w` and height `h` at `(x, y)`.
pub fn fill(img: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, c: Rgb<u8>) {
    for py in y..y.saturating_add(h).min(img.height()) {
        for px in x..x.saturating_add(w).min(img.width()) {
            img.put_pixel(px, py, c);
        }
    }
}

/// A line two pixels thick (Bresenham) from `(x0, y0)` to `(x1, y1)`.
pub fn line(img: &mut RgbImage, (x0, y0): (i64, i64), (x1, y1): (i64, i64), c: Rgb<u8>) {
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

#[cfg(test)]
mod tests {
    use super::*;

    const INK: Rgb<u8> = Rgb([0, 0, 0]);
    const PAPER: Rgb<u8> = Rgb([255, 255, 255]);

    fn inked(img: &RgbImage) -> Vec<(u32, u32)> {
        img.enumerate_pixels()
            .filter(|p| *p.2 == INK)
            .map(|p| (p.0, p.1))
            .collect()
    }

    #[test]
    fn text_is_drawn_in_its_box_and_clipped_at_the_edges() {
        let mut img = RgbImage::from_pixel(40, 12, PAPER);
        draw_text(&mut img, 2, 2, "1.5", INK);
        let px = inked(&img);
        assert!(!px.is_empty());
        let w = text_width("1.5");
        assert_eq!(w, 24);
        assert!(px
            .iter()
            .all(|&(x, y)| (2..2 + w).contains(&x) && (2..10).contains(&y)));
        // Half off the image: no panic, only the visible part drawn.
        let mut img = RgbImage::from_pixel(10, 10, PAPER);
        draw_text(&mut img, -4, -4, "88", INK);
        draw_text(&mut img, 6, 6, "88", INK);
        assert!(!inked(&img).is_empty());
    }

    #[test]
    fn fill_and_line_cover_what_they_say() {
        let mut img = RgbImage::from_pixel(10, 10, PAPER);
        fill(&mut img, 8, 8, 5, 5, INK);
        assert_eq!(inked(&img), vec![(8, 8), (9, 8), (8, 9), (9, 9)]);
        let mut img = RgbImage::from_pixel(10, 10, PAPER);
        line(&mut img, (0, 0), (9, 0), INK);
        assert_eq!(inked(&img).len(), 20, "two rows of ten");
        line(&mut img, (-5, -5), (20, 20), INK);
        assert!(img.get_pixel(5, 5) == &INK);
    }
}
