//! int8 kernels of the network, each as a plain reference (`*_plain`, straightforward loops)
//! beside the optimised version that inference uses. Both compute exactly the arithmetic of
//! `docs/QUANTISATION.md`; unit tests compare them element by element.
//!
//! Every kernel validates its shape and all slice lengths first and returns a
//! [`KernelError`] instead of panicking. It also checks, from the weights, biases and
//! multipliers, that no int32 accumulator and no requantisation left shift can overflow for
//! any int8 input (see [`accumulator_bound`]); after validation the arithmetic is exact.
//!
//! With the `dsp` cargo feature the convolution inner loops use `SMLAD`/`SXTB16`
//! ([`crate::arch`]); the results are the same bits (checked on QEMU Cortex-M7 by
//! `qemu-check/`).
//!
//! Tensor layouts are channel-major: 2D `[C][H][W]`, 3D `[C][D][H][W]`; weights `[O][I][k…]`
//! for convolutions and `[I][O][k…]` for transposed convolutions.

pub mod conv2d_s8;
pub mod conv3d_s8;
pub mod conv_transpose3d_s8;
pub mod cost_volume_s8;
pub mod head_s8;
mod line;
pub mod soft_argmax_s8;

pub use line::LineScratch;

use crate::config::LayerShape;
use crate::requant::Requant;

/// Which operand of a kernel a length error is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Operand {
    /// The input activation.
    Input,
    /// The output activation.
    Output,
    /// The weights.
    Weights,
    /// The biases.
    Bias,
    /// The per-channel requantisation multipliers.
    Requant,
    /// The skip tensor.
    Skip,
    /// The reference view's features.
    Reference,
    /// Source view `k` (0-based among the sources) features.
    Source(u8),
    /// Source view `k`'s warp table.
    Warp(u8),
    /// The soft-argmax logits.
    Logits,
    /// The depth map.
    Depth,
}

/// What a kernel found wrong with its arguments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KernelError {
    /// A slice does not have the length the shape implies.
    Length {
        /// Which slice.
        operand: Operand,
        /// Length the shape implies.
        expected: usize,
        /// Length given.
        actual: usize,
    },
    /// A size product does not fit `usize`.
    SizeOverflow,
    /// Zero kernel size or stride on an axis.
    ZeroKernelOrStride {
        /// Axis 0..3.
        axis: u8,
    },
    /// The padded input is smaller than the kernel on an axis.
    KernelLargerThanInput {
        /// Axis 0..3.
        axis: u8,
    },
    /// The shape's output size is not what the input size, kernel, stride and padding give.
    OutputSize {
        /// Axis 0..3.
        axis: u8,
        /// Size implied by the rest of the shape.
        expected: usize,
        /// Size in the shape.
        actual: usize,
    },
    /// A 2D kernel got a shape whose third axis is not trivial (size, kernel and stride 1,
    /// no padding).
    NotTwoDimensional,
    /// Output padding must be smaller than the stride (as in PyTorch).
    OutputPadding {
        /// Axis 0..3.
        axis: u8,
    },
    /// A requantisation shift outside `MIN_SHIFT..=MAX_SHIFT`.
    Shift {
        /// Output channel (or 0 for a per-tensor multiplier).
        channel: usize,
        /// The shift.
        shift: i32,
    },
    /// An accumulator of this channel could leave int32, or overflow in the requantisation
    /// left shift, for some int8 input.
    AccumulatorOverflow {
        /// Output channel (or 0 for a per-tensor multiplier).
        channel: usize,
        /// Worst-case |accumulator| over all int8 inputs.
        bound: i64,
    },
    /// The cost volume takes one or two source views.
    ViewCount {
        /// Source views given.
        sources: usize,
    },
    /// A visible warp entry points outside the source feature columns, or has a fraction
    /// above 256.
    WarpEntry {
        /// Source view (0-based among the sources).
        source: u8,
        /// Entry index `plane × width + column`.
        index: usize,
    },
    /// `EXP[0]` is zero, so the softmax denominator could be zero.
    ExpTable,
    /// Soft-argmax over more than 256 or zero bins (the u32 sums of the contract need ≤ 256).
    RangeBins {
        /// Bins given.
        bins: usize,
    },
    /// `r_min16 + (bins − 1 + 2K) · step16` does not fit U16F16.
    DepthOverflow,
    /// The soft-argmax end-bin offset `K` is above [`soft_argmax_s8::MAX_END_OFFSET`].
    EndOffset {
        /// The offset given.
        offset: u16,
    },
    /// The soft-argmax's no-return fraction is above 1 (`2^16` in Q16).
    NoReturnMass {
        /// The fraction given, Q16.
        mass16: u32,
    },
    /// The fused head needs kernel == stride, no padding and one output channel.
    NotStreamableHead,
    /// [`CheckedParams`] used with a kernel size, channel counts or direction other than the
    /// ones their bound was verified for.
    ParamsShape,
    /// `input_offset` (or a skip offset) outside `−MAX_INPUT_OFFSET..=MAX_INPUT_OFFSET`.
    InputOffset {
        /// The offset given.
        offset: i32,
    },
    /// A cost-volume zero point other than 0 or −128
    /// ([`cost_volume_s8::CostRequant::ZERO_POINTS`]).
    CostZeroPoint {
        /// The zero point given.
        zero_point: i32,
    },
    /// A negative mean-channel multiplier (the contract's are ≥ 0).
    NegativeMultiplier {
        /// The multiplier given.
        multiplier: i32,
    },
    /// More mean channels than cost-volume channels.
    MeanChannels {
        /// Mean channels given.
        mean_channels: usize,
        /// Channels of the cost volume.
        channels: usize,
    },
}

