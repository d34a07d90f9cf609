//! The transposed convolution on the i16 line: one line engine run per output phase (the
//! output positions one stride apart that share their taps).

use super::*;

/// Taps of phase `f` on an axis with kernel `k`, stride `s`: `k = f + t·s`, `t < count`.
#[inline(always)]
pub(crate) fn phase_taps(k: usize, s: usize, f: usize) -> usize {
    if f >= k {
        0
    } else {
        (k - f).div_ceil(s)
    }
}

/// Line columns the transposed engine needs at most: input columns `−(⌈kw/sw⌉ − 1)` to
/// the last one any output reaches.
const fn transposed_cols(shape: &ConvShape) -> usize {
    let (sw, pw) = (shape.stride[2], shape.padding[2]);
    (shape.out_size[2] - 1 + pw) / sw + shape.kernel[2].div_ceil(sw)
}

/// Line entries per column of a transposed convolution (phase 0 has the most taps), padded
/// to a multiple of 4.
pub(super) const fn transposed_v(shape: &ConvShape) -> usize {
    // One `div_ceil` call site (it is `#[track_caller]`) for both axes: their divide-by-zero
    // panics share one location, which keeps `transposed_fits` compiled as tightly as before.
    const fn taps(shape: &ConvShape, a: usize) -> usize {
        shape.kernel[a].div_ceil(shape.stride[a])
    }
    up4(shape.in_channels * taps(shape, 0) * taps(shape, 1))
}

/// Line words a transposed convolution fills per (plane, row) of a phase.
pub(crate) const fn transposed_line_words(shape: &ConvShape) -> usize {
    line_words(transposed_v(shape), transposed_cols(shape))
}

/// Weight words of a transposed convolution's `kw` x phases, held together, for its `vp`
/// ([`transposed_v`], computed once by the caller: a second call site would change how
/// [`transposed_fits`] compiles).
pub(crate) const fn transposed_weight_words(shape: &ConvShape, vp: usize) -> usize {
    shape.out_channels.div_ceil(2) * 2 * shape.kernel[2] * vp / 2
}

/// Whether the transposed convolution fits the engine's buffers (phase 0 has the most taps;
/// the x phases' weights, `kw` column taps in all, are held together).
pub(crate) fn transposed_fits(shape: &ConvShape) -> bool {
    let vp = transposed_v(shape);
    vp <= MAX_V
        && shape.in_size[2] <= MAX_ROW
        && line_words(vp, transposed_cols(shape)) <= LINE_WORDS
        && transposed_weight_words(shape, vp) <= WEIGHT_WORDS
        && shape.out_channels <= MAX_FAST_CHANNELS
        && shape.stride[2] <= MAX_STRIDE
        && shape.out_size[2] <= MAX_POSITIONS
}

/// First output coordinate of phase `f` on an axis with stride `s`, padding `p` and `n`
/// outputs, and how many outputs the phase has.
#[inline(always)]
fn phase_first(f: usize, s: usize, p: usize, n: usize) -> (usize, usize) {
    let z0 = (f + s - p % s) % s;
    (z0, if z0 < n { (n - z0).div_ceil(s) } else { 0 })
}

/// What the weight layout of one `(fz, fy)` phase of a transposed convolution needs.
#[derive(Clone, Copy)]
struct Phase {
    fz: usize,
    fy: usize,
    /// Plane and row taps of the phase.
    tz: usize,
    ty: usize,
    /// Line entries per column (`ic · tz · ty`), and their words once padded to a multiple
    /// of 4.
    v_len: usize,
    vw: usize,
}

impl Phase {
    /// Phase `(fz, fy)` with `(tz, ty)` plane and row taps of `ic` input channels.
    fn new(ic: usize, (fz, fy): (usize, usize), (tz, ty): (usize, usize)) -> Self {
        let v_len = ic * tz * ty;
        let vw = up4(v_len) / 2;
        Phase {
            fz,
            fy,
            tz,
            ty,
            v_len,
            vw,
        }
    }
}

