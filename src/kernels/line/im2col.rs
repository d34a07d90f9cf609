//! The im2col engine: the forward convolutions' path for layers the line engine does not
//! take ([`conv_fits`]) but whose taps of one output fit [`COL_LEN`].

use super::*;

/// Most taps per output the im2col path gathers (two i16 columns and their packed copy:
/// 4 KiB of stack).
pub const COL_LEN: usize = 512;

/// Fills `col[..K]` with the offset inputs of output position `(z, y, x)`, 0 at padding.
#[inline(always)]
pub(super) fn gather(
    shape: &ConvShape,
    input: &[i8],
    off: i16,
    (z, y, x): (usize, usize, usize),
    col: &mut [i16],
) {
    let [id, ih, iw] = shape.in_size;
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [pd, ph, pw] = shape.padding;
    let (kz_lo, kz_hi) = tap_range(z, sd, pd, kd, id);
    let (ky_lo, ky_hi) = tap_range(y, sh, ph, kh, ih);
    let (kx_lo, kx_hi) = tap_range(x, sw, pw, kw, iw);
    let interior =
        kz_lo == 0 && ky_lo == 0 && kx_lo == 0 && kz_hi == kd && ky_hi == kh && kx_hi == kw;
    if !interior {
        col.fill(0);
    }
    if kx_lo >= kx_hi {
        return;
    }
    let len = kx_hi - kx_lo;
    let ix0 = x * sw + kx_lo - pw;
    for i in 0..shape.in_channels {
        for kz in kz_lo..kz_hi {
            let iz = z * sd + kz - pd;
            for ky in ky_lo..ky_hi {
                let iy = y * sh + ky - ph;
                let src = &input[((i * id + iz) * ih + iy) * iw + ix0..][..len];
                let dst = &mut col[((i * kd + kz) * kh + ky) * kw + kx_lo..][..len];
                for (d, &s) in dst.iter_mut().zip(src) {
                    *d = s as i16 + off;
                }
            }
        }
    }
}

/// `acc[n] += Σ_t col[t] · ws[n][t]` (all slices of equal length): one position.
#[inline(always)]
pub(super) fn dot<const N: usize>(col: &[i16], ws: [&[i8]; N], mut acc: [i32; N]) -> [i32; N] {
    for (a, w) in acc.iter_mut().zip(ws) {
        for (&c, &w) in col.iter().zip(w) {
            *a += c as i32 * w as i32;
        }
    }
    acc
}

/// The gathered columns of two output positions (`k ≤ COL_LEN` taps each), laid out for
/// the build's dot product.
///
/// Portable build: one word per tap holding both positions' values (`lo` = position 0), so
/// one word load and one weight load feed two MACs (SMLABB/SMLATB on Cortex-M7; two
/// accumulators leave LLVM's 4× unroll enough registers).
///
/// `dsp` build (CMSIS-NN style): per position and per group of 4 taps the words
/// `(c0, c2)` and `(c1, c3)`, matching `SXTB16` / `SXTB16 ROR 8` of 4 weight bytes, so
/// one weight word and two `SMLAD` give 4 MACs of one position; the last `k mod 4` taps
/// stay scalar.
pub(crate) struct PairColumns {
    k: usize,
    #[cfg(not(feature = "dsp"))]
    words: [u32; COL_LEN],
    #[cfg(feature = "dsp")]
    pairs: [[u32; COL_LEN / 2]; 2],
    #[cfg(feature = "dsp")]
    tail: [[i16; 4]; 2],
}

impl PairColumns {
    pub(crate) fn new() -> Self {
        PairColumns {
            k: 0,
            #[cfg(not(feature = "dsp"))]
            words: [0; COL_LEN],
            #[cfg(feature = "dsp")]
            pairs: [[0; COL_LEN / 2]; 2],
            #[cfg(feature = "dsp")]
            tail: [[0; 4]; 2],
        }
    }

    /// Packs the columns `c0`, `c1` (equal lengths, at most [`COL_LEN`]).
    #[inline(always)]
    pub(crate) fn pack(&mut self, c0: &[i16], c1: &[i16]) {
        self.k = c0.len().min(c1.len()).min(COL_LEN);
        #[cfg(not(feature = "dsp"))]
        for ((w, &a), &b) in self.words[..self.k].iter_mut().zip(c0).zip(c1) {
            *w = crate::arch::pack(a, b);
        }
        #[cfg(feature = "dsp")]
        for (p, c) in [c0, c1].into_iter().enumerate() {
            let groups = self.k / 4;
            let (head, tail) = c[..self.k].split_at(groups * 4);
            for (g, w) in head.chunks_exact(4).zip(self.pairs[p].chunks_exact_mut(2)) {
                w[0] = crate::arch::pack(g[0], g[2]);
                w[1] = crate::arch::pack(g[1], g[3]);
            }
            self.tail[p] = [0; 4];
            self.tail[p][..tail.len()].copy_from_slice(tail);
        }
    }

