//! 2D convolution, int8 in/out, int32 accumulate, per-channel requantisation, fused ReLU.
//!
//! Input `[I][H][W]` i8 (each value plus `input_offset`), weights `[O][I][kh][kw]` i8,
//! bias `[O]` i32, multipliers `[O]`, output `[O][OH][OW]` i8. The shape uses axes 0 (H) and
//! 1 (W); axis 2 must be trivial.
//!
//! MACs: `O · OH · OW · I · kh · kw` (padded taps skipped, so slightly fewer at the border).

use super::line::{conv_fits, im2col_engine, line_shape, run_conv, COL_LEN};
use super::{
    check_conv, check_conv_shape, finish, CheckedParams, ConvParams, ConvShape, KernelError,
    LineScratch,
};

fn check_2d(shape: &ConvShape) -> Result<(), KernelError> {
    if shape.kernel[2] != 1
        || shape.stride[2] != 1
        || shape.padding[2] != 0
        || shape.in_size[2] != 1
        || shape.out_size[2] != 1
    {
        return Err(KernelError::NotTwoDimensional);
    }
    Ok(())
}

/// Plain reference: straightforward loops with a bounds test per tap.
pub fn conv2d_s8_plain(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_2d(shape)?;
    check_conv(shape, input.len(), params, output.len())?;
    let [ih, iw, _] = shape.in_size;
    let [oh, ow, _] = shape.out_size;
    let [kh, kw, _] = shape.kernel;
    let [sh, sw, _] = shape.stride;
    let [ph, pw, _] = shape.padding;
    let ic = shape.in_channels;
    for o in 0..shape.out_channels {
        for y in 0..oh {
            for x in 0..ow {
                let mut acc = params.bias[o];
                for i in 0..ic {
                    for ky in 0..kh {
                        for kx in 0..kw {
                            let iy = (y * sh + ky) as isize - ph as isize;
                            let ix = (x * sw + kx) as isize - pw as isize;
                            if iy < 0 || ix < 0 || iy >= ih as isize || ix >= iw as isize {
                                continue;
                            }
                            let v = input[(i * ih + iy as usize) * iw + ix as usize] as i32
                                + params.input_offset;
                            let w = params.weights[((o * ic + i) * kh + ky) * kw + kx] as i32;
                            acc += v * w;
                        }
                    }
                }
                let t = params.requant[o].apply(acc);
                output[(o * oh + y) * ow + x] = finish(t, params.relu, None);
            }
        }
    }
    Ok(())
}

/// Optimised: the line-buffer engine of the `line` module when the layer fits its stack
/// buffers (all EPSSN layers do). Otherwise, when the taps of one output (`I · kh · kw`) fit
/// [`super::conv3d_s8::COL_LEN`], the im2col engine (of the `line` module, which
/// [`super::conv3d_s8::conv3d_s8`] uses too; a 2D layer is a 3D one with a trivial third
/// axis, same memory layout): two output positions per dot product over packed i16 columns.
/// Otherwise the row-blocked engine (`conv2d_s8_rows`).
pub fn conv2d_s8(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_2d(shape)?;
    check_conv_shape(shape, input.len(), output.len())?;
    let checked = CheckedParams::new(shape, *params, false)?;
    engine(shape, input, &checked, output, &mut LineScratch::new());
    Ok(())
}

