//! The convolution engines the kernels share: the line-buffer engine of the forward and
//! transposed convolutions, and the im2col engine of the forward ones.
//!
//! For one output row (fixed plane and row of a forward convolution, or of one output phase
//! of a transposed one) the engine gathers, once, every input value the row reads into a
//! line buffer laid out `[column][v]`, where `v` runs over (input channel, plane tap, row
//! tap). The taps of one output position are then one contiguous window of the buffer
//! (`kw` consecutive columns), and the windows of neighbouring positions overlap instead of
//! being copied per position (im2col). The weights are reordered once per call (per phase)
//! to `[O][column tap][v]`, so every output is a dot product of two contiguous arrays.
//!
//! The inner loop computes 2 output channels × 2 positions at once
//! ([`crate::arch::dot2x2`]): the line holds i16 values (offset added, 0 at padding) two
//! per word, the weights are expanded once to i16 pairs with the two channels' words
//! interleaved, so per 2 taps one load of each position's word, one `LDRD` of the weights
//! and 4 `SMLAD` give 8 MACs. `v` is padded with zeros (and zero weights) to a multiple of
//! 4 so every window is an even number of words.
//!
//! With Helium (`mve`) the forward engine's line holds int8 instead (`conv_s8`): the raw
//! inputs, the zero point at padding, the offset's products folded into the biases, so that
//! `VMLADAV.S8` takes 16 MACs per instruction; the accumulators are the i16 line's exactly.
//!
//! Cost on the QEMU Cortex-M7 (EPSSN-S, whole layers including the fill and the
//! requantisation): f1 2.0, d1 2.2, u0 4.4 instructions per MAC; the inner loop alone is
//! about 1.1.
//!
//! Requantisation uses [`FastRequant`] when the layer's worst-case accumulator allows it
//! (always, for the EPSSN layers), else the exact [`Requant`] path, and a skip add reads a
//! 256-entry table of `MBQM(q_skip)`.
//!
//! The im2col engine (`im2col.rs`) is the forward convolutions' path for layers the
//! line engine does not take but whose taps of one output (`I · kd · kh · kw`) fit
//! [`COL_LEN`]: the inputs of two output positions are gathered once into i16 columns on the
//! stack (offset added, padding 0; CMSIS-NN's im2col), packed two per word, and every output
//! channel's contiguous weights `[K]` run one dot product over both positions, so each weight
//! load feeds two MACs and there is no index arithmetic in the inner loop (thumbv7em release:
//! about 2.4 instructions per MAC portable, 1.9 with the `dsp` feature's SMLAD). A 2D layer
//! runs it as a 3D one with a trivial third axis (same memory layout).
//!
//! Both engines serve the kernel files ([`super::conv2d_s8`], [`super::conv3d_s8`],
//! [`super::conv_transpose3d_s8`], [`super::head_s8`]), which import from here; nothing here
//! imports from them.
//!
//! One file per job: `requant_rows.rs` the accumulator rows and their requantisation,
//! `scratch.rs` the scratch buffers, `fill.rs` the line fills, `i16_line.rs` and `s8_line.rs`
//! the forward line engines (i16; int8 with Helium), `transposed.rs` the transposed phases,
//! `im2col.rs` the im2col engine; this file holds the shared limits and fit formulas and the
//! forward entry, [`run_conv`].

mod fill;
mod i16_line;
mod im2col;
mod requant_rows;
#[cfg(all(feature = "mve", target_arch = "arm"))]
mod s8_line;
mod scratch;
mod transposed;

use fill::*;
use i16_line::*;
use requant_rows::*;
#[cfg(all(feature = "mve", target_arch = "arm"))]
use s8_line::*;
use transposed::*;

pub(crate) use im2col::im2col_engine;
pub use im2col::COL_LEN;
pub(crate) use requant_rows::RowRequant;
pub use scratch::LineScratch;
pub(crate) use transposed::{run_transposed, transposed_fits};

use super::{finish, tap_range, ConvParams, ConvShape, Skip};
use crate::arch::RowPlan;
use crate::config::{LayerKind, LayerShape};
use crate::requant::{Apply, Requant};

