//! Fixed-point soft-argmax along range (QUANTISATION.md "Soft-argmax"), and the fused
//! streaming head + soft-argmax.
//!
//! Logits `[E][R][A]` int8 (elevation rows, range bins, azimuth columns; the head's output
//! with its single channel dropped). Per ray: `m = max q_i`, `e_i = EXP[m − q_i]`,
//! `S = Σ e_i`, `T = Σ e_i·j_i` with the bin index `j_i = i + K` except `j_0 = 0` and
//! `j_{R−1} = R − 1 + 2K` (the end bins reach `K = end_offset` steps beyond the window),
//! `b16 = (T·2^16 + S/2) / S`, `d16 = r_min16 + (b16·step16 + 2^15) >> 16` clamped to
//! `[r_min16 + K·step16, r_min16 + (R − 1 + K)·step16]` → depth `[E][A]` as [`U16F16`] metres.
//! With `K = 0` this is the plain soft-argmax and the clamp never acts.
//!
//! The no-return decision comes first: with `τ16 > 0`, a ray with `e_{R−1}·2^16 ≥ τ16·S` met
//! nothing and reads exactly the window's top `r_min16 + (R − 1 + K)·step16`; else one with
//! `e_0·2^16 ≥ τ16·S` met a surface nearer than the window and reads exactly its bottom
//! `r_min16 + K·step16`. The depth code is the mask: no bit travels beside it.
//!
//! Work: `E · A · R` table look-ups and `E · A · R` multiplies, one u64 division per ray.

use super::{check_conv_transpose, finish, mul3, ConvParams, ConvShape, KernelError, Operand};
use crate::requant::{Apply, FastRequant};
use fixed::types::U16F16;

/// Sizes of the logits volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SoftArgmaxShape {
    /// Elevation rows E.
    pub rows: usize,
    /// Range bins R (soft-argmax axis), at most [`MAX_BINS`].
    pub bins: usize,
    /// Azimuth columns A.
    pub columns: usize,
}

/// Most range bins: keeps `T = Σ e_i·i` within u32 as the contract requires.
pub const MAX_BINS: usize = 256;

/// The exp table and the depth of the bins.
#[derive(Clone, Copy, Debug)]
pub struct SoftArgmaxParams<'a> {
    /// `EXP[d] = round_half_away(65535 · exp(−d · s_l))`.
    pub exp: &'a [u16; 256],
    /// `round((r_min − K·step) · 2^16)`: depth of bin index 0.
    pub r_min16: U16F16,
    /// `round((r_max − r_min) / (bins − 1) · 2^16)`: depth step between bins.
    pub step16: U16F16,
    /// `K`: steps by which the first and last bins reach beyond the window (the spec's
    /// `end_bin_offset`; at most [`MAX_END_OFFSET`]).
    pub end_offset: u16,
    /// `τ16 = round(τ · 2^16)`: the end-bin mass at which a ray is decided to have met nothing
    /// inside the window (the spec's `no_return_mass`; at most `2^16`, 0 decides nothing).
    pub no_return16: u32,
}

/// Largest [`SoftArgmaxParams::end_offset`].
pub const MAX_END_OFFSET: u16 = 256;

/// Largest [`SoftArgmaxParams::no_return16`]: the whole mass.
pub const MAX_NO_RETURN16: u32 = 1 << 16;

pub(super) fn check_params(p: &SoftArgmaxParams<'_>, bins: usize) -> Result<(), KernelError> {
    if bins == 0 || bins > MAX_BINS {
        return Err(KernelError::RangeBins { bins });
    }
    if p.exp[0] == 0 {
        return Err(KernelError::ExpTable);
    }
    if p.end_offset > MAX_END_OFFSET {
        return Err(KernelError::EndOffset {
            offset: p.end_offset,
        });
    }
    if p.no_return16 > MAX_NO_RETURN16 {
        return Err(KernelError::NoReturnMass {
            mass16: p.no_return16,
        });
    }
    // b16 ≤ (bins − 1 + 2K)·2^16, so this is the largest depth any ray can produce.
    let max_b16 = ((bins - 1 + 2 * p.end_offset as usize) as u64) << 16;
    let top =
        p.r_min16.to_bits() as u64 + ((max_b16 * p.step16.to_bits() as u64 + (1 << 15)) >> 16);
    if top > u32::MAX as u64 {
        return Err(KernelError::DepthOverflow);
    }
    Ok(())
}

