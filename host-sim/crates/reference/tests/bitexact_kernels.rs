//! The library's int8 kernels (optimised and plain) against the independent integer
//! reference `epssn_reference::intref`, zero tolerance: random small shapes, the EPSSN-S layers
//! chained through the whole network with random weights, extreme inputs, the cost volume
//! with the real warp tables and soft-argmax on extreme logits.

use epssn::config::{self, LayerKind, LayerShape, LAYERS};
use epssn::geometry::WarpEntry;
use epssn::kernels::conv2d_s8::{conv2d_s8, conv2d_s8_plain, conv2d_s8_rows};
use epssn::kernels::conv3d_s8::{conv3d_s8, conv3d_s8_plain, conv3d_s8_rows};
use epssn::kernels::conv_transpose3d_s8::{
    conv_transpose3d_s8, conv_transpose3d_s8_plain, conv_transpose3d_s8_taps,
};
use epssn::kernels::cost_volume_s8::{
    cost_volume_s8, cost_volume_s8_plain, CostRequant, CostShape, SourceView,
};
use epssn::kernels::soft_argmax_s8::{
    soft_argmax_s8, soft_argmax_s8_plain, SoftArgmaxParams, SoftArgmaxShape,
};
use epssn::kernels::{ConvParams, ConvShape, Skip};
use epssn::requant::Requant;
use epssn_reference::intref::{self, Mult, Shape};
use fixed::types::U16F16;

use epssn_sim::synthetic::Rng;

/// Random test data on the host's one generator.
trait TestData {
    fn i8s(&mut self, n: usize) -> Vec<i8>;
    fn mult(&mut self, shift_lo: i32, shift_hi: i32) -> Mult;
}

impl TestData for Rng {
    fn i8s(&mut self, n: usize) -> Vec<i8> {
        (0..n).map(|_| self.range(-128, 127) as i8).collect()
    }
    fn mult(&mut self, shift_lo: i32, shift_hi: i32) -> Mult {
        Mult {
            m: self.range(1 << 30, (1i64 << 31) - 1) as i32,
            shift: self.range(shift_lo as i64, shift_hi as i64) as i32,
        }
    }
}

/// Random int8 weights (±127, as the quantiser makes them), int32 biases and multipliers.
struct Layer {
    w: Vec<i8>,
    b: Vec<i32>,
    m: Vec<Mult>,
    rq: Vec<Requant>,
}

fn random_layer(rng: &mut Rng, sh: &Shape, shifts: (i32, i32), bias: i64) -> Layer {
    let n = sh.cin * sh.cout * sh.k.iter().product::<usize>();
    let w = (0..n).map(|_| rng.range(-127, 127) as i8).collect();
    let b = (0..sh.cout)
        .map(|_| rng.range(-bias, bias) as i32)
        .collect();
    let m: Vec<Mult> = (0..sh.cout).map(|_| rng.mult(shifts.0, shifts.1)).collect();
    let rq = m.iter().map(|&x| requant(x)).collect();
    Layer { w, b, m, rq }
}

fn requant(m: Mult) -> Requant {
    Requant {
        multiplier: m.m,
        shift: m.shift,
    }
}

fn conv_shape(s: &Shape) -> ConvShape {
    ConvShape {
        in_channels: s.cin,
        out_channels: s.cout,
        kernel: s.k,
        stride: s.s,
        padding: s.p,
        output_padding: s.op,
        in_size: s.n_in,
        out_size: s.n_out,
    }
}

fn params<'a>(l: &'a Layer, input_offset: i32, relu: bool) -> ConvParams<'a> {
    ConvParams {
        weights: &l.w,
        bias: &l.b,
        requant: &l.rq,
        input_offset,
        relu,
    }
}

/// What a layer adds to its inputs (QUANTISATION.md): 128 for the network input (f0) and for
/// the unsigned cost volume (d1 reads it), else 0.
fn input_offset(layer: &str) -> i32 {
    if layer == "f0" || layer == "d1" {
        128
    } else {
        0
    }
}

