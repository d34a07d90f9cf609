//! The int8 line engine of the forward convolutions with Helium (`mve`): the raw inputs on
//! the line, the input offset folded into the biases, 16 MACs per `VMLADAV.S8`.

use super::*;

/// The forward line engine of a Helium build (the other builds' is `conv`), on an int8 line,
/// for the shapes it takes (false, nothing written, for the others, which the caller's im2col
/// engine runs): the line holds the raw inputs, entry `v = (tap,
/// channel)` of column `c` at byte `c·vp + v` (`arch::fill_bytes`), padding entries hold the
/// input's zero point `−input_offset`, and `input_offset · Σ w` is folded into each
/// channel's bias, so that `bias + Σ w·x` over the line is exactly the i16 line's `bias +
/// Σ w·(x + input_offset)` (padding adding nothing in both; modulo 2^32 like every
/// accumulator). The dot products take 16 int8 MACs per instruction (`arch::PairRowsS8`)
/// where the i16 line takes 8. Its shapes: an even output width whose accumulator rows all
/// fit (one call per line), one weight group, at most [`MAX_ROW_TAPS`] taps per channel, an
/// offset whose zero point is an int8, the fast requantisation's words.
#[cfg(all(feature = "mve", target_arch = "arm"))]
#[inline(never)]
pub(super) fn conv_s8<R: Apply>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    layer: Option<usize>,
    rq: &[R],
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> bool {
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let sw = shape.stride[2];
    let (pw, iw) = (shape.padding[2], shape.in_size[2]);
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let per_channel = kd * kh;
    let (vp, cols) = (conv_v(shape), conv_cols(shape));
    let (lo, hi) = (pw.min(cols), (iw + pw).min(cols));
    let len = hi.saturating_sub(lo).min(MAX_ROW);
    let in0 = lo.saturating_sub(pw);
    let n = kw * vp;
    let pairs = oc.div_ceil(2);
    let table = row_words(rq);
    let words = table
        .as_ref()
        .and_then(|t| crate::arch::RowWords::new(t.get(..oc)?));
    let (Ok(pad), Some(plan), Some(words)) = (
        i8::try_from(-params.input_offset),
        crate::arch::PairRowsS8::new(sw * vp, n, ow / 2),
        words,
    ) else {
        return false;
    };
    let wpair = plan.pair_bytes();
    // The kept slot: the channel pairs' folded biases, then their weight blocks.
    let slot_words = 2 * pairs + pairs * wpair / 4;
    if !ow.is_multiple_of(2)
        || len == 0
        || per_channel > MAX_ROW_TAPS
        || vp > MAX_V
        || oc > MAX_FAST_CHANNELS
        || params.bias.len() < oc
        || slot_words > WEIGHT_WORDS
        || vp * cols > 4 * LINE_WORDS
        || 2 * pairs * ow > 2 * (MAX_POSITIONS + 1)
    {
        return false;
    }
    let key = layer.map(|l| (l, shape.stride));
    let slot = scratch.kept.claim(key, slot_words, 1, 1);
    let base = scratch.kept.base(slot);
    let laid_out = scratch.kept.laid_out(slot, 1);
    let LineScratch {
        wbuf, line, acc, ..
    } = scratch;
    let Some(kept) = wbuf.get_mut(base..base + slot_words) else {
        return false;
    };
    let (bias_words, weight_words) = kept.split_at_mut(2 * pairs);
    if !laid_out {
        lay_out_s8(shape, params, (n, vp, wpair), bias_words, weight_words);
    }
    let biases: &[[i32; 2]] = bytemuck::cast_slice(&*bias_words);
    let weights: &[u8] = bytemuck::cast_slice(&*weight_words);
    let line: &mut [u8] = bytemuck::cast_slice_mut(&mut line[..]);
    let pad_row = [pad; MAX_ROW];
    let out_plane = od * oh * ow;
    for z in 0..od {
        for y in 0..oh {
            if z == 0 && y == 0 {
                // The padding columns, once per call: no fill writes there.
                let right = line.get_mut((lo + len) * vp..cols * vp).unwrap_or(&mut []);
                right.fill(pad as u8);
                line.get_mut(..lo * vp).unwrap_or(&mut []).fill(pad as u8);
            }
            let taps = LineTaps::forward(shape, z, y);
            let at = channel0_rows(taps, per_channel, in0);
            let filled = line.get_mut(lo * vp..).is_some_and(|dst| {
                let rows = (input, &at[..per_channel]);
                crate::arch::fill_bytes(dst, vp, len, rows, (ic, taps.cs), &pad_row)
            });
            if !(filled && plan.run_channels(line, (weights, wpair), biases, acc, (ow, 0))) {
                return true;
            }
            let at = ((z * oh + y) * ow, out_plane);
            requant_rows(
                acc,
                (ow, oc),
                rq,
                words,
                params.relu,
                SkipLut::None,
                output,
                at,
            );
        }
    }
    true
}

/// [`conv_s8`]'s weights and folded biases: channel pair `k`'s bytes from `k · wpair`,
/// 16-byte blocks of the window's entries `e = kx·vp + v` (`v = (tap, channel)`), the pair's
/// first channel's block then its second's, zero past the window and for an odd count's
/// missing channel; bias `b + input_offset · Σ w`, wrapping as the accumulators do.
#[cfg(all(feature = "mve", target_arch = "arm"))]
fn lay_out_s8(
    shape: &ConvShape,
    params: &ConvParams<'_>,
    (n, vp, wpair): (usize, usize, usize),
    bias_words: &mut [u32],
    weight_words: &mut [u32],
) {
    let [kd, kh, kw] = shape.kernel;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let per_channel = kd * kh;
    let v_len = ic * per_channel;
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(weight_words);
    bytes.fill(0);
    for o in 0..oc {
        let mut sum = 0i32;
        for e in 0..n {
            let (kx, v) = (e / vp, e % vp);
            if v >= v_len {
                continue;
            }
            let tap_major = v % ic * per_channel + v / ic;
            let w = params.weights[(o * v_len + tap_major) * kw + kx];
            sum += w as i32;
            let at = (o / 2) * wpair + (e / 16) * 32 + (o % 2) * 16 + e % 16;
            if let Some(b) = bytes.get_mut(at) {
                *b = w as u8;
            }
        }
        let folded = params.bias[o].wrapping_add(params.input_offset.wrapping_mul(sum));
        if let Some(b) = bias_words.get_mut(o) {
            *b = folded as u32;
        }
        // An odd count's last pair: its second channel repeats the first's bias (its row is
        // computed, never requantised).
        if o % 2 == 0 && o + 1 == oc {
            if let Some(b) = bias_words.get_mut(o + 1) {
                *b = folded as u32;
            }
        }
    }
}
