//! Plane-sweep warp of the source features and the variance (and mean) cost volume
//! (QUANTISATION.md "Warp and cost volume").
//!
//! Reference features `[C][H][W]` i8, one or two source feature maps of the same shape and
//! scale, each with its range-independent warp table `[plane][W]`; output cost volume
//! `[C][N][H][W]` i8 (codes per [`CostRequant`]'s zero point). For source entry (`column` c,
//! `fraction` α, `visible`): `w = (F[c]·(256 − α) + F[c+1]·α + 128) >> 8`, invisible → 0; with
//! `n` views `X = n·Σv² − (Σv)²`, `q = clamp(MBQM(X, M_n, shift_n), 0, 127 − z)` and the
//! stored value `q + z`, where the zero point `z` ([`CostRequant`]) is 0 (`q` in `0..=127`) or
//! −128 (the variance is never negative, so all 256 codes hold `0..=255`: twice the resolution).
//! The last [`CostShape::mean_channels`] channels hold the views' mean instead:
//! `q = clamp(MBQM(Σv, M'_n, shift'_n), 0, 127 − z)`, a mean clipped at 0 like the float model's.
//!
//! Work: `C · N · H · W · (n + 2·(n − 1))` multiplies (n views; 2 per bilinear warp).

use super::{expect, KernelError, Operand};
use crate::geometry::WarpEntry;
use crate::requant::{Apply, FastRequant, Requant};

/// Sizes of the cost volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CostShape {
    /// Feature channels C.
    pub channels: usize,
    /// Elevation planes N.
    pub planes: usize,
    /// Feature range bins H.
    pub height: usize,
    /// Feature columns W.
    pub width: usize,
    /// The last channels, which hold the views' mean (clipped at 0) instead of their variance.
    pub mean_channels: usize,
}

impl CostShape {
    /// The compiled configuration's cost volume.
    pub const EPSSN: CostShape = CostShape {
        channels: crate::config::FEATURE_CHANNELS,
        planes: crate::config::PLANES,
        height: crate::config::FEATURE_RANGE_BINS,
        width: crate::config::FEATURE_COLUMNS,
        mean_channels: crate::config::MEAN_CHANNELS,
    };

    /// True when channel `c` holds the views' mean rather than their variance.
    #[inline(always)]
    pub const fn is_mean(&self, c: usize) -> bool {
        c + self.mean_channels >= self.channels
    }
}

/// One source view: its features and its warp table.
#[derive(Clone, Copy, Debug)]
pub struct SourceView<'a> {
    /// Features `[C][H][W]`, same scale as the reference.
    pub features: &'a [i8],
    /// Warp table `[plane × W + column]`.
    pub warp: &'a [WarpEntry],
}

/// How the variance is requantised and stored (QUANTISATION.md "Warp and cost volume").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CostRequant {
    /// `m_n = s_f² / (n² · s_cost)`.
    pub requant: Requant,
    /// `m'_n = s_f / (n · s_cost)`: the mean channels' multiplier (unused without them).
    pub mean: Requant,
    /// Stored value of a zero variance: 0 (codes `0..=127`, blobs written before the
    /// unsigned cost volume) or −128 (codes `−128..=127` for `q` in `0..=255`). The layers
    /// that read the cost volume add `−zero_point` back (d1's `input_offset`, u0's skip offset).
    pub zero_point: i32,
}

impl CostRequant {
    /// The zero points the contract allows.
    pub const ZERO_POINTS: [i32; 2] = [0, -128];

    /// The stored value of a requantised variance `q`.
    #[inline(always)]
    pub fn store(self, q: i32) -> i8 {
        (q.clamp(0, 127 - self.zero_point) + self.zero_point) as i8
    }

    /// True when the zero point is one of [`CostRequant::ZERO_POINTS`].
    pub const fn zero_point_valid(self) -> bool {
        self.zero_point == Self::ZERO_POINTS[0] || self.zero_point == Self::ZERO_POINTS[1]
    }
}

/// Full interpolation weight of the warp fraction (8 fraction bits).
const ONE: u16 = 256;