/// What a layer adds to its skip values: 128 when the skip is the unsigned cost volume.
fn skip_offset(skip: &str) -> i32 {
    if skip == "cost" {
        128
    } else {
        0
    }
}

/// Library (optimised and plain) vs reference for a forward convolution; returns the output.
fn check_conv(
    kind: LayerKind,
    sh: &Shape,
    input: &[i8],
    l: &Layer,
    input_offset: i32,
    relu: bool,
    what: &str,
) -> Vec<i8> {
    let want = intref::conv(sh, input, &l.w, &l.b, &l.m, input_offset, relu);
    let cs = conv_shape(sh);
    let p = params(l, input_offset, relu);
    let n = want.len();
    let (mut opt, mut plain, mut rows) = (vec![0i8; n], vec![0i8; n], vec![0i8; n]);
    match kind {
        LayerKind::Conv2d => {
            conv2d_s8(&cs, input, &p, &mut opt).unwrap();
            conv2d_s8_plain(&cs, input, &p, &mut plain).unwrap();
            conv2d_s8_rows(&cs, input, &p, &mut rows).unwrap();
        }
        _ => {
            conv3d_s8(&cs, input, &p, &mut opt).unwrap();
            conv3d_s8_plain(&cs, input, &p, &mut plain).unwrap();
            conv3d_s8_rows(&cs, input, &p, &mut rows).unwrap();
        }
    }
    assert_eq!(opt, want, "{what}: optimised vs reference");
    assert_eq!(plain, want, "{what}: plain vs reference");
    assert_eq!(rows, want, "{what}: row-blocked vs reference");
    want
}

/// Library vs reference for a transposed convolution with optional skip; the skip is run
/// both in a separate slice and in place.
fn check_convt(
    sh: &Shape,
    input: &[i8],
    l: &Layer,
    relu: bool,
    skip: Option<(&[i8], Mult, i32)>,
    what: &str,
) -> Vec<i8> {
    let want = intref::conv_transpose(sh, input, &l.w, &l.b, &l.m, 0, relu, skip);
    let cs = conv_shape(sh);
    let p = params(l, 0, relu);
    let n = want.len();
    let mut outs = Vec::new();
    match skip {
        None => {
            let (mut a, mut b) = (vec![0i8; n], vec![0i8; n]);
            conv_transpose3d_s8(&cs, input, &p, Skip::None, &mut a).unwrap();
            conv_transpose3d_s8_plain(&cs, input, &p, Skip::None, &mut b).unwrap();
            let mut c = vec![0i8; n];
            conv_transpose3d_s8_taps(&cs, input, &p, Skip::None, &mut c).unwrap();
            outs.push(("optimised", a));
            outs.push(("plain", b));
            outs.push(("taps", c));
        }
        Some((s, m, offset)) => {
            let sep = Skip::Separate {
                skip: s,
                requant: requant(m),
                offset,
            };
            let ip = Skip::InPlace {
                requant: requant(m),
                offset,
            };
            let (mut a, mut b) = (vec![0i8; n], vec![0i8; n]);
            conv_transpose3d_s8(&cs, input, &p, sep, &mut a).unwrap();
            conv_transpose3d_s8_plain(&cs, input, &p, sep, &mut b).unwrap();
            let (mut c, mut d) = (s.to_vec(), s.to_vec());
            conv_transpose3d_s8(&cs, input, &p, ip, &mut c).unwrap();
            conv_transpose3d_s8_plain(&cs, input, &p, ip, &mut d).unwrap();
            let mut e = s.to_vec();
            conv_transpose3d_s8_taps(&cs, input, &p, ip, &mut e).unwrap();
            outs.push(("taps, in place", e));
            outs.push(("optimised, separate skip", a));
            outs.push(("plain, separate skip", b));
            outs.push(("optimised, in place", c));
            outs.push(("plain, in place", d));
        }
    }
    for (name, o) in outs {
        assert_eq!(o, want, "{what}: {name} vs reference");
    }
    want
}