/// [`conv2d_s8`] with parameters whose accumulator bound was verified once
/// ([`CheckedParams`]): per call only the shape and the slice lengths are validated, and the
/// line engine works in the caller's `scratch`.
pub(crate) fn conv2d_s8_checked(
    shape: &ConvShape,
    input: &[i8],
    checked: &CheckedParams<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> Result<(), KernelError> {
    check_2d(shape)?;
    checked.check_shape(shape, false)?;
    check_conv_shape(shape, input.len(), output.len())?;
    engine(shape, input, checked, output, scratch);
    Ok(())
}

/// The optimised engines on a validated shape and verified parameters.
fn engine(
    shape: &ConvShape,
    input: &[i8],
    checked: &CheckedParams<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) {
    let (params, bound) = (checked.params(), checked.bound());
    let s3 = line_shape(shape);
    // The line engine where it takes the shape and the fast requantisation fits.
    if conv_fits(&s3)
        && run_conv(
            &s3,
            input,
            params,
            (bound, checked.layer()),
            output,
            scratch,
        )
    {
        return;
    }
    if shape.in_channels * shape.kernel[0] * shape.kernel[1] <= COL_LEN {
        // Axes [H, W, 1] used as [D, H, W]: rows of length 1 in the gather, same sums.
        im2col_engine(shape, input, params, output);
    } else {
        rows(shape, input, params, output);
    }
}

/// Row-blocked variant: two output channels per pass share every input load; the valid tap
/// range of each output position is computed once per row/column (no per-tap bounds test,
/// the interior and the border run the same branch-free loops over contiguous kernel rows).
/// No stack buffer.
///
/// Public, hidden from the docs, only for the reference crate's bit-exactness tests, which
/// compare it with the plain reference on shapes the default kernel sends elsewhere.
#[doc(hidden)]
pub fn conv2d_s8_rows(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_2d(shape)?;
    check_conv(shape, input.len(), params, output.len())?;
    rows(shape, input, params, output);
    Ok(())
}

fn rows(shape: &ConvShape, input: &[i8], params: &ConvParams<'_>, output: &mut [i8]) {
    let oc = shape.out_channels;
    let mut o = 0;
    while o + 2 <= oc {
        block::<2>(shape, input, params, output, o);
        o += 2;
    }
    if o < oc {
        block::<1>(shape, input, params, output, o);
    }
}

/// Output channels `o0 .. o0 + N` (validated shape: every slice below is in bounds).
#[inline(always)]
fn block<const N: usize>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
    o0: usize,
) {
    let [ih, iw, _] = shape.in_size;
    let [oh, ow, _] = shape.out_size;
    let [kh, kw, _] = shape.kernel;
    let [sh, sw, _] = shape.stride;
    let [ph, pw, _] = shape.padding;
    let ic = shape.in_channels;
    let per_out = ic * kh * kw;
    let off = params.input_offset;
    let wts: [&[i8]; N] =
        core::array::from_fn(|n| &params.weights[(o0 + n) * per_out..(o0 + n + 1) * per_out]);
    for y in 0..oh {
        // Taps ky with 0 <= y·sh + ky − ph < ih.
        let ky_lo = ph.saturating_sub(y * sh);
        let ky_hi = kh.min((ih + ph).saturating_sub(y * sh));
        for x in 0..ow {
            let kx_lo = pw.saturating_sub(x * sw);
            let kx_hi = kw.min((iw + pw).saturating_sub(x * sw));
            let mut acc: [i32; N] = core::array::from_fn(|n| params.bias[o0 + n]);
            if kx_lo < kx_hi {
                let len = kx_hi - kx_lo;
                let ix0 = x * sw + kx_lo - pw;
                for i in 0..ic {
                    for ky in ky_lo..ky_hi {
                        let iy = y * sh + ky - ph;
                        let row = &input[(i * ih + iy) * iw + ix0..][..len];
                        let wo = (i * kh + ky) * kw + kx_lo;
                        let wr: [&[i8]; N] = core::array::from_fn(|n| &wts[n][wo..wo + len]);
                        for (t, &xv) in row.iter().enumerate() {
                            let v = xv as i32 + off;
                            for n in 0..N {
                                acc[n] += v * wr[n][t] as i32;
                            }
                        }
                    }
                }
            }
            for n in 0..N {
                let t = params.requant[o0 + n].apply(acc[n]);
                output[((o0 + n) * oh + y) * ow + x] = finish(t, params.relu, None);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testutil::{params, Rng};
    use super::*;
    use crate::config;
    use std::vec;

    fn random_shape(rng: &mut Rng) -> ConvShape {
        let kernel = [1 + rng.below(4), 1 + rng.below(4), 1];
        let stride = [1 + rng.below(3), 1 + rng.below(3), 1];
        let padding = [rng.below(kernel[0]), rng.below(kernel[1]), 0];
        let in_size = [kernel[0] + rng.below(9), kernel[1] + rng.below(9), 1];
        let out = |a: usize| (in_size[a] + 2 * padding[a] - kernel[a]) / stride[a] + 1;
        ConvShape {
            in_channels: 1 + rng.below(4),
            out_channels: 1 + rng.below(5),
            kernel,
            stride,
            padding,
            output_padding: [0; 3],
            in_size,
            out_size: [out(0), out(1), 1],
        }
    }

    #[test]
    fn optimised_equals_plain_on_random_shapes() {
        let mut rng = Rng(0x1234_5678);
        for case in 0..300 {
            let shape = random_shape(&mut rng);
            let (w, b, r) = params(&mut rng, &shape);
            let input = rng.i8s(shape.in_channels * shape.in_size.iter().product::<usize>());
            let p = ConvParams {
                weights: &w,
                bias: &b,
                requant: &r,
                input_offset: if case % 3 == 0 { 128 } else { 0 },
                relu: case % 2 == 0,
            };
            let n = shape.out_channels * shape.out_size.iter().product::<usize>();
            let (mut a, mut o) = (vec![0i8; n], vec![0i8; n]);
            conv2d_s8_plain(&shape, &input, &p, &mut a).unwrap();
            conv2d_s8(&shape, &input, &p, &mut o).unwrap();
            assert_eq!(a, o, "case {case}: {shape:?}");
            conv2d_s8_rows(&shape, &input, &p, &mut o).unwrap();
            assert_eq!(a, o, "rows, case {case}: {shape:?}");
        }
    }

    #[test]
    fn optimised_equals_plain_on_f0_and_f3() {
        let mut rng = Rng(99);
        for layer in [&config::LAYER_F0, &config::LAYER_F3] {
            let shape = ConvShape::from(layer);
            let (w, b, r) = params(&mut rng, &shape);
            let input = rng.i8s(layer.input_len());
            let p = ConvParams {
                weights: &w,
                bias: &b,
                requant: &r,
                input_offset: 128,
                relu: layer.relu,
            };
            let (mut a, mut o) = (vec![0i8; layer.output_len()], vec![1i8; layer.output_len()]);
            conv2d_s8_plain(&shape, &input, &p, &mut a).unwrap();
            conv2d_s8(&shape, &input, &p, &mut o).unwrap();
            assert_eq!(a, o);
            conv2d_s8_rows(&shape, &input, &p, &mut o).unwrap();
            assert_eq!(a, o);
            // Not a constant output: the comparison means something.
            assert!(a.iter().any(|&v| v != a[0]));
        }
    }

    #[test]
    fn bad_lengths_and_shapes_are_errors() {
        let shape = ConvShape::from(&config::LAYER_F1);
        let w = vec![0i8; config::LAYER_F1.weight_len()];
        let b = vec![0i32; 8];
        let r = vec![crate::requant::Requant::default(); 8];
        let p = ConvParams {
            weights: &w,
            bias: &b,
            requant: &r,
            input_offset: 0,
            relu: true,
        };
        let input = vec![0i8; config::LAYER_F1.input_len()];
        let mut out = vec![0i8; config::LAYER_F1.output_len()];
        assert!(conv2d_s8(&shape, &input, &p, &mut out).is_ok());
        assert_eq!(
            conv2d_s8(&shape, &input[1..], &p, &mut out),
            Err(KernelError::Length {
                operand: super::super::Operand::Input,
                expected: input.len(),
                actual: input.len() - 1
            })
        );
        let p2 = ConvParams { bias: &b[1..], ..p };
        assert!(matches!(
            conv2d_s8_plain(&shape, &input, &p2, &mut out),
            Err(KernelError::Length { .. })
        ));
        let mut s = shape;
        s.out_size[0] += 1;
        assert!(matches!(
            conv2d_s8(&s, &input, &p, &mut out),
            Err(KernelError::OutputSize { axis: 0, .. })
        ));
        let mut s = shape;
        s.kernel[2] = 2;
        assert_eq!(
            conv2d_s8(&s, &input, &p, &mut out),
            Err(KernelError::NotTwoDimensional)
        );
        let mut s = shape;
        s.stride[1] = 0;
        assert!(conv2d_s8(&s, &input, &p, &mut out).is_err());
    }
}
