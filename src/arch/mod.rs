//! The instruction sets of the convolution inner loops, chosen here and nowhere else.
//!
//! Every kernel loop that has an instruction-set version is one function of this module
//! ([`dot2x2`], [`RowPlan`], [`requant_row_s8`], [`pack_rows`], …), called by the kernels;
//! it checks its slices, hands the shape to the build's backend, and runs the portable loop
//! (plain Rust with the instructions' exact semantics) for what the backend leaves. Three
//! builds, one table of operations each (`isa` below), so dispatch runs one way (kernels →
//! `arch` → backend) and the choice is made once:
//!
//! | build | backend of the inner loops |
//! |---|---|
//! | portable (host, or no `dsp` feature) | none: every operation declines, the portable loops run |
//! | `dsp` on ARMv7E-M (Cortex-M4/M7) | `dsp.rs`: `SMLAD` / `SXTB16` / `SMMULR` loops in `asm!` |
//! | `mve` on a Cortex-M55/M85 | `mve.rs` (Helium) where it has a loop, `dsp.rs` for the cost-volume columns, `pack_strided`'s last words, `pack_rows`'s last entries |
//!
//! The single instructions (`SMLAD`, `SXTB16`, `SMMULR`) are one macro in `insn.rs`; the
//! types both backends read (a line fill's rows, a channel's requantisation words) are in
//! `rows.rs`. The backends never import each other; the asm is the only `unsafe` in the
//! crate (the intrinsics in `core::arch::arm` are unstable). The results are the same bits in
//! every build (checked on QEMU Cortex-M7 and Cortex-M55 by `qemu-check/`).

mod insn;
mod rows;

#[cfg(all(feature = "dsp", target_arch = "arm"))]
mod dsp;
#[cfg(all(feature = "mve", target_arch = "arm"))]
mod mve;

pub use insn::{pack, smlad, smmulr, sxtb16, sxtb16_ror8};
/// The Helium-only engines of the int8 line (`kernels::line`'s `conv_s8`, the head's int8
/// gather) and its channel-minor fill, which have no portable twin: the kernels call them only in `mve` builds.
#[cfg(all(feature = "mve", target_arch = "arm"))]
pub use mve::{fill_bytes, fill_channel_pairs, gather_bytes, PairRows, PairRowsS8, GATHER_ENTRIES};
pub use rows::RowWords;
use rows::{row_fits, Combine};
#[cfg(all(feature = "dsp", target_arch = "arm"))]
pub use rows::{ChannelTaps, LineRows};

/// The operations of a build: for each, the backend function that runs it, in one uniform
/// form (what it computes: the public function of the same name; `None`, `false` or 0 values
/// done where it declines, and the portable loop runs).
#[cfg(all(feature = "mve", target_arch = "arm"))]
mod isa {
    pub(super) use super::dsp::{cost_column3, pack_strided, table_column};
    pub(super) use super::mve::ops::{
        dot2x2, pack_strided_quads, pairs, requant_max_row, requant_row, requant_rows, row_pairs,
        run_channel_pairs, run_pairs, Pairs,
    };
    pub(super) use super::mve::{exp_sums, pack_line_quads, table_columns4, table_columns8};

    /// `arch::pack_rows`: Helium's blocks of four, the `dsp` loop's last entries.
    #[inline(always)]
    pub(super) fn pack_rows(
        dst: &mut [u32],
        stride: usize,
        ab: (&[i8], &[i8]),
        o: (i16, i16),
    ) -> bool {
        super::dsp::pack_rows(dst, stride, ab, o, super::mve::pack_row_quads)
    }
}

#[cfg(all(feature = "dsp", not(feature = "mve"), target_arch = "arm"))]
mod isa {
    pub(super) use super::declined::{
        pack_strided_quads, pairs, requant_rows, run_channel_pairs, run_pairs, table_columns4,
        table_columns8, Pairs,
    };
    pub(super) use super::dsp::{
        cost_column3, dot2x2, exp_sums, pack_line_quads, pack_strided, requant_max_row,
        requant_row, row_pairs, table_column,
    };

    /// `arch::pack_rows`: the `dsp` loops, blocks of four and last entries.
    #[inline(always)]
    pub(super) fn pack_rows(
        dst: &mut [u32],
        stride: usize,
        ab: (&[i8], &[i8]),
        o: (i16, i16),
    ) -> bool {
        super::dsp::pack_rows(dst, stride, ab, o, super::dsp::pack_row_quads)
    }
}

#[cfg(not(all(feature = "dsp", target_arch = "arm")))]
use declined as isa;

/// The operations a build has no instruction-set loop for: each declines, so the portable
/// loop runs (every one in portable builds; the Helium-only ones in `dsp` builds).
#[allow(dead_code)]
mod declined {
    /// No pair loop planned.
    #[derive(Clone, Copy, Debug)]
    pub(super) struct Pairs;

    macro_rules! declines {
        ($($name:ident($($ty:ty),*) -> $ret:ty = $value:expr;)*) => {$(
            #[inline(always)]
            #[allow(clippy::too_many_arguments)]
            pub(super) fn $name($(_: $ty),*) -> $ret {
                $value
            }
        )*};
    }

