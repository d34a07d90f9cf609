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

mod inner;

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

/// The most weights of any layer of the build's spec (m0's: 16 · 16 · 27 in EPSSN-S and
/// EPSSN-P, 32 · 32 · 27 in EPSSN-PW).
const MAXW: usize = most_of_layers(true);
/// The most output channels of any layer of the build's spec (their biases and requantisers).
const MAXC: usize = most_of_layers(false);

/// The largest weight count (`weights`) or output channel count over the spec's layers.
const fn most_of_layers(weights: bool) -> usize {
    let mut most = 0;
    let mut i = 0;
    while i < config::LAYER_COUNT {
        let l = &config::LAYERS[i];
        let n = if weights {
            l.weight_len()
        } else {
            l.out_channels
        };
        if n > most {
            most = n;
        }
        i += 1;
    }
    most
}
const MAXA: usize = 131072;

/// Checks run and mismatches found.
#[derive(Default)]
struct Tally {
    checked: u32,
    failures: u32,
}

impl Tally {
    /// Counts one check, and a failure unless `same`.
    fn check(&mut self, same: bool) {
        self.checked += 1;
        if !same {
            self.failures += 1;
        }
    }
}

/// The buffers the checks share: weights, an input and two outputs (on `main`'s stack,
/// which this harness's memory map widens to hold them).
struct Buffers<'a> {
    w: &'a mut [i8; MAXW],
    input: &'a mut [i8; MAXA],
    a: &'a mut [i8; MAXA],
    b: &'a mut [i8; MAXA],
}

/// The checks, in the order they run. They draw from one generator, so the order is part of
/// the test: each draws what it drew when they were one function.
const CASES: [fn(&mut Rng, &mut Buffers, &mut Tally); 5] =
    [layers, heads, cost_volumes, ping_average, inner_loops];