/// Words (two i16 entries each) of the line buffer: the most any layer of the build's spec
/// needs ([`layers_needs`], the fit formulas of [`conv_fits`] and [`transposed_fits`]
/// over the compiled shapes), so every layer takes the engine; rounded up to whole 1024 words
/// (4 KiB), the steps the scratch has been sized and budgeted in. EPSSN-S: d1's lines (72
/// entries × 17 columns) are the longest at 612 words, its scratch stays at the 1024 it was
/// measured with; EPSSN-P: d1's 72 × 33, 1188 words, 2048.
pub const LINE_WORDS: usize = SPEC_NEEDS.line_words.div_ceil(1024) * 1024;
/// Words (two i16 weights each) of the reordered weights of one call or phase: the 3456
/// EPSSN-S and EPSSN-P were measured with, or more when a layer of the build's spec needs more
/// ([`layers_needs`]: a wider bottleneck), so that no layer falls to the row engine.
pub const WEIGHT_WORDS: usize = at_least(3456, SPEC_NEEDS.weight_words);
/// Most line entries per column (`v`, padded to a multiple of 4): 256, or the build's spec's
/// most ([`layers_needs`]) when that is more.
pub const MAX_V: usize = at_least(256, SPEC_NEEDS.v);

/// What the build's spec's layers need of the buffers.
const SPEC_NEEDS: BufferNeeds = layers_needs(&crate::config::LAYERS);
/// Largest column stride of a transposed convolution the engine takes.
pub const MAX_STRIDE: usize = 8;
/// Most output channels with prepared [`FastRequant`]s.
pub const MAX_FAST_CHANNELS: usize = 32;

/// `x` rounded up to a multiple of 4.
#[inline(always)]
pub(crate) const fn up4(x: usize) -> usize {
    x.div_ceil(4) * 4
}

/// Longest input row the line engine reads (the zero row stands in for padding rows).
pub const MAX_ROW: usize = 256;
static ZEROS: [i8; MAX_ROW] = [0; MAX_ROW];

/// Most taps per channel (`na · nb`) [`fill_taps`] tabulates: 3 × 3 forward and 2 × 2
/// transposed ones in the EPSSN layers.
#[cfg(all(feature = "dsp", target_arch = "arm"))]
const MAX_ROW_TAPS: usize = crate::arch::ChannelTaps::MAX_TAPS;

/// Whether a line's entries go channel-minor, `v = (tap, i)` (two channels of one tap fill a
/// word, and the Helium fill computes their rows' addresses itself: `arch::fill_channel_pairs`),
/// rather than channel-major, `v = (i, tap)`: with Helium, for an even number of `channels`
/// whose `taps` per channel [`fill_taps`] tabulates. Each engine lays its weights out in the
/// order its lines are filled in, so this one function decides both.
#[inline(always)]
const fn channel_minor(channels: usize, taps: usize) -> bool {
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    {
        channels >= 2 && channels.is_multiple_of(2) && taps <= MAX_ROW_TAPS
    }
    #[cfg(not(all(feature = "mve", target_arch = "arm")))]
    {
        let _ = (channels, taps);
        false
    }
}

/// Line words of a row of `cols` columns of `vp` entries (two i16 per word). This and the
/// helpers below are the fit formulas, shared by the run-time fit checks and the const
/// [`LINE_WORDS`]; the checks evaluate them in the order they always had (`vp` and the
/// columns first), so the compiled kernels are unchanged.
#[inline(always)]
const fn line_words(vp: usize, cols: usize) -> usize {
    vp * cols / 2
}

/// Line entries per column of a forward convolution, `v` = (input channel, plane tap, row
/// tap), padded to a multiple of 4.
#[inline(always)]
const fn conv_v(shape: &ConvShape) -> usize {
    let [kd, kh, _] = shape.kernel;
    up4(shape.in_channels * kd * kh)
}

/// Input columns one output row of a forward convolution reads.
#[inline(always)]
const fn conv_cols(shape: &ConvShape) -> usize {
    (shape.out_size[2] - 1) * shape.stride[2] + shape.kernel[2]
}

/// Line words a forward convolution fills per output row.
pub(crate) const fn conv_line_words(shape: &ConvShape) -> usize {
    line_words(conv_v(shape), conv_cols(shape))
}