/// Largest `|input_offset|` the kernels accept (the contract uses 0 and 128).
pub const MAX_INPUT_OFFSET: i32 = 255;

/// Shape of a convolution or transposed convolution, axes `[D, H, W]`; a 2D layer `[H][W]`
/// uses axes 0 and 1 and has size, kernel and stride 1 on axis 2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConvShape {
    /// Input channels.
    pub in_channels: usize,
    /// Output channels.
    pub out_channels: usize,
    /// Kernel size per axis.
    pub kernel: [usize; 3],
    /// Stride per axis.
    pub stride: [usize; 3],
    /// Padding per axis (both sides).
    pub padding: [usize; 3],
    /// Output padding per axis (transposed convolutions only; ignored otherwise).
    pub output_padding: [usize; 3],
    /// Input size per axis.
    pub in_size: [usize; 3],
    /// Output size per axis.
    pub out_size: [usize; 3],
}

impl ConvShape {
    /// The shape of a compiled layer; a const fn, so that the kernels can size their buffers
    /// from the layers at compile time.
    pub const fn of(l: &LayerShape) -> Self {
        const fn u(a: [u8; 3]) -> [usize; 3] {
            [a[0] as usize, a[1] as usize, a[2] as usize]
        }
        ConvShape {
            in_channels: l.in_channels,
            out_channels: l.out_channels,
            kernel: u(l.kernel),
            stride: u(l.stride),
            padding: u(l.padding),
            output_padding: u(l.output_padding),
            in_size: l.in_size,
            out_size: l.out_size,
        }
    }
}

impl From<&LayerShape> for ConvShape {
    fn from(l: &LayerShape) -> Self {
        Self::of(l)
    }
}

/// Weights, biases and requantisation of one convolution layer.
#[derive(Clone, Copy, Debug)]
pub struct ConvParams<'a> {
    /// int8 weights, `[O][I][k…]` (convolution) or `[I][O][k…]` (transposed).
    pub weights: &'a [i8],
    /// int32 biases `[O]`.
    pub bias: &'a [i32],
    /// Per-output-channel multipliers `[O]`.
    pub requant: &'a [Requant],
    /// Added to every input value (128 for the network input, else 0); padding adds nothing.
    pub input_offset: i32,
    /// Fused ReLU.
    pub relu: bool,
}

