//! Runs the epssn kernels built with the `dsp` feature (SMLAD/SXTB16 inline assembly) on a
//! QEMU Cortex-M7, or with the `mve` feature (Helium) on a QEMU Cortex-M55, and compares them
//! with the plain kernels, bit for bit, on every layer of the build's spec (random weights;
//! random, all-127 and all-−128 inputs), and the inner loops with plain loops on random
//! lengths and tails. It also averages pings with
//! `epssn::ping_average` and checks that the device gets the host's bytes.
//!
//! Run: `cd qemu-check && cargo run --release` (needs `qemu-system-arm`; exits non-zero on
//! any mismatch); on the Cortex-M55: `cargo run --release --target thumbv8m.main-none-eabihf
//! --features mve`. A standalone crate so the library workspace stays host-only.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use epssn::config;
use epssn::kernels::conv2d_s8::{conv2d_s8, conv2d_s8_plain};
use epssn::kernels::conv3d_s8::{conv3d_s8, conv3d_s8_plain};
use epssn::kernels::conv_transpose3d_s8::{conv_transpose3d_s8, conv_transpose3d_s8_plain};
use epssn::kernels::cost_volume_s8::{
    cost_volume_s8, cost_volume_s8_plain, CostRequant, CostShape, CostVolume, SourceView,
};
use epssn::kernels::head_s8::{head_s8, head_step_planes, head_step_s8, head_steps};
use epssn::kernels::soft_argmax_s8::{
    head_soft_argmax_s8, soft_argmax_s8_plain, SoftArgmaxParams, SoftArgmaxShape,
};
use epssn::kernels::{ConvParams, ConvShape, Skip};
use epssn::requant::Requant;
use fixed::types::U16F16;

/// exp(x) for x ≤ 0 by squaring a Taylor series (no libm needed for a test table).
fn approx_exp(x: f64) -> f64 {
    let y = x / 1024.0;
    let mut e = 1.0 + y + y * y / 2.0 + y * y * y / 6.0;
    for _ in 0..10 {
        e *= e;
    }
    e
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn fill(&mut self, b: &mut [i8]) {
        for x in b {
            *x = self.next() as i8;
        }
    }
}

const MAXW: usize = 16 * 16 * 27;
const MAXA: usize = 131072;

