//! 3D transposed convolution in the gather form, int8 in/out, int32 accumulate,
//! per-channel requantisation, fused ReLU and optional skip add (QUANTISATION.md).
//!
//! Input `[I][D][H][W]` i8 (each value plus `input_offset`), weights `[I][O][kd][kh][kw]` i8,
//! bias `[O]` i32, multipliers `[O]`, output `[O][OD][OH][OW]` i8 with
//! `OD = (D − 1)·sd − 2·pd + kd + opd` (and likewise per axis).
//!
//! `out[o, z] = Σ_{i, k : z = in·stride − pad + k} in[i, in] · w[i, o, k]`: each output voxel
//! gathers its own taps, so the skip tensor may live in the output slice ([`Skip::InPlace`]).
//!
//! MACs: `I · D · H · W · O · kd · kh · kw` (the scatter count; taps falling outside the
//! output are skipped).

use super::{
    check_conv_transpose, check_conv_transpose_shape, check_skip, finish, CheckedParams,
    ConvParams, ConvShape, KernelError, LineScratch, Skip,
};

/// The requantised skip term `MBQM(q_skip + offset)` of output voxel `idx`, read before the
/// voxel is written.
#[inline(always)]
fn skip_at(skip: &Skip<'_>, output: &[i8], idx: usize) -> Option<i32> {
    let q = match *skip {
        Skip::None => return None,
        Skip::Separate { skip, .. } => skip[idx],
        Skip::InPlace { .. } => output[idx],
    };
    let (rq, offset) = skip.requant()?;
    Some(rq.apply(q as i32 + offset))
}

/// Plain reference: every (input channel, tap) of every output voxel, testing whether the
/// tap lands on an input voxel.
pub fn conv_transpose3d_s8_plain(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    skip: Skip<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_conv_transpose(shape, input.len(), params, output.len())?;
    check_skip(&skip, output.len())?;
    let [id, ih, iw] = shape.in_size;
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [pd, ph, pw] = shape.padding;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    // Input index on one axis that output `z` reaches through tap `k`, if any.
    let source = |z: usize, k: usize, s: usize, p: usize, n: usize| -> Option<usize> {
        let num = (z + p) as isize - k as isize;
        if num < 0 || !(num as usize).is_multiple_of(s) || num as usize / s >= n {
            None
        } else {
            Some(num as usize / s)
        }
    };
    for o in 0..oc {
        for z in 0..od {
            for y in 0..oh {
                for x in 0..ow {
                    let mut acc = params.bias[o];
                    for i in 0..ic {
                        for kz in 0..kd {
                            for ky in 0..kh {
                                for kx in 0..kw {
                                    let (Some(iz), Some(iy), Some(ix)) = (
                                        source(z, kz, sd, pd, id),
                                        source(y, ky, sh, ph, ih),
                                        source(x, kx, sw, pw, iw),
                                    ) else {
                                        continue;
                                    };
                                    let v = input[((i * id + iz) * ih + iy) * iw + ix] as i32
                                        + params.input_offset;
                                    let widx = (((i * oc + o) * kd + kz) * kh + ky) * kw + kx;
                                    acc += v * params.weights[widx] as i32;
                                }
                            }
                        }
                    }
                    let idx = ((o * od + z) * oh + y) * ow + x;
                    let t = params.requant[o].apply(acc);
                    output[idx] = finish(t, params.relu, skip_at(&skip, output, idx));
                }
            }
        }
    }
    Ok(())
}

/// Taps of output position `out` on one axis: `(k0, in0, count)`, the taps being
/// `k = k0 + t·s` reading input `in0 − t` for `t` in `0..count` (all in bounds).
#[inline(always)]
fn taps(out: usize, s: usize, p: usize, k: usize, n: usize) -> (usize, usize, usize) {
    let r = out + p;
    let (kf, inf) = (r % s, r / s);
    // Skip taps whose input index is past the end.
    let t_start = (inf + 1).saturating_sub(n);
    let t_end = if kf >= k {
        0
    } else {
        ((k - kf).div_ceil(s)).min(inf + 1)
    };
    if t_end <= t_start {
        return (0, 0, 0);
    }
    (kf + t_start * s, inf - t_start, t_end - t_start)
}

/// Optimised: the layer is split into its `sd·sh·sw` output phases (outputs with the same
/// `(z + pad) mod stride` on every axis use the same kernel taps, a sub-convolution); each
/// row of a phase gathers its inputs once into a line buffer and runs the shared
/// 2-channel × 2-position dot product (see the `line` module), with the fast
/// requantisation and a tabulated skip. Layers too large for its stack buffers fall back
/// to [`conv_transpose3d_s8_taps`].
pub fn conv_transpose3d_s8(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    skip: Skip<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_conv_transpose_shape(shape, input.len(), output.len())?;
    let checked = CheckedParams::new(shape, *params, true)?;
    check_skip(&skip, output.len())?;
    engine(
        shape,
        input,
        &checked,
        skip,
        output,
        &mut LineScratch::new(),
    );
    Ok(())
}