/// `⌊(t·2^16 + ⌊s/2⌋) / s⌋` for `0 < s < 2^24` in 32-bit divisions (Cortex-M `UDIV`; the u64
/// division is a library call of about 100 instructions): the quotient, then the remainder
/// long-divided a byte at a time (`r < s < 2^24`, so `r·2^8` fits), then the rounding half.
#[inline(always)]
fn round_div16(t: u32, s: u32) -> u64 {
    let (q, r) = (t / s, t % s);
    let a = r << 8;
    let (d1, r1) = (a / s, a % s);
    let b = r1 << 8;
    let (d2, r2) = (b / s, b % s);
    // r2 + ⌊s/2⌋ < 2s: the half adds at most one.
    let carry = u64::from(r2 as u64 + (s / 2) as u64 >= s as u64);
    ((q as u64) << 16) + ((d1 as u64) << 8) + d2 as u64 + carry
}

/// `S`, `T = Σ e_i·i`, the end weights `e_0`, `e_{R−1}` and `R` → depth (the contract's
/// integer formula, end bins moved out by `K` and the result clamped to the window).
#[inline(always)]
pub(super) fn depth_of(
    s: u32,
    t: u32,
    first: u32,
    last: u32,
    bins: usize,
    p: &SoftArgmaxParams<'_>,
) -> U16F16 {
    // S ≥ EXP[0] > 0 (checked), so the division is defined; first ≤ S, and every term
    // stays far inside u64 (T < 2^32, K ≤ 256, S < 2^24).
    let s64 = s as u64;
    let k = p.end_offset as u64;
    let step = p.step16.to_bits() as u64;
    let base = p.r_min16.to_bits() as u64;
    let lo = base + k * step;
    let hi = base + (bins as u64 - 1 + k) * step;
    if p.no_return16 != 0 {
        // e ≤ S < 2^24 and τ16 ≤ 2^16: both sides fit u64 (one UMULL on Cortex-M).
        let tau = p.no_return16 as u64 * s64;
        if (last as u64) << 16 >= tau {
            return U16F16::from_bits(hi as u32);
        }
        if (first as u64) << 16 >= tau {
            return U16F16::from_bits(lo as u32);
        }
    }
    let t = t as u64 + k * (s64 - first as u64 + last as u64);
    let b16 = match u32::try_from(t) {
        Ok(t) if s < 1 << 24 => round_div16(t, s.max(1)),
        _ => (t << 16).wrapping_add(s64 / 2) / s64.max(1),
    };
    let d = base + ((b16 * step + (1 << 15)) >> 16);
    U16F16::from_bits(d.clamp(lo, hi) as u32)
}

/// Soft-argmax of one ray's logits (at most [`MAX_BINS`], parameters checked).
#[inline(always)]
fn ray_depth(logits: &[i8], p: &SoftArgmaxParams<'_>) -> U16F16 {
    let m = logits.iter().copied().max().unwrap_or(0) as i32;
    let (mut s, mut t) = (0u32, 0u32);
    for (i, &q) in logits.iter().enumerate() {
        let e = p.exp[(m - q as i32) as usize] as u32;
        s += e;
        t += e * i as u32;
    }
    let bins = logits.len();
    let end = |i: usize| p.exp[(m - logits[i] as i32) as usize] as u32;
    depth_of(s, t, end(0), end(bins - 1), bins, p)
}