#[entry]
fn main() -> ! {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    let mut w = [0i8; MAXW];
    let mut input = [0i8; MAXA];
    let mut a = [0i8; MAXA];
    let mut b = [0i8; MAXA];
    let mut bias = [0i32; 16];
    let mut rq = [Requant::default(); 16];
    let mut failures = 0u32;
    let mut checked = 0u32;
    for round in 0..3 {
        for l in config::LAYERS.iter() {
            let shape = ConvShape::from(l);
            rng.fill(&mut w[..l.weight_len()]);
            for w in w[..l.weight_len()].iter_mut() {
                if *w == -128 {
                    *w = -127;
                }
            }
            for o in 0..l.out_channels {
                bias[o] = (rng.next() % 40_001) as i32 - 20_000;
                rq[o] = Requant {
                    multiplier: (1 << 30) + (rng.next() % (1 << 30)) as i32,
                    shift: -7 - (rng.next() % 3) as i32,
                };
            }
            let p = ConvParams {
                weights: &w[..l.weight_len()],
                bias: &bias[..l.out_channels],
                requant: &rq[..l.out_channels],
                // The network input and the unsigned cost volume (d1's input) add 128.
                input_offset: if l.name == "f0" || l.name == "d1" {
                    128
                } else {
                    0
                },
                relu: l.relu,
            };
            let n_in = l.input_len();
            let n_out = l.output_len();
            if n_in > MAXA || n_out > MAXA {
                continue;
            }
            match round {
                0 => rng.fill(&mut input[..n_in]),
                1 => input[..n_in].fill(127),
                _ => input[..n_in].fill(-128),
            }
            let skip_rq = Requant {
                multiplier: 1 << 30,
                shift: 1,
            };
            let (ra, rb) = match l.kind {
                config::LayerKind::Conv2d => (
                    conv2d_s8(&shape, &input[..n_in], &p, &mut a[..n_out]),
                    conv2d_s8_plain(&shape, &input[..n_in], &p, &mut b[..n_out]),
                ),
                config::LayerKind::Conv3d => (
                    conv3d_s8(&shape, &input[..n_in], &p, &mut a[..n_out]),
                    conv3d_s8_plain(&shape, &input[..n_in], &p, &mut b[..n_out]),
                ),
                config::LayerKind::ConvTranspose3d => {
                    rng.fill(&mut a[..n_out]);
                    b[..n_out].copy_from_slice(&a[..n_out]);
                    let s = Skip::InPlace {
                        requant: skip_rq,
                        offset: if l.skip == Some("cost") { 128 } else { 0 },
                    };
                    (
                        conv_transpose3d_s8(&shape, &input[..n_in], &p, s, &mut a[..n_out]),
                        conv_transpose3d_s8_plain(&shape, &input[..n_in], &p, s, &mut b[..n_out]),
                    )
                }
            };
            checked += 1;
            let same = ra.is_ok() && rb.is_ok() && a[..n_out] == b[..n_out];
            let distinct = {
                let mut seen = [false; 256];
                for &x in &a[..n_out] {
                    seen[(x as i32 + 128) as usize] = true;
                }
                seen.iter().filter(|&&s| s).count()
            };
            hprintln!(
                "round {} {}: {} ({} distinct values)",
                round,
                l.name,
                if same { "bit-exact" } else { "MISMATCH" },
                distinct
            );
            if !same {
                failures += 1;
            }
        }
    }
    // The head (fused streaming kernel, or the overlapping head fused with the soft-argmax on
    // the whole input and step by step from rings) vs the plain transposed convolution + plain
    // soft-argmax (round 2: a bias beyond the fast requantisation's range),
    // and the cost volume with the real warp tables, optimised vs plain.
    let exp: [u16; 256] =
        core::array::from_fn(|d| (65535.0 * approx_exp(-(d as f64) * 0.05) + 0.5) as u16);
    let sp = SoftArgmaxParams {
        exp: &exp,
        r_min16: U16F16::from_num(config::R_MIN_M),
        step16: U16F16::from_num((config::R_MAX_M - config::R_MIN_M) / 63.0),
        end_offset: config::END_BIN_OFFSET as u16,
        no_return16: config::NO_RETURN_MASS_Q16,
    };
    let head = &config::LAYER_HEAD;
    let hs = ConvShape::from(head);
    for round in 0..3 {
        rng.fill(&mut w[..head.weight_len()]);
        bias[0] = (rng.next() % 20_001) as i32 - 10_000;
        if round == 2 {
            bias[0] = 1 << 30;
        }
        rq[0] = Requant {
            multiplier: (1 << 30) + (rng.next() % (1 << 30)) as i32,
            shift: -8,
        };
        let p = ConvParams {
            weights: &w[..head.weight_len()],
            bias: &bias[..1],
            requant: &rq[..1],
            input_offset: 0,
            relu: false,
        };
        if round != 1 {
            rng.fill(&mut input[..head.input_len()]);
        } else {
            input[..head.input_len()].fill(127);
        }
        let mut d_fused = [U16F16::ZERO; config::DEPTH_LEN];
        let mut d_plain = [U16F16::ZERO; config::DEPTH_LEN];
        let ss = SoftArgmaxShape {
            rows: config::DEPTH_ROWS,
            bins: config::DEPTH_RANGE_BINS,
            columns: config::DEPTH_COLUMNS,
        };
        // A head whose kernel equals its stride is fused by head_soft_argmax_s8; any head
        // (overlapping or not) by head_s8 on the whole input and head_step_s8 step by step
        // from rings of the last P planes (built in `b`, absent planes filled with garbage).
        let fused = hs.kernel == hs.stride && hs.padding == [0; 3];
        let mut r1 = if fused {
            head_soft_argmax_s8(&hs, &input[..head.input_len()], &p, &sp, &mut d_fused)
        } else {
            head_s8(&hs, &input[..head.input_len()], &p, &sp, &mut d_fused)
        };
        let mut d_steps = [U16F16::ZERO; config::DEPTH_LEN];
        let [planes, rows_in, cols_in] = hs.in_size;
        let (hw, np) = (rows_in * cols_in, head_step_planes(&hs));
        let ring_len = hs.in_channels * np * hw;
        for t in 0..head_steps(&hs) {
            // Slot z mod P holds plane z; the other slots and planes past the end: garbage.
            b[..ring_len].fill(-99);
            for z in (t + 1).saturating_sub(np)..=t.min(planes - 1) {
                for c in 0..hs.in_channels {
                    let dst = &mut b[((z % np) * hs.in_channels + c) * hw..][..hw];
                    dst.copy_from_slice(&input[(c * planes + z) * hw..][..hw]);
                }
            }
            r1 = r1.and(head_step_s8(&hs, &b[..ring_len], t, &p, &sp, &mut d_steps));
        }
        let r2 = conv_transpose3d_s8_plain(
            &hs,
            &input[..head.input_len()],
            &p,
            Skip::None,
            &mut a[..head.output_len()],
        );
        let r3 = soft_argmax_s8_plain(&ss, &a[..head.output_len()], &sp, &mut d_plain);
        let same =
            r1.is_ok() && r2.is_ok() && r3.is_ok() && d_fused == d_plain && d_steps == d_plain;
        hprintln!(
            "round {} {} head + soft-argmax: {}",
            round,
            if fused { "fused" } else { "overlapping" },
            if same { "bit-exact" } else { "MISMATCH" }
        );
        checked += 1;
        if !same {
            failures += 1;
        }
    }
    for views in 1..=2usize {
        let n = config::FEATURE_LEN;
        rng.fill(&mut input[..3 * n]);
        let (reference, rest) = input[..3 * n].split_at(n);
        let srcs = [
            SourceView {
                features: &rest[..n],
                warp: &config::WARP_TABLES[0],
            },
            SourceView {
                features: &rest[n..],
                warp: &config::WARP_TABLES[1],
            },
        ];
        // Both zero points: the signed cost of older blobs with 2 views, the unsigned one
        // the quantiser now writes with 3.
        let crq = CostRequant {
            requant: Requant {
                multiplier: 1 << 30,
                shift: -6,
            },
            // m' = 3/4: the mean channels run on the M7 too (CostShape::EPSSN has them).
            mean: Requant {
                multiplier: 3 << 29,
                shift: 0,
            },
            zero_point: if views == 1 { 0 } else { -128 },
        };
        let len = config::COST_VOLUME_LEN;
        let r1 = cost_volume_s8(
            &CostShape::EPSSN,
            reference,
            &srcs[..views],
            crq,
            &mut a[..len],
        );
        let r2 = cost_volume_s8_plain(
            &CostShape::EPSSN,
            reference,
            &srcs[..views],
            crq,
            &mut b[..len],
        );
        let same = r1.is_ok() && r2.is_ok() && a[..len] == b[..len];
        hprintln!(
            "cost volume, {} views: {}",
            views + 1,
            if same { "bit-exact" } else { "MISMATCH" }
        );
        checked += 1;
        if !same {
            failures += 1;
        }
        // The streamed model's pieces (one channel, one plane, a range of rows) of the
        // prepared volume, which run the DSP column loop, against the plain volume.
        let CostShape {
            channels,
            planes,
            height,
            width,
            mean_channels: _,
        } = CostShape::EPSSN;
        a[..len].fill(0);
        let mut ok = true;
        match CostVolume::new(&CostShape::EPSSN, reference, &srcs[..views], crq) {
            Ok(cv) => {
                for c in 0..channels {
                    for j in 0..planes {
                        // Two pieces per plane, split at a row that varies with the plane.
                        let cut = (j * 5) % (height + 1);
                        for rows in [0..cut, cut..height] {
                            let at = ((c * planes + j) * height + rows.start) * width;
                            let n = rows.len() * width;
                            ok &= cv.rows(c, j, rows, &mut a[at..at + n]).is_ok();
                        }
                    }
                }
            }
            Err(_) => ok = false,
        }
        let same = ok && a[..len] == b[..len];
        hprintln!(
            "cost volume pieces, {} views: {}",
            views + 1,
            if same { "bit-exact" } else { "MISMATCH" }
        );
        checked += 1;
        if !same {
            failures += 1;
        }
    }
    let fingerprint = epssn::ping_average::fingerprint().unwrap_or(0);
    let same = fingerprint == epssn::ping_average::FINGERPRINT;
    hprintln!(
        "ping average: {:#010x}, {}",
        fingerprint,
        if same { "the host's bytes" } else { "MISMATCH" }
    );
    checked += 1;
    if !same {
        failures += 1;
    }
    let (runs, bad) = inner_loops(&mut rng);
    hprintln!(
        "inner loops (dot2x2, dot2x2_row, RowPlan, RowPlan::run_channels, pack_rows, pack_strided, requant_row_s8, requant_rows_s8, requant_max_row, table_columns4, table_columns8, exp_sums, pack_line_quads, ChannelTaps; fill_channel_pairs, fill_bytes, PairRowsS8 with mve): {} random cases, {} mismatches",
        runs,
        bad
    );
    checked += 1;
    if bad > 0 {
        failures += 1;
    }
    hprintln!("{} layer runs, {} mismatches", checked, failures);
    if failures == 0 {
        debug::exit(debug::EXIT_SUCCESS);
    } else {
        debug::exit(debug::EXIT_FAILURE);
    }
    // Unreachable after the semihosting exit; trap if it ever returns.
    cortex_m::asm::udf()
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    // Unreachable after the semihosting exit; trap if it ever returns.
    cortex_m::asm::udf()
}