/// Whether the forward convolution fits the engine's buffers.
pub(crate) fn conv_fits(shape: &ConvShape) -> bool {
    let kw = shape.kernel[2];
    let vp = conv_v(shape);
    let cols = conv_cols(shape);
    vp <= MAX_V
        && shape.in_size[2] <= MAX_ROW
        && line_words(vp, cols) <= LINE_WORDS
        && 2 * kw * vp / 2 <= WEIGHT_WORDS
        && shape.out_channels.div_ceil(conv_group(kw * vp / 2)) <= MAX_GROUPS
        && shape.out_channels <= MAX_FAST_CHANNELS
}

/// Most weight groups of a forward convolution: each further group refills the lines.
const MAX_GROUPS: usize = 2;

/// Output channels per weight group: an even number whose `n` words each fit
/// [`WEIGHT_WORDS`]. More than two groups refill the lines too often to beat im2col.
fn conv_group(n: usize) -> usize {
    (WEIGHT_WORDS / n.max(1) / 2 * 2).max(2)
}

/// [`conv`] with the fast requantisation, when the worst-case accumulator `bound` allows it;
/// false (nothing written) otherwise, for the caller's engine that takes any requantisation.
/// The line engine is built for the fast requantisation alone: a second build of it for the
/// exact one would cost flash the firmware does not have.
pub(crate) fn run_conv(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    (bound, layer): (i64, Option<usize>),
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> bool {
    let oc = shape.out_channels;
    let Some(f) = fast_requants(params.requant, bound) else {
        return false;
    };
    // With Helium the int8 line takes every shape it can, and the caller's im2col engine
    // the others: one forward line engine in the flash, not two.
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    return conv_s8(shape, input, params, layer, &f[..oc], output, scratch);
    #[cfg(not(all(feature = "mve", target_arch = "arm")))]
    {
        conv(shape, input, params, layer, &f[..oc], output, scratch);
        true
    }
}

/// A 2D shape as the line engine runs it: axes [H, W, 1] as [1, H, W], so that the engine's
/// rows run along W (same memory layout).
pub(crate) const fn line_shape(shape: &ConvShape) -> ConvShape {
    ConvShape {
        kernel: [1, shape.kernel[0], shape.kernel[1]],
        stride: [1, shape.stride[0], shape.stride[1]],
        padding: [0, shape.padding[0], shape.padding[1]],
        in_size: [1, shape.in_size[0], shape.in_size[1]],
        out_size: [1, shape.out_size[0], shape.out_size[1]],
        ..*shape
    }
}

/// What one layer needs of the line engine's buffers, by the fit formulas of the engine its
/// kind runs on: 2D layers as [`super::conv2d_s8`] hands them to the engine, every transposed
/// layer (the head too, though its kernel has its own buffers: an upper bound).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct BufferNeeds {
    /// Line words ([`conv_line_words`], [`transposed_line_words`]).
    pub line_words: usize,
    /// Laid-out weight words ([`conv_weight_words`], [`transposed_weight_words`]).
    pub weight_words: usize,
    /// Line entries per column (`v`, [`conv_v`], [`transposed_v`]).
    pub v: usize,
}

/// [`BufferNeeds`] of one layer.
const fn layer_needs(layer: &LayerShape) -> BufferNeeds {
    let shape = ConvShape::of(layer);
    match layer.kind {
        LayerKind::Conv2d => forward_needs(&line_shape(&shape)),
        LayerKind::Conv3d => forward_needs(&shape),
        LayerKind::ConvTranspose3d => {
            let v = transposed_v(&shape);
            BufferNeeds {
                line_words: transposed_line_words(&shape),
                weight_words: transposed_weight_words(&shape, v),
                v,
            }
        }
    }
}

/// [`BufferNeeds`] of a forward convolution.
const fn forward_needs(shape: &ConvShape) -> BufferNeeds {
    BufferNeeds {
        line_words: conv_line_words(shape),
        weight_words: conv_weight_words(shape),
        v: conv_v(shape),
    }
}