/// The tensor added after the ReLU of a transposed convolution (QUANTISATION.md "Skip add").
#[derive(Clone, Copy, Debug)]
pub enum Skip<'a> {
    /// No skip: `y = clamp(t)`.
    None,
    /// Skip tensor in its own slice, same layout and length as the output.
    Separate {
        /// The skip tensor.
        skip: &'a [i8],
        /// `m_skip = s_skip / s_y`.
        requant: Requant,
        /// Added to each skip value before its requantisation: 128 for an unsigned cost
        /// volume (zero point −128), else 0.
        offset: i32,
    },
    /// The output slice holds the skip tensor on entry and is overwritten voxel by voxel
    /// (each output voxel reads only its own skip value, so this is exact).
    InPlace {
        /// `m_skip = s_skip / s_y`.
        requant: Requant,
        /// Added to each skip value before its requantisation (as in [`Skip::Separate`]).
        offset: i32,
    },
}

impl Skip<'_> {
    /// The skip multiplier and offset, or `None` without a skip.
    pub fn requant(&self) -> Option<(Requant, i32)> {
        match *self {
            Skip::None => None,
            Skip::Separate {
                requant, offset, ..
            }
            | Skip::InPlace { requant, offset } => Some((requant, offset)),
        }
    }
}

/// Worst-case `|accumulator|`, over every int8 input and every partial sum, of one output
/// channel whose taps have `weights` and whose bias is `bias`, with inputs `q + input_offset`
/// for `q` in `−128..=127` (padded taps contribute 0, which the bound also covers).
///
/// The quantiser asserts this is `< 2^31` and that [`Requant::fits`] it; the kernels check
/// the same and refuse layers that could overflow.
pub fn accumulator_bound(
    weights: impl IntoIterator<Item = i8>,
    bias: i32,
    input_offset: i32,
) -> i64 {
    let lo = -128 + input_offset as i64;
    let hi = 127 + input_offset as i64;
    let (mut max, mut min) = (bias as i64, bias as i64);
    for w in weights {
        let (a, b) = (w as i64 * lo, w as i64 * hi);
        // Each term lies in [min(a, b, 0), max(a, b, 0)], so every partial sum lies in
        // [min, max] whatever the order and the padding.
        max = max.saturating_add(a.max(b).max(0));
        min = min.saturating_add(a.min(b).min(0));
    }
    max.saturating_abs().max(min.saturating_abs())
}

/// The worst-case accumulator of each output channel of a convolution (`[O][I][k…]` weights)
/// or, with `transposed`, of a transposed convolution (`[I][O][k…]`), checked against int32
/// and the channel's left shift. Returns the largest bound.
pub fn check_layer_bounds(
    shape: &ConvShape,
    params: &ConvParams<'_>,
    transposed: bool,
) -> Result<i64, KernelError> {
    if !(-MAX_INPUT_OFFSET..=MAX_INPUT_OFFSET).contains(&params.input_offset) {
        return Err(KernelError::InputOffset {
            offset: params.input_offset,
        });
    }
    let taps = mul3(shape.kernel)?;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    expect(Operand::Bias, oc, params.bias.len())?;
    expect(Operand::Requant, oc, params.requant.len())?;
    let per_out = ic.checked_mul(taps).ok_or(KernelError::SizeOverflow)?;
    expect(
        Operand::Weights,
        per_out.checked_mul(oc).ok_or(KernelError::SizeOverflow)?,
        params.weights.len(),
    )?;
    let mut worst = 0;
    for (o, (&bias, &rq)) in params.bias.iter().zip(params.requant).enumerate() {
        if !rq.shift_in_range() {
            return Err(KernelError::Shift {
                channel: o,
                shift: rq.shift,
            });
        }
        let bound = if transposed {
            let w = params.weights;
            accumulator_bound(
                (0..ic).flat_map(|i| {
                    let start = (i * oc + o) * taps;
                    w[start..start + taps].iter().copied()
                }),
                bias,
                params.input_offset,
            )
        } else {
            let start = o * per_out;
            accumulator_bound(
                params.weights[start..start + per_out].iter().copied(),
                bias,
                params.input_offset,
            )
        };
        if !rq.fits(bound) {
            return Err(KernelError::AccumulatorOverflow { channel: o, bound });
        }
        worst = worst.max(bound);
    }
    Ok(worst)
}