    /// `acc[p] += Σ_t column_p[t] · w[t]` for the two positions (`w` has `k` weights).
    #[inline(always)]
    pub(crate) fn dot(&self, w: &[i8], acc: [i32; 2]) -> [i32; 2] {
        let [mut a0, mut a1] = acc;
        #[cfg(not(feature = "dsp"))]
        for (&c, &w) in self.words[..self.k].iter().zip(w) {
            let w = w as i32;
            a0 += (c as u16 as i16 as i32) * w;
            a1 += ((c as i32) >> 16) * w;
        }
        #[cfg(feature = "dsp")]
        {
            use crate::arch::{smlad, sxtb16, sxtb16_ror8};
            let groups = self.k / 4;
            let (wg, wt) = w[..self.k.min(w.len())].split_at(groups * 4);
            let (p0, p1) = (&self.pairs[0][..2 * groups], &self.pairs[1][..2 * groups]);
            for ((w4, x0), x1) in wg
                .chunks_exact(4)
                .zip(p0.chunks_exact(2))
                .zip(p1.chunks_exact(2))
            {
                let word = u32::from_le_bytes([w4[0] as u8, w4[1] as u8, w4[2] as u8, w4[3] as u8]);
                let (even, odd) = (sxtb16(word), sxtb16_ror8(word));
                a0 = smlad(x0[1], odd, smlad(x0[0], even, a0));
                a1 = smlad(x1[1], odd, smlad(x1[0], even, a1));
            }
            for ((&w, &t0), &t1) in wt.iter().zip(&self.tail[0]).zip(&self.tail[1]) {
                a0 += t0 as i32 * w as i32;
                a1 += t1 as i32 * w as i32;
            }
        }
        [a0, a1]
    }
}

/// Convolution of a validated shape whose taps per output fit [`COL_LEN`], two output
/// positions at a time (an odd last position alone, two channels at a time).
pub(crate) fn im2col_engine(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
) {
    let [_, oh, ow] = shape.out_size;
    let k = shape.in_channels * shape.kernel.iter().product::<usize>();
    let positions = shape.out_size.iter().product::<usize>();
    let oc = shape.out_channels;
    // |offset| ≤ 255 is validated, so offset inputs fit i16.
    let off = params.input_offset as i16;
    let mut col0 = [0i16; COL_LEN];
    let mut col1 = [0i16; COL_LEN];
    let mut packed = PairColumns::new();
    let at = |p: usize| (p / (oh * ow), (p / ow) % oh, p % ow);
    let mut p = 0;
    while p < positions {
        let pair = p + 1 < positions;
        gather(shape, input, off, at(p), &mut col0[..k]);
        if pair {
            gather(shape, input, off, at(p + 1), &mut col1[..k]);
        }
        let (c0, c1) = (&col0[..k], &col1[..k]);
        if pair {
            packed.pack(c0, c1);
            let out_pos = &mut output[p..];
            for o in 0..oc {
                let w = &params.weights[o * k..(o + 1) * k];
                let b = params.bias[o];
                let acc = packed.dot(w, [b, b]);
                for (q, &a) in acc.iter().enumerate() {
                    let t = params.requant[o].apply(a);
                    out_pos[o * positions + q] = finish(t, params.relu, None);
                }
            }
        } else {
            // The last, unpaired position: two channels at a time.
            let mut o = 0;
            while o < oc {
                let n = if o + 1 < oc { 2 } else { 1 };
                let w0 = &params.weights[o * k..(o + 1) * k];
                let acc = if n == 2 {
                    let w1 = &params.weights[(o + 1) * k..(o + 2) * k];
                    dot::<2>(c0, [w0, w1], [params.bias[o], params.bias[o + 1]])
                } else {
                    [dot::<1>(c0, [w0], [params.bias[o]])[0], 0]
                };
                for (m, &a) in acc.iter().enumerate().take(n) {
                    let t = params.requant[o + m].apply(a);
                    output[(o + m) * positions + p] = finish(t, params.relu, None);
                }
                o += n;
            }
        }
        p += if pair { 2 } else { 1 };
    }
}
