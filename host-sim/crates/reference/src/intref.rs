//! Independent plain integer reference of the int8 network, written from
//! `docs/QUANTISATION.md` alone. It shares no kernel or requantisation code with the library:
//! 64-bit accumulators, the rounding rules re-derived in floor-division form, the transposed
//! convolution in the *scatter* form (the library gathers), no tiling, no streaming.
//! The bit-exactness tests compare the library's kernels with these functions.
//!
//! Layouts as everywhere in epssn: activations `[C][D][H][W]` (2D layers use `[C][H][W]`
//! with `D = 1` folded in as axes `[H, W, 1]`), convolution weights `[O][I][k…]`,
//! transposed-convolution weights `[I][O][k…]`.

use epssn::config::LayerShape;
use epssn::geometry::WarpEntry;

/// One requantisation multiplier `(M, shift)`: `m ≈ M · 2^(shift − 31)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mult {
    /// `M`.
    pub m: i32,
    /// `shift`.
    pub shift: i32,
}

/// Sizes of a (transposed) convolution, axes `[D, H, W]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shape {
    /// Input channels.
    pub cin: usize,
    /// Output channels.
    pub cout: usize,
    /// Kernel.
    pub k: [usize; 3],
    /// Stride.
    pub s: [usize; 3],
    /// Padding.
    pub p: [usize; 3],
    /// Output padding (transposed only).
    pub op: [usize; 3],
    /// Input size.
    pub n_in: [usize; 3],
    /// Output size.
    pub n_out: [usize; 3],
}

impl From<&LayerShape> for Shape {
    fn from(l: &LayerShape) -> Self {
        let u = |a: [u8; 3]| a.map(usize::from);
        Shape {
            cin: l.in_channels,
            cout: l.out_channels,
            k: u(l.kernel),
            s: u(l.stride),
            p: u(l.padding),
            op: u(l.output_padding),
            n_in: l.in_size,
            n_out: l.out_size,
        }
    }
}

/// `SRDHM(a, b)`. The contract's nudge-and-truncate form equals rounding `a·b / 2^31` to the
/// nearest integer with ties toward +∞, i.e. `floor((a·b + 2^30) / 2^31)`, which is what is
/// computed here (floor division), plus the one saturating case.
pub fn srdhm(a: i32, b: i32) -> i64 {
    if a == i32::MIN && b == i32::MIN {
        return i32::MAX as i64;
    }
    let ab = a as i128 * b as i128;
    (ab + (1i128 << 30)).div_euclid(1i128 << 31) as i64
}

/// `RDBPOT(x, e)`: `x / 2^e` rounded to nearest, ties away from zero, computed on the
/// magnitude.
pub fn rdbpot(x: i64, e: u32) -> i64 {
    if e == 0 {
        return x;
    }
    let mag = (x.unsigned_abs() + (1u64 << (e - 1))) >> e;
    if x < 0 {
        -(mag as i64)
    } else {
        mag as i64
    }
}

/// `MBQM(acc, M, shift)`. Panics if `acc · 2^left` leaves int32, which the contract excludes
/// (the quantiser proves it cannot happen); the reference refuses to guess.
pub fn mbqm(acc: i64, mult: Mult) -> i64 {
    let left = mult.shift.max(0) as u32;
    let right = (-mult.shift).max(0) as u32;
    let shifted = acc * (1i64 << left);
    assert!(
        i32::try_from(shifted).is_ok(),
        "accumulator {acc} << {left} leaves int32"
    );
    rdbpot(srdhm(shifted as i32, mult.m), right)
}

fn clamp_i8(x: i64) -> i8 {
    x.clamp(-128, 127) as i8
}