/// Layer parameters whose worst-case accumulator ([`check_layer_bounds`]) has been verified
/// once, for a kernel size, channel counts and direction: the `*_checked` kernel entries take
/// them and only validate the shape and the activation lengths per call (the weight walk of
/// the bound costs about as much as a small layer's arithmetic, and the streamed model calls
/// its kernels thousands of times per depth map).
#[derive(Clone, Copy, Debug)]
pub struct CheckedParams<'a> {
    params: ConvParams<'a>,
    in_channels: usize,
    out_channels: usize,
    kernel: [usize; 3],
    transposed: bool,
    bound: i64,
    /// Which of the model's layers these are (its index), `None` for parameters a caller
    /// verified ([`CheckedParams::new`]): the identity under which the line engine keeps
    /// laid-out weights ([`LineScratch::keep_weights`]). An index into the model's immutable
    /// layer table, unlike the weights' address, cannot stand for other weights.
    layer: Option<usize>,
}

impl<'a> CheckedParams<'a> {
    /// Verifies `params` for convolutions (or, with `transposed`, transposed convolutions)
    /// with `shape`'s kernel and channel counts.
    pub fn new(
        shape: &ConvShape,
        params: ConvParams<'a>,
        transposed: bool,
    ) -> Result<Self, KernelError> {
        let bound = check_layer_bounds(shape, &params, transposed)?;
        Ok(Self::verified(shape, params, transposed, bound, None))
    }

    /// Parameters whose bound the caller has already established with
    /// [`check_layer_bounds`] on the same `params`, kernel, channels and direction (the
    /// model does it once in `Model::from_blob`, and its parameters are immutable); `layer`:
    /// the model's index of the layer, `None` for any other caller.
    pub(crate) fn verified(
        shape: &ConvShape,
        params: ConvParams<'a>,
        transposed: bool,
        bound: i64,
        layer: Option<usize>,
    ) -> Self {
        Self {
            params,
            in_channels: shape.in_channels,
            out_channels: shape.out_channels,
            kernel: shape.kernel,
            transposed,
            bound,
            layer,
        }
    }

    /// The model's index of the layer these parameters are, if they are one's.
    pub(crate) fn layer(&self) -> Option<usize> {
        self.layer
    }

    /// The parameters.
    pub fn params(&self) -> &ConvParams<'a> {
        &self.params
    }

    /// The largest worst-case accumulator over the output channels.
    pub fn bound(&self) -> i64 {
        self.bound
    }

    /// Refuses a shape the parameters were not verified for.
    pub(crate) fn check_shape(
        &self,
        shape: &ConvShape,
        transposed: bool,
    ) -> Result<(), KernelError> {
        if shape.in_channels == self.in_channels
            && shape.out_channels == self.out_channels
            && shape.kernel == self.kernel
            && transposed == self.transposed
        {
            Ok(())
        } else {
            Err(KernelError::ParamsShape)
        }
    }
}