/// The build's grid with end bins reaching `end_offset` steps out and the no-return
/// threshold `no_return16`.
fn soft_params(exp: &[u16; 256], end_offset: u32, no_return16: u32) -> SoftArgmaxParams<'_> {
    let (r_min16, step16) = depth_grid(end_offset);
    SoftArgmaxParams {
        exp,
        r_min16: U16F16::from_bits(r_min16),
        step16: U16F16::from_bits(step16),
        end_offset: end_offset as u16,
        no_return16,
    }
}

/// `round((r_min − K·step) · 2^16)`, `round(step · 2^16)` with
/// `step = (r_max − r_min)/(bins − 1)`, from first principles.
fn depth_grid(end_offset: u32) -> (u32, u32) {
    let step = (config::R_MAX_M - config::R_MIN_M) / (config::DEPTH_RANGE_BINS - 1) as f64;
    (
        ((config::R_MIN_M - end_offset as f64 * step) * 65536.0).round() as u32,
        (step * 65536.0).round() as u32,
    )
}

#[test]
fn depth_grid_matches_the_build() {
    let k = config::END_BIN_OFFSET;
    assert_eq!(depth_grid(k), (config::R_MIN_Q16, config::DEPTH_STEP_Q16));
}

/// Library soft-argmax (optimised, plain) vs reference; returns the depth bits.
fn check_soft(logits: &[i8], rows: usize, bins: usize, cols: usize, exp: &[u16; 256]) -> Vec<u32> {
    check_soft_k(
        logits,
        rows,
        bins,
        cols,
        exp,
        config::END_BIN_OFFSET,
        config::NO_RETURN_MASS_Q16,
    )
}

/// [`check_soft`] with end bins reaching `k` steps beyond the window and no-return
/// threshold `tau16`.
fn check_soft_k(
    logits: &[i8],
    rows: usize,
    bins: usize,
    cols: usize,
    exp: &[u16; 256],
    k: u32,
    tau16: u32,
) -> Vec<u32> {
    let (r_min16, step16) = depth_grid(k);
    let want = intref::soft_argmax(logits, rows, bins, cols, exp, r_min16, step16, k, tau16);
    let shape = SoftArgmaxShape {
        rows,
        bins,
        columns: cols,
    };
    let p = soft_params(exp, k, tau16);
    let (mut a, mut b) = (
        vec![U16F16::ZERO; rows * cols],
        vec![U16F16::ZERO; rows * cols],
    );
    soft_argmax_s8(&shape, logits, &p, &mut a).unwrap();
    soft_argmax_s8_plain(&shape, logits, &p, &mut b).unwrap();
    let bits = |v: &[U16F16]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a), want, "soft-argmax optimised vs reference");
    assert_eq!(bits(&b), want, "soft-argmax plain vs reference");
    want
}

/// The head fused with the soft-argmax (head_s8: any head, overlapping or not) vs the
/// reference's scatter transposed convolution followed by its soft-argmax.
fn check_head(sh: &Shape, input: &[i8], l: &Layer, exp: &[u16; 256], what: &str) -> Vec<u32> {
    let logits = intref::conv_transpose(sh, input, &l.w, &l.b, &l.m, 0, false, None);
    let k = config::END_BIN_OFFSET;
    let (r_min16, step16) = depth_grid(k);
    let [rows, bins, cols] = sh.n_out;
    let tau16 = config::NO_RETURN_MASS_Q16;
    let want = intref::soft_argmax(&logits, rows, bins, cols, exp, r_min16, step16, k, tau16);
    let mut d = vec![U16F16::ZERO; rows * cols];
    epssn::kernels::head_s8::head_s8(
        &conv_shape(sh),
        input,
        &params(l, 0, false),
        &soft_params(exp, config::END_BIN_OFFSET, tau16),
        &mut d,
    )
    .unwrap();
    let got: Vec<u32> = d.iter().map(|x| x.to_bits()).collect();
    assert_eq!(got, want, "{what}: fused head vs reference");
    want
}

fn distinct(v: &[i8]) -> usize {
    let mut seen = [false; 256];
    for &x in v {
        seen[(x as i32 + 128) as usize] = true;
    }
    seen.iter().filter(|&&s| s).count()
}