    declines! {
        dot2x2(&[u32], usize, &[u32], usize, [i32; 4]) -> Option<[i32; 4]> = None;
        pairs(usize, usize, usize, usize) -> Pairs = Pairs;
        run_pairs(&Pairs, &[u32], &[u32], [i32; 2], (&mut [i32], &mut [i32])) -> Option<bool> = None;
        run_channel_pairs(
            &Pairs, &[u32], (&[u32], usize), &[[i32; 2]], &mut [i32], (usize, usize)
        ) -> Option<bool> = None;
        row_pairs(
            &[u32], (usize, usize, usize), &[u32], [i32; 2], (&mut [i32], &mut [i32], usize)
        ) -> bool = false;
        requant_rows(
            &[i32], &mut [i8], &[[i32; 5]], (usize, usize), bool, Option<&[i32; 256]>
        ) -> bool = false;
        pack_strided_quads(
            &mut [u32], usize, (&[i8], &[i8], usize), usize, (i16, i16)
        ) -> usize = 0;
        pack_strided(&mut [u32], usize, (&[i8], &[i8], usize), usize, (i16, i16)) -> bool = false;
        exp_sums(&[i8], i8, &[u16; 256]) -> Option<(u32, u32)> = None;
        table_column(
            &mut [i8], [&[i8]; 2], (usize, usize, usize), (i16, i16), &[i8; 512], super::Combine
        ) -> bool = false;
        cost_column3(
            &mut [i8], &[i8], [&[i8]; 2], (usize, usize), [(usize, i16, i16); 2],
            crate::requant::Requant, (u32, i32)
        ) -> bool = false;
        pack_rows(&mut [u32], usize, (&[i8], &[i8]), (i16, i16)) -> bool = false;
        table_columns4(
            &mut [i8], &[i8], &[i8], (usize, usize), [usize; 4], [(i16, i16); 4], &[i8; 512], bool
        ) -> bool = false;
        table_columns8(
            &mut [i8], &[i8], &[i8], (usize, usize), [usize; 8], [(i16, i16); 8], &[i8; 512], bool
        ) -> bool = false;
    }

    /// The whole-line `requant_max_row` and `requant_row` of the portable build: none done.
    #[inline(always)]
    pub(super) fn requant_max_row(
        _: &[i32],
        _: &mut [i8],
        _: (i32, u32, u32, i32, i32),
        _: bool,
        max: i8,
    ) -> (usize, i8) {
        (0, max)
    }

    /// See [`requant_max_row`].
    #[inline(always)]
    pub(super) fn requant_row(
        _: &[i32],
        _: &mut [i8],
        _: (i32, u32, u32, i32, i32),
        _: bool,
        _: Option<&[i32; 256]>,
    ) -> usize {
        0
    }
}

/// Two output channels × two positions of a dot product over i16 pairs (`SMLAD`):
/// with `x0 = x[..n]`, `x1 = x[step..step + n]` and the channels' weights interleaved
/// word by word in `w` (`w[2k]` channel 0, `w[2k + 1]` channel 1), returns `acc` plus
/// `[x0·w_0, x1·w_0, x0·w_1, x1·w_1]` (each word two i16 products), wrapping like the
/// instruction.
///
/// Slices too short for `n`, `step` give `acc` unchanged (the kernels never pass them).
/// With the `dsp` feature on ARM and even `n` it is a hand-scheduled loop: LLVM spills
/// the 4 accumulators of the Rust version to the stack (12 live registers are needed,
/// exactly what Thumb-2 leaves to inline assembly), which costs about 2 instructions per
/// MAC instead of 1.
#[inline(always)]
pub fn dot2x2(x: &[u32], step: usize, w: &[u32], n: usize, acc: [i32; 4]) -> [i32; 4] {
    let (Some(xe), Some(we)) = (step.checked_add(n), n.checked_mul(2)) else {
        return acc;
    };
    if x.len() < xe || x.len() < n || w.len() < we {
        return acc;
    }
    if let Some(r) = isa::dot2x2(x, step, w, n, acc) {
        return r;
    }
    let [mut a00, mut a01, mut a10, mut a11] = acc;
    for ((&x0, &x1), w) in x[..n].iter().zip(&x[step..xe]).zip(w[..we].chunks_exact(2)) {
        a00 = smlad(x0, w[0], a00);
        a01 = smlad(x1, w[0], a01);
        a10 = smlad(x0, w[1], a10);
        a11 = smlad(x1, w[1], a11);
    }
    [a00, a01, a10, a11]
}

/// A row of [`dot2x2`]s: for every position `q < positions`, with `x_q = x[q·step ..
/// q·step + n]`, `acc0[q·astep] = bias[0] + x_q·w_0` and `acc1[q·astep] = bias[1] + x_q·w_1`
/// (channel words interleaved in `w` as for [`dot2x2`]), two positions per inner loop.
///
/// Returns false, leaving the accumulators alone, when a slice is too short for `positions`,
/// `step` and `n` (the kernels never pass such slices). The slices are validated once per
/// row, so a pair of positions costs the inner loop and about 12 instructions.
pub fn dot2x2_row(
    x: &[u32],
    step: usize,
    positions: usize,
    w: &[u32],
    n: usize,
    bias: [i32; 2],
    (acc0, acc1, astep): (&mut [i32], &mut [i32], usize),
) -> bool {
    RowPlan::new(step, positions, n, astep).run(x, w, bias, (acc0, acc1))
}

/// The shape of a [`dot2x2_row`] call (`step`, `positions`, `n`, `astep`), prepared once for
/// the many rows that share it: with Helium and an even number of positions, the pair loop's
/// shape checked up front (`mve::PairRows`), so a row's call only compares slice
/// lengths. [`RowPlan::run`] computes exactly what [`dot2x2_row`] does.
#[derive(Clone, Copy, Debug)]
pub struct RowPlan {
    step: usize,
    positions: usize,
    n: usize,
    astep: usize,
    pairs: isa::Pairs,
}