/// Checks a per-tensor skip multiplier and offset against int8 skip values.
pub(crate) fn check_skip(skip: &Skip<'_>, output_len: usize) -> Result<(), KernelError> {
    if let Skip::Separate { skip, .. } = *skip {
        expect(Operand::Skip, output_len, skip.len())?;
    }
    let Some((rq, offset)) = skip.requant() else {
        return Ok(());
    };
    if !(-MAX_INPUT_OFFSET..=MAX_INPUT_OFFSET).contains(&offset) {
        return Err(KernelError::InputOffset { offset });
    }
    if !rq.shift_in_range() {
        return Err(KernelError::Shift {
            channel: 0,
            shift: rq.shift,
        });
    }
    let bound = skip_value_bound(offset);
    if !rq.fits(bound) {
        return Err(KernelError::AccumulatorOverflow { channel: 0, bound });
    }
    Ok(())
}

/// Largest `|q + offset|` of an int8 skip value `q` with `offset` added (what the skip
/// multiplier's left shift must survive).
pub(crate) const fn skip_value_bound(offset: i32) -> i64 {
    128 + offset.unsigned_abs() as i64
}

/// `t` → output value: ReLU, then the skip add (`u`, the requantised skip value) and the
/// int8 clamp.
#[inline(always)]
pub(crate) fn finish(t: i32, relu: bool, u: Option<i32>) -> i8 {
    let t = if relu { t.max(0) } else { t };
    let y = match u {
        // Saturation only acts far outside int8, so it cannot change the clamped result.
        Some(u) => t.saturating_add(u),
        None => t,
    };
    y.clamp(-128, 127) as i8
}

/// Valid taps `lo..hi` of output position `out` on one axis: `0 <= out·s + k − p < n`.
#[inline(always)]
pub(crate) fn tap_range(out: usize, s: usize, p: usize, k: usize, n: usize) -> (usize, usize) {
    (
        p.saturating_sub(out * s),
        k.min((n + p).saturating_sub(out * s)),
    )
}

pub(crate) fn expect(operand: Operand, expected: usize, actual: usize) -> Result<(), KernelError> {
    if expected == actual {
        Ok(())
    } else {
        Err(KernelError::Length {
            operand,
            expected,
            actual,
        })
    }
}

pub(crate) fn mul3(a: [usize; 3]) -> Result<usize, KernelError> {
    a[0].checked_mul(a[1])
        .and_then(|x| x.checked_mul(a[2]))
        .ok_or(KernelError::SizeOverflow)
}

/// Validates a forward convolution's shape and every slice, which guarantees that all
/// indices the kernels form are in bounds; returns the worst-case accumulator.
pub(crate) fn check_conv(
    shape: &ConvShape,
    input_len: usize,
    params: &ConvParams<'_>,
    output_len: usize,
) -> Result<i64, KernelError> {
    check_conv_shape(shape, input_len, output_len)?;
    check_layer_bounds(shape, params, false)
}

/// The shape and activation-length part of [`check_conv`] (no walk over the weights).
pub(crate) fn check_conv_shape(
    shape: &ConvShape,
    input_len: usize,
    output_len: usize,
) -> Result<(), KernelError> {
    for axis in 0..3 {
        let (k, s, p) = (shape.kernel[axis], shape.stride[axis], shape.padding[axis]);
        if k == 0 || s == 0 {
            return Err(KernelError::ZeroKernelOrStride { axis: axis as u8 });
        }
        let padded = shape.in_size[axis]
            .checked_add(p.checked_mul(2).ok_or(KernelError::SizeOverflow)?)
            .ok_or(KernelError::SizeOverflow)?;
        if padded < k {
            return Err(KernelError::KernelLargerThanInput { axis: axis as u8 });
        }
        let expected = (padded - k) / s + 1;
        if expected != shape.out_size[axis] {
            return Err(KernelError::OutputSize {
                axis: axis as u8,
                expected,
                actual: shape.out_size[axis],
            });
        }
    }
    check_lengths(shape, input_len, output_len)
}

