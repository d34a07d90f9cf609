//! 3D convolution, int8 in/out, int32 accumulate, per-channel requantisation, fused ReLU.
//!
//! Input `[I][D][H][W]` i8 (each value plus `input_offset`), weights `[O][I][kd][kh][kw]` i8,
//! bias `[O]` i32, multipliers `[O]`, output `[O][OD][OH][OW]` i8.
//!
//! MACs: `O · OD · OH · OW · I · kd · kh · kw` (padded taps skipped).

pub use super::line::COL_LEN;
use super::line::{conv_fits, im2col_engine, run_conv};
use super::{
    check_conv, check_conv_shape, finish, tap_range, CheckedParams, ConvParams, ConvShape,
    KernelError, LineScratch,
};

/// Plain reference: straightforward loops with a bounds test per tap.
pub fn conv3d_s8_plain(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_conv(shape, input.len(), params, output.len())?;
    let [id, ih, iw] = shape.in_size;
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [pd, ph, pw] = shape.padding;
    let ic = shape.in_channels;
    for o in 0..shape.out_channels {
        for z in 0..od {
            for y in 0..oh {
                for x in 0..ow {
                    let mut acc = params.bias[o];
                    for i in 0..ic {
                        for kz in 0..kd {
                            for ky in 0..kh {
                                for kx in 0..kw {
                                    let iz = (z * sd + kz) as isize - pd as isize;
                                    let iy = (y * sh + ky) as isize - ph as isize;
                                    let ix = (x * sw + kx) as isize - pw as isize;
                                    if iz < 0
                                        || iy < 0
                                        || ix < 0
                                        || iz >= id as isize
                                        || iy >= ih as isize
                                        || ix >= iw as isize
                                    {
                                        continue;
                                    }
                                    let idx = ((i * id + iz as usize) * ih + iy as usize) * iw
                                        + ix as usize;
                                    let v = input[idx] as i32 + params.input_offset;
                                    let widx = (((o * ic + i) * kd + kz) * kh + ky) * kw + kx;
                                    acc += v * params.weights[widx] as i32;
                                }
                            }
                        }
                    }
                    let t = params.requant[o].apply(acc);
                    output[((o * od + z) * oh + y) * ow + x] = finish(t, params.relu, None);
                }
            }
        }
    }
    Ok(())
}

/// Optimised. Layers that fit its stack buffers run the line-buffer engine (the `line`
/// module: each output row's inputs gathered once, windows shared by neighbouring
/// positions, 2 channels × 2 positions per inner loop, fast requantisation). Otherwise,
/// when the taps of one output (`I · kd · kh · kw`) fit [`COL_LEN`], the im2col engine
/// (also in the `line` module): the inputs of two output positions are gathered once into
/// i16 columns on the stack (offset added, padding 0; CMSIS-NN's im2col), packed two per
/// word, and every output channel's contiguous weights `[K]` run one dot product over both
/// positions, so each weight load feeds two MACs and there is no index arithmetic in the
/// inner loop (thumbv7em release: about 2.4 instructions per MAC portable, 1.9 with the
/// `dsp` feature's SMLAD).
/// Larger layers fall back to the row-blocked engine (`conv3d_s8_rows`).
pub fn conv3d_s8(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_conv_shape(shape, input.len(), output.len())?;
    let checked = CheckedParams::new(shape, *params, false)?;
    engine(shape, input, &checked, output, &mut LineScratch::new());
    Ok(())
}