/// The `epssn::arch` inner loops (with `dsp` their SMLAD assembly, with `mve` their Helium
/// assembly) against plain loops written here, on random lengths, strides, offsets and
/// values, every tail included (lengths not a multiple of 4, an odd last position, `n` of
/// 2, 4 and 6 words). Returns (cases, mismatches).
fn inner_loops(rng: &mut Rng) -> (u32, u32) {
    use epssn::arch::{
        dot2x2, dot2x2_row, pack, pack_rows, requant_max_row, requant_row_s8, smmulr, RowPlan,
    };
    let (mut runs, mut bad) = (0u32, 0u32);
    let mut x = [0u32; 2048];
    let mut w = [0u32; 512];
    let mut bytes = [0i8; 512];
    for case in 0..600u32 {
        for v in x.iter_mut().chain(w.iter_mut()) {
            *v = rng.next() as u32;
        }
        rng.fill(&mut bytes);
        let n = 1 + (rng.next() % 40) as usize;
        let step = n + (rng.next() % 8) as usize;
        let positions = 1 + (rng.next() % 9) as usize;
        let astep = 1 + (rng.next() % 3) as usize;
        let bias = [rng.next() as i32 >> 8, rng.next() as i32 >> 8];
        // Plain dot products, wrapping as the instructions do.
        let plain = |q: usize, c: usize| -> i32 {
            let mut a = bias[c];
            for k in 0..n {
                let (xv, wv) = (x[q * step + k], w[2 * k + c]);
                let lo = (xv as u16 as i16 as i32).wrapping_mul(wv as u16 as i16 as i32);
                let hi =
                    ((xv >> 16) as u16 as i16 as i32).wrapping_mul((wv >> 16) as u16 as i16 as i32);
                a = a.wrapping_add(lo).wrapping_add(hi);
            }
            a
        };
        let d = dot2x2(&x, step, &w, n, [bias[0], bias[0], bias[1], bias[1]]);
        runs += 1;
        if d != [plain(0, 0), plain(1, 0), plain(0, 1), plain(1, 1)] {
            bad += 1;
        }
        let (mut acc0, mut acc1) = ([0i32; 32], [0i32; 32]);
        let ok = dot2x2_row(
            &x,
            step,
            positions,
            &w,
            n,
            bias,
            (&mut acc0, &mut acc1, astep),
        );
        runs += 1;
        if !ok
            || (0..positions)
                .any(|q| acc0[q * astep] != plain(q, 0) || acc1[q * astep] != plain(q, 1))
        {
            bad += 1;
        }
        // RowPlan: the shape prepared once, then a row at another offset of x (as the kernels
        // run every row of a layer), and a too-short x refused with the accumulators untouched.
        let plan = RowPlan::new(step, positions, n, astep);
        let shift = (rng.next() % 64) as usize;
        let (mut acc0, mut acc1) = ([0i32; 32], [0i32; 32]);
        let ok = plan.run(&x[shift..], &w, bias, (&mut acc0, &mut acc1));
        let plain_at = |q: usize, c: usize| -> i32 {
            let mut a = bias[c];
            for k in 0..n {
                let (xv, wv) = (x[shift + q * step + k], w[2 * k + c]);
                let lo = (xv as u16 as i16 as i32).wrapping_mul(wv as u16 as i16 as i32);
                let hi =
                    ((xv >> 16) as u16 as i16 as i32).wrapping_mul((wv >> 16) as u16 as i16 as i32);
                a = a.wrapping_add(lo).wrapping_add(hi);
            }
            a
        };
        runs += 1;
        if !ok
            || (0..positions)
                .any(|q| acc0[q * astep] != plain_at(q, 0) || acc1[q * astep] != plain_at(q, 1))
        {
            bad += 1;
        }
        let need = (positions - 1) * step + n;
        let (mut s0, mut s1) = ([7i32; 32], [7i32; 32]);
        runs += 1;
        if plan.run(&x[..need - 1], &w, bias, (&mut s0, &mut s1)) || s0 != [7; 32] || s1 != [7; 32]
        {
            bad += 1;
        }
        // RowPlan::run_channels: every channel pair of a line in one call (weights `wstride`
        // apart, rows `rstride` apart from `first`), against the plain dot products.
        let pairs_c = 1 + (rng.next() % 4) as usize;
        let wstride = 2 * n + (rng.next() % 3) as usize;
        let first = (rng.next() % 3) as usize;
        let rstride = first + (positions - 1) * astep + 1 + (rng.next() % 3) as usize;
        let mut biases = [[0i32; 2]; 4];
        for b in biases.iter_mut() {
            *b = [rng.next() as i32 >> 8, rng.next() as i32 >> 8];
        }
        if (pairs_c - 1) * wstride + 2 * n <= w.len() && 2 * pairs_c * rstride <= 256 {
            let mut rows = [0x5a5a_5a5ai32; 256];
            let ok = plan.run_channels(
                &x[shift..],
                (&w, wstride),
                &biases[..pairs_c],
                &mut rows,
                (rstride, first),
            );
            let plain_c = |k: usize, q: usize, c: usize| -> i32 {
                let mut a = biases[k][c];
                for j in 0..n {
                    let (xv, wv) = (x[shift + q * step + j], w[k * wstride + 2 * j + c]);
                    let lo = (xv as u16 as i16 as i32).wrapping_mul(wv as u16 as i16 as i32);
                    let hi = ((xv >> 16) as u16 as i16 as i32)
                        .wrapping_mul((wv >> 16) as u16 as i16 as i32);
                    a = a.wrapping_add(lo).wrapping_add(hi);
                }
                a
            };
            let at = |k: usize, c: usize, q: usize| (2 * k + c) * rstride + first + q * astep;
            let right = (0..pairs_c).all(|k| {
                (0..positions).all(|q| (0..2).all(|c| rows[at(k, c, q)] == plain_c(k, q, c)))
            });
            let touched = |i: usize| {
                (0..pairs_c).any(|k| (0..2).any(|c| (0..positions).any(|q| at(k, c, q) == i)))
            };
            let rest = (0..256).all(|i| touched(i) || rows[i] == 0x5a5a_5a5a);
            runs += 1;
            if !(ok && right && rest) {
                bad += 1;
            }
        }
        // pack_rows: a line column of two rows, with and without offsets.
        let len = (rng.next() % 70) as usize;
        let stride = 1 + (rng.next() % 5) as usize;
        let (oa, ob) = if case % 2 == 0 { (128, 128) } else { (0, 0) };
        let (ra, rb) = (&bytes[..len], &bytes[100..100 + len]);
        let mut dst = [0u32; 512];
        pack_rows(&mut dst, stride, ra, rb, oa, ob);
        runs += 1;
        if (0..len).any(|j| dst[j * stride] != pack(ra[j] as i16 + oa, rb[j] as i16 + ob)) {
            bad += 1;
        }
        // pack_strided: a column of two planes, any count (passes of eight, blocks of four and
        // the rest), the two columns' offsets different or equal.
        let count = (rng.next() % 24) as usize;
        let (sstride, dstride) = (1 + (rng.next() % 8) as usize, 1 + (rng.next() % 7) as usize);
        let mut dst = [0u32; 512];
        let (pa, pb) = (&bytes[..200], &bytes[250..450]);
        let (oa, ob) = if case % 3 == 0 { (128, -3) } else { (oa, ob) };
        epssn::arch::pack_strided(&mut dst, dstride, (pa, pb, sstride), count, oa, ob);
        runs += 1;
        let column = (0..count).all(|j| {
            dst[j * dstride] == pack(pa[j * sstride] as i16 + oa, pb[j * sstride] as i16 + ob)
        });
        let untouched = (0..512).all(|i| i % dstride == 0 && i / dstride < count || dst[i] == 0);
        if !(column && untouched) {
            bad += 1;
        }
        // requant_row_s8 with each of ReLU and the skip table.
        let mut acc = [0i32; 70];
        for a in acc.iter_mut() {
            *a = rng.next() as i32 >> (rng.next() % 16);
        }
        let mut table = [0i32; 256];
        for t in table.iter_mut() {
            *t = (rng.next() % 300) as i32 - 150;
        }
        let multiplier = (1 << 30) + (rng.next() % (1 << 30)) as i32;
        let (left1, right) = ((rng.next() % 3) as u32, (rng.next() % 12) as u32);
        let half = if right == 0 { 0 } else { 1 << (right - 1) };
        let neg = -((rng.next() % 2) as i32);
        let relu = case % 3 == 0;
        let skip = if case % 4 < 2 { Some(&table) } else { None };
        let mut out = [0i8; 70];
        rng.fill(&mut out[..len]);
        let old = out;
        requant_row_s8(
            &acc[..len],
            &mut out[..len],
            (multiplier, left1, right, half, neg),
            relu,
            skip,
        );
        runs += 1;
        let expect = |i: usize| -> i8 {
            let x = smmulr(acc[i].wrapping_shl(left1), multiplier);
            let t = x.wrapping_add(half).wrapping_add((x >> 31) & neg) >> right;
            let t = if relu { t.max(0) } else { t };
            let t = match skip {
                Some(l) => t.saturating_add(l[old[i] as u8 as usize]),
                None => t,
            };
            t.clamp(-128, 127) as i8
        };
        if (0..len).any(|i| out[i] != expect(i)) || out[len..] != old[len..] {
            bad += 1;
        }
        // requant_rows_s8: rows of their own parameters, `plane` apart (the bytes between
        // rows untouched), the width a multiple of 4 or not; shifts of 32 refused up front.
        let rows = 1 + (rng.next() % 4) as usize;
        let width = 1 + (rng.next() % 13) as usize;
        let plane = width + (rng.next() % 4) as usize;
        let mut words = [[0i32; 5]; 5];
        for p in words.iter_mut() {
            let (l, r) = ((rng.next() % 3) as i32, (rng.next() % 12) as i32);
            let m = (1 << 30) + (rng.next() % (1 << 30)) as i32;
            let n = -((rng.next() % 2) as i32);
            *p = [m, l, r, if r == 0 { 0 } else { 1 << (r - 1) }, n];
        }
        let params = epssn::arch::RowWords::new(&words[..rows]);
        let mut out = old;
        let ok = params.is_some_and(|p| {
            epssn::arch::requant_rows_s8(&acc, &mut out, p, (width, plane), relu, skip)
        });
        let expect_row = |c: usize, i: usize| -> i8 {
            let [m, l, r, h, n] = words[c];
            let x = smmulr(acc[c * width + i].wrapping_shl(l as u32), m);
            let t = x.wrapping_add(h).wrapping_add((x >> 31) & n) >> r;
            let t = if relu { t.max(0) } else { t };
            let t = match skip {
                Some(lut) => t.saturating_add(lut[old[c * plane + i] as u8 as usize]),
                None => t,
            };
            t.clamp(-128, 127) as i8
        };
        let written = |j: usize| j / plane < rows && j % plane < width;
        runs += 1;
        if !ok
            || (0..rows).any(|c| (0..width).any(|i| out[c * plane + i] != expect_row(c, i)))
            || (0..70).any(|j| !written(j) && out[j] != old[j])
        {
            bad += 1;
        }
        let mut wide = words;
        wide[rows - 1][1 + (case % 2) as usize] = 32;
        runs += 1;
        if epssn::arch::RowWords::new(&wide[..rows]).is_some() {
            bad += 1;
        }
        // requant_max_row: the same arithmetic, the int8 (or ReLU) clamp, and the maximum.
        let max0 = (rng.next() % 256) as u8 as i8;
        let mut out = old;
        let got = requant_max_row(
            &acc[..len],
            &mut out[..len],
            (multiplier, left1, right, half, neg),
            relu,
            max0,
        );
        runs += 1;
        let plain_max = |i: usize| -> i8 {
            let x = smmulr(acc[i].wrapping_shl(left1), multiplier);
            let t = x.wrapping_add(half).wrapping_add((x >> 31) & neg) >> right;
            if relu {
                t.clamp(0, 127) as i8
            } else {
                t.clamp(-128, 127) as i8
            }
        };
        let want = (0..len).map(plain_max).fold(max0, i8::max);
        if got != want || (0..len).any(|i| out[i] != plain_max(i)) || out[len..] != old[len..] {
            bad += 1;
        }
        runs += 1;
        if !table_columns_agree(rng, &bytes, 4) {
            bad += 1;
        }
        runs += 1;
        if !table_columns_agree(rng, &bytes, 8) {
            bad += 1;
        }
        runs += 2;
        bad += u32::from(!line_fill_agrees(rng, &bytes));
        bad += u32::from(!channel_taps_agree(rng, &bytes));
        #[cfg(feature = "mve")]
        {
            runs += 3;
            bad += u32::from(!channel_pairs_agree(rng, &bytes));
            bad += u32::from(!fill_bytes_agree(rng, &bytes));
            bad += u32::from(!pair_rows_s8_agree(rng, &bytes));
        }
        // exp_sums: any m (the sums wrap the index mod 256 as the table lookup does).
        let mut exp = [0u16; 256];
        for e in exp.iter_mut() {
            *e = rng.next() as u16;
        }
        let logits = &bytes[..len];
        let m = if case % 2 == 0 {
            logits.iter().copied().max().unwrap_or(0)
        } else {
            rng.next() as i8
        };
        let (mut ps, mut pt) = (0u32, 0u32);
        for (i, &q) in logits.iter().enumerate() {
            let e = exp[(m as i32 - q as i32) as u8 as usize] as u32;
            ps = ps.wrapping_add(e);
            pt = pt.wrapping_add(e.wrapping_mul(i as u32));
        }
        runs += 1;
        if epssn::arch::exp_sums(logits, m, &exp) != (ps, pt) {
            bad += 1;
        }
    }
    (runs, bad)
}