/// Validates a transposed convolution's shape and every slice; returns the worst-case
/// accumulator.
pub(crate) fn check_conv_transpose(
    shape: &ConvShape,
    input_len: usize,
    params: &ConvParams<'_>,
    output_len: usize,
) -> Result<i64, KernelError> {
    check_conv_transpose_shape(shape, input_len, output_len)?;
    check_layer_bounds(shape, params, true)
}

/// The shape and activation-length part of [`check_conv_transpose`].
pub(crate) fn check_conv_transpose_shape(
    shape: &ConvShape,
    input_len: usize,
    output_len: usize,
) -> Result<(), KernelError> {
    for axis in 0..3 {
        let (k, s, p, op) = (
            shape.kernel[axis],
            shape.stride[axis],
            shape.padding[axis],
            shape.output_padding[axis],
        );
        if k == 0 || s == 0 {
            return Err(KernelError::ZeroKernelOrStride { axis: axis as u8 });
        }
        if op >= s {
            return Err(KernelError::OutputPadding { axis: axis as u8 });
        }
        // (in − 1)·s + k + op − 2p, which must be positive.
        let full = shape.in_size[axis]
            .checked_sub(1)
            .and_then(|x| x.checked_mul(s))
            .and_then(|x| x.checked_add(k))
            .and_then(|x| x.checked_add(op))
            .ok_or(KernelError::SizeOverflow)?;
        let expected = full
            .checked_sub(p.checked_mul(2).ok_or(KernelError::SizeOverflow)?)
            .filter(|&x| x > 0)
            .ok_or(KernelError::KernelLargerThanInput { axis: axis as u8 })?;
        if expected != shape.out_size[axis] {
            return Err(KernelError::OutputSize {
                axis: axis as u8,
                expected,
                actual: shape.out_size[axis],
            });
        }
    }
    check_lengths(shape, input_len, output_len)
}

fn check_lengths(
    shape: &ConvShape,
    input_len: usize,
    output_len: usize,
) -> Result<(), KernelError> {
    let inl = mul3(shape.in_size)?
        .checked_mul(shape.in_channels)
        .ok_or(KernelError::SizeOverflow)?;
    let outl = mul3(shape.out_size)?
        .checked_mul(shape.out_channels)
        .ok_or(KernelError::SizeOverflow)?;
    expect(Operand::Input, inl, input_len)?;
    expect(Operand::Output, outl, output_len)
}

/// Small deterministic generator for the kernels' unit tests.
#[cfg(test)]
pub(crate) mod testutil {
    use super::soft_argmax_s8::SoftArgmaxParams;
    use super::*;
    use crate::config;
    use fixed::types::U16F16;

    /// `EXP[d] = round(65535 · exp(−d · scale))`.
    pub fn exp_table(scale: f64) -> [u16; 256] {
        core::array::from_fn(|d| libm::round(65535.0 * libm::exp(-(d as f64) * scale)) as u16)
    }