// ---------------------------------------------------------------- (a) random small shapes

#[test]
fn random_small_convolutions() {
    let mut rng = Rng(0x5eed_0001);
    for case in 0..150 {
        let three_d = case % 2 == 1;
        let mut sh = Shape {
            cin: 1 + rng.below(3),
            cout: 1 + rng.below(4),
            k: [1; 3],
            s: [1; 3],
            p: [0; 3],
            op: [0; 3],
            n_in: [1; 3],
            n_out: [1; 3],
        };
        let axes = if three_d { 3 } else { 2 };
        for a in 0..axes {
            sh.k[a] = 1 + rng.below(4);
            sh.s[a] = 1 + rng.below(3);
            sh.p[a] = rng.below(sh.k[a]);
            sh.n_in[a] = sh.k[a] + rng.below(6);
            sh.n_out[a] = (sh.n_in[a] + 2 * sh.p[a] - sh.k[a]) / sh.s[a] + 1;
        }
        let l = random_layer(&mut rng, &sh, (-9, 0), 30_000);
        let input = rng.i8s(sh.cin * sh.n_in.iter().product::<usize>());
        let kind = if three_d {
            LayerKind::Conv3d
        } else {
            LayerKind::Conv2d
        };
        let offset = if case % 5 == 0 { 128 } else { 0 };
        check_conv(kind, &sh, &input, &l, offset, case % 3 != 0, "random conv");
    }
}

#[test]
fn random_small_conv_transposes_with_and_without_skip() {
    let mut rng = Rng(0x5eed_0002);
    for case in 0..150 {
        let mut sh = Shape {
            cin: 1 + rng.below(3),
            cout: 1 + rng.below(4),
            k: [1; 3],
            s: [1; 3],
            p: [0; 3],
            op: [0; 3],
            n_in: [1; 3],
            n_out: [1; 3],
        };
        for a in 0..3 {
            sh.k[a] = 1 + rng.below(4);
            sh.s[a] = 1 + rng.below(3);
            sh.op[a] = rng.below(sh.s[a]);
            sh.n_in[a] = 1 + rng.below(4);
            let full = (sh.n_in[a] - 1) * sh.s[a] + sh.k[a] + sh.op[a];
            sh.p[a] = rng.below(sh.k[a].min((full - 1) / 2 + 1));
            sh.n_out[a] = full - 2 * sh.p[a];
        }
        let l = random_layer(&mut rng, &sh, (-9, 0), 30_000);
        let input = rng.i8s(sh.cin * sh.n_in.iter().product::<usize>());
        let n = sh.cout * sh.n_out.iter().product::<usize>();
        let skip_t = rng.i8s(n);
        let sm = rng.mult(-2, 1);
        let skip = (case % 2 == 0).then_some((skip_t.as_slice(), sm, [0, 128][(case / 2) % 2]));
        check_convt(
            &sh,
            &input,
            &l,
            case % 3 != 0,
            skip,
            "random conv-transpose",
        );
    }
}