/// The most of each need over `layers`.
pub(crate) const fn layers_needs(layers: &[LayerShape]) -> BufferNeeds {
    let mut most = BufferNeeds {
        line_words: 0,
        weight_words: 0,
        v: 0,
    };
    let mut i = 0;
    while i < layers.len() {
        let n = layer_needs(&layers[i]);
        most.line_words = at_least(most.line_words, n.line_words);
        most.weight_words = at_least(most.weight_words, n.weight_words);
        most.v = at_least(most.v, n.v);
        i += 1;
    }
    most
}

/// The larger of `floor` and `need` (`max` is not a const fn).
const fn at_least(floor: usize, need: usize) -> usize {
    if need > floor {
        need
    } else {
        floor
    }
}

/// Weight words a forward convolution's engines need for its output channels to go in at most
/// [`MAX_GROUPS`] groups on the i16 line ([`conv_group`]), and for the int8 line's one slot of
/// folded biases and 16-byte weight blocks (`conv_s8`, Helium builds).
const fn conv_weight_words(shape: &ConvShape) -> usize {
    let (vp, kw, oc) = (conv_v(shape), shape.kernel[2], shape.out_channels);
    let per_channel = kw * vp / 2;
    let per_group = oc.div_ceil(MAX_GROUPS).div_ceil(2) * 2;
    let i16_line = per_group * per_channel;
    let pairs = oc.div_ceil(2);
    let s8_slot = 2 * pairs + pairs * (kw * vp).div_ceil(16) * 32 / 4;
    at_least(i16_line, s8_slot)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config;

    #[test]
    fn line_words_come_from_the_layers_fit_formulas() {
        // Every layer of the build's spec takes the engine its kind runs on (the head, the last
        // layer, has its own kernel).
        for l in &config::LAYERS[..config::LAYER_COUNT - 1] {
            let shape = ConvShape::of(l);
            let fits = match l.kind {
                LayerKind::Conv2d => conv_fits(&line_shape(&shape)),
                LayerKind::Conv3d => conv_fits(&shape),
                LayerKind::ConvTranspose3d => transposed_fits(&shape),
            };
            assert!(fits, "{} does not take the line engine", l.name);
        }
        // The buffer is the longest lines rounded up to whole 1024 words, no more.
        let need = layers_needs(&config::LAYERS).line_words;
        assert!(
            need <= LINE_WORDS && LINE_WORDS < need + 1024,
            "{need} {LINE_WORDS}"
        );
        // In EPSSN-S and EPSSN-P d1 has the longest lines (S: 612 words, so 1024 as measured);
        // a wider bottleneck (EPSSN-PW) has m0's.
        let d1 = conv_line_words(&ConvShape::of(&config::LAYER_D1));
        if config::LAYER_M0.in_channels <= 16 {
            assert_eq!(need, d1);
        }
        assert_eq!(LINE_WORDS, need.div_ceil(1024) * 1024);
    }

    #[test]
    fn weight_buffer_grows_only_for_layers_that_need_it() {
        let needs = layers_needs(&config::LAYERS);
        let (need, v) = (needs.weight_words, needs.v);
        assert_eq!(WEIGHT_WORDS, need.max(3456));
        assert_eq!(MAX_V, v.max(256));
        if config::LAYER_M0.in_channels <= 16 {
            // EPSSN-S and EPSSN-P keep the sizes their RAM and instructions were measured with:
            // m0 (16 channels in and out) needs the most, 1744 words (its int8 slot), v 144.
            assert_eq!((WEIGHT_WORDS, MAX_V), (3456, 256));
            assert_eq!(need, conv_weight_words(&ConvShape::of(&config::LAYER_M0)));
        } else {
            // A 32-channel m0 (EPSSN-PW): v = 32 · 9 = 288, and 16 channel pairs of 54 int8
            // blocks each (plus their biases) for its one int8 slot; the i16 line's two groups
            // of 16 channels need 6912.
            let m0 = ConvShape::of(&config::LAYER_M0);
            assert_eq!((conv_v(&m0), conv_weight_words(&m0)), (288, 32 + 16 * 432));
            assert_eq!((WEIGHT_WORDS, MAX_V), (6944, 288));
        }
    }
}
