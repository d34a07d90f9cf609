//! Generates, from the model spec in `weights/`, everything the library needs at compile time:
//! size constants, the sonar's angle grids and the warp tables for the fixed roll baseline.
//! The spec types, the spec loader, the beam-table parser and the geometry are `epssn-spec`'s,
//! the very crate the library runs, so build-time tables and run-time code cannot disagree.

use epssn_spec::load::{beam_table_path, build_spec_path, load_beam_table, load_spec};
use epssn_spec::{grids, spec};
use std::fmt::Write as _;
use std::path::PathBuf;

fn main() {
    check_mve_target();
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let spec_path = build_spec_path(&root);
    println!("cargo:rerun-if-changed={}", spec_path.display());
    println!("cargo:rerun-if-env-changed=EPSSN_SPEC");
    let loaded = load_spec(&spec_path).unwrap_or_else(|e| panic!("{e}"));
    let spec = loaded.spec;
    let table = spec.sonar.beam_table.as_str();
    println!(
        "cargo:rerun-if-changed={}",
        beam_table_path(&root, table).display()
    );
    let beam_deg = load_beam_table(&root, table)
        .unwrap_or_else(|e| panic!("{e}"))
        .centre_deg;
    let mut out = generate(&spec, &beam_deg, loaded.hash);
    let spec_file = spec_path.canonicalize().unwrap_or_else(|e| panic!("{e}"));
    writeln!(
        out,
        "/// The model spec file this build was generated from, as text (for host tools that\n/// load the same spec at run time; unused on the device, so not linked there).\npub const SPEC_JSON: &str = include_str!({:?});\n/// That file's name (`epssn-s.json` by default; `EPSSN_SPEC` names another).\npub const SPEC_FILE_NAME: &str = {:?};\n/// The int8 blob's file name in a weights folder of this spec (`<spec file stem>.q8.bin`).\npub const BLOB_FILE_NAME: &str = {:?};",
        spec_file.display().to_string(),
        spec_file.file_name().and_then(|n| n.to_str()).unwrap_or_default(),
        format!(
            "{}.q8.bin",
            spec_file.file_stem().and_then(|n| n.to_str()).unwrap_or_default()
        )
    )
    .unwrap();
    let out_path = PathBuf::from(std::env::var("OUT_DIR").unwrap()).join("config.rs");
    std::fs::write(&out_path, out).unwrap();
}

fn check(cond: bool, what: &str) {
    assert!(cond, "model spec: {what}");
}

fn array_f64(name: &str, doc: &str, values: &[f64]) -> String {
    let mut s = format!("/// {doc}\npub static {name}: [f64; {}] = [", values.len());
    for v in values {
        write!(s, "{v:?}, ").unwrap();
    }
    s.push_str("];\n");
    s
}