/// [`conv3d_s8`] with parameters whose accumulator bound was verified once
/// ([`CheckedParams`]): per call only the shape and the slice lengths are validated, and the
/// line engine works in the caller's `scratch`.
pub(crate) fn conv3d_s8_checked(
    shape: &ConvShape,
    input: &[i8],
    checked: &CheckedParams<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> Result<(), KernelError> {
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
    // Engine selection, made here only: the first engine that takes the shape runs; one that
    // declines writes nothing and the next is tried.
    //
    //   build          takes the shape when                 engine, inner loop
    //   mve (M55)      `conv_fits`, fast requantisation,    int8 line (`line::conv_s8`),
    //                  and `conv_s8`'s own limits: even     `VMLADAV.S8`, 16 MACs an instruction
    //                  output width, one weight group,
    //                  few taps per channel, int8 zero
    //                  point
    //   dsp (M7)       `conv_fits`, fast requantisation     i16 line (`line::conv`), `SMLAD`
    //                                                       2 channels × 2 positions, 8 MACs per
    //                                                       `LDRD` and 4 `SMLAD`; tap-table fill
    //   portable       `conv_fits`, fast requantisation     i16 line, the same loop in plain Rust
    //   any            `I · kd · kh · kw <= COL_LEN`        im2col: two positions' i16 columns
    //                                                       on the stack (`SMLAD` with `dsp`)
    //   any            otherwise                            `rows_engine`: no buffer at all
    //
    // Why: the line gathers each input once per output row and neighbouring positions share
    // their windows, so it costs the fewest instructions per MAC; the EPSSN forward layers all
    // pass `conv_fits` (`line`'s tests check the spec's shapes). The line is built for the
    // fast requantisation alone, and a Helium build holds only the int8 line, since the flash
    // has room for one forward line engine: a shape the line declines falls to im2col, which
    // needs one output's taps on the stack (`COL_LEN`, 4 KiB); larger ones take the row
    // engine, slower but bufferless.
    // `dsp` against portable is chosen inside `crate::arch`, not here.
    if conv_fits(shape)
        && run_conv(
            shape,
            input,
            params,
            (bound, checked.layer()),
            output,
            scratch,
        )
    {
        return;
    }
    if shape.in_channels * shape.kernel.iter().product::<usize>() <= COL_LEN {
        im2col_engine(shape, input, params, output);
    } else {
        rows_engine(shape, input, params, output);
    }
}

/// The row-blocked variant: two output channels per pass share every input load; valid
/// tap ranges are computed once per plane/row/column, so the interior and the border run
/// the same branch-free loops over contiguous kernel rows. No stack buffer; used for layers
/// whose taps exceed [`COL_LEN`].
///
/// Public, hidden from the docs, only for the reference crate's bit-exactness tests, which
/// compare it with the plain reference on shapes the default kernel sends elsewhere.
#[doc(hidden)]
pub fn conv3d_s8_rows(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check_conv(shape, input.len(), params, output.len())?;
    rows_engine(shape, input, params, output);
    Ok(())
}

fn rows_engine(shape: &ConvShape, input: &[i8], params: &ConvParams<'_>, output: &mut [i8]) {
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

#[inline(always)]
fn block<const N: usize>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
    o0: usize,
) {
    let [id, ih, iw] = shape.in_size;
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [pd, ph, pw] = shape.padding;
    let ic = shape.in_channels;
    let per_out = ic * kd * kh * kw;
    let off = params.input_offset;
    let wts: [&[i8]; N] =
        core::array::from_fn(|n| &params.weights[(o0 + n) * per_out..(o0 + n + 1) * per_out]);
    let out_plane = od * oh * ow;
    for z in 0..od {
        let (kz_lo, kz_hi) = tap_range(z, sd, pd, kd, id);
        for y in 0..oh {
            let (ky_lo, ky_hi) = tap_range(y, sh, ph, kh, ih);
            for x in 0..ow {
                let (kx_lo, kx_hi) = tap_range(x, sw, pw, kw, iw);
                let mut acc: [i32; N] = core::array::from_fn(|n| params.bias[o0 + n]);
                if kx_lo < kx_hi {
                    let len = kx_hi - kx_lo;
                    let ix0 = x * sw + kx_lo - pw;
                    for i in 0..ic {
                        for kz in kz_lo..kz_hi {
                            let iz = z * sd + kz - pd;
                            for ky in ky_lo..ky_hi {
                                let iy = y * sh + ky - ph;
                                let row = &input[((i * id + iz) * ih + iy) * iw + ix0..][..len];
                                let wo = ((i * kd + kz) * kh + ky) * kw + kx_lo;
                                let wr: [&[i8]; N] =
                                    core::array::from_fn(|n| &wts[n][wo..wo + len]);
                                for (t, &xv) in row.iter().enumerate() {
                                    let v = xv as i32 + off;
                                    for n in 0..N {
                                        acc[n] += v * wr[n][t] as i32;
                                    }
                                }
                            }
                        }
                    }
                }
                let pos = (z * oh + y) * ow + x;
                for n in 0..N {
                    let t = params.requant[o0 + n].apply(acc[n]);
                    output[(o0 + n) * out_plane + pos] = finish(t, params.relu, None);
                }
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

    #[test]
    fn optimised_equals_plain_on_random_shapes() {
        let mut rng = Rng(0xfeed_beef);
        for case in 0..200 {
            let kernel = [1 + rng.below(3), 1 + rng.below(3), 1 + rng.below(4)];
            let stride = [1 + rng.below(2), 1 + rng.below(3), 1 + rng.below(2)];
            let padding = [
                rng.below(kernel[0]),
                rng.below(kernel[1]),
                rng.below(kernel[2]),
            ];
            let in_size = [
                kernel[0] + rng.below(5),
                kernel[1] + rng.below(6),
                kernel[2] + rng.below(5),
            ];
            let out = |a: usize| (in_size[a] + 2 * padding[a] - kernel[a]) / stride[a] + 1;
            let shape = ConvShape {
                in_channels: 1 + rng.below(3),
                out_channels: 1 + rng.below(5),
                kernel,
                stride,
                padding,
                output_padding: [0; 3],
                in_size,
                out_size: [out(0), out(1), out(2)],
            };
            let (w, b, r) = params(&mut rng, &shape);
            let input = rng.i8s(shape.in_channels * in_size.iter().product::<usize>());
            let p = ConvParams {
                weights: &w,
                bias: &b,
                requant: &r,
                input_offset: if case % 4 == 0 { 128 } else { 0 },
                relu: case % 2 == 1,
            };
            let n = shape.out_channels * shape.out_size.iter().product::<usize>();
            let (mut a, mut o) = (vec![0i8; n], vec![0i8; n]);
            conv3d_s8_plain(&shape, &input, &p, &mut a).unwrap();
            conv3d_s8(&shape, &input, &p, &mut o).unwrap();
            assert_eq!(a, o, "case {case}: {shape:?}");
            conv3d_s8_rows(&shape, &input, &p, &mut o).unwrap();
            assert_eq!(a, o, "rows, case {case}: {shape:?}");
        }
    }

    #[test]
    fn optimised_equals_plain_on_d2() {
        let mut rng = Rng(7);
        let layer = &config::LAYER_D2;
        let shape = ConvShape::from(layer);
        let (w, b, r) = params(&mut rng, &shape);
        let input = rng.i8s(layer.input_len());
        let p = ConvParams {
            weights: &w,
            bias: &b,
            requant: &r,
            input_offset: 0,
            relu: false,
        };
        let (mut a, mut o) = (vec![0i8; layer.output_len()], vec![1i8; layer.output_len()]);
        conv3d_s8_plain(&shape, &input, &p, &mut a).unwrap();
        conv3d_s8(&shape, &input, &p, &mut o).unwrap();
        assert_eq!(a, o);
        assert!(a.iter().any(|&v| v != a[0]));
        conv3d_s8_rows(&shape, &input, &p, &mut o).unwrap();
        assert_eq!(a, o);
    }

    #[test]
    fn line_engine_channel_groups_equal_plain() {
        // d2 (2 groups of 8 channels) and a layer whose last group is odd (8 + 3).
        let mut rng = Rng(0x6d30);
        let odd = ConvShape {
            in_channels: 40,
            out_channels: 11,
            kernel: [1, 2, 3],
            stride: [1, 1, 2],
            padding: [0, 1, 1],
            output_padding: [0; 3],
            in_size: [2, 3, 7],
            out_size: [2, 4, 4],
        };
        for (k, shape) in [ConvShape::from(&config::LAYER_D2), odd].iter().enumerate() {
            assert!(super::super::line::conv_fits(shape));
            let (w, b, r) = params(&mut rng, shape);
            let input = rng.i8s(shape.in_channels * shape.in_size.iter().product::<usize>());
            let p = ConvParams {
                weights: &w,
                bias: &b,
                requant: &r,
                input_offset: if k == 1 { 128 } else { 0 },
                relu: k == 0,
            };
            let n = shape.out_channels * shape.out_size.iter().product::<usize>();
            let (mut a, mut o) = (vec![0i8; n], vec![1i8; n]);
            conv3d_s8_plain(shape, &input, &p, &mut a).unwrap();
            conv3d_s8(shape, &input, &p, &mut o).unwrap();
            assert_eq!(a, o, "{shape:?}");
            assert!(a.iter().any(|&v| v != a[0]));
        }
    }

    #[test]
    fn layer_too_large_for_the_column_buffer_takes_the_row_path() {
        let mut rng = Rng(21);
        let shape = ConvShape {
            in_channels: 40,
            out_channels: 3,
            kernel: [3, 3, 3],
            stride: [1, 2, 1],
            padding: [1, 1, 1],
            output_padding: [0; 3],
            in_size: [3, 4, 5],
            out_size: [3, 2, 5],
        };
        // Too many taps for the line engine (v = 40·9 > MAX_V) and for the columns.
        const { assert!(40 * 27 > COL_LEN && 40 * 9 > super::super::line::MAX_V) };
        let (w, b, r) = params(&mut rng, &shape);
        let input = rng.i8s(40 * 60);
        let p = ConvParams {
            weights: &w,
            bias: &b,
            requant: &r,
            input_offset: 0,
            relu: false,
        };
        let (mut a, mut o) = (vec![0i8; 90], vec![0i8; 90]);
        conv3d_s8_plain(&shape, &input, &p, &mut a).unwrap();
        conv3d_s8(&shape, &input, &p, &mut o).unwrap();
        assert_eq!(a, o);
    }

    #[test]
    fn bad_output_length_is_an_error() {
        let layer = &config::LAYER_M0;
        let shape = ConvShape::from(layer);
        let w = vec![1i8; layer.weight_len()];
        let b = vec![0i32; 16];
        let r = vec![crate::requant::Requant::default(); 16];
        let p = ConvParams {
            weights: &w,
            bias: &b,
            requant: &r,
            input_offset: 0,
            relu: true,
        };
        let input = vec![0i8; layer.input_len()];
        let mut out = vec![0i8; layer.output_len() + 1];
        assert!(matches!(
            conv3d_s8(&shape, &input, &p, &mut out),
            Err(KernelError::Length {
                operand: super::super::Operand::Output,
                ..
            })
        ));
    }
}
