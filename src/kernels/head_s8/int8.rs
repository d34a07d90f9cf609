//! The head's int8 line with Helium (`mve`): the optimised head kernel with the gathered
//! inputs raw, one byte per entry, and `input_offset · Σ w` folded into each ray's bias (as
//! `kernels::line`'s `conv_s8` folds it), so that `bias' + Σ w·x` is exactly the i16
//! gather's `bias + Σ w·(x + input_offset)` (modulo 2^32, like every accumulator). A plane
//! or column outside the input holds the input's zero point `−input_offset`, which adds
//! nothing. `arch::PairRowsS8` takes 16 MACs per `VMLADAVA.S8` where the i16 gather's
//! `VMLAVA.S16` takes 8, and `arch::gather_bytes` gathers a column's entries in one call.
//!
//! Layout of [`super::HeadWeights`] (words): the folded biases `[block][ray of the pair]`,
//! then each block's `arch::PairRowsS8` weights (16-byte runs of entries, the pair's first
//! ray then its second), block `b = (r·pairs + p)·kh + ky` for rotation `r`, ray pair `p`
//! and range tap `ky`. Entry `e = (s·P + j)·C + c` of a range row: column slot `s`, plane
//! tap `j`, channel `c` (slot `s` holds column tap `(r − s) mod Q`, as in the i16 layout).

use super::{row_of, Fast, LogitRequant, Planes, HEAD_COL_WORDS, HEAD_W_WORDS, MAX_FAST_ROWS};
use crate::arch::{PairRowsS8, GATHER_ENTRIES};
use crate::kernels::soft_argmax_s8::{ray_depth_max, SoftArgmaxParams, MAX_BINS};
use crate::kernels::{ConvParams, ConvShape};
use fixed::types::U16F16;

/// The int8 line of a head whose shape and offset suit it.
#[derive(Clone, Copy)]
pub(super) struct Line {
    /// Bytes of one range row: `Q · P · C`.
    nb: usize,
    plan: PairRowsS8,
    /// The input's zero point: the padding entries.
    pad: i8,
    /// Weight blocks `Q · pairs · kh`.
    blocks: usize,
}

/// Lays out the int8 line's weights and folded biases in `wbuf` and returns the line, or
/// `None` (nothing laid out) where the shape, the offset or the buffers do not suit it.
pub(super) fn prepare(
    shape: &ConvShape,
    f: &Fast,
    params: &ConvParams<'_>,
    wbuf: &mut [u32; HEAD_W_WORDS],
) -> Option<Line> {
    let [_, ih, iw] = shape.in_size;
    let [kd, kh, kw] = shape.kernel;
    let [sd, _, sw] = shape.stride;
    let ic = shape.in_channels;
    let nb = f.cols.checked_mul(f.planes)?.checked_mul(ic)?;
    let pad = i8::try_from(params.input_offset.checked_neg()?).ok()?;
    let blocks = f.cols.checked_mul(f.pairs)?.checked_mul(kh)?;
    let plan = PairRowsS8::new(nb, nb, ih / 2)?;
    let wpair = plan.pair_bytes();
    let fits = ih.is_multiple_of(2)
        && ih <= MAX_FAST_ROWS
        && f.planes
            .checked_mul(ic)
            .is_some_and(|e| e <= GATHER_ENTRIES)
        && ih.checked_mul(nb).is_some_and(|b| b <= 4 * HEAD_COL_WORDS)
        && iw.checked_mul(7).is_some_and(|s| s <= u16::MAX as usize)
        && nb.checked_mul(7).is_some_and(|s| s <= u16::MAX as usize)
        && blocks
            .checked_mul(wpair)
            .and_then(|w| w.checked_add(8 * blocks))
            .is_some_and(|b| b <= 4 * HEAD_W_WORDS);
    if !fits {
        return None;
    }
    let (bias_words, rest) = wbuf.split_at_mut(2 * blocks);
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(rest);
    bytes.fill(0);
    let taps = kd * kh * kw;
    for r in 0..f.cols {
        for p in 0..f.pairs {
            for ky in 0..kh {
                let b = (r * f.pairs + p) * kh + ky;
                for half in 0..2 {
                    // An odd last ray is paired with itself, as in the i16 layout.
                    let ray = (2 * p + half).min(f.rays - 1);
                    let (psi, phi) = (ray / sw, ray % sw);
                    let mut sum = 0i32;
                    for s in 0..f.cols {
                        let kx = phi + sw * ((r + f.cols - s) % f.cols);
                        for j in 0..f.planes {
                            let kz = psi + sd * j;
                            for c in 0..ic {
                                let w = if kz < kd && kx < kw {
                                    params.weights[c * taps + (kz * kh + ky) * kw + kx]
                                } else {
                                    0
                                };
                                sum = sum.wrapping_add(w as i32);
                                let e = (s * f.planes + j) * ic + c;
                                let at = b * wpair + (e / 16) * 32 + half * 16 + e % 16;
                                if let Some(x) = bytes.get_mut(at) {
                                    *x = w as u8;
                                }
                            }
                        }
                    }
                    let folded = params.bias[0].wrapping_add(params.input_offset.wrapping_mul(sum));
                    if let Some(x) = bias_words.get_mut(2 * b + half) {
                        *x = folded as u32;
                    }
                }
            }
        }
    }
    Some(Line {
        nb,
        plan,
        pad,
        blocks,
    })
}