impl RowPlan {
    /// The plan of rows of `positions` dot products of `n` words, `step` words apart, into
    /// accumulators `astep` words apart.
    #[inline(always)]
    pub fn new(step: usize, positions: usize, n: usize, astep: usize) -> Self {
        RowPlan {
            step,
            positions,
            n,
            astep,
            pairs: isa::pairs(step, positions, n, astep),
        }
    }

    /// One row, as [`dot2x2_row`] with this plan's shape.
    #[inline(always)]
    pub fn run(
        &self,
        x: &[u32],
        w: &[u32],
        bias: [i32; 2],
        (acc0, acc1): (&mut [i32], &mut [i32]),
    ) -> bool {
        // With Helium's pair loop planned, it checks exactly the slices
        // `dot2x2_row_checked` checks (and refuses what they refuse), so it runs alone.
        if let Some(done) = isa::run_pairs(&self.pairs, x, w, bias, (&mut *acc0, &mut *acc1)) {
            return done;
        }
        let (step, positions, n) = (self.step, self.positions, self.n);
        dot2x2_row_checked(x, step, positions, w, n, bias, (acc0, acc1, self.astep))
    }

    /// Every channel pair `k < bias.len()` of a line: [`RowPlan::run`] with the weights
    /// `w[k·wstride ..]`, biases `bias[k]` and accumulator rows `acc[2k·rstride + first ..]`
    /// and `acc[(2k + 1)·rstride + first ..]`; with Helium one call for every pair
    /// (`mve::PairRows::run_channels`). Returns false when a slice is too short for
    /// a pair (earlier pairs may have been written). Not inlined: the line engines share it.
    #[inline(never)]
    pub fn run_channels(
        &self,
        x: &[u32],
        (w, wstride): (&[u32], usize),
        bias: &[[i32; 2]],
        acc: &mut [i32],
        (rstride, first): (usize, usize),
    ) -> bool {
        // Helium's register loop takes every pair at once; other shapes run pair by pair.
        if let Some(done) =
            isa::run_channel_pairs(&self.pairs, x, (w, wstride), bias, acc, (rstride, first))
        {
            return done;
        }
        for (k, &b) in bias.iter().enumerate() {
            let Some((head, tail)) = acc.split_at_mut_checked((2 * k + 1) * rstride + first) else {
                return false;
            };
            let a0 = head.get_mut(2 * k * rstride + first..).unwrap_or(&mut []);
            let wk = w.get(k * wstride..).unwrap_or(&[]);
            if !self.run(x, wk, b, (a0, tail)) {
                return false;
            }
        }
        true
    }
}

/// [`dot2x2_row`] for the shapes [`RowPlan`] does not hand to Helium's pair loop alone: the
/// shape and the slices checked here, every row. Not inlined: each kernel's row loop calls it
/// from one place, and its code stays out of the kernels' hot loops.
#[inline(never)]
fn dot2x2_row_checked(
    x: &[u32],
    step: usize,
    positions: usize,
    w: &[u32],
    n: usize,
    bias: [i32; 2],
    (acc0, acc1, astep): (&mut [i32], &mut [i32], usize),
) -> bool {
    if positions == 0 {
        return true;
    }
    let shape = (x.len(), step, positions, n);
    if !row_fits(shape, w.len(), (acc0.len(), acc1.len(), astep)) {
        return false;
    }
    // The backend's pair loop over the pairs of positions, then an odd last position by
    // `dot2x2`; else every pair by `dot2x2` below.
    if isa::row_pairs(
        x,
        (step, positions, n),
        w,
        bias,
        (&mut *acc0, &mut *acc1, astep),
    ) {
        if positions % 2 == 1 {
            let q = positions - 1;
            let bias4 = [bias[0], bias[0], bias[1], bias[1]];
            let r = dot2x2(x.get(q * step..).unwrap_or(&[]), 0, w, n, bias4);
            store_pair(acc0, acc1, astep, q, false, r);
        }
        return true;
    }
    for p in 0..positions.div_ceil(2) {
        let q = 2 * p;
        let pair = q + 1 < positions;
        let second = if pair { step } else { 0 };
        let bias4 = [bias[0], bias[0], bias[1], bias[1]];
        let r = dot2x2(x.get(q * step..).unwrap_or(&[]), second, w, n, bias4);
        store_pair(acc0, acc1, astep, q, pair, r);
    }
    true
}

/// `r(a)` of the requantising row functions: `x = SMMULR(a << left1, multiplier)`, then
/// `(x + half + (x >> 31 & neg)) >> right` (`right < 32`). One definition for their portable
/// loops and the kernels' `RowRequant::apply`, so the three cannot drift apart.
#[inline(always)]
pub(crate) fn row_requant(
    a: i32,
    multiplier: i32,
    left1: u32,
    right: u32,
    half: i32,
    neg: i32,
) -> i32 {
    let x = smmulr(a.wrapping_shl(left1), multiplier);
    x.wrapping_add(half).wrapping_add((x >> 31) & neg) >> right
}