/// Convolution (2D layers as 3D with a trivial third axis): `acc = b + Σ (x + offset)·w`,
/// `t = MBQM(acc)`, ReLU, clamp.
#[allow(clippy::too_many_arguments)]
pub fn conv(
    sh: &Shape,
    input: &[i8],
    weights: &[i8],
    bias: &[i32],
    mults: &[Mult],
    input_offset: i32,
    relu: bool,
) -> Vec<i8> {
    let [d, h, w] = sh.n_in;
    let [od, oh, ow] = sh.n_out;
    assert_eq!(input.len(), sh.cin * d * h * w);
    assert_eq!(
        weights.len(),
        sh.cout * sh.cin * sh.k.iter().product::<usize>()
    );
    let mut out = vec![0i8; sh.cout * od * oh * ow];
    for o in 0..sh.cout {
        for z in 0..od {
            for y in 0..oh {
                for x in 0..ow {
                    let mut acc = bias[o] as i64;
                    for i in 0..sh.cin {
                        for a in 0..sh.k[0] {
                            for b in 0..sh.k[1] {
                                for c in 0..sh.k[2] {
                                    let pz = (z * sh.s[0] + a) as i64 - sh.p[0] as i64;
                                    let py = (y * sh.s[1] + b) as i64 - sh.p[1] as i64;
                                    let px = (x * sh.s[2] + c) as i64 - sh.p[2] as i64;
                                    let inside = (0..d as i64).contains(&pz)
                                        && (0..h as i64).contains(&py)
                                        && (0..w as i64).contains(&px);
                                    if !inside {
                                        continue; // padding: real value 0
                                    }
                                    let xi = input[i * d * h * w
                                        + pz as usize * h * w
                                        + py as usize * w
                                        + px as usize]
                                        as i64
                                        + input_offset as i64;
                                    let wi = weights[o * sh.cin * sh.k[0] * sh.k[1] * sh.k[2]
                                        + i * sh.k[0] * sh.k[1] * sh.k[2]
                                        + a * sh.k[1] * sh.k[2]
                                        + b * sh.k[2]
                                        + c] as i64;
                                    acc += xi * wi;
                                }
                            }
                        }
                    }
                    assert!(i32::try_from(acc).is_ok(), "accumulator leaves int32");
                    let mut t = mbqm(acc, mults[o]);
                    if relu {
                        t = t.max(0);
                    }
                    out[o * od * oh * ow + z * oh * ow + y * ow + x] = clamp_i8(t);
                }
            }
        }
    }
    out
}