fn check(
    shape: &CostShape,
    reference: &[i8],
    sources: &[SourceView<'_>],
    cq: CostRequant,
    output: &[i8],
) -> Result<(), KernelError> {
    check_inner(shape, reference, sources, cq, output.len())
}

fn check_inner(
    shape: &CostShape,
    reference: &[i8],
    sources: &[SourceView<'_>],
    cq: CostRequant,
    output_len: usize,
) -> Result<(), KernelError> {
    let requant = cq.requant;
    if !cq.zero_point_valid() {
        return Err(KernelError::CostZeroPoint {
            zero_point: cq.zero_point,
        });
    }
    if !(1..=2).contains(&sources.len()) {
        return Err(KernelError::ViewCount {
            sources: sources.len(),
        });
    }
    let ch = shape.height.checked_mul(shape.width);
    let feat = ch
        .and_then(|x| x.checked_mul(shape.channels))
        .ok_or(KernelError::SizeOverflow)?;
    let table = shape
        .planes
        .checked_mul(shape.width)
        .ok_or(KernelError::SizeOverflow)?;
    let vol = feat
        .checked_mul(shape.planes)
        .ok_or(KernelError::SizeOverflow)?;
    expect(Operand::Reference, feat, reference.len())?;
    expect(Operand::Output, vol, output_len)?;
    for (k, s) in sources.iter().enumerate() {
        expect(Operand::Source(k as u8), feat, s.features.len())?;
        expect(Operand::Warp(k as u8), table, s.warp.len())?;
        for (index, e) in s.warp.iter().enumerate() {
            let c = e.column as usize;
            let bad =
                e.fraction > ONE || c >= shape.width || (e.fraction > 0 && c + 1 >= shape.width);
            if e.visible && bad {
                return Err(KernelError::WarpEntry {
                    source: k as u8,
                    index,
                });
            }
        }
    }
    if shape.mean_channels > shape.channels {
        return Err(KernelError::MeanChannels {
            mean_channels: shape.mean_channels,
            channels: shape.channels,
        });
    }
    // X ≤ n²·128² (< 2^18 for n ≤ 3); |Σv| ≤ n·128.
    let n = sources.len() as i64 + 1;
    check_requant(requant, n * n * 128 * 128)?;
    if shape.mean_channels > 0 {
        // A mean below 0 stores what 0 does only for M' ≥ 0 (the streamed kernel relies on it).
        if cq.mean.multiplier < 0 {
            return Err(KernelError::NegativeMultiplier {
                multiplier: cq.mean.multiplier,
            });
        }
        check_requant(cq.mean, n * 128)?;
    }
    Ok(())
}

/// A per-tensor multiplier's shift range and its accumulator bound.
fn check_requant(rq: Requant, bound: i64) -> Result<(), KernelError> {
    if !rq.shift_in_range() {
        return Err(KernelError::Shift {
            channel: 0,
            shift: rq.shift,
        });
    }
    if !rq.fits(bound) {
        return Err(KernelError::AccumulatorOverflow { channel: 0, bound });
    }
    Ok(())
}

/// Warped value of one source pixel from the row of its features (validated entry).
#[inline(always)]
fn warp(row: &[i8], e: WarpEntry) -> i32 {
    if !e.visible {
        return 0;
    }
    let c = e.column as usize;
    let a = e.fraction as i32;
    let left = row[c] as i32 * (ONE as i32 - a);
    // F[c+1] is read only when α > 0 (it may not exist for the last column).
    let right = if a > 0 { row[c + 1] as i32 * a } else { 0 };
    (left + right + 128) >> 8
}

#[inline(always)]
fn cost(sum: i32, sum_sq: i32, n: i32, cq: CostRequant) -> i8 {
    let x = n * sum_sq - sum * sum;
    cq.store(cq.requant.apply(x))
}

/// Plain reference: one voxel at a time, index arithmetic from scratch.
pub fn cost_volume_s8_plain(
    shape: &CostShape,
    reference: &[i8],
    sources: &[SourceView<'_>],
    cq: CostRequant,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check(shape, reference, sources, cq, output)?;
    let CostShape {
        channels,
        planes,
        height,
        width,
        mean_channels: _,
    } = *shape;
    let n = sources.len() as i32 + 1;
    for c in 0..channels {
        let is_mean = shape.is_mean(c);
        for j in 0..planes {
            for r in 0..height {
                for b in 0..width {
                    let v0 = reference[(c * height + r) * width + b] as i32;
                    let (mut sum, mut sum_sq) = (v0, v0 * v0);
                    for s in sources {
                        let e = s.warp[j * width + b];
                        let row_start = (c * height + r) * width;
                        let v = warp(&s.features[row_start..row_start + width], e);
                        sum += v;
                        sum_sq += v * v;
                    }
                    output[((c * planes + j) * height + r) * width + b] = if is_mean {
                        cq.store(cq.mean.apply(sum))
                    } else {
                        cost(sum, sum_sq, n, cq)
                    };
                }
            }
        }
    }
    Ok(())
}

/// A validated warp entry as two column indices and two weights (invisible → weights 0,
/// which gives `(0 + 0 + 128) >> 8 = 0`, the contract's invisible value).
#[derive(Clone, Copy, Default)]
struct Tap {
    left: u8,
    right: u8,
    wl: i16,
    wr: i16,
}

impl Tap {
    #[inline(always)]
    fn new(e: WarpEntry) -> Tap {
        if !e.visible {
            return Tap::default();
        }
        let a = e.fraction as i16;
        // F[c+1] is read only when α > 0 (it may not exist for the last column).
        let right = if a > 0 { e.column + 1 } else { e.column };
        Tap {
            left: e.column,
            right,
            wl: ONE as i16 - a,
            wr: a,
        }
    }

    #[inline(always)]
    fn warp(self, row: &[i8]) -> i32 {
        let l = row[self.left as usize] as i32 * self.wl as i32;
        (l + row[self.right as usize] as i32 * self.wr as i32 + 128) >> 8
    }

    /// The tap as two adjacent source columns `c, c + 1` and their weights, what the column
    /// kernels read (`arch::cost_column`, `arch::cost_column3`): a last-column tap weighs its
    /// left neighbour 0, an invisible one has both weights 0. `None` for rows narrower than
    /// two columns.
    #[inline(always)]
    fn window(self, width: usize) -> Option<(usize, i16, i16)> {
        if width < 2 {
            None
        } else if (self.left as usize) + 1 < width {
            Some((self.left as usize, self.wl, self.wr))
        } else {
            Some((width - 2, 0, self.wl))
        }
    }
}

/// Most feature columns the optimised kernel's per-plane tap table holds.
const MAX_WIDTH: usize = 64;

/// Optimised: each plane's warp entries become column/weight pairs once (no visibility
/// test per voxel); with two views `X = (v0 − v1)²` depends only on `|v0 − v1| ≤ 255`, so
/// the stored cost of `MBQM(X)` is a 256-entry table built once per call; three views use the
/// fast requantisation when the bound allows it.
pub fn cost_volume_s8(
    shape: &CostShape,
    reference: &[i8],
    sources: &[SourceView<'_>],
    cq: CostRequant,
    output: &mut [i8],
) -> Result<(), KernelError> {
    check(shape, reference, sources, cq, output)?;
    let CostShape {
        channels: _,
        planes,
        height,
        width,
        mean_channels: _,
    } = *shape;
    let plane_len = height * width;
    if output.is_empty() {
        // Nothing to compute (and a zero chunk size below would be meaningless).
        return Ok(());
    }
    if width > MAX_WIDTH {
        return cost_volume_s8_plain(shape, reference, sources, cq, output);
    }
    // |v0 − v1| ≤ 255 for int8 values and warps in −128..=127.
    let requant = cq.requant;
    let table: [i8; 256] = core::array::from_fn(|d| cq.store(requant.apply((d * d) as i32)));
    // X ≤ 9·128² for three views.
    let fast = requant.fits_fast(9 * 128 * 128);
    let frq = FastRequant::new(requant);
    for (c, out_c) in output.chunks_exact_mut(planes * plane_len).enumerate() {
        let ref_c = &reference[c * plane_len..(c + 1) * plane_len];
        for (j, out_j) in out_c.chunks_exact_mut(plane_len).enumerate() {
            let mut taps = [[Tap::default(); MAX_WIDTH]; 2];
            for (t, s) in taps.iter_mut().zip(sources) {
                for (t, &e) in t.iter_mut().zip(&s.warp[j * width..(j + 1) * width]) {
                    *t = Tap::new(e);
                }
            }
            let src0 = &sources[0].features[c * plane_len..(c + 1) * plane_len];
            if shape.is_mean(c) {
                let store = |sum: i32| cq.store(cq.mean.apply(sum));
                match sources.get(1) {
                    None => mean_columns2(out_j, ref_c, src0, 0..width, width, &taps[0], store),
                    Some(s1) => {
                        let src1 = &s1.features[c * plane_len..(c + 1) * plane_len];
                        mean_columns3(out_j, ref_c, [src0, src1], width, &taps, store)
                    }
                }
                continue;
            }
            match sources.get(1) {
                None => {
                    for ((out_r, ref_r), src_r) in out_j
                        .chunks_exact_mut(width)
                        .zip(ref_c.chunks_exact(width))
                        .zip(src0.chunks_exact(width))
                    {
                        for ((o, &v0), &t) in out_r.iter_mut().zip(ref_r).zip(&taps[0]) {
                            let d = v0 as i32 - t.warp(src_r);
                            *o = table[d.unsigned_abs() as u8 as usize];
                        }
                    }
                }
                Some(s1) => {
                    let src1 = &s1.features[c * plane_len..(c + 1) * plane_len];
                    for (r, out_r) in out_j.chunks_exact_mut(width).enumerate() {
                        let ref_r = &ref_c[r * width..(r + 1) * width];
                        let s0r = &src0[r * width..(r + 1) * width];
                        let s1r = &src1[r * width..(r + 1) * width];
                        for (b, o) in out_r.iter_mut().enumerate() {
                            let v0 = ref_r[b] as i32;
                            let v1 = taps[0][b].warp(s0r);
                            let v2 = taps[1][b].warp(s1r);
                            let sum = v0 + v1 + v2;
                            let x = 3 * (v0 * v0 + v1 * v1 + v2 * v2) - sum * sum;
                            let q = if fast { frq.apply(x) } else { requant.apply(x) };
                            *o = cq.store(q);
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// The cost volume prepared once for computing it piece by piece (the streamed model
/// computes it in rows of single planes, twice per depth map): the arguments are validated
/// and the two-view table built once in [`CostVolume::new`], so a piece costs its voxels and
/// a per-plane tap set-up. Same bits as [`cost_volume_s8`] and [`cost_volume_s8_plain`].
pub struct CostVolume<'a> {
    shape: CostShape,
    reference: &'a [i8],
    sources: [SourceView<'a>; 2],
    views: usize,
    cq: CostRequant,
    /// Two views: the stored cost of `MBQM((v0 − v1)²)` ([`CostRequant::store`]) at index
    /// `v0 − v1 + 255` (`0..=510`; the last entry is never read, it makes the index mask
    /// `& 511` exact).
    table: [i8; 512],
    /// Mean channels: the stored value of `MBQM(S, M', shift')` for the views' sum `S`, at
    /// index `S + 256` with two views (`S` in −256..=254, [`crate::arch::mean_column`]'s
    /// layout), at index `max(S, 0)` with three (`S ≤ 3·127`; a negative sum stores what 0
    /// does, the clipped mean, because `M' ≥ 0`).
    mean_table: [i8; 512],
}

impl<'a> CostVolume<'a> {
    /// Validates the operands as [`cost_volume_s8`] does (the output is not known yet).
    // Not inlined: the tables' temporaries then live in this frame, not in the caller's, which
    // stays on the stack while the UNet streams.
    #[inline(never)]
    pub fn new(
        shape: &CostShape,
        reference: &'a [i8],
        sources: &[SourceView<'a>],
        cq: CostRequant,
    ) -> Result<Self, KernelError> {
        let vol = shape
            .channels
            .checked_mul(shape.planes)
            .and_then(|x| x.checked_mul(shape.height))
            .and_then(|x| x.checked_mul(shape.width))
            .ok_or(KernelError::SizeOverflow)?;
        // `check` wants an output slice of the volume's length; only its length is read.
        check_lengths_only(shape, reference, sources, cq, vol)?;
        if shape.width > MAX_WIDTH {
            return Err(KernelError::SizeOverflow);
        }
        let empty = SourceView {
            features: &[],
            warp: &[],
        };
        let mut views = [empty; 2];
        for (v, s) in views.iter_mut().zip(sources) {
            *v = *s;
        }
        Ok(Self {
            shape: *shape,
            reference,
            sources: views,
            views: sources.len(),
            cq,
            table: core::array::from_fn(|i| {
                let d = i as i32 - 255;
                cq.store(cq.requant.apply(d * d))
            }),
            // `cq.mean` is validated only when there are mean channels.
            mean_table: core::array::from_fn(|i| match (shape.mean_channels, sources.len()) {
                (0, _) => 0,
                (_, 1) => cq.store(cq.mean.apply(i as i32 - 256)),
                _ => cq.store(cq.mean.apply(i as i32)),
            }),
        })
    }

    /// Rows `rows` of plane `plane` of channel `channel` (`rows.len() × width` voxels).
    pub fn rows(
        &self,
        channel: usize,
        plane: usize,
        rows: core::ops::Range<usize>,
        out: &mut [i8],
    ) -> Result<(), KernelError> {
        let CostShape {
            channels,
            planes,
            height,
            width,
            mean_channels: _,
        } = self.shape;
        if channel >= channels || plane >= planes || rows.start > rows.end || rows.end > height {
            return Err(KernelError::SizeOverflow);
        }
        let n = (rows.end - rows.start) * width;
        expect(Operand::Output, n, out.len())?;
        if n == 0 {
            return Ok(());
        }
        let start = (channel * height + rows.start) * width;
        let span = start..start + n;
        let reference = &self.reference[span.clone()];
        let mut taps = [[Tap::default(); MAX_WIDTH]; 2];
        for (t, s) in taps.iter_mut().zip(&self.sources[..self.views]) {
            for (t, &e) in t
                .iter_mut()
                .zip(&s.warp[plane * width..(plane + 1) * width])
            {
                *t = Tap::new(e);
            }
        }
        let src0 = &self.sources[0].features[span.clone()];
        if self.shape.is_mean(channel) {
            if self.views == 1 {
                // Column by column as the variance: the DSP loop where the tap has two
                // columns, else the plain arithmetic (`v0 + w + 256` in 0..=510).
                let done = self.quad_columns(out, reference, src0, &taps[0], true);
                for (b, t) in taps[0][..width].iter().enumerate() {
                    if done & (1 << b) != 0 {
                        continue;
                    }
                    if let Some((c, wl, wr)) = t.window(width) {
                        let table = &self.mean_table;
                        if crate::arch::mean_column(
                            out,
                            reference,
                            src0,
                            width,
                            b,
                            c,
                            (wl, wr),
                            table,
                        ) {
                            continue;
                        }
                    }
                    let store = |sum: i32| self.mean_table[(sum + 256).clamp(0, 511) as usize];
                    mean_columns2(out, reference, src0, b..b + 1, width, &taps[0], store);
                }
            } else {
                // Every sum ≤ 0 stores entry 0 (`z`, as M' ≥ 0); no sum exceeds 3·127.
                let store = |sum: i32| self.mean_table[sum.clamp(0, 511) as usize];
                let src1 = &self.sources[1].features[span];
                mean_columns3(out, reference, [src0, src1], width, &taps, store);
            }
            return Ok(());
        }
        if self.views == 1 {
            // Column by column (the column's tap stays in registers down the rows), each
            // tap as two adjacent source columns `c, c + 1` and their weights.
            let done = self.quad_columns(out, reference, src0, &taps[0], false);
            for (b, t) in taps[0][..width].iter().enumerate() {
                if done & (1 << b) != 0 {
                    continue;
                }
                if let Some((c, wl, wr)) = t.window(width) {
                    if crate::arch::cost_column(
                        out,
                        reference,
                        src0,
                        width,
                        b,
                        c,
                        (wl, wr),
                        &self.table,
                    ) {
                        continue;
                    }
                }
                // Not a two-column tap (a single column): the plain arithmetic.
                let (l, r) = (
                    (t.left as usize).min(width - 1),
                    (t.right as usize).min(width - 1),
                );
                let (wl, wr) = (t.wl as i32, t.wr as i32);
                let b = b.min(width - 1);
                for ((o, v), s) in out
                    .chunks_exact_mut(width)
                    .zip(reference.chunks_exact(width))
                    .zip(src0.chunks_exact(width))
                {
                    let w = (s[l] as i32 * wl + s[r] as i32 * wr + 128) >> 8;
                    o[b] = self.table[(v[b] as i32 - w + 255) as usize & 511];
                }
            }
            return Ok(());
        }
        let src1 = &self.sources[1].features[span];
        // One requantisation variant: the DSP kernel takes the columns of every blob the
        // quantiser writes (zero point −128), so the portable loop's speed matters little
        // and a second, fast-requantisation copy of it is not worth its flash.
        let requant = self.cq.requant;
        three_view_columns(out, reference, [src0, src1], width, &taps, requant, self.cq);
        Ok(())
    }
}

impl CostVolume<'_> {
    /// Two views with Helium: the columns of a piece four at a time where all four taps have
    /// two columns ([`crate::arch::table_columns4`]; the mean table when `mean`), as a mask of
    /// the columns done (bit `b`, `width ≤ MAX_WIDTH = 64`). 0 in builds without Helium, so
    /// the column loops there compile as before.
    #[inline(always)]
    fn quad_columns(
        &self,
        out: &mut [i8],
        reference: &[i8],
        src: &[i8],
        taps: &[Tap; MAX_WIDTH],
        mean: bool,
    ) -> u64 {
        if !cfg!(all(feature = "mve", target_arch = "arm")) {
            return 0;
        }
        let width = self.shape.width.min(MAX_WIDTH);
        let table = if mean { &self.mean_table } else { &self.table };
        let mut done = 0u64;
        let mut b = 0;
        while b + 4 <= width {
            let cols = (self.shape.width, b);
            // Eight columns in one pass where all eight taps have two columns, else four.
            if b + 8 <= width {
                let w: [_; 8] = core::array::from_fn(|k| taps[b + k].window(width));
                if let [Some(a), Some(c), Some(d), Some(e), Some(f), Some(g), Some(h), Some(i)] = w
                {
                    let eight = [a, c, d, e, f, g, h, i];
                    if crate::arch::table_columns8(out, reference, src, cols, eight, table, mean) {
                        done |= 0xff << b;
                        b += 8;
                        continue;
                    }
                }
            }
            let w = [0, 1, 2, 3].map(|k| taps[b + k].window(width));
            if let [Some(t0), Some(t1), Some(t2), Some(t3)] = w {
                let quad = [t0, t1, t2, t3];
                if crate::arch::table_columns4(out, reference, src, cols, quad, table, mean) {
                    done |= 0xf << b;
                }
            }
            b += 4;
        }
        done
    }
}

/// Three views, column by column: both taps of a column stay in registers down its rows, and
/// the variance is `n·Σv² − (Σv)² = (v0 − v1)² + (v0 − v2)² + (v1 − v2)²` (three multiplies).
/// [`crate::arch::cost_column3`] takes the columns it can (the unsigned cost volume); the rest
/// run here.
#[inline(always)]
fn three_view_columns(
    out: &mut [i8],
    reference: &[i8],
    sources: [&[i8]; 2],
    width: usize,
    taps: &[[Tap; MAX_WIDTH]; 2],
    requant: impl Apply,
    cq: CostRequant,
) {
    for b in 0..width {
        let (t0, t1) = (taps[0][b], taps[1][b]);
        if let (Some(w0), Some(w1)) = (t0.window(width), t1.window(width)) {
            let (rq, z) = (cq.requant, cq.zero_point);
            if crate::arch::cost_column3(out, reference, sources, (width, b), [w0, w1], rq, z) {
                continue;
            }
        }
        let rows = out
            .chunks_exact_mut(width)
            .zip(reference.chunks_exact(width))
            .zip(sources[0].chunks_exact(width))
            .zip(sources[1].chunks_exact(width));
        for (((o, v), s0), s1) in rows {
            let (v0, v1, v2) = (v[b] as i32, t0.warp(s0), t1.warp(s1));
            let (d01, d02, d12) = (v0 - v1, v0 - v2, v1 - v2);
            o[b] = cq.store(requant.apply(d01 * d01 + d02 * d02 + d12 * d12));
        }
    }
}

/// The mean channels of two views, column by column (the column's tap stays in registers down
/// the rows): `store(v0 + w1)`, where `store` gives `clamp(MBQM(Σv, M', shift'), 0, 127 − z) + z`.
#[inline(never)]
fn mean_columns2(
    out: &mut [i8],
    reference: &[i8],
    src0: &[i8],
    columns: core::ops::Range<usize>,
    width: usize,
    taps: &[Tap; MAX_WIDTH],
    store: impl Fn(i32) -> i8,
) {
    for b in columns {
        let t0 = taps[b];
        let rows = out
            .chunks_exact_mut(width)
            .zip(reference.chunks_exact(width))
            .zip(src0.chunks_exact(width));
        for ((o, v), s0) in rows {
            o[b] = store(v[b] as i32 + t0.warp(s0));
        }
    }
}

/// [`mean_columns2`] for three views: `store(v0 + w1 + w2)`.
#[inline(never)]
fn mean_columns3(
    out: &mut [i8],
    reference: &[i8],
    sources: [&[i8]; 2],
    width: usize,
    taps: &[[Tap; MAX_WIDTH]; 2],
    store: impl Fn(i32) -> i8,
) {
    for b in 0..width {
        let (t0, t1) = (taps[0][b], taps[1][b]);
        let rows = out
            .chunks_exact_mut(width)
            .zip(reference.chunks_exact(width))
            .zip(sources[0].chunks_exact(width))
            .zip(sources[1].chunks_exact(width));
        for (((o, v), s0), s1) in rows {
            o[b] = store(v[b] as i32 + t0.warp(s0) + t1.warp(s1));
        }
    }
}

/// [`check`] for an output of `output_len` elements.
fn check_lengths_only(
    shape: &CostShape,
    reference: &[i8],
    sources: &[SourceView<'_>],
    cq: CostRequant,
    output_len: usize,
) -> Result<(), KernelError> {
    check_inner(shape, reference, sources, cq, output_len)
}

#[cfg(test)]
mod tests {
    use super::super::testutil::Rng;
    use super::*;
    use crate::config;
    use std::vec;
    use std::vec::Vec;

    fn random_table(rng: &mut Rng, planes: usize, width: usize) -> Vec<WarpEntry> {
        (0..planes * width)
            .map(|_| {
                let column = rng.below(width) as u8;
                let fraction = if column as usize + 1 < width {
                    rng.range(0, 256) as u16
                } else {
                    0
                };
                WarpEntry {
                    column,
                    fraction,
                    visible: rng.below(5) != 0,
                }
            })
            .collect()
    }

    #[test]
    fn optimised_equals_plain_random() {
        let mut rng = Rng(42);
        for case in 0..100 {
            let channels = 1 + rng.below(3);
            let shape = CostShape {
                channels,
                planes: 1 + rng.below(4),
                height: 1 + rng.below(5),
                width: 1 + rng.below(7),
                mean_channels: rng.below(channels + 1),
            };
            let feat = shape.channels * shape.height * shape.width;
            let reference = rng.i8s(feat);
            let f1 = rng.i8s(feat);
            let f2 = rng.i8s(feat);
            let t1 = random_table(&mut rng, shape.planes, shape.width);
            let t2 = random_table(&mut rng, shape.planes, shape.width);
            let views = [
                SourceView {
                    features: &f1,
                    warp: &t1,
                },
                SourceView {
                    features: &f2,
                    warp: &t2,
                },
            ];
            let n_src = 1 + case % 2;
            let zero_point = CostRequant::ZERO_POINTS[(case / 2) % 2];
            let rq = CostRequant {
                requant: Requant {
                    multiplier: rng.range(1 << 30, (1i64 << 31) - 1) as i32,
                    shift: rng.range(-14, 0) as i32,
                },
                // From the mean's shrinking (shift −9) to its growing (shift 1) multipliers.
                mean: Requant {
                    multiplier: rng.range(1 << 30, (1i64 << 31) - 1) as i32,
                    shift: rng.range(-9, 2) as i32,
                },
                zero_point,
            };
            let len = feat * shape.planes;
            let (mut a, mut o) = (vec![0i8; len], vec![1i8; len]);
            cost_volume_s8_plain(&shape, &reference, &views[..n_src], rq, &mut a).unwrap();
            cost_volume_s8(&shape, &reference, &views[..n_src], rq, &mut o).unwrap();
            assert_eq!(a, o, "case {case} {shape:?}");
            assert!(a.iter().all(|&v| v as i32 >= zero_point));
            // Piece by piece: every (channel, plane, row range) of the prepared volume.
            let cv = CostVolume::new(&shape, &reference, &views[..n_src], rq).unwrap();
            let (h, w) = (shape.height, shape.width);
            for c in 0..shape.channels {
                for j in 0..shape.planes {
                    for r0 in 0..=h {
                        for r1 in r0..=h {
                            let mut piece = vec![7i8; (r1 - r0) * w];
                            cv.rows(c, j, r0..r1, &mut piece).unwrap();
                            let at = ((c * shape.planes + j) * h + r0) * w;
                            assert_eq!(piece, a[at..at + (r1 - r0) * w], "case {case}");
                        }
                    }
                }
            }
            let mut one = vec![0i8; w];
            assert!(cv.rows(shape.channels, 0, 0..1, &mut one).is_err());
            assert!(cv.rows(0, shape.planes, 0..1, &mut one).is_err());
            assert!(cv.rows(0, 0, 0..h + 1, &mut one).is_err());
            assert!(cv.rows(0, 0, 0..1, &mut one[..w - 1]).is_err());
        }
    }

    #[test]
    fn real_tables_two_and_three_views() {
        let mut rng = Rng(5);
        let shape = CostShape::EPSSN;
        let reference = rng.i8s(config::FEATURE_LEN);
        let f1 = rng.i8s(config::FEATURE_LEN);
        let f2 = rng.i8s(config::FEATURE_LEN);
        let views = [
            SourceView {
                features: &f1,
                warp: &config::WARP_TABLES[0],
            },
            SourceView {
                features: &f2,
                warp: &config::WARP_TABLES[1],
            },
        ];
        for (n, zero_point) in [(1, 0), (2, 0), (1, -128), (2, -128)] {
            let rq = CostRequant {
                requant: Requant::from_real(1.0 / 512.0).unwrap(),
                mean: Requant::from_real(0.75).unwrap(),
                zero_point,
            };
            let (mut a, mut o) = (
                vec![0i8; config::COST_VOLUME_LEN],
                vec![0i8; config::COST_VOLUME_LEN],
            );
            cost_volume_s8_plain(&shape, &reference, &views[..n], rq, &mut a).unwrap();
            cost_volume_s8(&shape, &reference, &views[..n], rq, &mut o).unwrap();
            assert_eq!(a, o);
            assert!(a.iter().any(|&v| v != a[0]));
        }
    }

    /// A warp table `[planes][width]` mapping every column onto itself (α = 0): the source
    /// seen through it is the source itself.
    fn identity_table(planes: usize, width: usize) -> Vec<WarpEntry> {
        (0..planes * width)
            .map(|i| WarpEntry {
                column: (i % width) as u8,
                fraction: 0,
                visible: true,
            })
            .collect()
    }

    #[test]
    fn identical_views_have_zero_cost_and_errors() {
        // A source whose table maps every column onto itself, α = 0: variance 0.
        let shape = CostShape {
            channels: 2,
            planes: 3,
            height: 4,
            width: 5,
            mean_channels: 0,
        };
        let mut rng = Rng(8);
        let f = rng.i8s(40);
        let table = identity_table(3, 5);
        let v = [SourceView {
            features: &f,
            warp: &table,
        }];
        let mut out = vec![1i8; 120];
        for zero_point in CostRequant::ZERO_POINTS {
            let rq = CostRequant {
                requant: Requant::from_real(1.0).unwrap(),
                zero_point,
                ..CostRequant::default()
            };
            cost_volume_s8(&shape, &f, &v, rq, &mut out).unwrap();
            assert!(out.iter().all(|&x| x as i32 == zero_point));
        }
        let rq = CostRequant {
            requant: Requant::from_real(1.0).unwrap(),
            zero_point: 0,
            ..CostRequant::default()
        };
        // Only the two zero points of the contract are accepted.
        assert_eq!(
            cost_volume_s8(
                &shape,
                &f,
                &v,
                CostRequant {
                    zero_point: -1,
                    ..rq
                },
                &mut out
            ),
            Err(KernelError::CostZeroPoint { zero_point: -1 })
        );
        // α = 256 reads the right neighbour exactly.
        let mut bad = table.clone();
        bad[4].fraction = 1;
        let v = [SourceView {
            features: &f,
            warp: &bad,
        }];
        assert_eq!(
            cost_volume_s8(&shape, &f, &v, rq, &mut out),
            Err(KernelError::WarpEntry {
                source: 0,
                index: 4
            })
        );
        assert_eq!(
            cost_volume_s8(&shape, &f, &[], rq, &mut out),
            Err(KernelError::ViewCount { sources: 0 })
        );
        let v = [SourceView {
            features: &f[1..],
            warp: &table,
        }];
        assert!(matches!(
            cost_volume_s8_plain(&shape, &f, &v, rq, &mut out),
            Err(KernelError::Length {
                operand: Operand::Source(0),
                ..
            })
        ));
    }

    #[test]
    fn mean_channels_hold_the_clipped_mean_and_errors() {
        // Two views whose source equals the reference (α = 0): the mean is the reference
        // itself; with M' = 1/2 per view pair the stored code is max(v, 0) + z.
        let shape = CostShape {
            channels: 2,
            planes: 3,
            height: 4,
            width: 5,
            mean_channels: 1,
        };
        let mut rng = Rng(9);
        let f = rng.i8s(40);
        let table = identity_table(3, 5);
        let v = [SourceView {
            features: &f,
            warp: &table,
        }];
        for zero_point in CostRequant::ZERO_POINTS {
            let rq = CostRequant {
                requant: Requant::from_real(1.0).unwrap(),
                mean: Requant::from_real(0.5).unwrap(),
                zero_point,
            };
            let mut out = vec![1i8; 120];
            cost_volume_s8(&shape, &f, &v, rq, &mut out).unwrap();
            let (variance, mean) = out.split_at(60);
            assert!(variance.iter().all(|&x| x as i32 == zero_point));
            for (k, &x) in mean.iter().enumerate() {
                let v = f[20 + k % 20] as i32;
                let expect = v.clamp(0, 127 - zero_point) + zero_point;
                assert_eq!(x as i32, expect, "zero point {zero_point}, voxel {k}");
            }
        }
        // More mean channels than channels, and a mean multiplier whose bound overflows.
        let rq = CostRequant {
            requant: Requant::from_real(1.0).unwrap(),
            mean: Requant::from_real(0.5).unwrap(),
            zero_point: -128,
        };
        let mut out = vec![0i8; 120];
        let too_many = CostShape {
            mean_channels: 3,
            ..shape
        };
        assert_eq!(
            cost_volume_s8(&too_many, &f, &v, rq, &mut out),
            Err(KernelError::MeanChannels {
                mean_channels: 3,
                channels: 2
            })
        );
        let huge = CostRequant {
            mean: Requant {
                multiplier: 1 << 30,
                shift: 30,
            },
            ..rq
        };
        assert!(matches!(
            cost_volume_s8(&shape, &f, &v, huge, &mut out),
            Err(KernelError::AccumulatorOverflow { .. })
        ));
        assert!(CostVolume::new(&shape, &f, &v, huge).is_err());
        let negative = CostRequant {
            mean: Requant {
                multiplier: -(1 << 30),
                shift: 0,
            },
            ..rq
        };
        assert_eq!(
            cost_volume_s8(&shape, &f, &v, negative, &mut out),
            Err(KernelError::NegativeMultiplier {
                multiplier: -(1 << 30)
            })
        );
        // Without mean channels the mean multiplier is not read.
        let none = CostShape {
            mean_channels: 0,
            ..shape
        };
        assert!(cost_volume_s8(&none, &f, &v, huge, &mut out).is_ok());
    }
}