/// `dsp::pack_line_quads` (a line fill of up to 16 words; with `mve` its Helium loop) against
/// `pack_rows` word by word:
/// random rows (some the zero row without offset), lengths a multiple of 4, line widths and
/// fills shorter than the capacity; a row shorter than the fill's length is refused.
fn line_fill_agrees(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::pack_rows;
    use epssn::arch::{pack_line_quads, LineRows};
    static ZEROS: [i8; 64] = [0; 64];
    let len = 4 * (1 + (rng.next() % 12) as usize);
    let words = 1 + (rng.next() % 16) as usize;
    let vw = words + (rng.next() % 3) as usize;
    let mut rows = LineRows::new(len);
    let mut want = [0u32; 1024];
    let mut got = [0u32; 1024];
    let mut picked: [(usize, i16); 32] = [(0, 0); 32];
    for p in picked[..2 * words].iter_mut() {
        *p = if rng.next().is_multiple_of(5) {
            (usize::MAX, 0)
        } else {
            (
                (rng.next() as usize) % (512 - len),
                if rng.next().is_multiple_of(2) {
                    128
                } else {
                    -3
                },
            )
        };
    }
    let row = |(at, off): (usize, i16)| -> (&[i8], i16) {
        if at == usize::MAX {
            (&ZEROS[..len], 0)
        } else {
            (&bytes[at..at + len], off)
        }
    };
    let ok = rows.fill_with(2 * words, {
        let mut i = 0;
        move || {
            i += 1;
            row(picked[i - 1])
        }
    });
    if !ok || rows.push(&bytes[..len - 1], 0) {
        return false;
    }
    if !pack_line_quads(&mut got[..len * vw], vw, &rows) {
        return false;
    }
    for k in 0..words {
        let ((ra, oa), (rb, ob)) = (row(picked[2 * k]), row(picked[2 * k + 1]));
        pack_rows(&mut want[k..len * vw], vw, ra, rb, oa, ob);
    }
    got == want
}