#[test]
fn random_small_cost_volumes_soft_argmax_and_heads() {
    let mut rng = Rng(0x5eed_0003);
    for case in 0..60 {
        let (c, planes, h, w) = (
            1 + rng.below(3),
            1 + rng.below(4),
            1 + rng.below(5),
            2 + rng.below(6),
        );
        let feat = c * h * w;
        let reference = rng.i8s(feat);
        let srcs: Vec<Vec<i8>> = (0..2).map(|_| rng.i8s(feat)).collect();
        let tables: Vec<Vec<WarpEntry>> = (0..2)
            .map(|_| {
                (0..planes * w)
                    .map(|_| {
                        let column = rng.below(w) as u8;
                        WarpEntry {
                            column,
                            fraction: if (column as usize) + 1 < w {
                                rng.range(0, 256) as u16
                            } else {
                                0
                            },
                            visible: rng.below(4) != 0,
                        }
                    })
                    .collect()
            })
            .collect();
        let n_src = 1 + case % 2;
        let m = rng.mult(-10, 0);
        let zero_point = [0, -128][(case / 2) % 2];
        let mean = (rng.below(c + 1), rng.mult(-9, 1));
        check_cost(
            &reference,
            &srcs,
            &tables,
            n_src,
            (c, planes, h, w),
            (m, mean),
            zero_point,
        );

        let (rows, bins, cols) = (1 + rng.below(3), 1 + rng.below(80), 1 + rng.below(90));
        let logits = rng.i8s(rows * bins * cols);
        let exp = intref::exp_table(0.005 + rng.below(60) as f64 * 0.01);
        check_soft(&logits, rows, bins, cols, &exp);

        let k = [1 + rng.below(3), 1 + rng.below(2), 1 + rng.below(4)];
        let n_in = [1 + rng.below(3), 1 + rng.below(8), 1 + rng.below(4)];
        let sh = Shape {
            cin: 1 + rng.below(4),
            cout: 1,
            k,
            s: k,
            p: [0; 3],
            op: [0; 3],
            n_in,
            n_out: [n_in[0] * k[0], n_in[1] * k[1], n_in[2] * k[2]],
        };
        let l = random_layer(&mut rng, &sh, (-8, -2), 10_000);
        let input = rng.i8s(sh.cin * n_in.iter().product::<usize>());
        check_head(&sh, &input, &l, &exp, "random head");
    }
}

fn check_cost(
    reference: &[i8],
    srcs: &[Vec<i8>],
    tables: &[Vec<WarpEntry>],
    n_src: usize,
    (c, planes, h, w): (usize, usize, usize, usize),
    (m, (mean_channels, mean_m)): (Mult, (usize, Mult)),
    zero_point: i32,
) -> Vec<i8> {
    let pairs: Vec<(&[i8], &[WarpEntry])> = (0..n_src)
        .map(|k| (srcs[k].as_slice(), tables[k].as_slice()))
        .collect();
    let want = intref::cost_volume(
        reference,
        &pairs,
        c,
        planes,
        h,
        w,
        m,
        mean_channels,
        mean_m,
        zero_point,
    );
    let views: Vec<SourceView> = pairs
        .iter()
        .map(|&(features, warp)| SourceView { features, warp })
        .collect();
    let shape = CostShape {
        channels: c,
        planes,
        height: h,
        width: w,
        mean_channels,
    };
    let cq = CostRequant {
        requant: requant(m),
        mean: requant(mean_m),
        zero_point,
    };
    let (mut a, mut b) = (vec![0i8; want.len()], vec![0i8; want.len()]);
    cost_volume_s8(&shape, reference, &views, cq, &mut a).unwrap();
    cost_volume_s8_plain(&shape, reference, &views, cq, &mut b).unwrap();
    assert_eq!(
        a,
        want,
        "cost volume optimised vs reference ({} views)",
        n_src + 1
    );
    assert_eq!(
        b,
        want,
        "cost volume plain vs reference ({} views)",
        n_src + 1
    );
    want
}

// -------------------------------------------- (b) EPSSN-S layers chained through the network

fn layer(name: &str) -> &'static LayerShape {
    LAYERS
        .iter()
        .find(|l| l.name == name)
        .expect("layer in the spec")
}

/// The real warp tables as vectors.
fn real_tables() -> Vec<Vec<WarpEntry>> {
    config::WARP_TABLES.iter().map(|t| t.to_vec()).collect()
}