fn check_shape(
    shape: &SoftArgmaxShape,
    logits: &[i8],
    p: &SoftArgmaxParams<'_>,
    depth: &[U16F16],
) -> Result<(), KernelError> {
    check_params(p, shape.bins)?;
    let rays = shape
        .rows
        .checked_mul(shape.columns)
        .ok_or(KernelError::SizeOverflow)?;
    let n = rays
        .checked_mul(shape.bins)
        .ok_or(KernelError::SizeOverflow)?;
    super::expect(Operand::Logits, n, logits.len())?;
    super::expect(Operand::Depth, rays, depth.len())
}

/// Plain reference: one ray at a time, strided reads.
pub fn soft_argmax_s8_plain(
    shape: &SoftArgmaxShape,
    logits: &[i8],
    params: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) -> Result<(), KernelError> {
    check_shape(shape, logits, params, depth)?;
    let SoftArgmaxShape {
        rows,
        bins,
        columns,
    } = *shape;
    for e in 0..rows {
        for a in 0..columns {
            let at = |i: usize| logits[(e * bins + i) * columns + a] as i32;
            let mut m = at(0);
            for i in 1..bins {
                m = m.max(at(i));
            }
            let (mut s, mut t) = (0u32, 0u32);
            for i in 0..bins {
                let ei = params.exp[(m - at(i)) as usize] as u32;
                s += ei;
                t += ei * i as u32;
            }
            let first = params.exp[(m - at(0)) as usize] as u32;
            let last = params.exp[(m - at(bins - 1)) as usize] as u32;
            depth[e * columns + a] = depth_of(s, t, first, last, bins, params);
        }
    }
    Ok(())
}

/// Columns processed together by [`soft_argmax_s8`].
const TILE: usize = 64;

/// Optimised: rows of the logits are read contiguously, a tile of up to 64 rays at a time
/// (max pass, then sum pass), with the per-ray state in stack arrays.
pub fn soft_argmax_s8(
    shape: &SoftArgmaxShape,
    logits: &[i8],
    params: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) -> Result<(), KernelError> {
    check_shape(shape, logits, params, depth)?;
    let SoftArgmaxShape {
        rows,
        bins,
        columns,
    } = *shape;
    if columns == 0 {
        return Ok(());
    }
    for e in 0..rows {
        let plane = &logits[e * bins * columns..(e + 1) * bins * columns];
        let mut a0 = 0;
        while a0 < columns {
            let w = TILE.min(columns - a0);
            let mut m = [i8::MIN; TILE];
            for row in plane.chunks_exact(columns) {
                for (mx, &q) in m[..w].iter_mut().zip(&row[a0..a0 + w]) {
                    *mx = (*mx).max(q);
                }
            }
            let mut s = [0u32; TILE];
            let mut t = [0u32; TILE];
            for (i, row) in plane.chunks_exact(columns).enumerate() {
                for (k, &q) in row[a0..a0 + w].iter().enumerate() {
                    let ei = params.exp[(m[k] as i32 - q as i32) as usize] as u32;
                    s[k] += ei;
                    t[k] += ei * i as u32;
                }
            }
            let first_row = &plane[a0..a0 + w];
            let last_row = &plane[(bins - 1) * columns + a0..][..w];
            for k in 0..w {
                let end = |q: i8| params.exp[(m[k] as i32 - q as i32) as usize] as u32;
                depth[e * columns + a0 + k] = depth_of(
                    s[k],
                    t[k],
                    end(first_row[k]),
                    end(last_row[k]),
                    bins,
                    params,
                );
            }
            a0 += w;
        }
    }
    Ok(())
}