/// Gathers input column `x` (if inside `0..W`, else the zero point) of every plane tap and
/// channel into slot `s` of the range rows' bytes.
#[inline(always)]
fn gather_column(
    shape: &ConvShape,
    f: &Fast,
    line: &Line,
    src: &Planes<'_>,
    x: Option<usize>,
    s: usize,
    col: &mut [u8],
) {
    let [_, ih, iw] = shape.in_size;
    let ic = shape.in_channels;
    let mut at = [usize::MAX; GATHER_ENTRIES];
    for j in 0..f.planes {
        if let (Some(x), Some(poff)) = (x, src.at(j)) {
            for c in 0..ic {
                if let Some(a) = at.get_mut(j * ic + c) {
                    *a = c * src.channel + poff + x;
                }
            }
        }
    }
    let dst = col.get_mut(s * f.planes * ic..).unwrap_or(&mut []);
    let entries = at.get(..f.planes * ic).unwrap_or(&[]);
    crate::arch::gather_bytes(dst, (line.nb, ih), (src.data, entries), iw, line.pad);
}

/// One step on the int8 line (validated shape, [`prepare`] laid out `wbuf`): the i16
/// kernel's `step_fast` with the int8 gather and dot products.
#[allow(clippy::too_many_arguments)]
pub(super) fn step<R: LogitRequant>(
    shape: &ConvShape,
    f: &Fast,
    line: &Line,
    src: &Planes<'_>,
    params: &ConvParams<'_>,
    rq: R,
    wbuf: &[u32; HEAD_W_WORDS],
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) {
    let [_, ih, iw] = shape.in_size;
    let kh = shape.kernel[1];
    let [sd, _, sw] = shape.stride;
    let pw = shape.padding[2];
    let [_, bins, columns] = shape.out_size;
    let t = src.t;
    if (0..sd).all(|psi| row_of(shape, t, psi).is_none()) {
        return;
    }
    let (bias_words, rest) = wbuf.split_at(2 * line.blocks);
    let biases: &[[i32; 2]] = bytemuck::cast_slice(bias_words);
    let weights: &[u8] = bytemuck::cast_slice(rest);
    let wpair = line.plan.pair_bytes();
    // Column positions g with a column a = sw·g − pw + φ inside 0..A.
    let g_lo = pw / sw;
    let g_hi = (columns - 1 + pw) / sw;
    let mut words = [0u32; HEAD_COL_WORDS];
    let col: &mut [u8] = bytemuck::cast_slice_mut(&mut words[..]);
    let mut logits = [[0i8; MAX_BINS]; 2];
    // The pair's two rays' accumulator rows, one after the other.
    let mut acc = [0i32; 2 * MAX_FAST_ROWS];
    let inside = |x: usize| (x < iw).then_some(x);
    for j in 0..f.cols {
        // Columns g_lo − j, in slot (g_lo − j) mod Q.
        let x = g_lo.checked_sub(j).and_then(inside);
        let s = (g_lo % f.cols + f.cols - j) % f.cols;
        gather_column(shape, f, line, src, x, s, col);
    }
    for g in g_lo..=g_hi {
        if g > g_lo {
            gather_column(shape, f, line, src, inside(g), g % f.cols, col);
        }
        let r = g % f.cols;
        for p in 0..f.pairs {
            // Depth index of each ray of the pair, if inside the map.
            let target = |half: usize| {
                let ray = 2 * p + half;
                if ray >= f.rays {
                    return None;
                }
                let e = row_of(shape, t, ray / sw)?;
                let a = (sw * g + ray % sw).checked_sub(pw)?;
                (a < columns).then_some(e * columns + a)
            };
            let targets = [target(0), target(1)];
            if targets == [None, None] {
                continue;
            }
            let mut max = [i8::MIN; 2];
            for ky in 0..kh {
                let b = (r * f.pairs + p) * kh + ky;
                let w = weights.get(b * wpair..).unwrap_or(&[]);
                let bias = biases.get(b..b + 1).unwrap_or(&[]);
                // Both rays' accumulators over the range rows in one call ([`prepare`]
                // checked the slices), then each ray's logits.
                let short = bias.first().is_some_and(|&b| {
                    line.plan
                        .run_pair_short(col, w, b, (&mut acc, MAX_FAST_ROWS))
                });
                if !short {
                    line.plan
                        .run_channels(col, (w, wpair), bias, &mut acc, (MAX_FAST_ROWS, 0));
                }
                for half in 0..2 {
                    let a = acc.get(half * MAX_FAST_ROWS..).unwrap_or(&[]);
                    max[half] = rq.logits(
                        a.get(..ih).unwrap_or(&[]),
                        params.relu,
                        &mut logits[half][..bins],
                        (ky, kh),
                        max[half],
                    );
                }
            }
            for (half, at) in targets.iter().enumerate() {
                if let Some(at) = *at {
                    depth[at] = ray_depth_max(&logits[half][..bins], max[half], soft);
                }
            }
        }
    }
}