/// A row of requantised int8 values and their maximum: `out[i] = sat(r(acc[i]))` for the
/// first `min(acc.len(), out.len())` values, with `x = SMMULR(acc << left1, multiplier)`,
/// `r = (x + half + (x >> 31 & neg)) >> right` (the kernels' `RowRequant`) and `sat` the int8
/// clamp (`SSAT #8`), or with `relu` the clamp to `0..=127` (`USAT #7`). Returns the larger
/// of `max` and every value written. With the `dsp` feature on ARM: 14 instructions per
/// value (the Rust loop takes 24: LLVM spills and sign-extends around two compare-and-move
/// clamps).
pub fn requant_max_row(
    acc: &[i32],
    out: &mut [i8],
    (multiplier, left1, right, half, neg): (i32, u32, u32, i32, i32),
    relu: bool,
    max: i8,
) -> i8 {
    let (done, max) =
        isa::requant_max_row(acc, out, (multiplier, left1, right, half, neg), relu, max);
    let (acc, out) = (
        acc.get(done..).unwrap_or(&[]),
        out.get_mut(done..).unwrap_or(&mut []),
    );
    let len = acc.len().min(out.len());
    let mut mx = max as i32;
    for (d, &a) in out[..len].iter_mut().zip(&acc[..len]) {
        let t = row_requant(a, multiplier, left1, right.min(31), half, neg);
        let t = if relu {
            t.clamp(0, 127)
        } else {
            t.clamp(-128, 127)
        };
        *d = t as i8;
        mx = mx.max(t);
    }
    mx as i8
}

/// Rows of [`requant_row_s8`], one per channel of a line: row `c < params.len()` turns
/// `acc[c·width ..][..width]` into `out[c·plane ..][..width]` with channel `c`'s words. With
/// Helium and a width that is a multiple of 4, one call for every row
/// (`mve::requant_rows_quads`). Returns false, writing nothing, when a row's slices
/// do not fit.
pub fn requant_rows_s8(
    acc: &[i32],
    out: &mut [i8],
    params: RowWords<'_>,
    (width, plane): (usize, usize),
    relu: bool,
    skip: Option<&[i32; 256]>,
) -> bool {
    let (rows, params) = (params.len(), params.words());
    let fits = rows.checked_mul(width).is_some_and(|n| n <= acc.len())
        && rows.checked_sub(1).is_none_or(|r| {
            r.checked_mul(plane)
                .and_then(|a| a.checked_add(width))
                .is_some_and(|n| n <= out.len())
        });
    if !fits {
        return false;
    }
    if isa::requant_rows(acc, out, params, (width, plane), relu, skip) {
        return true;
    }
    for (c, p) in params.iter().enumerate() {
        let f = (p[0], p[1] as u32, p[2] as u32, p[3], p[4]);
        let dst = &mut out[c * plane..][..width];
        requant_row_s8(&acc[c * width..][..width], dst, f, relu, skip);
    }
    true
}

/// A row of a layer's int8 outputs from its accumulators: for the first
/// `min(acc.len(), out.len())` values, `t = r(acc[i])` as in [`requant_max_row`], then with
/// `relu` `t = max(t, 0)`, then with a skip table `t = t +sat skip[out[i] as u8]` (the value
/// `out[i]` held before: an in-place skip), and `out[i] = clamp(t, −128, 127)`. With the
/// `dsp` feature on ARM: 11 instructions per value (15 with the skip; `QADD` is the
/// saturating add, `BIC … ASR #31` the ReLU), against 13–19 for the Rust loop.
pub fn requant_row_s8(
    acc: &[i32],
    out: &mut [i8],
    (multiplier, left1, right, half, neg): (i32, u32, u32, i32, i32),
    relu: bool,
    skip: Option<&[i32; 256]>,
) {
    let rq = (multiplier, left1, right, half, neg);
    let done = isa::requant_row(acc, out, rq, relu, skip);
    let (acc, out) = (
        acc.get(done..).unwrap_or(&[]),
        out.get_mut(done..).unwrap_or(&mut []),
    );
    let len = acc.len().min(out.len());
    for (d, &a) in out[..len].iter_mut().zip(&acc[..len]) {
        let t = row_requant(a, multiplier, left1, right.min(31), half, neg);
        let t = if relu { t.max(0) } else { t };
        let t = match skip {
            Some(l) => t.saturating_add(l[*d as u8 as usize]),
            None => t,
        };
        *d = t.clamp(-128, 127) as i8;
    }
}

/// Strided pairs: `dst[j·dstride] = pack(a[j·sstride] + oa, b[j·sstride] + ob)` for
/// `j < count` (a column of two int8 planes into i16 pairs). Does nothing when a slice is too
/// short for `count` and the strides (the kernels never pass such slices). With the `dsp`
/// feature on ARM: 8 instructions per word without offsets (10 with), against about 12.5 for
/// the Rust loop; with Helium 2.5 per word (`mve::pack_strided_quads`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn pack_strided(
    dst: &mut [u32],
    dstride: usize,
    (a, b, sstride): (&[i8], &[i8], usize),
    count: usize,
    oa: i16,
    ob: i16,
) {
    let Some(last) = count.checked_sub(1) else {
        return;
    };
    let fits = |len: usize, stride: usize| last.checked_mul(stride).is_some_and(|e| e < len);
    if !(fits(dst.len(), dstride) && fits(a.len(), sstride) && fits(b.len(), sstride)) {
        return;
    }
    // Helium's blocks of four by gathers, then the rest below.
    let done = isa::pack_strided_quads(dst, dstride, (a, b, sstride), count, (oa, ob));
    if done == count {
        return;
    }
    // done < count: the indices below are at most last · stride, in bounds.
    let (Some(dst), Some(a), Some(b)) = (
        dst.get_mut(done * dstride..),
        a.get(done * sstride..),
        b.get(done * sstride..),
    ) else {
        return;
    };
    let count = count - done;
    if isa::pack_strided(dst, dstride, (a, b, sstride), count, (oa, ob)) {
        return;
    }
    for j in 0..count {
        dst[j * dstride] = pack(a[j * sstride] as i16 + oa, b[j * sstride] as i16 + ob);
    }
}