/// `mve::fill_channel_pairs` (a channel-minor line fill: each tap's channel pairs from
/// channel 0's row and the channel step) against `pack_rows` on the rows it names, zero
/// rows for taps outside the input; words it must not write keep their value; a tap whose
/// last channel's row leaves the input, or an odd channel count, is refused.
#[cfg(feature = "mve")]
fn channel_pairs_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::fill_channel_pairs;
    use epssn::arch::pack_rows;
    static ZEROS: [i8; 64] = [0; 64];
    let need = 4 * (1 + (rng.next() % 12) as usize);
    let taps = 1 + (rng.next() % 9) as usize;
    let channels = 2 * (1 + (rng.next() % 4) as usize);
    // Every channel's row within the 512 bytes.
    let cs = (need + (rng.next() % 20) as usize).min((512 - need) / (channels - 1));
    let span = (channels - 1) * cs + need;
    let off = if rng.next().is_multiple_of(2) {
        128
    } else {
        -3
    };
    let mut at = [usize::MAX; 9];
    for a in at[..taps].iter_mut() {
        if !rng.next().is_multiple_of(4) {
            *a = (rng.next() as usize) % (512 - span + 1);
        }
    }
    let words = taps * channels / 2;
    let vw = words + (rng.next() % 3) as usize;
    let fill = rng.next() as u32;
    let (mut got, mut want) = ([fill; 48 * 40], [fill; 48 * 40]);
    let len = (need - 1) * vw + words;
    if !fill_channel_pairs(
        &mut got[..len],
        vw,
        need,
        (bytes, &at[..taps]),
        (channels, cs),
        off,
    ) {
        return false;
    }
    for (t, &a) in at[..taps].iter().enumerate() {
        for k in 0..channels / 2 {
            let row = |c: usize| -> (&[i8], i16) {
                if a == usize::MAX {
                    (&ZEROS[..need], 0)
                } else {
                    (&bytes[a + c * cs..a + c * cs + need], off)
                }
            };
            let ((ra, oa), (rb, ob)) = (row(2 * k), row(2 * k + 1));
            pack_rows(&mut want[t * channels / 2 + k..len], vw, ra, rb, oa, ob);
        }
    }
    // Refused: a row past the input, an odd channel count, a destination one word short.
    let mut past = at;
    past[0] = 512 - span + 1;
    let mut spare = [0u32; 48 * 40];
    if fill_channel_pairs(
        &mut spare[..len],
        vw,
        need,
        (bytes, &past[..taps]),
        (channels, cs),
        off,
    ) || fill_channel_pairs(
        &mut spare[..len],
        vw,
        need,
        (bytes, &at[..taps]),
        (3, cs),
        off,
    ) || fill_channel_pairs(
        &mut spare[..len - 1],
        vw,
        need,
        (bytes, &at[..taps]),
        (channels, cs),
        off,
    ) {
        return false;
    }
    got == want
}