/// Runs the whole EPSSN-S network layer by layer on random weights (realistic multipliers:
/// outputs spread over int8), comparing every layer's output with the reference.
fn run_network(seed: u64, views: usize) {
    let mut rng = Rng(seed);
    // Shifts chosen so that typical accumulators land in int8 (m ≈ 2^-9 … 2^-7).
    let mut layers = std::collections::HashMap::new();
    for l in LAYERS.iter() {
        let sh = Shape::from(l);
        layers.insert(l.name, random_layer(&mut rng, &sh, (-9, -7), 20_000));
    }
    let features = |rng: &mut Rng| -> Vec<i8> {
        // A u8 image stored as q = u8 − 128.
        let mut x = rng.i8s(config::INPUT_LEN);
        for name in ["f0", "f1", "f2", "f3"] {
            let l = layer(name);
            x = check_conv(
                l.kind,
                &Shape::from(l),
                &x,
                &layers[name],
                input_offset(name),
                l.relu,
                name,
            );
            assert!(
                distinct(&x) > 20,
                "{name}: degenerate output, test would be weak"
            );
        }
        x
    };
    let reference = features(&mut rng);
    let srcs: Vec<Vec<i8>> = (1..views).map(|_| features(&mut rng)).collect();
    let cost_m = rng.mult(-7, -6);
    let cost = check_cost(
        &reference,
        &srcs,
        &real_tables(),
        views - 1,
        (
            config::FEATURE_CHANNELS,
            config::PLANES,
            config::FEATURE_RANGE_BINS,
            config::FEATURE_COLUMNS,
        ),
        // A mean of features of the cost volume's scale: m' between 1/4 and 1.
        (cost_m, (config::MEAN_CHANNELS, rng.mult(-1, 1))),
        // The unsigned cost volume the quantiser writes: d1 and u0's skip add 128 back.
        -128,
    );
    assert!(distinct(&cost) > 20, "cost volume degenerate");
    let mut x = cost.clone();
    let mut d1_out = Vec::new();
    for name in ["d1", "d2", "m0"] {
        let l = layer(name);
        x = check_conv(
            l.kind,
            &Shape::from(l),
            &x,
            &layers[name],
            input_offset(name),
            l.relu,
            name,
        );
        assert!(distinct(&x) > 10, "{name}: degenerate output");
        if name == "d1" {
            d1_out = x.clone();
        }
    }
    let skip_m = rng.mult(0, 0);
    let u1 = layer("u1");
    x = check_convt(
        &Shape::from(u1),
        &x,
        &layers["u1"],
        true,
        Some((&d1_out, skip_m, skip_offset("d1"))),
        "u1",
    );
    let u0 = layer("u0");
    x = check_convt(
        &Shape::from(u0),
        &x,
        &layers["u0"],
        true,
        Some((&cost, skip_m, skip_offset("cost"))),
        "u0",
    );
    assert!(distinct(&x) > 10, "u0: degenerate output");
    let head = layer("head");
    let exp = intref::exp_table(0.06);
    let depth = check_head(&Shape::from(head), &x, &layers["head"], &exp, "head");
    // And the unfused path: head transposed convolution, then soft-argmax.
    let logits = check_convt(&Shape::from(head), &x, &layers["head"], false, None, "head");
    let unfused = check_soft(
        &logits,
        config::DEPTH_ROWS,
        config::DEPTH_RANGE_BINS,
        config::DEPTH_COLUMNS,
        &exp,
    );
    assert_eq!(depth, unfused);
    let k = config::END_BIN_OFFSET;
    let (base, step) = depth_grid(k);
    let last = config::DEPTH_RANGE_BINS as u32 - 1;
    let (lo, hi) = (base + k * step, base + (last + k) * step);
    assert!(depth.iter().all(|&d| d >= lo && d <= hi));
}

#[test]
fn epssn_s_network_two_views_every_layer_bit_exact() {
    run_network(0xe55_0002, 2);
}

#[test]
fn epssn_s_network_three_views_every_layer_bit_exact() {
    run_network(0xe55_0003, 3);
}

// ------------------------------------------------------------------- (c) extreme inputs

fn patterns(rng: &mut Rng, n: usize) -> Vec<(&'static str, Vec<i8>)> {
    vec![
        ("all -128", vec![-128; n]),
        ("all 127", vec![127; n]),
        ("all 0", vec![0; n]),
        (
            "alternating",
            (0..n)
                .map(|i| if i % 2 == 0 { -128 } else { 127 })
                .collect(),
        ),
        ("noise", rng.i8s(n)),
    ]
}