/// The soft-argmax sums of one ray: with `e_i = exp[(m − q_i) mod 256]`, returns
/// `(S, T) = (Σ e_i, Σ i·e_i)` (wrapping u32, as the kernels' exact sums never wrap). With the
/// `dsp` feature on ARM and a multiple of 4 logits: `USUB8` forms four table indices at once
/// and `T = n·S − Σ_i S_i` (the prefix sums) replaces the multiply-accumulate, 5 instructions
/// per logit instead of 7.
#[inline(always)]
pub fn exp_sums(logits: &[i8], m: i8, exp: &[u16; 256]) -> (u32, u32) {
    if let Some(sums) = isa::exp_sums(logits, m, exp) {
        return sums;
    }
    let (mut s, mut t) = (0u32, 0u32);
    for (i, &q) in logits.iter().enumerate() {
        let e = exp[(m as i32 - q as i32) as u8 as usize] as u32;
        s = s.wrapping_add(e);
        t = t.wrapping_add(e.wrapping_mul(i as u32));
    }
    (s, t)
}

/// The results of positions `q` and (with `pair`) `q + 1` of [`dot2x2_row`].
#[inline(always)]
fn store_pair(acc0: &mut [i32], acc1: &mut [i32], astep: usize, q: usize, pair: bool, r: [i32; 4]) {
    let i = q * astep;
    if let (Some(a), Some(b)) = (acc0.get_mut(i), acc1.get_mut(i)) {
        *a = r[0];
        *b = r[2];
    }
    if pair {
        let i = i + astep;
        if let (Some(a), Some(b)) = (acc0.get_mut(i), acc1.get_mut(i)) {
            *a = r[1];
            *b = r[3];
        }
    }
}

/// One column of a two-view cost-volume piece (rows of `width` values): for every row
/// `k`, with `i = k·width + col`, the warped source value
/// `w = (src[k·width + c]·wl + src[k·width + c + 1]·wr + 128) >> 8` and
/// `out[i] = table[reference[i] − w + 255]`.
///
/// Returns false, doing nothing, when the slices do not have one common length that is a
/// multiple of `width`, `col` or `c + 1` is not below `width`, or the weights are not
/// `wl, wr ≥ 0` with `wl + wr = 256` or both 0 (an invisible entry). Then `w` lies between
/// the two int8 source values (or is 0), `reference − w + 255` in `0..=510`, inside the
/// 512-entry table. With the `dsp` feature on ARM: 12 instructions per value (the two
/// source values are one halfword load, `SMUAD` weighs them).
#[allow(clippy::too_many_arguments)]
pub fn cost_column(
    out: &mut [i8],
    reference: &[i8],
    src: &[i8],
    width: usize,
    col: usize,
    c: usize,
    taps: (i16, i16),
    table: &[i8; 512],
) -> bool {
    table_column(
        out,
        [reference, src],
        (width, col, c),
        taps,
        table,
        Combine::Difference,
    )
}