#[entry]
fn main() -> ! {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    let mut w = [0i8; MAXW];
    let mut input = [0i8; MAXA];
    let mut a = [0i8; MAXA];
    let mut b = [0i8; MAXA];
    let mut buffers = Buffers {
        w: &mut w,
        input: &mut input,
        a: &mut a,
        b: &mut b,
    };
    let mut tally = Tally::default();
    for case in CASES {
        case(&mut rng, &mut buffers, &mut tally);
    }
    hprintln!(
        "{} layer runs, {} mismatches",
        tally.checked,
        tally.failures
    );
    if tally.failures == 0 {
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

/// Every layer of the build's spec, optimised vs plain, in three rounds: random, all-127 and
/// all-−128 inputs.
fn layers(rng: &mut Rng, buf: &mut Buffers, tally: &mut Tally) {
    for round in 0..3 {
        for l in config::LAYERS.iter() {
            if let Some(same) = layer(rng, buf, l, round) {
                tally.check(same);
            }
        }
    }
}

/// One layer with random weights, biases and requantisation: `None` when its activations do
/// not fit the buffers.
fn layer(rng: &mut Rng, buf: &mut Buffers, l: &config::LayerShape, round: u32) -> Option<bool> {
    let Buffers { w, input, a, b } = buf;
    let (mut bias, mut rq) = ([0i32; MAXC], [Requant::default(); MAXC]);
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
        return None;
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
    Some(same)
}

/// The head (fused streaming kernel, or the overlapping head fused with the soft-argmax on
/// the whole input and step by step from rings) vs the plain transposed convolution + plain
/// soft-argmax, in three rounds (round 2: a bias beyond the fast requantisation's range).
fn heads(rng: &mut Rng, buf: &mut Buffers, tally: &mut Tally) {
    // EPSSN-P's sizes (512 x 128) outgrow the buffers; their heads run in the SIL.
    if config::LAYER_HEAD.input_len() > MAXA {
        hprintln!("heads: skipped (input larger than the harness's buffers)");
        return;
    }
    let exp: [u16; 256] =
        core::array::from_fn(|d| (65535.0 * approx_exp(-(d as f64) * 0.05) + 0.5) as u16);
    let sp = SoftArgmaxParams {
        exp: &exp,
        r_min16: U16F16::from_num(config::R_MIN_M),
        step16: U16F16::from_num((config::R_MAX_M - config::R_MIN_M) / 63.0),
        end_offset: config::END_BIN_OFFSET as u16,
        no_return16: config::NO_RETURN_MASS_Q16,
    };
    for round in 0..3 {
        tally.check(head_round(rng, buf, &sp, round));
    }
}

/// One round of [`heads`].
fn head_round(rng: &mut Rng, buf: &mut Buffers, sp: &SoftArgmaxParams, round: u32) -> bool {
    let Buffers { w, input, a, b } = buf;
    let head = &config::LAYER_HEAD;
    let hs = ConvShape::from(head);
    rng.fill(&mut w[..head.weight_len()]);
    let mut bias = (rng.next() % 20_001) as i32 - 10_000;
    if round == 2 {
        bias = 1 << 30;
    }
    let rq = Requant {
        multiplier: (1 << 30) + (rng.next() % (1 << 30)) as i32,
        shift: -8,
    };
    let p = ConvParams {
        weights: &w[..head.weight_len()],
        bias: &[bias],
        requant: &[rq],
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
        head_soft_argmax_s8(&hs, &input[..head.input_len()], &p, sp, &mut d_fused)
    } else {
        head_s8(&hs, &input[..head.input_len()], &p, sp, &mut d_fused)
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
        r1 = r1.and(head_step_s8(&hs, &b[..ring_len], t, &p, sp, &mut d_steps));
    }
    let r2 = conv_transpose3d_s8_plain(
        &hs,
        &input[..head.input_len()],
        &p,
        Skip::None,
        &mut a[..head.output_len()],
    );
    let r3 = soft_argmax_s8_plain(&ss, &a[..head.output_len()], sp, &mut d_plain);
    let same = r1.is_ok() && r2.is_ok() && r3.is_ok() && d_fused == d_plain && d_steps == d_plain;
    hprintln!(
        "round {} {} head + soft-argmax: {}",
        round,
        if fused { "fused" } else { "overlapping" },
        if same { "bit-exact" } else { "MISMATCH" }
    );
    same
}

/// The cost volume with the real warp tables, optimised vs plain, with two and three views:
/// whole, and in the streamed model's pieces.
fn cost_volumes(rng: &mut Rng, buf: &mut Buffers, tally: &mut Tally) {
    // As for the heads: a 512 x 128 spec's volume outgrows the buffers (the SIL runs it).
    if config::COST_VOLUME_LEN > MAXA || 3 * config::FEATURE_LEN > MAXA {
        hprintln!("cost volumes: skipped (larger than the harness's buffers)");
        return;
    }
    for views in 1..=2usize {
        let n = config::FEATURE_LEN;
        rng.fill(&mut buf.input[..3 * n]);
        let (reference, rest) = buf.input[..3 * n].split_at(n);
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
        let (a, b) = (&mut buf.a[..len], &mut buf.b[..len]);
        let r1 = cost_volume_s8(&CostShape::EPSSN, reference, &srcs[..views], crq, a);
        let r2 = cost_volume_s8_plain(&CostShape::EPSSN, reference, &srcs[..views], crq, b);
        let same = r1.is_ok() && r2.is_ok() && a == b;
        hprintln!(
            "cost volume, {} views: {}",
            views + 1,
            if same { "bit-exact" } else { "MISMATCH" }
        );
        tally.check(same);
        let same = cost_volume_pieces(reference, &srcs[..views], crq, a) && a == b;
        hprintln!(
            "cost volume pieces, {} views: {}",
            views + 1,
            if same { "bit-exact" } else { "MISMATCH" }
        );
        tally.check(same);
    }
}

/// The streamed model's pieces (one channel, one plane, a range of rows) of the prepared
/// volume, which run the DSP column loop, written into `out` (zeroed first).
fn cost_volume_pieces(
    reference: &[i8],
    srcs: &[SourceView],
    crq: CostRequant,
    out: &mut [i8],
) -> bool {
    let CostShape {
        channels,
        planes,
        height,
        width,
        mean_channels: _,
    } = CostShape::EPSSN;
    out.fill(0);
    let Ok(cv) = CostVolume::new(&CostShape::EPSSN, reference, srcs, crq) else {
        return false;
    };
    let mut ok = true;
    for c in 0..channels {
        for j in 0..planes {
            // Two pieces per plane, split at a row that varies with the plane.
            let cut = (j * 5) % (height + 1);
            for rows in [0..cut, cut..height] {
                let at = ((c * planes + j) * height + rows.start) * width;
                let n = rows.len() * width;
                ok &= cv.rows(c, j, rows, &mut out[at..at + n]).is_ok();
            }
        }
    }
    ok
}

/// `epssn::ping_average` on the device gives the host's bytes.
fn ping_average(_: &mut Rng, _: &mut Buffers, tally: &mut Tally) {
    let fingerprint = epssn::ping_average::fingerprint().unwrap_or(0);
    let same = fingerprint == epssn::ping_average::FINGERPRINT;
    hprintln!(
        "ping average: {:#010x}, {}",
        fingerprint,
        if same { "the host's bytes" } else { "MISMATCH" }
    );
    tally.check(same);
}

/// The inner loops ([`inner`]), one check of the tally: none of their cases mismatches.
fn inner_loops(rng: &mut Rng, _: &mut Buffers, tally: &mut Tally) {
    let (runs, bad) = inner::run(rng);
    hprintln!(
        "inner loops (dot2x2, dot2x2_row, RowPlan, RowPlan::run_channels, pack_rows, pack_strided, requant_row_s8, requant_rows_s8, requant_max_row, table_columns4, table_columns8, exp_sums, pack_line_quads, ChannelTaps; fill_channel_pairs, fill_bytes, PairRowsS8, gather_bytes, PairRowsS8::run_pair_short with mve): {} random cases, {} mismatches",
        runs,
        bad
    );
    tally.check(bad == 0);
}