/// `mve::fill_bytes` (the int8 line: each tap's channels' rows, raw, the pad row for taps
/// outside the input) against a plain loop; bytes it must not write keep their value; a row
/// past the input, a column of too few entries or a destination one byte short is refused.
#[cfg(feature = "mve")]
fn fill_bytes_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::fill_bytes;
    let len = 1 + (rng.next() % 40) as usize;
    let taps = 1 + (rng.next() % 9) as usize;
    let channels = 1 + (rng.next() % 8) as usize;
    let cs = len + (rng.next() % 20) as usize;
    let span = (channels - 1) * cs + len;
    let pad = [rng.next() as i8; 64];
    let mut at = [usize::MAX; 9];
    for a in at[..taps].iter_mut() {
        if !rng.next().is_multiple_of(4) {
            *a = (rng.next() as usize) % (512 - span + 1);
        }
    }
    let entries = taps * channels;
    // An even column for an even channel count (the halfword stores' alignment).
    let vp = entries + 2 * (rng.next() % 3) as usize;
    let fill = rng.next() as u8;
    // Word-aligned, as the line is (the halfword stores need their alignment).
    let (mut got, mut want) = (Aligned([fill; 80 * 40]), [fill; 80 * 40]);
    let got = &mut got.0;
    let n = (len - 1) * vp + entries;
    if !fill_bytes(
        &mut got[..n],
        vp,
        len,
        (bytes, &at[..taps]),
        (channels, cs),
        &pad,
    ) {
        return false;
    }
    for (t, &a) in at[..taps].iter().enumerate() {
        for i in 0..channels {
            for j in 0..len {
                let x = if a == usize::MAX {
                    pad[j]
                } else {
                    bytes[a + i * cs + j]
                };
                want[t * channels + i + j * vp] = x as u8;
            }
        }
    }
    let mut past = at;
    past[0] = 512 - span + 1;
    let mut spare = Aligned([0u8; 80 * 40]);
    let spare = &mut spare.0;
    if fill_bytes(
        &mut spare[..n],
        vp,
        len,
        (bytes, &past[..taps]),
        (channels, cs),
        &pad,
    ) || fill_bytes(
        &mut spare[..n],
        entries - 1,
        len,
        (bytes, &at[..taps]),
        (channels, cs),
        &pad,
    ) || fill_bytes(
        &mut spare[..n - 1],
        vp,
        len,
        (bytes, &at[..taps]),
        (channels, cs),
        &pad,
    ) {
        return false;
    }
    *got == want
}