/// [`cost_column`] for a mean channel: `out[i] = table[reference[i] + w + 256]`
/// (`reference + w` in `−256..=254`, so the index lies in `0..=510`). Same conditions, same
/// 12 instructions per value (one `ADD` where the variance has a `SUB`).
#[allow(clippy::too_many_arguments)]
pub fn mean_column(
    out: &mut [i8],
    reference: &[i8],
    src: &[i8],
    width: usize,
    col: usize,
    c: usize,
    taps: (i16, i16),
    table: &[i8; 512],
) -> bool {
    table_column(
        out,
        [reference, src],
        (width, col, c),
        taps,
        table,
        Combine::Sum,
    )
}
/// `table_columns!(name, lanes)`: the build's kernel of the same name (Helium's), false in
/// builds without it; one body for both widths.
macro_rules! table_columns {
    ($(#[$doc:meta])* $name:ident, $lanes:literal) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        #[inline(always)]
        pub fn $name(
            out: &mut [i8],
            reference: &[i8],
            src: &[i8],
            (width, col): (usize, usize),
            taps: [(usize, i16, i16); $lanes],
            table: &[i8; 512],
            sum: bool,
        ) -> bool {
            let cs = taps.map(|t| t.0);
            let weights = taps.map(|t| (t.1, t.2));
            isa::$name(out, reference, src, (width, col), cs, weights, table, sum)
        }
    };
}

table_columns!(
    /// Eight adjacent columns `col .. col + 8` of [`cost_column`] (or of [`mean_column`] when
    /// `sum`), as [`table_columns4`] (`mve::table_columns8`, 16-bit lanes). False, and nothing
    /// written, in other builds or where it refuses; the caller then takes four columns or one.
    table_columns8,
    8
);

table_columns!(
    /// Four adjacent columns `col .. col + 4` of [`cost_column`] (or of [`mean_column`] when
    /// `sum`), one tap `(c, wl, wr)` per column: the same values, in one pass down the rows with
    /// Helium (`mve::table_columns4`). False, and nothing written, in other builds or under
    /// conditions either one-column function would refuse; the caller then goes column by
    /// column.
    table_columns4,
    4
);

/// The loop of [`cost_column`] and [`mean_column`]: the backend's (one audited `asm!`
/// template in `dsp`, the combining instruction its only difference), else the portable one.
#[inline(always)]
fn table_column(
    out: &mut [i8],
    [reference, src]: [&[i8]; 2],
    (width, col, c): (usize, usize, usize),
    (wl, wr): (i16, i16),
    table: &[i8; 512],
    combine: Combine,
) -> bool {
    let n = out.len();
    let ok = rows::column_fits(&[reference.len(), src.len()], n, (width, col))
        && rows::tap_fits((c, wl, wr), width);
    if !ok {
        return false;
    }
    if isa::table_column(
        out,
        [reference, src],
        (width, col, c),
        (wl, wr),
        table,
        combine,
    ) {
        return true;
    }
    for ((o, r), s) in out
        .chunks_exact_mut(width)
        .zip(reference.chunks_exact(width))
        .zip(src.chunks_exact(width))
    {
        let w = (s[c] as i32 * wl as i32 + s[c + 1] as i32 * wr as i32 + 128) >> 8;
        let index = match combine {
            Combine::Difference => r[col] as i32 - w + 255,
            Combine::Sum => r[col] as i32 + w + 256,
        };
        o[col] = table[index.clamp(0, 511) as usize];
    }
    true
}

/// One column of a three-view cost-volume piece (rows of `width` values) with the unsigned
/// cost volume (zero point −128): for every row `k`, with `i = k·width + col`, the warped
/// source values `v_s = (src_s[k·width + c_s]·wl_s + src_s[k·width + c_s + 1]·wr_s + 128) >> 8`,
/// `X = (v0 − v1)² + (v0 − v2)² + (v1 − v2)²` with `v0 = reference[i]`, and
/// `out[i] = clamp(MBQM(X, M, shift), 0, 255) − 128` (QUANTISATION.md; `CostRequant::store`).
///
/// Here `X ≥ 0`, `M ≥ 0` and `shift ≤ 0`, so `MBQM(X) = (((2X·M + 2^31) >> 32) + half) >> right`
/// with `right = −shift` and `half = 2^(right − 1)` (0 when `right = 0`): `SMMLAR` gives the
/// first shift and the rounding half in one instruction (`2X < 2^19` fits, and
/// `(2X·M + 2^31) >> 32 = (X·M + 2^30) >> 31` exactly).
///
/// Returns false, doing nothing, when the slices do not have one common length that is a
/// multiple of `width`, `col` or a `c_s + 1` is not below `width`, a tap's weights are not
/// `wl, wr ≥ 0` with `wl + wr = 256` or both 0, the multiplier is negative, the shift is
/// positive, or the zero point is not −128: the caller's portable loop serves those. With the
/// `dsp` feature on ARM: 33 instructions per value (the caller's loop: about 55).
pub fn cost_column3(
    out: &mut [i8],
    reference: &[i8],
    sources: [&[i8]; 2],
    (width, col): (usize, usize),
    taps: [(usize, i16, i16); 2],
    requant: crate::requant::Requant,
    zero_point: i32,
) -> bool {
    let n = out.len();
    let lens = [reference.len(), sources[0].len(), sources[1].len()];
    let ok = rows::column_fits(&lens, n, (width, col))
        && taps.iter().all(|&t| rows::tap_fits(t, width))
        && requant.multiplier >= 0
        && requant.shift <= 0
        && zero_point == -128;
    if !ok {
        return false;
    }
    let right = requant.shift.unsigned_abs().min(31);
    let half = if right > 0 { 1i32 << (right - 1) } else { 0 };
    if isa::cost_column3(
        out,
        reference,
        sources,
        (width, col),
        taps,
        requant,
        (right, half),
    ) {
        return true;
    }
    // The same arithmetic, for hosts (the tests check it against the plain kernel).
    let warp = |row: &[i8], (c, wl, wr): (usize, i16, i16)| {
        (row[c] as i32 * wl as i32 + row[c + 1] as i32 * wr as i32 + 128) >> 8
    };
    let rows = out
        .chunks_exact_mut(width)
        .zip(reference.chunks_exact(width))
        .zip(sources[0].chunks_exact(width))
        .zip(sources[1].chunks_exact(width));
    for (((o, r), s0), s1) in rows {
        let (v0, v1, v2) = (r[col] as i32, warp(s0, taps[0]), warp(s1, taps[1]));
        let x = (v0 - v1).pow(2) + (v0 - v2).pow(2) + (v1 - v2).pow(2);
        let q = ((((2 * x) as i64 * requant.multiplier as i64 + (1 << 31)) >> 32) as i32 + half)
            >> right;
        o[col] = (q.clamp(0, 255) - 128) as i8;
    }
    true
}

/// Interleaves two i8 rows into i16 pairs: `dst[j · stride] = pack(a[j] + oa, b[j] + ob)`
/// for `j < min(a.len(), b.len())` (a line-buffer column of the convolution engines).
///
/// Positions past the end of `dst` are skipped (the kernels never pass them). With the
/// `dsp` feature on ARM it is a 9-instruction loop (`PKHBT` packs the pair); the Rust
/// version costs about 20 instructions per word on Cortex-M7 (iterator bookkeeping).
#[inline(always)]
pub fn pack_rows(dst: &mut [u32], stride: usize, a: &[i8], b: &[i8], oa: i16, ob: i16) {
    let n = a.len().min(b.len());
    if isa::pack_rows(dst, stride, (a, b), (oa, ob)) {
        return;
    }
    for (j, (&x, &y)) in a[..n].iter().zip(&b[..n]).enumerate() {
        if let Some(d) = dst.get_mut(j * stride) {
            *d = pack(x as i16 + oa, y as i16 + ob);
        }
    }
}

/// A whole line fill (the line engine's, `kernels::line`): for each pair `k` of `rows`
/// (entries `2k`, `2k + 1`: rows `a`, `b` with offsets `oa`, `ob`), `dst[k + j · vw] =
/// pack(a[j] + oa, b[j] + ob)` for `j < need`, `need` a multiple of 4: what [`pack_rows`]
/// does for one word, for up to 16 words in one call, with the pair loop in assembly too
/// (Helium's eight columns per pass, or the `SXTB16` loop of `dsp`: about 6 or 16 instructions
/// per line word, where the Rust loop around [`pack_rows`] spent about 100 choosing the rows
/// and checking slices). Returns false, doing nothing, for an odd number of rows, `need` not a
/// positive multiple of 4, or a `dst` too short.
#[cfg(all(feature = "dsp", target_arch = "arm"))]
#[inline(always)]
pub fn pack_line_quads(dst: &mut [u32], vw: usize, rows: &LineRows<'_>) -> bool {
    isa::pack_line_quads(dst, vw, rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec;
    use std::vec::Vec;

    #[test]
    fn fallbacks_have_the_instruction_semantics() {
        assert_eq!(sxtb16(0x80_7f_01_ff), 0x007f_ffff); // bytes 0 (−1) and 2 (127)
        assert_eq!(sxtb16_ror8(0x80_7f_01_ff), 0xff80_0001); // bytes 1 (1) and 3 (−128)
        assert_eq!(smlad(pack(-3, 7), pack(100, -2), 5), 5 - 300 - 14);
        assert_eq!(
            smlad(pack(i16::MIN, i16::MIN), pack(i16::MIN, i16::MIN), 0),
            i32::MIN // 2^31 wraps, as SMLAD does (and sets Q)
        );
        let mut s = 0x1234_5678u32;
        for _ in 0..1000 {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let w = s;
            let (e, o) = (sxtb16(w), sxtb16_ror8(w));
            let bytes = w.to_le_bytes().map(|b| b as i8 as i32);
            assert_eq!(e as u16 as i16 as i32, bytes[0]);
            assert_eq!((e >> 16) as u16 as i16 as i32, bytes[2]);
            assert_eq!(o as u16 as i16 as i32, bytes[1]);
            assert_eq!((o >> 16) as u16 as i16 as i32, bytes[3]);
        }
    }

    #[test]
    fn smmulr_rounds_the_high_word() {
        let mut s = 0x9e37_79b9u32;
        for _ in 0..10_000 {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let x = s as i32;
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let y = s as i32;
            let want = ((x as i64 * y as i64 + (1i64 << 31)) >> 32) as i32;
            assert_eq!(smmulr(x, y), want);
        }
        assert_eq!(smmulr(i32::MIN, i32::MIN), 1 << 30);
        assert_eq!(smmulr(-1, 1), 0);
        assert_eq!(smmulr(1 << 30, 2), 1); // 2^31 / 2^32: the tie rounds up
        assert_eq!(smmulr(-(1 << 30), 2), 0);
    }

    #[test]
    fn dot2x2_is_the_sum_of_products() {
        let mut s = 0x1234_5678u32;
        let mut r = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            s
        };
        for n in 0..9 {
            for step in 0..4 {
                let x: std::vec::Vec<u32> = (0..n + step + 2).map(|_| r()).collect();
                let w: std::vec::Vec<u32> = (0..2 * n + 1).map(|_| r()).collect();
                let acc = [r() as i32 >> 4, 5, -7, 11];
                let half = |v: u32, h: u32| (v >> (16 * h)) as u16 as i16 as i64;
                let mut want = acc.map(|a| a as i64);
                for k in 0..n {
                    for h in 0..2 {
                        want[0] += half(x[k], h) * half(w[2 * k], h);
                        want[1] += half(x[k + step], h) * half(w[2 * k], h);
                        want[2] += half(x[k], h) * half(w[2 * k + 1], h);
                        want[3] += half(x[k + step], h) * half(w[2 * k + 1], h);
                    }
                }
                let got = dot2x2(&x, step, &w, n, acc);
                assert_eq!(got, want.map(|v| v as i32), "n={n} step={step}");
            }
        }
        // Too-short slices: nothing happens, no panic.
        assert_eq!(
            dot2x2(&[1, 2], 1, &[1, 2, 3, 4], 2, [1, 2, 3, 4]),
            [1, 2, 3, 4]
        );
    }

    #[test]
    fn dot2x2_row_is_a_row_of_dot2x2() {
        let mut s = 0x5555_1234u32;
        let mut r = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            s
        };
        for n in 0..7 {
            for step in 0..4 {
                for positions in 0..6 {
                    let len = positions.max(1) * step + n + 1;
                    let x: Vec<u32> = (0..len).map(|_| r()).collect();
                    let w: Vec<u32> = (0..2 * n).map(|_| r()).collect();
                    let bias = [r() as i32 >> 8, -(r() as i32 >> 9)];
                    let (mut a0, mut a1) = (vec![7i32; positions], vec![9i32; positions]);
                    let accs = (&mut a0[..], &mut a1[..], 1);
                    assert!(dot2x2_row(&x, step, positions, &w, n, bias, accs));
                    for q in 0..positions {
                        let want = dot2x2(&x[q * step..], 0, &w, n, [bias[0], 0, bias[1], 0]);
                        let got = (a0[q], a1[q]);
                        assert_eq!(got, (want[0], want[2]), "n={n} step={step} q={q}");
                    }
                    // Every third accumulator.
                    let (mut b0, mut b1) = (vec![5i32; 3 * positions], vec![6; 3 * positions]);
                    let accs = (&mut b0[..], &mut b1[..], 3);
                    assert!(dot2x2_row(&x, step, positions, &w, n, bias, accs));
                    for q in 0..3 * positions {
                        let want = if q % 3 == 0 {
                            (a0[q / 3], a1[q / 3])
                        } else {
                            (5, 6)
                        };
                        assert_eq!((b0[q], b1[q]), want);
                    }
                }
            }
        }
        // Too short: refused, untouched, no panic.
        let (mut a0, mut a1) = ([1i32; 3], [2i32; 3]);
        let accs = (&mut a0[..], &mut a1[..], 1);
        assert!(!dot2x2_row(&[0; 4], 2, 3, &[0; 4], 2, [0, 0], accs));
        assert_eq!((a0, a1), ([1; 3], [2; 3]));
        let accs = (&mut a0[..2], &mut a1[..], 1);
        assert!(!dot2x2_row(&[0; 8], 1, 3, &[0; 4], 2, [0, 0], accs));
        let accs = (&mut a0[..], &mut a1[..], 2);
        assert!(!dot2x2_row(&[0; 8], 1, 3, &[0; 4], 2, [0, 0], accs));
    }

    #[test]
    fn pack_rows_interleaves_with_offsets() {
        let a = [1i8, -128, 127, 0, -5];
        let b = [-1i8, 127, -128, 9, 3];
        for stride in 1..4 {
            let mut dst = std::vec![0xdead_beefu32; 5 * stride];
            pack_rows(&mut dst, stride, &a, &b[..4], 128, -3);
            for (j, w) in dst.iter().enumerate() {
                let want = if j % stride == 0 && j / stride < 4 {
                    let k = j / stride;
                    pack(a[k] as i16 + 128, b[k] as i16 - 3)
                } else {
                    0xdead_beef
                };
                assert_eq!(*w, want, "stride {stride} word {j}");
            }
        }
        // A destination too short: the words that fit, no panic.
        let mut short = [0u32; 3];
        pack_rows(&mut short, 2, &a, &b, 0, 0);
        assert_eq!(short, [pack(1, -1), 0, pack(-128, 127)]);
    }

    #[test]
    fn pack_strided_packs_a_column() {
        let a: Vec<i8> = (0..20).map(|i| (i * 13 - 100) as i8).collect();
        let b: Vec<i8> = (0..20).map(|i| (50 - i * 7) as i8).collect();
        for (offsets, sstride, dstride) in [((0, 0), 4, 3), ((128, -3), 5, 1), ((7, 0), 1, 2)] {
            let count = (a.len() - 1) / sstride + 1;
            let mut dst = std::vec![0xdead_beefu32; count * dstride];
            let (oa, ob) = offsets;
            pack_strided(&mut dst, dstride, (&a, &b, sstride), count, oa, ob);
            for (j, w) in dst.iter().enumerate() {
                let want = if j % dstride == 0 {
                    let k = j / dstride * sstride;
                    pack(a[k] as i16 + oa, b[k] as i16 + ob)
                } else {
                    0xdead_beef
                };
                assert_eq!(*w, want, "strides {sstride} {dstride} word {j}");
            }
        }
        // Too short for the count: nothing written, no panic.
        let mut dst = [7u32; 4];
        pack_strided(&mut dst, 1, (&a, &b, 4), 6, 0, 0);
        assert_eq!(dst, [7; 4]);
    }

    /// The plain definition of a requantised output (`RowRequant` fields, ReLU, skip, clamp).
    fn requantised(a: i32, f: (i32, u32, u32, i32, i32), relu: bool, skip: Option<i32>) -> i32 {
        let (m, left1, right, half, neg) = f;
        let x = ((a.wrapping_shl(left1) as i64 * m as i64 + (1 << 31)) >> 32) as i32;
        let t = x.wrapping_add(half).wrapping_add((x >> 31) & neg) >> right;
        let t = if relu { t.max(0) } else { t };
        t.saturating_add(skip.unwrap_or(0)).clamp(-128, 127)
    }

    #[test]
    fn requant_rows_match_the_definition() {
        let mut s = 0x2545_f491u32;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s
        };
        let table: [i32; 256] = core::array::from_fn(|i| (i as i32 - 128) * 3 - 7);
        for round in 0..200 {
            let right = next() % 12;
            let f = (
                (next() >> 1) as i32 | 0x4000_0000,
                1 + next() % 3,
                right,
                if right > 0 { 1 << (right - 1) } else { 0 },
                if right > 0 { -1 } else { 0 },
            );
            let acc: Vec<i32> = (0..37).map(|_| (next() as i32) >> 12).collect();
            let old: Vec<i8> = (0..37).map(|_| next() as i8).collect();
            let relu = round % 2 == 0;
            let skip = (round % 3 == 0).then_some(&table);
            let mut out = old.clone();
            requant_row_s8(&acc, &mut out, f, relu, skip);
            let mut with_max = std::vec![0i8; 37];
            let max = requant_max_row(&acc, &mut with_max, f, relu, -100);
            let mut want_max = -100;
            for i in 0..37 {
                let sk = skip.map(|t| t[old[i] as u8 as usize]);
                assert_eq!(
                    out[i] as i32,
                    requantised(acc[i], f, relu, sk),
                    "round {round} {i}"
                );
                let plain = requantised(acc[i], f, relu, None);
                assert_eq!(with_max[i] as i32, plain, "round {round} {i}");
                want_max = want_max.max(plain);
            }
            assert_eq!(max as i32, want_max);
        }
    }

    #[test]
    fn exp_sums_are_the_sums() {
        let exp: [u16; 256] =
            core::array::from_fn(|d| (65535.0 * (-(d as f64) * 0.03).exp()) as u16);
        let mut x = 0x1234_5678u32;
        for len in [4usize, 8, 64, 256, 3, 13] {
            let logits: Vec<i8> = (0..len)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as i8
                })
                .collect();
            let m = *logits.iter().max().unwrap();
            let (mut s, mut t) = (0u32, 0u32);
            for (i, &q) in logits.iter().enumerate() {
                let e = exp[(m as i32 - q as i32) as usize] as u32;
                s += e;
                t += e * i as u32;
            }
            assert_eq!(exp_sums(&logits, m, &exp), (s, t), "len {len}");
        }
    }
}
