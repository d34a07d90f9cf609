//! The i16 line engine of the forward convolutions (every build but Helium's; the Helium
//! build's is `s8_line`): 2 channels × 2 positions per inner loop over a line of i16
//! pairs, and the i16 weight-pair layout the transposed phases share.

// The Helium build keeps only the weight-pair layout here, which needs nothing from the parent.
#[cfg_attr(all(feature = "mve", target_arch = "arm"), allow(unused_imports))]
use super::*;

/// One row of outputs for all channels: 2 channels × 2 positions per inner loop
/// ([`crate::arch::dot2x2`]) into a row of accumulators per channel, then each channel's row
/// requantised and stored ([`requant_row`]). `weights` holds, per channel pair, the two
/// channels' words interleaved (`rin.words` words per channel; an odd last channel is paired
/// with itself).
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn row<R: Apply>(
    line: &[u32],
    rin: RowIn,
    weights: &[u32],
    bias: &[i32],
    rq: &[R],
    relu: bool,
    skip: SkipLut<'_>,
    out: &mut [i8],
    rout: RowOut,
    acc: &mut RowAcc,
    (words, biases): (Option<crate::arch::RowWords<'_>>, &[[i32; 2]]),
) {
    let (n, positions) = (rin.words, rin.positions);
    let oc = bias.len().min(rq.len());
    let rows = AccRows::new(oc, positions, words.is_some(), rout.step, skip);
    // A row per channel: every channel pair's dot products in one call, then every row's
    // requantisation in one.
    if let (true, Some(words)) = (rows.flat, words) {
        let lines = (positions, oc);
        let at = (rout.base, rout.plane);
        let all = (weights, 2 * n);
        let pairs = biases.get(..oc.div_ceil(2)).unwrap_or(&[]);
        if rin.plan.run_channels(line, all, pairs, acc, (positions, 0)) {
            requant_rows(acc, lines, rq, words, relu, skip, out, at);
        }
        return;
    }
    let mut o = 0;
    while o < oc {
        let two = o + 1 < oc;
        let Some(w) = weights.get(o * n..(o + 2) * n) else {
            break;
        };
        let b = biases.get(o / 2).copied().unwrap_or([0, 0]);
        let (acc0, acc1) = rows.pair(acc, o);
        if !rin.plan.run(line, w, b, (&mut *acc0, &mut *acc1)) {
            break;
        }
        let at = |o: usize| o * rout.plane + rout.base;
        requant_row(&acc0[..positions], rq[o], relu, skip, out, at(o), rout.step);
        if two {
            requant_row(
                &acc1[..positions],
                rq[o + 1],
                relu,
                skip,
                out,
                at(o + 1),
                rout.step,
            );
        }
        o += 2;
    }
}

/// Two i16 weights as one word, `a` in the low half.
#[inline(always)]
pub(super) fn word(a: i8, b: i8) -> u32 {
    crate::arch::pack(a as i16, b as i16)
}

/// Index of word `k` of channel `o` in the pair-interleaved weight buffer (`n` words per
/// channel).
#[inline(always)]
pub(super) fn wslot(o: usize, k: usize, n: usize) -> usize {
    (o / 2) * 2 * n + 2 * k + o % 2
}

/// Pads an odd channel count's last pair by copying the last channel's words.
pub(super) fn pad_pairs(wbuf: &mut [u32], oc: usize, n: usize) {
    if oc % 2 == 1 {
        for k in 0..n {
            wbuf[wslot(oc, k, n)] = wbuf[wslot(oc - 1, k, n)];
        }
    }
}

/// Forward convolution (validated shape that [`conv_fits`]), requantising with `rq`.
/// Output channels go in groups whose expanded weights fit [`WEIGHT_WORDS`] (one group for
/// most layers; each further group refills the lines). `layer`: the model's index of the
/// layer, under which its laid-out weights may be kept when they form one group
/// ([`LineScratch::keep_weights`]); `None` lays them out at every call. Not in a Helium
/// build, whose forward line engine is [`conv_s8`].
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
pub(crate) fn conv<R: Apply>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    layer: Option<usize>,
    rq: &[R],
    output: &mut [i8],
    scratch: &mut LineScratch,
) {
    let [_, _, iw] = shape.in_size;
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let [_, _, sw] = shape.stride;
    let [_, _, pw] = shape.padding;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let v_len = ic * kd * kh;
    let vp = up4(v_len);
    let cols = (ow - 1) * sw + kw;
    // Line column c reads input column c − pw.
    let (lo, hi) = (pw.min(cols), (iw + pw).min(cols));
    let span = (lo, hi, lo.saturating_sub(pw));
    let off = params.input_offset as i16;
    let n = kw * vp / 2;
    let group = conv_group(n);
    // Line entry v is (i, kz, ky), or (kz, ky, i) where the line goes channel-minor.
    let minor = channel_minor(ic, kd * kh);
    let wv = |o: usize, kx: usize, v: usize| {
        if v >= v_len {
            return 0;
        }
        let v = if minor {
            v % ic * (kd * kh) + v / ic
        } else {
            v
        };
        params.weights[(o * v_len + v) * kw + kx]
    };
    // One group's weights may be kept; more groups take turns in the buffer.
    let key = layer.filter(|_| group >= oc).map(|l| (l, shape.stride));
    let slot = scratch.kept.claim(key, oc.div_ceil(2) * 2 * n, 1, 1);
    let base = scratch.kept.base(slot);
    let laid_out = scratch.kept.laid_out(slot, 1);
    let LineScratch {
        wbuf, line, acc, ..
    } = scratch;
    let out_plane = od * oh * ow;
    let rin = RowIn::new(ow, sw * vp / 2, n);
    let table = row_words(rq);
    let words = table
        .as_ref()
        .and_then(|t| crate::arch::RowWords::new(t.get(..oc)?));
    let mut o0 = 0;
    while o0 < oc {
        let g = group.min(oc - o0);
        let wb = &mut wbuf[base..base + g.div_ceil(2) * 2 * n];
        if !laid_out {
            // Weights [o][kx][v] (v = (i, kz, ky)) as i16 pairs, zero for the padding entries.
            for o in 0..g {
                for kx in 0..kw {
                    for j in 0..vp / 2 {
                        let k = kx * vp / 2 + j;
                        wb[wslot(o, k, n)] = word(wv(o0 + o, kx, 2 * j), wv(o0 + o, kx, 2 * j + 1));
                    }
                }
            }
            pad_pairs(wb, g, n);
        }
        // The group's channel pairs' biases, for every row of the layer.
        let biases = bias_pairs(params.bias.get(o0..o0 + g).unwrap_or(&[]));
        for z in 0..od {
            for y in 0..oh {
                // Lines after the call's first keep its zero padding columns.
                #[cfg(all(feature = "dsp", target_arch = "arm"))]
                fill_taps(
                    line,
                    (vp, cols, o0 > 0 || z > 0 || y > 0),
                    span,
                    input,
                    off,
                    LineTaps::forward(shape, z, y),
                );
                #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
                fill_forward(line, (vp, cols), span, input, off, shape, (z, y));
                row(
                    line,
                    rin,
                    wb,
                    &params.bias[o0..o0 + g],
                    &rq[o0..o0 + g],
                    params.relu,
                    SkipLut::None,
                    output,
                    RowOut {
                        plane: out_plane,
                        base: o0 * out_plane + (z * oh + y) * ow,
                        step: 1,
                    },
                    acc,
                    (words.and_then(|w| w.get(o0..o0 + g)), &biases),
                );
            }
        }
        o0 += g;
    }
}