/// `mve::PairRowsS8::run_channels` (int8 dot products, 16 per instruction, the tail by
/// predication) against a plain loop: random lengths 1 to 80 bytes, 1 to 6 pairs of
/// positions, 1 to 4 channel pairs, the rows' spare words untouched; slices one short
/// refused.
#[cfg(feature = "mve")]
fn pair_rows_s8_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::PairRowsS8;
    let n = 1 + (rng.next() % 80) as usize;
    let pairs = 1 + (rng.next() % 6) as usize;
    let step = 1 + (rng.next() % 24) as usize;
    let chans = 1 + (rng.next() % 4) as usize;
    let Some(plan) = PairRowsS8::new(step, n, pairs) else {
        return false;
    };
    let x_len = (2 * pairs - 1) * step + n;
    let x: &[u8] = &bytemuck_bytes(bytes)[..x_len];
    let wpair = plan.pair_bytes();
    let wstride = wpair + 4 * (rng.next() % 3) as usize;
    let mut w = [0u8; 4 * 112 * 2];
    for (k, b) in w.iter_mut().enumerate() {
        // Zero past the window in each block, as the engine lays it out.
        let (pair_at, block_at) = (k % wstride, k % wstride % 32);
        let e = (pair_at / 32) * 16 + block_at % 16;
        *b = if pair_at < wpair && e < n {
            rng.next() as u8
        } else {
            0
        };
    }
    let mut bias = [[0i32; 2]; 4];
    for b in bias[..chans].iter_mut() {
        *b = [rng.next() as i32 >> 8, rng.next() as i32 >> 8];
    }
    let rstride = 2 * pairs + (rng.next() % 3) as usize;
    let fill = rng.next() as i32;
    let acc_len = (2 * chans - 1) * rstride + 2 * pairs;
    let (mut got, mut want) = ([fill; 8 * 16], [fill; 8 * 16]);
    let w_len = (chans - 1) * wstride + wpair;
    if !plan.run_channels(
        x,
        (&w[..w_len], wstride),
        &bias[..chans],
        &mut got[..acc_len],
        (rstride, 0),
    ) {
        return false;
    }
    for k in 0..chans {
        for c in 0..2 {
            for q in 0..2 * pairs {
                let mut a = bias[k][c];
                for e in 0..n {
                    let wb = w[k * wstride + (e / 16) * 32 + c * 16 + e % 16] as i8;
                    a = a.wrapping_add(wb as i32 * x[q * step + e] as i8 as i32);
                }
                want[(2 * k + c) * rstride + q] = a;
            }
        }
    }
    let mut spare = [0i32; 8 * 16];
    if plan.run_channels(
        &x[..x_len - 1],
        (&w[..w_len], wstride),
        &bias[..chans],
        &mut spare[..acc_len],
        (rstride, 0),
    ) || plan.run_channels(
        x,
        (&w[..w_len - 1], wstride),
        &bias[..chans],
        &mut spare[..acc_len],
        (rstride, 0),
    ) || plan.run_channels(
        x,
        (&w[..w_len], wstride),
        &bias[..chans],
        &mut spare[..acc_len - 1],
        (rstride, 0),
    ) {
        return false;
    }
    got == want
}

/// A word-aligned byte array.
#[cfg(feature = "mve")]
#[repr(align(4))]
struct Aligned([u8; 80 * 40]);