#[test]
fn every_epssn_s_layer_on_extreme_inputs_and_weights() {
    let mut rng = Rng(0xe57_0001);
    for l in LAYERS.iter() {
        let sh = Shape::from(l);
        let mut variants = vec![(
            "random weights",
            random_layer(&mut rng, &sh, (-9, -6), 20_000),
        )];
        // Extreme weights: every weight −128 or 127 and extreme biases, still provably within
        // int32 (the kernels would refuse otherwise).
        let mut ext = random_layer(&mut rng, &sh, (-12, -10), 1_000_000);
        for (i, w) in ext.w.iter_mut().enumerate() {
            *w = if (i / 3) % 2 == 0 { 127 } else { -128 };
        }
        variants.push(("extreme weights", ext));
        let offset = input_offset(l.name);
        for (wname, lp) in &variants {
            for (pname, input) in patterns(&mut rng, l.input_len()) {
                let what = format!("{} {wname} {pname}", l.name);
                match l.kind {
                    LayerKind::Conv2d | LayerKind::Conv3d => {
                        check_conv(l.kind, &sh, &input, lp, offset, l.relu, &what);
                    }
                    LayerKind::ConvTranspose3d => {
                        let skip_in: Vec<i8> =
                            input.iter().cycle().take(l.output_len()).copied().collect();
                        let sm = Mult {
                            m: i32::MAX,
                            shift: 1,
                        };
                        let skip = l
                            .skip
                            .map(|name| (skip_in.as_slice(), sm, skip_offset(name)));
                        check_convt(&sh, &input, lp, l.relu, skip, &what);
                        if l.name == "head" {
                            check_head(&sh, &input, lp, &intref::exp_table(0.03), &what);
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn cost_volume_with_real_warp_tables_on_extreme_features() {
    let mut rng = Rng(0xc057);
    let dims = (
        config::FEATURE_CHANNELS,
        config::PLANES,
        config::FEATURE_RANGE_BINS,
        config::FEATURE_COLUMNS,
    );
    let tables = real_tables();
    let n = config::FEATURE_LEN;
    let pats = patterns(&mut rng, n);
    for (rname, reference) in &pats {
        for (sname, src) in &pats {
            let srcs = vec![src.clone(), pats[(rname.len() + sname.len()) % 5].1.clone()];
            for n_src in 1..=2 {
                for m in [
                    Mult {
                        m: 1 << 30,
                        shift: -10,
                    },
                    rng.mult(-14, 0),
                ] {
                    for zero_point in [0, -128] {
                        let mean = (config::MEAN_CHANNELS, m);
                        check_cost(
                            reference,
                            &srcs,
                            &tables,
                            n_src,
                            dims,
                            (m, mean),
                            zero_point,
                        );
                    }
                }
            }
        }
    }
    // Largest possible variance with the largest multiplier allowed for it saturates at 127.
    let lo = vec![-128i8; n];
    let hi = vec![127i8; n];
    let one = Mult {
        m: 1 << 30,
        shift: 1,
    };
    // The reference alone already differs from an invisible (0) source by 128, so every
    // variance voxel saturates, whatever the tables say: at 127 (code 127 or 255).
    for zero_point in [0, -128] {
        let out = check_cost(
            &lo,
            &[hi.clone(), hi.clone()],
            &tables,
            2,
            dims,
            (one, (0, one)),
            zero_point,
        );
        assert!(out.iter().all(|&v| v == 127));
    }
}

#[test]
fn soft_argmax_on_extreme_logits() {
    let (rows, bins, cols) = (
        config::DEPTH_ROWS,
        config::DEPTH_RANGE_BINS,
        config::DEPTH_COLUMNS,
    );
    let n = rows * bins * cols;
    let exp = intref::exp_table(0.1);
    for k in [0, 1, config::END_BIN_OFFSET, 40] {
        let (r_min16, step16) = depth_grid(k);
        // All equal (any value): every ray reads the middle of the window.
        for v in [-128i8, 0, 127] {
            let d = check_soft_k(&vec![v; n], rows, bins, cols, &exp, k, 0);
            // The mean of the bins' positions (index 0, interior i + K, last bins − 1 + 2K) is
            // index (bins − 1) / 2 + K on the Q16.16 grid: the window's middle, up to the grid's
            // rounding (step16 is rounded once, so the error grows with the bin count).
            let want = r_min16 as f64 + ((bins - 1) as f64 / 2.0 + k as f64) * step16 as f64;
            assert!(
                (d[0] as f64 - want).abs() <= 1.0,
                "K {k}: {} vs {want}",
                d[0]
            );
            let metres = d[0] as f64 / 65536.0;
            let grid_rounding = (bins as f64 / 2.0 + k as f64 + 1.0) * 0.5 / 65536.0;
            assert!(
                (metres - (config::R_MIN_M + config::R_MAX_M) / 2.0).abs() <= grid_rounding,
                "K {k}: {metres}"
            );
            assert!(d.iter().all(|&x| x == d[0]));
        }
        // One-hot with the largest gap (EXP underflows to 0): exactly the bin's depth, the
        // end bins clamped to the window's ends.
        assert_eq!(exp[255], 0);
        let mut logits = vec![-128i8; n];
        for e in 0..rows {
            for a in 0..cols {
                let bin = (e * 7 + a * 3) % bins;
                logits[(e * bins + bin) * cols + a] = 127;
            }
        }
        let d = check_soft_k(&logits, rows, bins, cols, &exp, k, 0);
        for e in 0..rows {
            for a in 0..cols {
                let bin = ((e * 7 + a * 3) % bins) as u32;
                assert_eq!(d[e * cols + a], r_min16 + (bin + k) * step16, "K {k}");
            }
        }
        // Half the mass in the last bin, half in the one before: K ≥ 1 reads r_max exactly,
        // K = 0 half a step short.
        let mut logits = vec![-128i8; n];
        for e in 0..rows {
            for a in 0..cols {
                logits[(e * bins + bins - 1) * cols + a] = 127;
                logits[(e * bins + bins - 2) * cols + a] = 127;
            }
        }
        let d = check_soft_k(&logits, rows, bins, cols, &exp, k, 0);
        let top = r_min16 + (bins as u32 - 1 + k) * step16;
        let want = if k == 0 { top - step16 / 2 } else { top };
        assert!(
            d.iter().all(|&x| x.abs_diff(want) <= 1),
            "K {k}: {} vs {want}",
            d[0]
        );
        // Alternating and noise only need to agree.
        let mut rng = Rng(1 + k as u64);
        for (_, p) in patterns(&mut rng, n) {
            check_soft_k(&p, rows, bins, cols, &exp, k, 0);
        }
    }
}

#[test]
fn soft_argmax_no_return_decision_matches_the_reference() {
    let (rows, bins, cols) = (
        config::DEPTH_ROWS,
        config::DEPTH_RANGE_BINS,
        config::DEPTH_COLUMNS,
    );
    let n = rows * bins * cols;
    let exp = intref::exp_table(0.08);
    let mut rng = Rng(0x0e7d);
    // Thresholds from a sliver to the whole mass, the build's among them; logits with their
    // largest values often in an end bin, so both decisions and their ties are met.
    let thresholds = [1, 1 << 14, 1 << 15, 1 << 16, config::NO_RETURN_MASS_Q16];
    for tau16 in thresholds.into_iter().filter(|&t| t > 0) {
        for (_, mut p) in patterns(&mut rng, n) {
            for e in 0..rows {
                for a in 0..cols {
                    let end = [0, bins - 1][rng.below(2)];
                    if rng.below(3) == 0 {
                        p[(e * bins + end) * cols + a] = 127 - rng.below(20) as i8;
                    }
                }
            }
            let k = config::END_BIN_OFFSET;
            let d = check_soft_k(&p, rows, bins, cols, &exp, k, tau16);
            let (base, step) = depth_grid(k);
            let (lo, hi) = (base + k * step, base + (bins as u32 - 1 + k) * step);
            assert!(d.iter().all(|&x| x >= lo && x <= hi));
        }
    }
}