fn generate(spec: &spec::ModelSpec, beam_deg: &[f64], spec_hash: u32) -> String {
    let beams = spec.sonar.beams as usize;
    check(
        beam_deg.len() == beams,
        "beam count differs from the beam table",
    );
    let r = spec.input.range_bins as usize;
    let b = spec.input.beam_columns as usize;
    check(
        beams.is_multiple_of(b),
        "beams must be a multiple of beam_columns",
    );
    let group = beams / b;
    let stride = spec.features.stride as usize;
    check(
        r.is_multiple_of(stride) && b.is_multiple_of(stride),
        "input size must be a multiple of the stride",
    );
    let (fr, fb) = (r / stride, b / stride);
    let c = spec.features.channels as usize;
    let n = spec.planes as usize;
    let (e, a, dr) = (
        spec.output.elevation_rows as usize,
        spec.output.azimuth_columns as usize,
        spec.output.range_bins as usize,
    );
    check(
        a == b,
        "azimuth_columns must equal beam_columns (depth columns are input columns)",
    );
    check(
        spec.baseline.max_views >= 2 && spec.baseline.max_views <= 3,
        "max_views is 2 or 3",
    );
    check(
        spec.baseline.views >= 2 && spec.baseline.views <= spec.baseline.max_views,
        "views within 2..=max_views",
    );
    let g = grids::ModelGrids::derive(spec, beam_deg).expect("model spec grids");
    let half = g.half_elevation;
    let (input_az, feature_az) = (&g.input_azimuths, &g.feature_azimuths);
    let (planes, rows, depth_bins) = (
        &g.plane_elevations,
        &g.depth_row_elevations,
        &g.depth_bin_ranges,
    );
    let (input_ranges, feature_ranges) = (&g.input_ranges, &g.feature_ranges);

    // Layer shapes, chained from the input / cost-volume sizes.
    let mut layers = String::new();
    let mut sizes_2d = vec![r, b];
    let mut layer_count = 0usize;
    let mut max_feature_act = r * b;
    let mut names = Vec::new();
    for l in spec.feature_net.iter() {
        check(
            l.kind == spec::LayerKind::Conv2d,
            "feature_net layers are conv2d",
        );
        let out = l.output_size(&sizes_2d);
        layers += &layer_const(l, &sizes_2d, &out);
        max_feature_act =
            max_feature_act.max(out.iter().product::<usize>() * l.out_channels as usize);
        sizes_2d = out.to_vec();
        names.push(l.name.to_string());
        layer_count += 1;
    }
    check(
        sizes_2d == vec![fr, fb],
        "feature_net output size must be input / stride",
    );
    check(
        spec.feature_net.last().map(|l| l.out_channels as usize) == Some(c),
        "feature_net output channels must be features.channels",
    );
    check(
        spec.features.mean_channels as usize <= c,
        "features.mean_channels must not exceed features.channels",
    );
    let mut sizes_3d = vec![n, fr, fb];
    let mut max_cost_act = c * n * fr * fb;
    for l in spec.cost_net.iter() {
        check(l.kind != spec::LayerKind::Conv2d, "cost_net layers are 3D");
        let out = l.output_size(&sizes_3d);
        layers += &layer_const(l, &sizes_3d, &out);
        max_cost_act = max_cost_act.max(out.iter().product::<usize>() * l.out_channels as usize);
        sizes_3d = out.to_vec();
        names.push(l.name.to_string());
        layer_count += 1;
    }
    check(
        sizes_3d == vec![e, dr, a],
        "cost_net output must be (elevation_rows, range_bins, azimuth_columns)",
    );
    check(
        spec.cost_net.last().map(|l| l.out_channels) == Some(1),
        "the head has one output channel",
    );

    // Warp tables, one per extra view.
    let views = spec.baseline.max_views as usize;
    let mut warp = String::new();
    writeln!(
        warp,
        "/// Warp tables for source views 1..MAX_VIEWS (view k is the reference rolled by \
         k × ROLL_STEP_DEG), `[plane × FEATURE_COLUMNS + column]`.\n\
         pub static WARP_TABLES: [[WarpEntry; PLANES * FEATURE_COLUMNS]; MAX_VIEWS - 1] = ["
    )
    .unwrap();
    for k in 1..views {
        let table = g.warp_table(spec, k).expect("warp table (a lever arm needs the range-dependent table, which the library does not run yet)");
        warp.push_str("    [\n");
        for en in &table {
            writeln!(
                warp,
                "        WarpEntry {{ column: {}, fraction: {}, visible: {} }},",
                en.column, en.fraction, en.visible
            )
            .unwrap();
        }
        warp.push_str("    ],\n");
    }
    warp.push_str("];\n");

    let mut s = String::new();
    s += "// @generated by build.rs from the model spec. Do not edit.\n";
    writeln!(s, "/// Name of the model spec this build was generated from.\npub const SPEC_NAME: &str = {:?};", spec.name.as_str()).unwrap();
    writeln!(s, "/// CRC-32 of the model spec file's bytes; weight blobs carry it.\npub const SPEC_HASH: u32 = {spec_hash:#010x};").unwrap();
    writeln!(
        s,
        "/// Sonar system the model is built for.\npub const SONAR_SYSTEM: &str = {:?};",
        spec.sonar.system.as_str()
    )
    .unwrap();
    writeln!(
        s,
        "/// Beam-angle table name.\npub const BEAM_TABLE: &str = {:?};",
        spec.sonar.beam_table.as_str()
    )
    .unwrap();
    let consts: &[(&str, &str, usize)] = &[
        ("BEAMS", "Sonar beams.", beams),
        (
            "BEAMS_PER_COLUMN",
            "Adjacent beams averaged into one input column.",
            group,
        ),
        ("INPUT_RANGE_BINS", "Input range bins R.", r),
        ("INPUT_COLUMNS", "Input beam columns B.", b),
        ("FEATURE_CHANNELS", "Feature channels C.", c),
        (
            "MEAN_CHANNELS",
            "The last cost channels that hold the views' mean (clipped at 0), not their variance.",
            spec.features.mean_channels as usize,
        ),
        ("FEATURE_STRIDE", "Feature stride.", stride),
        ("FEATURE_RANGE_BINS", "Feature range bins R / stride.", fr),
        ("FEATURE_COLUMNS", "Feature columns B / stride.", fb),
        ("PLANES", "Elevation planes N.", n),
        ("DEPTH_ROWS", "Depth map elevation rows E.", e),
        ("DEPTH_COLUMNS", "Depth map azimuth columns A.", a),
        ("DEPTH_RANGE_BINS", "Range bins of the soft-argmax.", dr),
        (
            "VIEWS",
            "Views used by default, reference included.",
            spec.baseline.views as usize,
        ),
        (
            "MAX_VIEWS",
            "Most views supported, reference included.",
            views,
        ),
        ("LAYER_COUNT", "Layers in the network.", layer_count),
        (
            "MAX_FEATURE_ACTIVATION",
            "Largest activation of the feature net, elements.",
            max_feature_act,
        ),
        (
            "MAX_COST_ACTIVATION",
            "Largest activation of the cost net, elements.",
            max_cost_act,
        ),
        (
            "COST_VOLUME_LEN",
            "Cost volume elements C × N × R/4 × B/4.",
            c * n * fr * fb,
        ),
        (
            "FEATURE_LEN",
            "Feature map elements C × R/4 × B/4.",
            c * fr * fb,
        ),
        ("INPUT_LEN", "Input image elements R × B.", r * b),
        ("DEPTH_LEN", "Depth map elements E × A.", e * a),
    ];
    for (name, doc, v) in consts {
        writeln!(s, "/// {doc}\npub const {name}: usize = {v};").unwrap();
    }
    writeln!(
        s,
        "/// Bits of the warp table's bilinear fraction.\npub const WARP_FRACTION_BITS: u32 = {};",
        spec.warp.fraction_bits
    )
    .unwrap();
    let fconsts: &[(&str, &str, f64)] = &[
        (
            "R_MIN_M",
            "Start of the range window, metres.",
            spec.range_window.r_min_m,
        ),
        (
            "R_MAX_M",
            "End of the range window, metres.",
            spec.range_window.r_max_m,
        ),
        (
            "HALF_ELEVATION_RAD",
            "Half the elevation aperture, radians.",
            half,
        ),
        (
            "ROLL_STEP_DEG",
            "Roll between consecutive views, degrees.",
            spec.baseline.roll_step_deg,
        ),
        (
            "PAIR_TOLERANCE_DEG",
            "Roll tolerance for pairing frames, degrees.",
            spec.baseline.pair_tolerance_deg,
        ),
        (
            "PAIR_RESIDUAL_TOLERANCE_DEG",
            "Largest tilt of the source's forward axis relative to the reference's (the pitch/yaw \
             residual of the relative rotation) for pairing frames with attitude, degrees; \
             infinite when the spec sets none (docs/POSE.md).",
            spec.baseline
                .pair_residual_tolerance_deg
                .unwrap_or(f64::INFINITY),
        ),
    ];
    for (name, doc, v) in fconsts {
        if v.is_infinite() {
            writeln!(s, "/// {doc}\npub const {name}: f64 = f64::INFINITY;").unwrap();
        } else {
            writeln!(s, "/// {doc}\npub const {name}: f64 = {v:?};").unwrap();
        }
    }
    // Soft-argmax depth constants in unsigned Q16.16 metres (docs/QUANTISATION.md).
    let q16 = |x: f64| (x * 65536.0).round() as u32;
    let step = (spec.range_window.r_max_m - spec.range_window.r_min_m) / (dr as f64 - 1.0);
    let offset = spec.output.end_bin_offset;
    check(
        spec.range_window.r_min_m - offset as f64 * step >= 0.0,
        "end_bin_offset reaches below zero range",
    );
    writeln!(
        s,
        "/// `round((r_min − K·step) · 2^16)`: the depth that soft-argmax index 0 stands for\n/// (K = `END_BIN_OFFSET`), Q16.16 metres.\npub const R_MIN_Q16: u32 = {};",
        q16(spec.range_window.r_min_m - offset as f64 * step)
    )
    .unwrap();
    writeln!(
        s,
        "/// `round((r_max − r_min) / (bins − 1) · 2^16)`: step between soft-argmax bins.\npub const DEPTH_STEP_Q16: u32 = {};",
        q16(step)
    )
    .unwrap();
    writeln!(
        s,
        "/// Steps by which the end soft-argmax bins reach beyond the window (spec `end_bin_offset`).\npub const END_BIN_OFFSET: u32 = {offset};"
    )
    .unwrap();
    let no_return = spec.output.no_return_mass;
    check(
        no_return == 0.0 || (no_return > 0.0 && no_return <= 1.0),
        "no_return_mass must be 0 (no decision) or in (0, 1]",
    );
    writeln!(
        s,
        "/// `round(τ · 2^16)` of the spec's `no_return_mass` τ: a ray with `e_{{R−1}}·2^16 ≥ τ16·S`\n/// reads exactly r_max (no return), else one with `e_0·2^16 ≥ τ16·S` reads exactly r_min;\n/// 0 decides nothing.\npub const NO_RETURN_MASS_Q16: u32 = {};\n/// The spec's `no_return_mass` τ (0: no decision).\npub const NO_RETURN_MASS: f64 = {no_return:?};",
        q16(no_return)
    )
    .unwrap();
    writeln!(
        s,
        "/// Rotator lever arm, metres.\npub const LEVER_ARM_M: [f64; 3] = {:?};",
        spec.baseline.lever_arm_m
    )
    .unwrap();
    s += &array_f64(
        "BEAM_CENTRES_DEG",
        "Beam centres of the sonar's table, degrees, beam 0 first.",
        beam_deg,
    );
    s += &array_f64(
        "INPUT_COLUMN_AZIMUTH_RAD",
        "Azimuth of each input column (and depth column), radians.",
        input_az,
    );
    s += &array_f64(
        "FEATURE_COLUMN_AZIMUTH_RAD",
        "Azimuth of each feature column, radians.",
        feature_az,
    );
    s += &array_f64(
        "PLANE_ELEVATION_RAD",
        "Elevation of each virtual plane, radians.",
        planes,
    );
    s += &array_f64(
        "DEPTH_ROW_ELEVATION_RAD",
        "Elevation of each depth-map row, radians.",
        rows,
    );
    s += &array_f64(
        "DEPTH_BIN_RANGE_M",
        "Range value of each soft-argmax bin, metres.",
        depth_bins,
    );
    s += &array_f64(
        "INPUT_RANGE_M",
        "Centre range of each input range bin, metres.",
        input_ranges,
    );
    s += &array_f64(
        "FEATURE_RANGE_M",
        "Centre range of each feature range bin, metres.",
        feature_ranges,
    );
    s += &layers;
    write!(
        s,
        "/// Every layer in execution order.\npub static LAYERS: [LayerShape; LAYER_COUNT] = ["
    )
    .unwrap();
    for nm in &names {
        write!(s, "LAYER_{}, ", nm.to_uppercase()).unwrap();
    }
    s += "];\n";
    s += &warp;
    s
}