/// The head (a transposed convolution with kernel == stride and no padding, one output
/// channel, so each output voxel depends on exactly one input voxel) fused with the
/// soft-argmax: each ray's logits are computed into a stack buffer and reduced at once,
/// never storing the `[E][R][A]` logits volume (MCUNetV2-style streaming).
///
/// `shape` is the head's transposed-convolution shape, output axes `[E][R][A]`; `params` as
/// for [`super::conv_transpose3d_s8::conv_transpose3d_s8`]; `depth` is `[E][A]`.
///
/// MACs: `E · R · A · I` (one tap per input channel per logit), plus the soft-argmax.
pub fn head_soft_argmax_s8(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) -> Result<(), KernelError> {
    if shape.kernel != shape.stride
        || shape.padding != [0; 3]
        || shape.output_padding != [0; 3]
        || shape.out_channels != 1
    {
        return Err(KernelError::NotStreamableHead);
    }
    let out_len = mul3(shape.out_size)?;
    let bound = check_conv_transpose(shape, input.len(), params, out_len)?;
    let [rows, bins, columns] = shape.out_size;
    check_params(soft, bins)?;
    super::expect(Operand::Depth, rows * columns, depth.len())?;
    if head_fits(shape) {
        let rq = params.requant[0];
        if rq.fits_fast(bound) {
            head_by_columns(shape, input, params, FastRequant::new(rq), soft, depth);
        } else {
            head_by_columns(shape, input, params, rq, soft, depth);
        }
    } else {
        head_by_rays(shape, input, params, soft, depth);
    }
    Ok(())
}

/// Most words of one gathered input column (`H` rows of `I` i16 values padded to a
/// multiple of 4, two per word) the fused head keeps on the stack.
pub const HEAD_COL_WORDS: usize = 1024;
/// Most words of the fused head's prepared weights (ray pairs × `kh` × 2 × column words).
pub const HEAD_W_WORDS: usize = 256;

/// Whether [`head_by_columns`] fits its stack buffers.
fn head_fits(shape: &ConvShape) -> bool {
    let [kd, kh, kw] = shape.kernel;
    let n = up4(shape.in_channels) / 2;
    shape.in_size[1] * n <= HEAD_COL_WORDS && (kd * kw).div_ceil(2) * kh * 2 * n <= HEAD_W_WORDS
}

/// `x` rounded up to a multiple of 4.
fn up4(x: usize) -> usize {
    x.div_ceil(4) * 4
}

/// The i16 slot of value `k` in a word buffer viewed as i16 (`2j`, `2j + 1` share word `j`,
/// the even one in the low half as [`crate::arch::pack`]).
#[inline(always)]
const fn slot(k: usize) -> usize {
    if cfg!(target_endian = "little") {
        k
    } else {
        k ^ 1
    }
}