/// The bytes of an int8 array, as the int8 line engine reads them.
#[cfg(feature = "mve")]
fn bytemuck_bytes(b: &[i8; 512]) -> [u8; 512] {
    b.map(|x| x as u8)
}

/// `dsp::ChannelTaps` (a whole line's rows, channel by channel and tap by tap, then zero
/// rows) through `pack_line_quads`, chunk by chunk, against `pack_rows` on the rows the
/// definition names; a tap whose last channel's row leaves the input is refused.
fn channel_taps_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::pack_rows;
    use epssn::arch::{pack_line_quads, ChannelTaps, LineRows};
    static ZEROS: [i8; 16] = [0; 16];
    let len = 4 * (1 + (rng.next() % 4) as usize);
    let taps = 1 + (rng.next() % 9) as usize;
    let channels = 1 + (rng.next() % 4) as usize;
    let cs = len + (rng.next() % 40) as usize;
    let span = (channels - 1) * cs + len;
    let off = if rng.next().is_multiple_of(2) { 128 } else { 0 };
    let mut at = [usize::MAX; 9];
    for a in at[..taps].iter_mut() {
        if !rng.next().is_multiple_of(4) {
            *a = (rng.next() as usize) % (512 - span + 1);
        }
    }
    let entries = (channels * taps).div_ceil(4) * 4 + 4 * (rng.next() % 2) as usize;
    let mut rows_of = ChannelTaps::new(bytes, &at[..taps], (channels, cs), (len, off), entries);
    // The same taps with one row past the end are refused.
    let mut past = at;
    past[0] = 512 - span + 1;
    let mut rows = LineRows::new(len);
    let mut refused = ChannelTaps::new(bytes, &past[..taps], (channels, cs), (len, off), entries);
    if refused.next_rows(&mut rows, 2) || refused.next_rows(&mut rows, 0) {
        return false;
    }
    let vw = entries / 2;
    let (mut got, mut want) = ([0u32; 16 * 64], [0u32; 16 * 64]);
    let mut k0 = 0;
    while k0 < vw {
        let kn = (vw - k0).min(LineRows::CAPACITY / 2);
        if !rows_of.next_rows(&mut rows, 2 * kn)
            || !pack_line_quads(&mut got[k0..len * vw], vw, &rows)
        {
            return false;
        }
        k0 += kn;
    }
    // Nothing is left.
    if rows_of.next_rows(&mut rows, 2) {
        return false;
    }
    let row = |v: usize| -> (&[i8], i16) {
        let (i, t) = (v / taps, v % taps);
        if i < channels && at[t] != usize::MAX {
            (&bytes[at[t] + i * cs..][..len], off)
        } else {
            (&ZEROS[..len], 0)
        }
    };
    for k in 0..vw {
        let ((ra, oa), (rb, ob)) = (row(2 * k), row(2 * k + 1));
        pack_rows(&mut want[k..len * vw], vw, ra, rb, oa, ob);
    }
    got == want
}

/// `dsp::table_columns4` or `dsp::table_columns8` (`lanes` cost-volume columns of two views in
/// one pass) against the one-column formula on a random piece: Helium builds must take it,
/// the others refuse it and leave `out` alone. Extreme values (−128, 127 and weights of 256)
/// come often, the edges of the eight-lane version's 16-bit sums.
fn table_columns_agree(rng: &mut Rng, bytes: &[i8; 512], lanes: usize) -> bool {
    let width = lanes + (rng.next() % 13) as usize;
    let rows = 1 + (rng.next() as usize) % (256 / width);
    let n = rows * width;
    let col = (rng.next() as usize) % (width - lanes + 1);
    let taps: [(usize, i16, i16); 8] = core::array::from_fn(|_| {
        let c = (rng.next() as usize) % (width - 1);
        let wr = match rng.next() % 4 {
            0 => 0,
            1 => 256,
            _ => (rng.next() % 257) as i16,
        };
        if rng.next().is_multiple_of(8) {
            (c, 0, 0)
        } else {
            (c, 256 - wr, wr)
        }
    });
    let mut table = [0i8; 512];
    rng.fill(&mut table);
    let sum = rng.next().is_multiple_of(2);
    let mut piece = [0i8; 512];
    piece.copy_from_slice(bytes);
    for v in piece.iter_mut() {
        match rng.next() % 4 {
            0 => *v = -128,
            1 => *v = 127,
            _ => {}
        }
    }
    let (reference, src) = (&piece[..n], &piece[256..256 + n]);
    let mut out = [0i8; 256];
    rng.fill(&mut out);
    let old = out;
    let cols = (width, col);
    let took = if lanes == 8 {
        epssn::arch::table_columns8(&mut out[..n], reference, src, cols, taps, &table, sum)
    } else {
        let four = [taps[0], taps[1], taps[2], taps[3]];
        epssn::arch::table_columns4(&mut out[..n], reference, src, cols, four, &table, sum)
    };
    if took != cfg!(feature = "mve") {
        return false;
    }
    (0..n).all(|i| {
        let (k, b) = (i / width, i % width);
        if !took || b < col || b >= col + lanes {
            return out[i] == old[i];
        }
        let (c, wl, wr) = taps[b - col];
        let s = &src[k * width..];
        let w = (s[c] as i32 * wl as i32 + s[c + 1] as i32 * wr as i32 + 128) >> 8;
        let index = if sum {
            reference[i] as i32 + w + 256
        } else {
            reference[i] as i32 - w + 255
        };
        out[i] == table[index as usize]
    })
}