/// Each x phase's dot products have one shape for every row of the phase: their plans.
fn phase_plans(xs: &[XPhase; MAX_STRIDE], vw: usize, sw: usize) -> [RowPlan; MAX_STRIDE] {
    xs.map(|(_, nx, tx, _, _)| {
        let n = tx * vw;
        RowPlan::new(if n == 0 { 0 } else { vw }, nx, n, sw)
    })
}

/// One output row of a transposed phase with a row per channel ([`AccRows`] flat): each x
/// phase's dot products for every channel pair in one call (phase `fx` at `x0, x0 + sw, …` of
/// rows `width` words apart). `line`: the line and its filled words.
#[inline(always)]
fn run_phases(
    xs: &[XPhase; MAX_STRIDE],
    plans: &[RowPlan; MAX_STRIDE],
    (wbuf, vw): (&[u32; WEIGHT_WORDS], usize),
    (line, filled): (&[u32], usize),
    biases: &[[i32; 2]],
    (acc, width): (&mut RowAcc, usize),
    sw: usize,
) {
    let phases = xs.iter().zip(plans).take(sw.min(MAX_STRIDE));
    for (&(x0, nx, tx, wofs, start), plan) in phases {
        if nx == 0 {
            continue;
        }
        let w = (wbuf.get(wofs..).unwrap_or(&[]), 2 * tx * vw);
        let x = line.get(start..filled).unwrap_or(&[]);
        plan.run_channels(x, w, biases, acc, (width, x0));
    }
}

/// One x phase of a phase: (first output x, count, column taps, offset of its weights in the
/// weight buffer, first line word its first output reads).
type XPhase = (usize, usize, usize, usize, usize);

/// `vbase[v]`: weight index of line entry `v = (i, a, b)` of phase `(fz, fy)` for output
/// channel 0 and column tap 0 (`v = (a, b, i)` where the line goes channel-minor).
#[inline(always)]
fn phase_vbase(shape: &ConvShape, phase: &Phase, vbase: &mut [usize; MAX_V]) {
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, _] = shape.stride;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let Phase { fz, fy, tz, ty, .. } = *phase;
    // ((i·oc·kd + kz)·kh + ky)·kw with kz = fz + a·sd, ky = fy + b·sh (counted up).
    let taps_o = kd * kh * kw;
    // Line entry v is (i, a, b), or (a, b, i) where the line goes channel-minor.
    let minor = channel_minor(ic, tz * ty);
    let mut v = 0;
    for i in 0..ic {
        for a in 0..tz {
            for b in 0..ty {
                let at = if minor { (a * ty + b) * ic + i } else { v };
                if let Some(slot) = vbase.get_mut(at) {
                    *slot = i * oc * taps_o + ((fz + a * sd) * kh + fy + b * sh) * kw;
                }
                v += 1;
            }
        }
    }
}