/// Transposed convolution in the scatter form: every input voxel adds `x · w[i, o, k]` to
/// output `in·stride − pad + k` (dropped when outside). Then requantise, ReLU, optional skip
/// add `u = MBQM(q_skip + skip_offset, M_skip)`, `y = clamp(t + u)`.
#[allow(clippy::too_many_arguments)]
pub fn conv_transpose(
    sh: &Shape,
    input: &[i8],
    weights: &[i8],
    bias: &[i32],
    mults: &[Mult],
    input_offset: i32,
    relu: bool,
    skip: Option<(&[i8], Mult, i32)>,
) -> Vec<i8> {
    let [d, h, w] = sh.n_in;
    let [od, oh, ow] = sh.n_out;
    // Output size from the transposed-convolution formula, checked against the shape.
    for a in 0..3 {
        assert_eq!(
            (sh.n_in[a] - 1) * sh.s[a] + sh.k[a] + sh.op[a] - 2 * sh.p[a],
            sh.n_out[a]
        );
    }
    let kk = sh.k.iter().product::<usize>();
    assert_eq!(weights.len(), sh.cin * sh.cout * kk);
    let vol = od * oh * ow;
    let mut acc: Vec<i64> = (0..sh.cout * vol).map(|i| bias[i / vol] as i64).collect();
    for i in 0..sh.cin {
        for z in 0..d {
            for y in 0..h {
                for x in 0..w {
                    let xi = input[((i * d + z) * h + y) * w + x] as i64 + input_offset as i64;
                    for o in 0..sh.cout {
                        for a in 0..sh.k[0] {
                            for b in 0..sh.k[1] {
                                for c in 0..sh.k[2] {
                                    let tz = (z * sh.s[0] + a) as i64 - sh.p[0] as i64;
                                    let ty = (y * sh.s[1] + b) as i64 - sh.p[1] as i64;
                                    let tx = (x * sh.s[2] + c) as i64 - sh.p[2] as i64;
                                    if tz < 0
                                        || ty < 0
                                        || tx < 0
                                        || tz >= od as i64
                                        || ty >= oh as i64
                                        || tx >= ow as i64
                                    {
                                        continue;
                                    }
                                    let wi = weights[((i * sh.cout + o) * sh.k[0] + a)
                                        * sh.k[1]
                                        * sh.k[2]
                                        + b * sh.k[2]
                                        + c] as i64;
                                    acc[o * vol
                                        + tz as usize * oh * ow
                                        + ty as usize * ow
                                        + tx as usize] += xi * wi;
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    acc.iter()
        .enumerate()
        .map(|(idx, &a)| {
            assert!(i32::try_from(a).is_ok(), "accumulator leaves int32");
            let mut t = mbqm(a, mults[idx / vol]);
            if relu {
                t = t.max(0);
            }
            if let Some((s, m, offset)) = skip {
                t += mbqm(s[idx] as i64 + offset as i64, m);
            }
            clamp_i8(t)
        })
        .collect()
}

/// The warped value of source features `f` (`[C][H][W]`) at channel `c`, range `r`, for
/// table entry `e`: `(F[col]·(256 − α) + F[col+1]·α + 128) >> 8` (floor), invisible → 0.
pub fn warp_value(f: &[i8], h: usize, w: usize, c: usize, r: usize, e: WarpEntry) -> i64 {
    if !e.visible {
        return 0;
    }
    let col = e.column as usize;
    let alpha = e.fraction as i64;
    let base = (c * h + r) * w;
    let left = f[base + col] as i64 * (256 - alpha);
    let right = if alpha > 0 {
        f[base + col + 1] as i64 * alpha
    } else {
        0
    };
    (left + right + 128).div_euclid(256)
}

/// Variance cost volume `[C][N][H][W]` from the reference `[C][H][W]` and 1 or 2 sources
/// with their warp tables `[N][W]`: `X = n·Σv² − (Σv)²`, `q = clamp(MBQM(X), 0, 127 − z)`
/// stored as `q + z` for the zero point `z` (0 or −128); the last `mean_channels` channels
/// hold `clamp(MBQM(Σv, mean_mult), 0, 127 − z) + z` instead.
#[allow(clippy::too_many_arguments)]
pub fn cost_volume(
    reference: &[i8],
    sources: &[(&[i8], &[WarpEntry])],
    c: usize,
    planes: usize,
    h: usize,
    w: usize,
    mult: Mult,
    mean_channels: usize,
    mean_mult: Mult,
    zero_point: i32,
) -> Vec<i8> {
    assert!(
        zero_point == 0 || zero_point == -128,
        "zero point {zero_point}"
    );
    let z = zero_point as i64;
    let n = sources.len() as i64 + 1;
    let mut out = vec![0i8; c * planes * h * w];
    for ch in 0..c {
        for j in 0..planes {
            for r in 0..h {
                for b in 0..w {
                    let mut vals = vec![reference[(ch * h + r) * w + b] as i64];
                    for (f, table) in sources {
                        vals.push(warp_value(f, h, w, ch, r, table[j * w + b]));
                    }
                    let sum: i64 = vals.iter().sum();
                    let sum_sq: i64 = vals.iter().map(|v| v * v).sum();
                    let x = n * sum_sq - sum * sum;
                    assert!(x >= 0);
                    let q = if ch + mean_channels >= c {
                        mbqm(sum, mean_mult)
                    } else {
                        mbqm(x, mult)
                    };
                    out[((ch * planes + j) * h + r) * w + b] = (q.clamp(0, 127 - z) + z) as i8;
                }
            }
        }
    }
    out
}

/// `EXP[d] = round_half_away(65535 · exp(−d · s_l))`, d = 0..=255.
pub fn exp_table(logit_scale: f64) -> [u16; 256] {
    std::array::from_fn(|d| (65535.0 * (-(d as f64) * logit_scale).exp()).round() as u16)
}

/// Fixed-point soft-argmax of logits `[E][R][A]` along R → depth `[E][A]` as U16F16 bits:
/// with the bin index `j_i = i + K` (`j_0 = 0`, `j_{R−1} = R − 1 + 2K`: the end bins reach
/// `K = end_offset` steps beyond the window), `T = Σ e_i·j_i`, `b16 = (T·2^16 + S/2) / S`,
/// `d16 = r_min16 + (b16·step16 + 2^15) >> 16`, clamped to the window
/// `[r_min16 + K·step16, r_min16 + (R − 1 + K)·step16]`. With `no_return16 = τ16 > 0`
/// (QUANTISATION.md "No-return decision") a ray with `e_{R−1}·2^16 ≥ τ16·S` reads the
/// window's top exactly, else one with `e_0·2^16 ≥ τ16·S` its bottom.
#[allow(clippy::too_many_arguments)]
pub fn soft_argmax(
    logits: &[i8],
    rows: usize,
    bins: usize,
    cols: usize,
    exp: &[u16; 256],
    r_min16: u32,
    step16: u32,
    end_offset: u32,
    no_return16: u32,
) -> Vec<u32> {
    assert_eq!(logits.len(), rows * bins * cols);
    let k = end_offset as u128;
    let index = |i: usize| -> u128 {
        if i == 0 {
            0
        } else if i == bins - 1 {
            (bins - 1) as u128 + 2 * k
        } else {
            i as u128 + k
        }
    };
    let mut depth = Vec::with_capacity(rows * cols);
    for e in 0..rows {
        for a in 0..cols {
            let ray: Vec<i64> = (0..bins)
                .map(|i| logits[(e * bins + i) * cols + a] as i64)
                .collect();
            let m = *ray.iter().max().expect("at least one bin");
            let weights: Vec<u128> = ray.iter().map(|&q| exp[(m - q) as usize] as u128).collect();
            let s: u128 = weights.iter().sum();
            let lo = r_min16 as u128 + k * step16 as u128;
            let hi = r_min16 as u128 + ((bins - 1) as u128 + k) * step16 as u128;
            let tau = no_return16 as u128 * s;
            let d = if no_return16 > 0 && weights[bins - 1] * 65536 >= tau {
                hi
            } else if no_return16 > 0 && weights[0] * 65536 >= tau {
                lo
            } else {
                let t: u128 = weights.iter().enumerate().map(|(i, &x)| x * index(i)).sum();
                let b16 = (t * 65536 + s / 2) / s;
                let d = r_min16 as u128 + ((b16 * step16 as u128 + 32768) >> 16);
                d.clamp(lo, hi)
            };
            depth.push(u32::try_from(d).expect("depth fits U16F16"));
        }
    }
    depth
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_helpers_match_their_definitions() {
        // RDBPOT: ties away from zero.
        assert_eq!(rdbpot(3, 1), 2);
        assert_eq!(rdbpot(-3, 1), -2);
        assert_eq!(rdbpot(-5, 2), -1);
        assert_eq!(rdbpot(-6, 2), -2);
        // SRDHM: ties toward +∞.
        assert_eq!(srdhm(-3, 1 << 30), -1);
        assert_eq!(srdhm(3, 1 << 30), 2);
        assert_eq!(srdhm(i32::MIN, i32::MIN), i32::MAX as i64);
        // The contract's literal SRDHM formula, for a sweep of products.
        for a in (-100_000i64..100_000).step_by(37) {
            for b in [1i64 << 30, (1 << 31) - 1, 1_234_567_891] {
                let ab = a * b;
                let nudge = if ab >= 0 {
                    1i64 << 30
                } else {
                    1 - (1i64 << 30)
                };
                assert_eq!(srdhm(a as i32, b as i32), (ab + nudge) / (1i64 << 31));
            }
        }
    }

    #[test]
    fn scatter_conv_transpose_of_a_single_voxel_is_the_kernel() {
        // One input voxel of value 1, stride 2, no padding: the output is the kernel itself,
        // placed at the origin, with multiplier 1 (M = 2^30, shift 1).
        let sh = Shape {
            cin: 1,
            cout: 1,
            k: [1, 2, 3],
            s: [2, 2, 2],
            p: [0; 3],
            op: [0; 3],
            n_in: [1, 1, 1],
            n_out: [1, 2, 3],
        };
        let w = [1i8, -2, 3, -4, 5, -6];
        let one = Mult {
            m: 1 << 30,
            shift: 1,
        };
        let out = conv_transpose(&sh, &[1], &w, &[0], &[one], 0, false, None);
        assert_eq!(out, w.to_vec());
    }
}