/// Fused head, column by column: the `I × H` inputs of one input (plane, column) are
/// gathered once (i16 pairs, offset added, `[y][c]`) and shared by the `kd · kw` rays that
/// read them. Two rays × two range bins per [`crate::arch::dot2x2`] (the rays' weights
/// interleaved), the fast requantisation when the bound allows it, and each ray's maximum
/// tracked while its logits are produced, so the soft-argmax is a single pass (EPSSN-S on
/// the QEMU Cortex-M7: about 86 instructions per logit, soft-argmax included).
fn head_by_columns<R: Apply>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    rq: R,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) {
    let [id, ih, iw] = shape.in_size;
    let [kd, kh, kw] = shape.kernel;
    let columns = shape.out_size[2];
    let bins = ih * kh;
    let taps = kd * kh * kw;
    let ic = shape.in_channels;
    let vp = up4(ic);
    let n = vp / 2;
    let rays = kd * kw;
    // |offset| ≤ 255 is validated, so offset inputs fit i16.
    let (bias, off) = (params.bias[0], params.input_offset as i16);
    // Weights of ray pair p, row tap ky: the two rays' words interleaved (an odd last ray
    // is paired with itself).
    let mut wbuf = [0u32; HEAD_W_WORDS];
    for p in 0..rays.div_ceil(2) {
        for ky in 0..kh {
            for half in 0..2 {
                let r = (2 * p + half).min(rays - 1);
                let (kz, kx) = (r / kw, r % kw);
                let w = |c: usize| {
                    if c < ic {
                        params.weights[c * taps + (kz * kh + ky) * kw + kx] as i16
                    } else {
                        0
                    }
                };
                for k in 0..n {
                    wbuf[(p * kh + ky) * 2 * n + 2 * k + half] =
                        crate::arch::pack(w(2 * k), w(2 * k + 1));
                }
            }
        }
    }
    let mut col = [0u32; HEAD_COL_WORDS];
    let mut logits = [[0i8; MAX_BINS]; 2];
    for z in 0..id {
        for x in 0..iw {
            let slots: &mut [i16] = bytemuck::cast_slice_mut(&mut col[..ih * n]);
            // Channel by channel: the channel's column is every iw-th input value; the
            // destination rows are vp-value chunks (no index arithmetic per value).
            for c in 0..vp {
                let sc = slot(c);
                let rows = slots.chunks_exact_mut(vp);
                if c < ic {
                    let src = input[(c * id + z) * ih * iw + x..].chunks(iw);
                    for (d, r) in rows.zip(src) {
                        d[sc] = r[0] as i16 + off;
                    }
                } else {
                    for d in rows {
                        d[sc] = 0;
                    }
                }
            }
            for p in 0..rays.div_ceil(2) {
                let mut max = [i8::MIN; 2];
                for ky in 0..kh {
                    let w = &wbuf[(p * kh + ky) * 2 * n..][..2 * n];
                    let mut y = 0;
                    while y < ih {
                        let two = y + 1 < ih;
                        let acc = crate::arch::dot2x2(
                            &col[y * n..ih * n],
                            if two { n } else { 0 },
                            w,
                            n,
                            [bias; 4],
                        );
                        for (j, &a) in acc.iter().enumerate() {
                            let (r, dy) = (j / 2, j % 2);
                            if dy == 1 && !two {
                                continue;
                            }
                            let q = finish(rq.apply(a), params.relu, None);
                            logits[r][(y + dy) * kh + ky] = q;
                            max[r] = max[r].max(q);
                        }
                        y += 2;
                    }
                }
                for (half, (l, &m)) in logits.iter().zip(&max).enumerate() {
                    let r = 2 * p + half;
                    if r >= rays {
                        break;
                    }
                    let (e, a) = (z * kd + r / kw, x * kw + r % kw);
                    depth[e * columns + a] = ray_depth_max(&l[..bins], m, soft);
                }
            }
        }
    }
}

/// Soft-argmax of one ray whose maximum logit `m` is known (the contract's sums).
#[inline(always)]
pub(super) fn ray_depth_max(logits: &[i8], m: i8, p: &SoftArgmaxParams<'_>) -> U16F16 {
    // m ≥ q, so m − q is in 0..=255 and the table index exact.
    let (s, t) = crate::arch::exp_sums(logits, m, p.exp);
    let end = |q: i8| p.exp[(m as i32 - q as i32) as u8 as usize] as u32;
    depth_of(
        s,
        t,
        end(logits[0]),
        end(logits[logits.len() - 1]),
        logits.len(),
        p,
    )
}