/// The x phases of `phase`, their weights laid out in `wbuf` from word `base` on unless
/// `laid_out` (kept there by an earlier call).
#[inline(always)]
fn x_phases(
    shape: &ConvShape,
    params: &ConvParams<'_>,
    phase: &Phase,
    (ixlo, base, laid_out): (isize, usize, bool),
    wbuf: &mut [u32; WEIGHT_WORDS],
) -> [XPhase; MAX_STRIDE] {
    let [_, _, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let [_, _, sw] = shape.stride;
    let [_, _, pw] = shape.padding;
    let oc = shape.out_channels;
    let Phase { v_len, vw, .. } = *phase;
    let mut xs = [(0usize, 0usize, 0usize, 0usize, 0usize); MAX_STRIDE];
    let mut wofs = base;
    let taps_o = kd * kh * kw;
    let mut vbase = [0usize; MAX_V];
    phase_vbase(shape, phase, &mut vbase);
    for (fx, x) in xs.iter_mut().enumerate().take(sw.min(MAX_STRIDE)) {
        let (tx, (x0, nx)) = (phase_taps(kw, sw, fx), phase_first(fx, sw, pw, ow));
        // Output x reads input columns bx − (tx − 1) ..= bx, bx = (x + pw) / sw.
        let bx0 = (x0 + pw) / sw;
        let start = (bx0 as isize + 1 - tx as isize - ixlo).max(0) as usize * vw;
        *x = (x0, nx, tx, wofs, start);
        // Weights [O][c'][v] as i16 pairs: column tap c' reads input column
        // bx − (tx − 1 − c').
        let n = tx * vw;
        if laid_out {
            wofs += oc.div_ceil(2) * 2 * n;
            continue;
        }
        let wv = |o: usize, cp: usize, v: usize| {
            if v >= v_len {
                return 0;
            }
            let kx = fx + (tx - 1 - cp) * sw;
            params.weights[vbase[v] + o * taps_o + kx]
        };
        let wb = &mut wbuf[wofs..wofs + oc.div_ceil(2) * 2 * n];
        for o in 0..oc {
            for cp in 0..tx {
                for j in 0..vw {
                    let k = cp * vw + j;
                    wb[wslot(o, k, n)] = word(wv(o, cp, 2 * j), wv(o, cp, 2 * j + 1));
                }
            }
        }
        pad_pairs(wb, oc, n);
        wofs += oc.div_ceil(2) * 2 * n;
    }
    xs
}

/// Transposed convolution (validated shape that [`transposed_fits`]) in the gather form,
/// phase by phase: outputs with the same `(z + pad) mod stride` on every axis use the same
/// taps, and along a row of one phase output `bx` reads input columns `bx − c`, a window
/// of the line buffer like a forward convolution's. The `sw` x phases of a (plane, row)
/// read the same input rows, so they share one line fill. `layer`: the model's index of the
/// layer `params` belong to, under which their laid-out weights may be kept
/// ([`LineScratch::keep_weights`]); `None` lays them out at every call.
#[allow(clippy::too_many_arguments)]
pub(crate) fn transposed<R: Apply>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    layer: Option<usize>,
    rq: &[R],
    skip: SkipLut<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) {
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, _] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [pd, ph, _] = shape.padding;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let out_plane = od * oh * ow;
    let off = params.input_offset as i16;
    let cols = transposed_cols(shape);
    let (ixlo, span) = transposed_span(shape);
    let (slot, mut phase_base) = scratch.kept.claim_phases(shape, layer);
    let table = row_words(rq);
    let words = table
        .as_ref()
        .and_then(|t| crate::arch::RowWords::new(t.get(..oc)?));
    let rows = AccRows::new(oc, ow, words.is_some(), 1, skip);
    let bias_table = bias_pairs(params.bias.get(..oc).unwrap_or(&[]));
    let biases = bias_table.get(..oc.div_ceil(2)).unwrap_or(&[]);
    let LineScratch {
        wbuf,
        line,
        acc,
        kept,
    } = scratch;
    for fz in 0..sd {
        let (tz, (z0, nz)) = (phase_taps(kd, sd, fz), phase_first(fz, sd, pd, od));
        for fy in 0..sh {
            let (ty, (y0, ny)) = (phase_taps(kh, sh, fy), phase_first(fy, sh, ph, oh));
            let base = if slot.is_some() { phase_base } else { 0 };
            phase_base += transposed_phase_words(shape, fz, fy);
            if nz * ny == 0 {
                continue;
            }
            let laid_out = kept.laid_out(slot, 1u64 << ((fz * MAX_STRIDE + fy) % 64));
            let phase = Phase::new(ic, (fz, fy), (tz, ty));
            let (vw, vp) = (phase.vw, 2 * phase.vw);
            let xs = x_phases(shape, params, &phase, (ixlo, base, laid_out), wbuf);
            let plans = phase_plans(&xs, vw, sw);
            // The hot loop stays in this body: moved into an `#[inline(always)]` helper it
            // cost about 95 k instructions per pair more on the QEMU Cortex-M7.
            for qz in 0..nz {
                let z = z0 + qz * sd;
                let bz = (z + pd) / sd;
                for qy in 0..ny {
                    let y = y0 + qy * sh;
                    let by = (y + ph) / sh;
                    #[cfg(all(feature = "dsp", target_arch = "arm"))]
                    {
                        // Lines after the phase's first keep its zero padding columns.
                        let taps = LineTaps::transposed(shape, (bz, by), (tz, ty));
                        let padded = qz > 0 || qy > 0;
                        fill_taps(line, (vp, cols, padded), span, input, off, taps);
                    }
                    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
                    fill_transposed(
                        line,
                        (vp, cols),
                        span,
                        input,
                        off,
                        shape,
                        (bz, by),
                        (tz, ty),
                    );
                    // Every x phase's dot products into one row of accumulators per
                    // channel (phase fx at x0, x0 + sw, …), then one requantisation pass
                    // over the whole output row.
                    let base = (z * oh + y) * ow;
                    if let (true, Some(words)) = (rows.flat, words) {
                        // A row per channel: each x phase's dot products for every channel
                        // pair in one call, then every row's requantisation in one.
                        let x = (&line[..], vw * cols);
                        run_phases(&xs, &plans, (wbuf, vw), x, biases, (acc, ow), sw);
                        let at = (base, out_plane);
                        requant_rows(acc, (ow, oc), rq, words, params.relu, skip, output, at);
                        continue;
                    }
                    let mut o = 0;
                    while o < oc {
                        let two = o + 1 < oc;
                        let b = biases.get(o / 2).copied().unwrap_or([0, 0]);
                        let (acc0, acc1) = rows.pair(acc, o);
                        let phases = xs.iter().zip(&plans).take(sw.min(MAX_STRIDE));
                        for (&(x0, nx, tx, wofs, start), plan) in phases {
                            if nx == 0 {
                                continue;
                            }
                            let n = tx * vw;
                            let w = wbuf.get(wofs + o * n..wofs + (o + 2) * n).unwrap_or(&[]);
                            let x = line.get(start..vw * cols).unwrap_or(&[]);
                            let a0 = acc0.get_mut(x0..).unwrap_or(&mut []);
                            let a1 = acc1.get_mut(x0..).unwrap_or(&mut []);
                            plan.run(x, w, b, (a0, a1));
                        }
                        let mut req = |a: &[i32], o: usize| {
                            let at = o * out_plane + base;
                            requant_row(&a[..ow], rq[o], params.relu, skip, output, at, 1);
                        };
                        req(acc0, o);
                        if two {
                            req(acc1, o + 1);
                        }
                        o += 2;
                    }
                }
            }
        }
    }
}