/// [`conv_transpose3d_s8`] with parameters whose accumulator bound was verified once
/// ([`CheckedParams`]): per call only the shape, the slice lengths and the skip multiplier
/// are validated, and the line engine works in the caller's `scratch`.
pub(crate) fn conv_transpose3d_s8_checked(
    shape: &ConvShape,
    input: &[i8],
    checked: &CheckedParams<'_>,
    skip: Skip<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> Result<(), KernelError> {
    checked.check_shape(shape, true)?;
    check_conv_transpose_shape(shape, input.len(), output.len())?;
    check_skip(&skip, output.len())?;
    engine(shape, input, checked, skip, output, scratch);
    Ok(())
}

/// The optimised engines on a validated shape, verified parameters and skip.
fn engine(
    shape: &ConvShape,
    input: &[i8],
    checked: &CheckedParams<'_>,
    skip: Skip<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) {
    let (params, bound) = (checked.params(), checked.bound());
    let layer = checked.layer();
    // The line engine, where it takes the shape and the fast requantisation fits.
    let done = super::line::transposed_fits(shape)
        && super::line::run_transposed(shape, input, params, bound, layer, &skip, output, scratch);
    if !done {
        taps_engine(shape, input, params, &skip, output);
    }
}

/// Gather variant without stack buffers: per-axis tap lists computed once per
/// plane/row/column (no divisibility test per tap), two output channels per pass sharing
/// every input load.
pub fn conv_transpose3d_s8_taps(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    skip: Skip<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_conv_transpose(shape, input.len(), params, output.len())?;
    check_skip(&skip, output.len())?;
    taps_engine(shape, input, params, &skip, output);
    Ok(())
}

fn taps_engine(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    skip: &Skip<'_>,
    output: &mut [i8],
) {
    let oc = shape.out_channels;
    let mut o = 0;
    while o + 2 <= oc {
        block::<2>(shape, input, params, skip, output, o);
        o += 2;
    }
    if o < oc {
        block::<1>(shape, input, params, skip, output, o);
    }
}

#[inline(always)]
fn block<const N: usize>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    skip: &Skip<'_>,
    output: &mut [i8],
    o0: usize,
) {
    let [id, ih, iw] = shape.in_size;
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [pd, ph, pw] = shape.padding;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let taps_len = kd * kh * kw;
    let in_plane = id * ih * iw;
    let out_plane = od * oh * ow;
    let off = params.input_offset;
    for z in 0..od {
        let (kz0, iz0, cz) = taps(z, sd, pd, kd, id);
        for y in 0..oh {
            let (ky0, iy0, cy) = taps(y, sh, ph, kh, ih);
            for x in 0..ow {
                let (kx0, ix0, cx) = taps(x, sw, pw, kw, iw);
                let mut acc: [i32; N] = core::array::from_fn(|n| params.bias[o0 + n]);
                for i in 0..ic {
                    let inp = &input[i * in_plane..(i + 1) * in_plane];
                    let wbase = (i * oc + o0) * taps_len;
                    let w = &params.weights[wbase..wbase + N * taps_len];
                    for tz in 0..cz {
                        let (iz, kz) = (iz0 - tz, kz0 + tz * sd);
                        for ty in 0..cy {
                            let (iy, ky) = (iy0 - ty, ky0 + ty * sh);
                            let irow = (iz * ih + iy) * iw;
                            let wrow = (kz * kh + ky) * kw;
                            for tx in 0..cx {
                                let v = inp[irow + ix0 - tx] as i32 + off;
                                let k = wrow + kx0 + tx * sw;
                                for n in 0..N {
                                    acc[n] += v * w[n * taps_len + k] as i32;
                                }
                            }
                        }
                    }
                }
                let pos = (z * oh + y) * ow + x;
                for (n, &a) in acc.iter().enumerate() {
                    let idx = (o0 + n) * out_plane + pos;
                    let t = params.requant[o0 + n].apply(a);
                    output[idx] = finish(t, params.relu, skip_at(skip, output, idx));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testutil::{params, Rng};
    use super::super::Operand;
    use super::*;
    use crate::config;
    use crate::requant::Requant;
    use std::vec;
    use std::vec::Vec;

    fn random_shape(rng: &mut Rng) -> ConvShape {
        let mut s = ConvShape {
            in_channels: 1 + rng.below(3),
            out_channels: 1 + rng.below(5),
            kernel: [0; 3],
            stride: [0; 3],
            padding: [0; 3],
            output_padding: [0; 3],
            in_size: [0; 3],
            out_size: [0; 3],
        };
        for a in 0..3 {
            s.kernel[a] = 1 + rng.below(4);
            s.stride[a] = 1 + rng.below(3);
            s.output_padding[a] = rng.below(s.stride[a]);
            s.in_size[a] = 1 + rng.below(5);
            let full = (s.in_size[a] - 1) * s.stride[a] + s.kernel[a] + s.output_padding[a];
            s.padding[a] = rng.below(s.kernel[a].min((full - 1) / 2 + 1));
            s.out_size[a] = full - 2 * s.padding[a];
        }
        s
    }

    fn run_all(shape: &ConvShape, rng: &mut Rng, relu: bool) {
        let (w, b, r) = params(rng, shape);
        let input = rng.i8s(shape.in_channels * shape.in_size.iter().product::<usize>());
        let p = ConvParams {
            weights: &w,
            bias: &b,
            requant: &r,
            input_offset: 0,
            relu,
        };
        let n = shape.out_channels * shape.out_size.iter().product::<usize>();
        let (mut a, mut o) = (vec![0i8; n], vec![0i8; n]);
        conv_transpose3d_s8_plain(shape, &input, &p, Skip::None, &mut a).unwrap();
        conv_transpose3d_s8(shape, &input, &p, Skip::None, &mut o).unwrap();
        assert_eq!(a, o, "no skip: {shape:?}");
        conv_transpose3d_s8_taps(shape, &input, &p, Skip::None, &mut o).unwrap();
        assert_eq!(a, o, "taps, no skip: {shape:?}");
        // Skip in its own slice, then in place: all four must agree.
        let skip_t = rng.i8s(n);
        let srq = Requant {
            multiplier: rng.range(1 << 30, (1i64 << 31) - 1) as i32,
            shift: rng.range(-3, 1) as i32,
        };
        // An unsigned cost volume as the skip adds 128 to each value first.
        let offset = [0, 128][rng.below(2)];
        let sep = Skip::Separate {
            skip: &skip_t,
            requant: srq,
            offset,
        };
        conv_transpose3d_s8_plain(shape, &input, &p, sep, &mut a).unwrap();
        conv_transpose3d_s8(shape, &input, &p, sep, &mut o).unwrap();
        assert_eq!(a, o, "separate skip: {shape:?}");
        conv_transpose3d_s8_taps(shape, &input, &p, sep, &mut o).unwrap();
        assert_eq!(a, o, "taps, separate skip: {shape:?}");
        let mut in_place_taps: Vec<i8> = skip_t.clone();
        let ip = Skip::InPlace {
            requant: srq,
            offset,
        };
        conv_transpose3d_s8_taps(shape, &input, &p, ip, &mut in_place_taps).unwrap();
        assert_eq!(a, in_place_taps, "taps, in place: {shape:?}");
        let mut in_place_plain: Vec<i8> = skip_t.clone();
        let mut in_place_opt: Vec<i8> = skip_t.clone();
        let ip = Skip::InPlace {
            requant: srq,
            offset,
        };
        conv_transpose3d_s8_plain(shape, &input, &p, ip, &mut in_place_plain).unwrap();
        conv_transpose3d_s8(shape, &input, &p, ip, &mut in_place_opt).unwrap();
        assert_eq!(a, in_place_plain, "in place plain: {shape:?}");
        assert_eq!(a, in_place_opt, "in place optimised: {shape:?}");
    }

    #[test]
    fn optimised_equals_plain_on_random_shapes() {
        let mut rng = Rng(0xabcd_ef01);
        for case in 0..250 {
            let shape = random_shape(&mut rng);
            run_all(&shape, &mut rng, case % 2 == 0);
        }
    }

    #[test]
    fn layer_too_large_for_the_phase_buffers_takes_the_taps_path() {
        let shape = ConvShape {
            in_channels: 40,
            out_channels: 3,
            kernel: [3, 3, 3],
            stride: [1, 1, 1],
            padding: [1, 1, 1],
            output_padding: [0; 3],
            in_size: [2, 3, 2],
            out_size: [2, 3, 2],
        };
        const { assert!(40 * 9 > super::super::line::MAX_V) };
        run_all(&shape, &mut Rng(77), true);
    }

    #[test]
    fn kept_weights_follow_the_layer_not_the_address() {
        // Other weights in the same memory (same address and length) under another layer
        // index must be laid out again; parameters of no layer are never kept.
        let shape = ConvShape::from(&config::LAYER_U1);
        assert!(super::super::line::transposed_fits(&shape));
        let mut rng = Rng(0x6b65);
        let input = rng.i8s(shape.in_channels * shape.in_size.iter().product::<usize>());
        let n = shape.out_channels * shape.out_size.iter().product::<usize>();
        let (mut w, b, r) = params(&mut rng, &shape);
        let (w2, _, _) = params(&mut rng, &shape);
        let at = w.as_ptr();
        let mut scratch = LineScratch::new();
        scratch.keep_weights();
        for (layer, weights) in [(Some(0), None), (Some(1), Some(&w2)), (None, None)] {
            if let Some(other) = weights {
                w.copy_from_slice(other);
            } else {
                w.iter_mut().for_each(|v| *v = v.wrapping_add(1));
            }
            assert_eq!(w.as_ptr(), at);
            let p = ConvParams {
                weights: &w,
                bias: &b,
                requant: &r,
                input_offset: 0,
                relu: true,
            };
            let bound = super::super::check_layer_bounds(&shape, &p, true).unwrap();
            let checked = CheckedParams::verified(&shape, p, true, bound, layer);
            let (mut a, mut o) = (vec![0i8; n], vec![0i8; n]);
            conv_transpose3d_s8_plain(&shape, &input, &p, Skip::None, &mut a).unwrap();
            // Twice: the second call of a layer reuses the kept layout.
            for _ in 0..2 {
                conv_transpose3d_s8_checked(
                    &shape,
                    &input,
                    &checked,
                    Skip::None,
                    &mut o,
                    &mut scratch,
                )
                .unwrap();
                assert_eq!(a, o, "layer {layer:?}");
            }
        }
        scratch.forget_weights();
    }

    #[test]
    fn optimised_equals_plain_on_u1_and_head() {
        let mut rng = Rng(3);
        run_all(&ConvShape::from(&config::LAYER_U1), &mut rng, true);
        run_all(&ConvShape::from(&config::LAYER_HEAD), &mut rng, false);
    }

    #[test]
    fn skip_changes_the_output() {
        // Guards against a skip path that is silently ignored.
        let shape = ConvShape::from(&config::LAYER_U1);
        let mut rng = Rng(11);
        let (w, b, r) = params(&mut rng, &shape);
        let input = rng.i8s(config::LAYER_U1.input_len());
        let p = ConvParams {
            weights: &w,
            bias: &b,
            requant: &r,
            input_offset: 0,
            relu: true,
        };
        let n = config::LAYER_U1.output_len();
        let (mut a, mut o) = (vec![0i8; n], vec![0i8; n]);
        conv_transpose3d_s8(&shape, &input, &p, Skip::None, &mut a).unwrap();
        let skip_t = vec![100i8; n];
        let sep = Skip::Separate {
            skip: &skip_t,
            requant: Requant::from_real(0.5).unwrap(),
            offset: 0,
        };
        conv_transpose3d_s8(&shape, &input, &p, sep, &mut o).unwrap();
        for (&x, &y) in a.iter().zip(&o) {
            assert_eq!(y as i32, (x as i32 + 50).min(127));
        }
    }

    #[test]
    fn errors() {
        let shape = ConvShape::from(&config::LAYER_U0);
        let w = vec![0i8; config::LAYER_U0.weight_len()];
        let b = vec![0i32; 8];
        let r = vec![Requant::default(); 8];
        let p = ConvParams {
            weights: &w,
            bias: &b,
            requant: &r,
            input_offset: 0,
            relu: true,
        };
        let input = vec![0i8; config::LAYER_U0.input_len()];
        let mut out = vec![0i8; config::LAYER_U0.output_len()];
        let short = vec![0i8; 5];
        let sep = Skip::Separate {
            skip: &short,
            requant: Requant::default(),
            offset: 0,
        };
        assert_eq!(
            conv_transpose3d_s8(&shape, &input, &p, sep, &mut out),
            Err(KernelError::Length {
                operand: Operand::Skip,
                expected: out.len(),
                actual: 5
            })
        );
        let mut s = shape;
        s.output_padding[1] = 2;
        assert_eq!(
            conv_transpose3d_s8(&s, &input, &p, Skip::None, &mut out),
            Err(KernelError::OutputPadding { axis: 1 })
        );
        let bad = Skip::InPlace {
            requant: Requant {
                multiplier: 1 << 30,
                shift: 30,
            },
            offset: 0,
        };
        assert!(matches!(
            conv_transpose3d_s8_plain(&shape, &input, &p, bad, &mut out),
            Err(KernelError::AccumulatorOverflow { .. })
        ));
        let w = vec![0i8; 3];
        let p = ConvParams { weights: &w, ..p };
        assert!(matches!(
            conv_transpose3d_s8(&shape, &input, &p, Skip::None, &mut out),
            Err(KernelError::Length {
                operand: Operand::Weights,
                ..
            })
        ));
    }
}