/// Fused head, ray by ray, without gather buffers (layers too large for them).
fn head_by_rays(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) {
    let [rows, bins, columns] = shape.out_size;
    let [id, ih, iw] = shape.in_size;
    let [kd, kh, kw] = shape.kernel;
    let taps = kd * kh * kw;
    let ic = shape.in_channels;
    let in_plane = id * ih * iw;
    let (bias, rq, off) = (params.bias[0], params.requant[0], params.input_offset);
    let mut logits = [0i8; MAX_BINS];
    for e in 0..rows {
        let (z, kz) = (e / kd, e % kd);
        for a in 0..columns {
            let (x, kx) = (a / kw, a % kw);
            for (i, l) in logits[..bins].iter_mut().enumerate() {
                let (y, ky) = (i / kh, i % kh);
                let in_at = (z * ih + y) * iw + x;
                let w_at = (kz * kh + ky) * kw + kx;
                let mut acc = bias;
                for c in 0..ic {
                    let v = input[c * in_plane + in_at] as i32 + off;
                    acc += v * params.weights[c * taps + w_at] as i32;
                }
                *l = finish(rq.apply(acc), params.relu, None);
            }
            depth[e * columns + a] = ray_depth(&logits[..bins], soft);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::conv_transpose3d_s8::conv_transpose3d_s8_plain;
    use super::super::testutil::{exp_table, params, soft_params, Rng};
    use super::super::Skip;
    use super::*;

    #[test]
    fn round_div16_is_the_u64_division() {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let edges = [
            (0, 1),
            (u32::MAX, 1),
            (u32::MAX, (1 << 24) - 1),
            (1, 3),
            (5, 2),
        ];
        for i in 0..100_000 {
            let (t, s) = match edges.get(i) {
                Some(&e) => e,
                None => (
                    next() as u32 >> (next() % 32),
                    1 + (next() as u32 % ((1 << 24) - 1)),
                ),
            };
            let want = ((t as u64) << 16).wrapping_add(s as u64 / 2) / s as u64;
            assert_eq!(round_div16(t, s), want, "t {t} s {s}");
        }
    }
    use crate::config;
    use std::vec;

    #[test]
    fn optimised_equals_plain_random() {
        let mut rng = Rng(77);
        for case in 0..100 {
            let shape = SoftArgmaxShape {
                rows: 1 + rng.below(4),
                bins: 1 + rng.below(70),
                columns: 1 + rng.below(150),
            };
            let exp = exp_table(0.01 + rng.below(100) as f64 * 0.01);
            let mut p = soft_params(&exp, rng.below(12) as u16);
            // Every other case decides no-returns, at thresholds from a sliver to the whole mass.
            if case % 2 == 1 {
                p.no_return16 = 1 + rng.below(1 << 16) as u32;
            }
            let n = shape.rows * shape.bins * shape.columns;
            let logits = rng.i8s(n);
            let rays = shape.rows * shape.columns;
            let (mut a, mut o) = (vec![U16F16::ZERO; rays], vec![U16F16::ZERO; rays]);
            soft_argmax_s8_plain(&shape, &logits, &p, &mut a).unwrap();
            soft_argmax_s8(&shape, &logits, &p, &mut o).unwrap();
            assert_eq!(a, o, "case {case} {shape:?}");
        }
    }

    #[test]
    fn equal_logits_give_the_middle_and_one_hot_gives_the_bin() {
        let exp = exp_table(0.2);
        let p = soft_params(&exp, 0);
        // The build's bins: `soft_params` spreads them over the spec's range window.
        let bins = config::DEPTH_RANGE_BINS;
        let shape = SoftArgmaxShape {
            rows: 1,
            bins,
            columns: 2,
        };
        let mut logits = vec![-7i8; 2 * bins];
        // Column 1: one-hot at bin 10 with a gap of 255, where EXP underflows to 0.
        for i in 0..bins {
            logits[i * 2 + 1] = -128;
        }
        logits[10 * 2 + 1] = 127;
        let mut d = vec![U16F16::ZERO; 2];
        soft_argmax_s8(&shape, &logits, &p, &mut d).unwrap();
        assert_eq!(exp[255], 0);
        // Middle bin (bins − 1) / 2: r_min16 + ((bins − 1)/2·2^16·step16 + 2^15) >> 16.
        let mid = p.r_min16.to_bits()
            + (((bins - 1) as u64 * p.step16.to_bits() as u64 * (1 << 15) + (1 << 15)) >> 16)
                as u32;
        assert_eq!(d[0].to_bits(), mid);
        assert_eq!(
            d[1].to_bits(),
            p.r_min16.to_bits() + 10 * p.step16.to_bits()
        );
        // In metres the window's middle, up to Q16.16 rounding: half an LSB each of r_min16,
        // of step16 per bin of the (bins − 1) / 2 and of the result.
        let metres = d[0].to_num::<f64>();
        let lsb = 1.0 / 65536.0;
        let tolerance = ((bins - 1) as f64 / 2.0 + 2.0) * lsb / 2.0;
        let error = (metres - (config::R_MIN_M + config::R_MAX_M) / 2.0).abs();
        assert!(error <= tolerance, "{error} > {tolerance}");
    }

    #[test]
    fn fused_head_equals_conv_transpose_then_soft_argmax() {
        let mut rng = Rng(2024);
        let exp = exp_table(0.05);
        let p = soft_params(&exp, 3);
        // EPSSN-S's fused head shape (the compiled spec's head may overlap, which is not fused).
        let mut shapes = vec![ConvShape {
            in_channels: 8,
            out_channels: 1,
            kernel: [2, 1, 4],
            stride: [2, 1, 4],
            padding: [0; 3],
            output_padding: [0; 3],
            in_size: [16, 64, 16],
            out_size: [32, 64, 64],
        }];
        // Too large for the column buffers: the ray-by-ray path.
        shapes.push(ConvShape {
            in_channels: 70,
            out_channels: 1,
            kernel: [2, 2, 3],
            stride: [2, 2, 3],
            padding: [0; 3],
            output_padding: [0; 3],
            in_size: [2, 16, 2],
            out_size: [4, 32, 6],
        });
        // 3 ray pairs × kh 2 × 2 × 36 words of 70 padded channels.
        const { assert!(3 * 2 * 2 * 36 > HEAD_W_WORDS) };
        for _ in 0..60 {
            let kernel = [1 + rng.below(3), 1 + rng.below(3), 1 + rng.below(4)];
            let in_size = [1 + rng.below(3), 1 + rng.below(6), 1 + rng.below(4)];
            shapes.push(ConvShape {
                in_channels: 1 + rng.below(17),
                out_channels: 1,
                kernel,
                stride: kernel,
                padding: [0; 3],
                output_padding: [0; 3],
                in_size,
                out_size: core::array::from_fn(|a| in_size[a] * kernel[a]),
            });
        }
        for (case, shape) in shapes.iter().enumerate() {
            let (w, mut b, r) = params(&mut rng, shape);
            if case % 5 == 4 {
                // Beyond the fast requantisation's range: the exact path.
                b[0] = 1 << 30;
            }
            let input = rng.i8s(shape.in_channels * shape.in_size.iter().product::<usize>());
            let cp = ConvParams {
                weights: &w,
                bias: &b,
                requant: &r,
                input_offset: if case % 4 == 2 { 128 } else { 0 },
                relu: case % 3 == 1,
            };
            let [rows, bins, columns] = shape.out_size;
            let mut logits = vec![0i8; rows * bins * columns];
            conv_transpose3d_s8_plain(shape, &input, &cp, Skip::None, &mut logits).unwrap();
            let ss = SoftArgmaxShape {
                rows,
                bins,
                columns,
            };
            let (mut a, mut o) = (
                vec![U16F16::ZERO; rows * columns],
                vec![U16F16::ONE; rows * columns],
            );
            soft_argmax_s8_plain(&ss, &logits, &p, &mut a).unwrap();
            head_soft_argmax_s8(shape, &input, &cp, &p, &mut o).unwrap();
            assert_eq!(a, o, "case {case} {shape:?}");
        }
    }

    #[test]
    fn no_return_decision_reads_the_window_ends_exactly() {
        let exp = exp_table(0.2);
        let bins = 8;
        let shape = SoftArgmaxShape {
            rows: 1,
            bins,
            columns: 5,
        };
        let mut p = soft_params(&exp, 4);
        let (lo, hi) = (
            p.r_min16.to_bits() + 4 * p.step16.to_bits(),
            p.r_min16.to_bits() + (bins as u32 - 1 + 4) * p.step16.to_bits(),
        );
        // Rays (columns): mass on the last bin; on the first; on bin 3; last and first
        // equal (far wins); spread evenly (no end holds half).
        let mut logits = [0i8; 8 * 5];
        let mut set = |bin: usize, col: usize, v: i8| logits[bin * 5 + col] = v;
        set(bins - 1, 0, 100);
        set(0, 1, 100);
        set(3, 2, 100);
        set(0, 3, 100);
        set(bins - 1, 3, 100);
        let run = |p: &SoftArgmaxParams<'_>| {
            let mut d = [U16F16::ZERO; 5];
            soft_argmax_s8(&shape, &logits, p, &mut d).unwrap();
            let mut plain = [U16F16::ZERO; 5];
            soft_argmax_s8_plain(&shape, &logits, p, &mut plain).unwrap();
            assert_eq!(d, plain);
            d.map(|x| x.to_bits())
        };
        let soft = run(&p);
        p.no_return16 = 1 << 15;
        let decided = run(&p);
        assert_eq!(decided[0], hi);
        assert_eq!(decided[1], lo);
        assert_eq!(decided[2], soft[2]);
        assert_eq!(decided[3], hi);
        assert_eq!(decided[4], soft[4]);
        assert!(soft[2] > lo && soft[2] < hi);
        assert!(soft[4] > lo && soft[4] < hi);
        // A threshold above the end's mass decides nothing.
        p.no_return16 = MAX_NO_RETURN16;
        assert_eq!(run(&p)[2..], soft[2..]);
    }

    #[test]
    fn errors() {
        let exp = [0u16; 256];
        let p = SoftArgmaxParams {
            exp: &exp,
            r_min16: U16F16::ZERO,
            step16: U16F16::ZERO,
            end_offset: 0,
            no_return16: 0,
        };
        let s = SoftArgmaxShape {
            rows: 1,
            bins: 2,
            columns: 1,
        };
        let mut d = [U16F16::ZERO; 1];
        assert_eq!(
            soft_argmax_s8(&s, &[0, 0], &p, &mut d),
            Err(KernelError::ExpTable)
        );
        let exp = [1u16; 256];
        let p = SoftArgmaxParams { exp: &exp, ..p };
        let big = SoftArgmaxShape { bins: 257, ..s };
        assert_eq!(
            soft_argmax_s8_plain(&big, &[0; 257], &p, &mut d),
            Err(KernelError::RangeBins { bins: 257 })
        );
        let p2 = SoftArgmaxParams {
            r_min16: U16F16::MAX,
            step16: U16F16::ONE,
            ..p
        };
        assert_eq!(
            soft_argmax_s8(&s, &[0, 0], &p2, &mut d),
            Err(KernelError::DepthOverflow)
        );
        let far = SoftArgmaxParams {
            end_offset: MAX_END_OFFSET + 1,
            ..p
        };
        assert_eq!(
            soft_argmax_s8(&s, &[0, 0], &far, &mut d),
            Err(KernelError::EndOffset {
                offset: MAX_END_OFFSET + 1
            })
        );
        let whole = SoftArgmaxParams {
            no_return16: MAX_NO_RETURN16 + 1,
            ..p
        };
        assert_eq!(
            soft_argmax_s8(&s, &[0, 0], &whole, &mut d),
            Err(KernelError::NoReturnMass {
                mass16: MAX_NO_RETURN16 + 1
            })
        );
        // The end bins' reach counts towards the overflow check.
        let reach = SoftArgmaxParams {
            r_min16: U16F16::from_bits(u32::MAX - 250),
            step16: U16F16::from_bits(100),
            end_offset: 1,
            ..p
        };
        assert_eq!(
            soft_argmax_s8(
                &s,
                &[0, 0],
                &SoftArgmaxParams {
                    end_offset: 0,
                    ..reach
                },
                &mut d
            ),
            Ok(())
        );
        assert_eq!(
            soft_argmax_s8(&s, &[0, 0], &reach, &mut d),
            Err(KernelError::DepthOverflow)
        );
        assert!(matches!(
            soft_argmax_s8(&s, &[0, 0, 0], &p, &mut d),
            Err(KernelError::Length {
                operand: Operand::Logits,
                ..
            })
        ));
        let shape = ConvShape::from(&config::LAYER_U0);
        let cp = ConvParams {
            weights: &[],
            bias: &[],
            requant: &[],
            input_offset: 0,
            relu: false,
        };
        assert_eq!(
            head_soft_argmax_s8(&shape, &[], &cp, &p, &mut d),
            Err(KernelError::NotStreamableHead)
        );
    }
}