/// Where a transposed convolution's line lies: it holds input columns `ixlo..` (`ixlo ≤ 0`:
/// the taps left of column 0 are zeros), the input's columns at line columns `lo..hi`.
fn transposed_span(shape: &ConvShape) -> (isize, (usize, usize, usize)) {
    let (iw, kw, sw) = (shape.in_size[2], shape.kernel[2], shape.stride[2]);
    let ixlo = 1 - kw.div_ceil(sw) as isize;
    let cols = transposed_cols(shape);
    let (lo, hi) = (
        (-ixlo).clamp(0, cols as isize) as usize,
        (iw as isize - ixlo).clamp(0, cols as isize) as usize,
    );
    (ixlo, (lo, hi.max(lo), 0))
}

/// Words of the laid-out weights of a transposed convolution's phase `(fz, fy)`: every x
/// phase's `[O][c'][v]` pairs.
pub(super) fn transposed_phase_words(shape: &ConvShape, fz: usize, fy: usize) -> usize {
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let vw = up4(ic * phase_taps(kd, sd, fz) * phase_taps(kh, sh, fy)) / 2;
    (0..sw.min(MAX_STRIDE))
        .map(|fx| oc.div_ceil(2) * 2 * phase_taps(kw, sw, fx) * vw)
        .sum::<usize>()
}

/// [`transposed`] with the fast requantisation and the skip table, when `bound` allows the
/// fast requantisation; false (nothing written) otherwise, as [`run_conv`].
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_transposed(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    bound: i64,
    layer: Option<usize>,
    skip: &Skip<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> bool {
    let oc = shape.out_channels;
    let Some(f) = fast_requants(params.requant, bound) else {
        return false;
    };
    let table = skip_table(skip);
    let lut = skip_lut(skip, &table);
    transposed(shape, input, params, layer, &f[..oc], lut, output, scratch);
    true
}