fn layer_const(l: &spec::LayerSpec, input: &[usize], out: &[usize]) -> String {
    let pad3 = |v: &[u8], fill: u8| {
        let mut a = [fill; 3];
        for (i, x) in v.iter().enumerate() {
            a[i] = *x;
        }
        a
    };
    let pad3u = |v: &[usize]| {
        let mut a = [1usize; 3];
        for (i, x) in v.iter().enumerate() {
            a[i] = *x;
        }
        a
    };
    let kind = match l.kind {
        spec::LayerKind::Conv2d => "Conv2d",
        spec::LayerKind::Conv3d => "Conv3d",
        spec::LayerKind::ConvTranspose3d => "ConvTranspose3d",
    };
    format!(
        "/// Layer `{name}`.\npub const LAYER_{upper}: LayerShape = LayerShape {{ name: {name:?}, kind: LayerKind::{kind}, \
         in_channels: {}, out_channels: {}, kernel: {:?}, stride: {:?}, padding: {:?}, output_padding: {:?}, \
         in_size: {:?}, out_size: {:?}, relu: {}, skip: {:?} }};\n",
        l.in_channels,
        l.out_channels,
        pad3(&l.kernel, 1),
        pad3(&l.stride, 1),
        pad3(&l.padding, 0),
        pad3(&l.output_padding, 0),
        pad3u(input),
        pad3u(out),
        l.relu,
        l.skip.as_ref().map(|s| s.as_str()),
        name = l.name.as_str(),
        upper = l.name.to_uppercase(),
    )
}

/// The `mve` feature's assembly needs a core with Helium; rustc does not report ARM target
/// features to `cfg`, so the build checks the flags it compiles with and names the fix.
fn check_mve_target() {
    if std::env::var_os("CARGO_FEATURE_MVE").is_none()
        || std::env::var("CARGO_CFG_TARGET_ARCH").as_deref() != Ok("arm")
    {
        return;
    }
    let flags = std::env::var("CARGO_ENCODED_RUSTFLAGS").unwrap_or_default();
    let helium = ["cortex-m55", "cortex-m85", "+mve"]
        .iter()
        .any(|f| flags.contains(f));
    assert!(
        helium,
        "the `mve` feature needs a Helium core: build with `-C target-cpu=cortex-m55` (or \
         cortex-m85, or `-C target-feature=+mve`) for thumbv8m.main-none-eabihf"
    );
}