    /// Soft-argmax parameters of the compiled depth grid with end bins reaching `end_offset`
    /// steps beyond the window.
    pub fn soft_params(exp: &[u16; 256], end_offset: u16) -> SoftArgmaxParams<'_> {
        let step = (config::R_MAX_M - config::R_MIN_M) / (config::DEPTH_RANGE_BINS - 1) as f64;
        let base = config::R_MIN_M - end_offset as f64 * step;
        SoftArgmaxParams {
            exp,
            r_min16: U16F16::from_bits(libm::round(base * 65536.0) as u32),
            step16: U16F16::from_bits(libm::round(step * 65536.0) as u32),
            end_offset,
            no_return16: 0,
        }
    }

    pub struct Rng(pub u64);

    impl Rng {
        pub fn next(&mut self) -> u64 {
            // xorshift64*
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
        pub fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
        pub fn range(&mut self, lo: i64, hi: i64) -> i64 {
            lo + (self.next() % (hi - lo + 1) as u64) as i64
        }
        pub fn i8s(&mut self, n: usize) -> std::vec::Vec<i8> {
            (0..n).map(|_| self.range(-128, 127) as i8).collect()
        }
        /// A multiplier in [2^30, 2^31) with a shift in a realistic range.
        pub fn requant(&mut self) -> Requant {
            Requant {
                multiplier: self.range(1 << 30, (1i64 << 31) - 1) as i32,
                shift: self.range(-12, 0) as i32,
            }
        }
    }

    /// Random biases, weights and multipliers for `shape`, with weights ±127.
    pub fn params(
        rng: &mut Rng,
        shape: &ConvShape,
    ) -> (
        std::vec::Vec<i8>,
        std::vec::Vec<i32>,
        std::vec::Vec<Requant>,
    ) {
        let n = shape.in_channels * shape.out_channels * shape.kernel.iter().product::<usize>();
        let w = (0..n).map(|_| rng.range(-127, 127) as i8).collect();
        let b = (0..shape.out_channels)
            .map(|_| rng.range(-100_000, 100_000) as i32)
            .collect();
        let r = (0..shape.out_channels).map(|_| rng.requant()).collect();
        (w, b, r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bound_is_attained_by_extreme_inputs() {
        let w = [3i8, -5, 127, -128];
        // With offset 0: max = 7 + 3·127 + (−5)(−128) + 127·127 + (−128)(−128).
        let max = 7 + 3 * 127 + 5 * 128 + 127 * 127 + 128 * 128;
        let min = 7 - 3 * 128 - 5 * 127 - 127 * 128 - 128 * 127;
        assert_eq!(accumulator_bound(w, 7, 0), (max as i64).max(-min as i64));
        // With offset 128 inputs are 0..=255: the negative weights give the minimum.
        assert_eq!(accumulator_bound(w, 0, 128), (5 + 128) * 255);
    }

    #[test]
    fn layer_bounds_refuse_overflowing_shift() {
        let shape = ConvShape {
            in_channels: 1,
            out_channels: 1,
            kernel: [1, 1, 1],
            stride: [1, 1, 1],
            padding: [0; 3],
            output_padding: [0; 3],
            in_size: [1, 1, 1],
            out_size: [1, 1, 1],
        };
        let rq = [Requant {
            multiplier: 1 << 30,
            shift: 20,
        }];
        let p = ConvParams {
            weights: &[127],
            bias: &[0],
            requant: &rq,
            input_offset: 0,
            relu: false,
        };
        assert!(matches!(
            check_layer_bounds(&shape, &p, false),
            Err(KernelError::AccumulatorOverflow { channel: 0, .. })
        ));
        let rq = [Requant {
            multiplier: 1 << 30,
            shift: 10,
        }];
        let p = ConvParams { requant: &rq, ..p };
        assert_eq!(check_layer_bounds(&shape, &p, false), Ok(128 * 127));
    }
}

/// Degenerate and hostile arguments give errors or empty results, never a panic.
#[cfg(test)]
mod no_panic {
    use super::conv2d_s8::*;
    use super::conv3d_s8::*;
    use super::conv_transpose3d_s8::*;
    use super::cost_volume_s8::*;
    use super::soft_argmax_s8::*;
    use super::testutil::Rng;
    use super::*;
    use fixed::types::U16F16;
    use std::vec;

    #[test]
    fn random_hostile_arguments_never_panic() {
        let mut rng = Rng(0xdead_beef);
        let buf_i8 = vec![1i8; 4096];
        let bias = vec![i32::MAX; 64];
        let rq_hostile = [
            Requant {
                multiplier: i32::MIN,
                shift: 31,
            },
            Requant {
                multiplier: i32::MAX,
                shift: -40,
            },
            Requant::default(),
        ];
        let exp = [65535u16; 256];
        for _ in 0..5000 {
            let dim = |r: &mut Rng| [r.below(4), r.below(4), r.below(4)];
            let shape = ConvShape {
                in_channels: rng.below(3),
                out_channels: rng.below(3),
                kernel: dim(&mut rng),
                stride: dim(&mut rng),
                padding: dim(&mut rng),
                output_padding: dim(&mut rng),
                in_size: dim(&mut rng),
                out_size: dim(&mut rng),
            };
            let rq = [rq_hostile[rng.below(3)]; 64];
            let params = ConvParams {
                weights: &buf_i8[..rng.below(200)],
                bias: &bias[..rng.below(4)],
                requant: &rq[..rng.below(4)],
                input_offset: [0, 128, i32::MAX, i32::MIN][rng.below(4)],
                relu: true,
            };
            let input = &buf_i8[..rng.below(300)];
            let mut out = vec![0i8; rng.below(300)];
            let _ = conv2d_s8(&shape, input, &params, &mut out);
            let _ = conv2d_s8_plain(&shape, input, &params, &mut out);
            let _ = conv3d_s8(&shape, input, &params, &mut out);
            let _ = conv3d_s8_plain(&shape, input, &params, &mut out);
            let skip = Skip::InPlace {
                requant: rq[0],
                offset: [0, 128, i32::MIN][rng.below(3)],
            };
            let _ = conv_transpose3d_s8(&shape, input, &params, skip, &mut out);
            let _ = conv_transpose3d_s8_plain(&shape, input, &params, Skip::None, &mut out);
            let sp = SoftArgmaxParams {
                exp: &exp,
                r_min16: U16F16::from_bits(rng.next() as u32),
                step16: U16F16::from_bits(rng.next() as u32 >> rng.below(32)),
                end_offset: rng.below(300) as u16,
                no_return16: rng.next() as u32 >> rng.below(32),
            };
            let mut depth = vec![U16F16::ZERO; rng.below(20)];
            let _ = head_soft_argmax_s8(&shape, input, &params, &sp, &mut depth);
            let ss = SoftArgmaxShape {
                rows: rng.below(3),
                bins: rng.below(4),
                columns: rng.below(3),
            };
            let _ = soft_argmax_s8(&ss, input, &sp, &mut depth);
            let _ = soft_argmax_s8_plain(&ss, input, &sp, &mut depth);
            let cs = CostShape {
                channels: rng.below(3),
                planes: rng.below(3),
                height: rng.below(3),
                width: rng.below(3),
                mean_channels: rng.below(4),
            };
            let table = [crate::geometry::WarpEntry {
                column: rng.below(4) as u8,
                fraction: rng.below(300) as u16,
                visible: true,
            }; 16];
            let views = [SourceView {
                features: input,
                warp: &table[..rng.below(16)],
            }; 3];
            let nv = rng.below(4);
            let cq = CostRequant {
                requant: rq[0],
                mean: rq[rng.below(rq.len())],
                zero_point: [0, -128, 5][rng.below(3)],
            };
            let _ = cost_volume_s8(&cs, input, &views[..nv], cq, &mut out);
            let _ = cost_volume_s8_plain(&cs, input, &views[..nv], cq, &mut out);
        }
    }

    #[test]
    fn zero_sized_shapes_are_fine() {
        let cs = CostShape {
            channels: 2,
            planes: 0,
            height: 3,
            width: 4,
            mean_channels: 1,
        };
        let f = [0i8; 24];
        let views = [SourceView {
            features: &f,
            warp: &[],
        }];
        assert_eq!(
            cost_volume_s8(&cs, &f, &views, CostRequant::default(), &mut []),
            Ok(())
        );
        let ss = SoftArgmaxShape {
            rows: 2,
            bins: 3,
            columns: 0,
        };
        let exp = [1u16; 256];
        let sp = SoftArgmaxParams {
            exp: &exp,
            r_min16: U16F16::ZERO,
            step16: U16F16::ZERO,
            end_offset: 0,
            no_return16: 0,
        };
        assert_eq!(soft_argmax_s8(&ss, &[], &sp, &mut []), Ok(()));
    }
}
