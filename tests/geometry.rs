//! The geometry module and the build-time warp tables, checked from first principles: points
//! are placed on the virtual planes in Cartesian space, moved by the roll baseline with plain
//! rotation matrices written here, and compared with what the tables say.

use epssn::config;
use epssn::geometry::{self, Polar, RigidTransform};
use epssn_tests::model_beam_centres_deg;

/// Rotation of the point coordinates when the sonar rolls by `deg` (left side up), written
/// out independently of `RigidTransform`.
fn roll_point(p: [f64; 3], deg: f64) -> [f64; 3] {
    let a = deg.to_radians();
    // The sonar turns by +a about x, so the fixed point turns by −a in sonar coordinates.
    [
        p[0],
        p[1] * a.cos() + p[2] * a.sin(),
        -p[1] * a.sin() + p[2] * a.cos(),
    ]
}

fn feature_column_position(theta: f64) -> Option<f64> {
    let az = &config::FEATURE_COLUMN_AZIMUTH_RAD;
    (0..az.len() - 1).find_map(|c| {
        (theta >= az[c] && theta <= az[c + 1])
            .then(|| c as f64 + (theta - az[c]) / (az[c + 1] - az[c]))
    })
}

#[test]
fn generated_grids_follow_the_beam_table() {
    let beams = model_beam_centres_deg();
    assert_eq!(beams.len(), config::BEAMS);
    assert!(beams[0] < 0.0, "beam 0 is the right-most, negative angle");
    // A column is the mean angle of its group of beams (pairs in EPSSN-S, single beams in
    // EPSSN-P).
    let group = config::BEAMS / config::INPUT_COLUMNS;
    for k in 0..config::INPUT_COLUMNS {
        let sum: f64 = beams[group * k..group * (k + 1)].iter().sum();
        let expect = (sum / group as f64).to_radians();
        assert!((config::INPUT_COLUMN_AZIMUTH_RAD[k] - expect).abs() < 1e-12);
    }
    // The table is not a linear fan: column spacing varies.
    let d =
        |k: usize| config::INPUT_COLUMN_AZIMUTH_RAD[k + 1] - config::INPUT_COLUMN_AZIMUTH_RAD[k];
    assert!((d(0) - d(config::INPUT_COLUMNS / 2 - 1)).abs() > 1e-5);
    let half = 7f64.to_radians();
    assert!((config::PLANE_ELEVATION_RAD[0] + half).abs() < 1e-12);
    assert!((config::PLANE_ELEVATION_RAD[config::PLANES - 1] - half).abs() < 1e-12);
    // Interior bins evenly spaced over the window; the end bins reach K steps beyond it.
    let bins = config::DEPTH_RANGE_BINS;
    let step = (config::R_MAX_M - config::R_MIN_M) / (bins - 1) as f64;
    let reach = config::END_BIN_OFFSET as f64 * step;
    assert!((config::DEPTH_BIN_RANGE_M[0] - (config::R_MIN_M - reach)).abs() < 1e-12);
    assert!((config::DEPTH_BIN_RANGE_M[bins - 1] - (config::R_MAX_M + reach)).abs() < 1e-12);
    for i in 1..bins - 1 {
        let want = config::R_MIN_M + i as f64 * step;
        assert!((config::DEPTH_BIN_RANGE_M[i] - want).abs() < 1e-12);
    }
}

#[test]
fn warp_table_matches_points_moved_by_the_baseline() {
    let half = config::HALF_ELEVATION_RAD;
    let az = &config::FEATURE_COLUMN_AZIMUTH_RAD;
    let mut visible = 0;
    for view in 1..config::MAX_VIEWS {
        let roll = config::ROLL_STEP_DEG * view as f64;
        let table = &config::WARP_TABLES[view - 1];
        for j in 0..config::PLANES {
            for b in 0..config::FEATURE_COLUMNS {
                let entry = table[j * config::FEATURE_COLUMNS + b];
                for &r in &[config::R_MIN_M, 2.7, config::R_MAX_M] {
                    let phi = config::PLANE_ELEVATION_RAD[j];
                    let theta = az[b];
                    let p = [
                        r * phi.cos() * theta.cos(),
                        r * phi.cos() * theta.sin(),
                        r * phi.sin(),
                    ];
                    let q = roll_point(p, roll);
                    let rq = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
                    assert!((rq - r).abs() < 1e-12, "roll preserves range");
                    let theta_s = q[1].atan2(q[0]);
                    let phi_s = (q[2] / rq).asin();
                    let inside =
                        phi_s.abs() <= half && theta_s >= az[0] && theta_s <= az[az.len() - 1];
                    assert_eq!(entry.visible, inside, "view {view} plane {j} column {b}");
                    if inside {
                        let pos = feature_column_position(theta_s).unwrap();
                        let table_pos = entry.column as f64
                            + entry.fraction as f64 / (1u32 << config::WARP_FRACTION_BITS) as f64;
                        // Sub-column accuracy: within half a quantisation step of the fraction.
                        let step = 0.5 / (1u32 << config::WARP_FRACTION_BITS) as f64;
                        assert!(
                            (pos - table_pos).abs() <= step + 1e-9,
                            "view {view} plane {j} column {b}: {pos} vs {table_pos}"
                        );
                    }
                }
                visible += entry.visible as usize;
            }
        }
    }
    // The tables are not trivially empty or full.
    let total = (config::MAX_VIEWS - 1) * config::PLANES * config::FEATURE_COLUMNS;
    assert!(
        visible > total / 4 && visible < total,
        "{visible} of {total}"
    );
}

#[test]
fn general_table_with_lever_arm_changes_range_and_reduces_to_pure_roll() {
    let az = &config::FEATURE_COLUMN_AZIMUTH_RAD;
    let ranges = &config::FEATURE_RANGE_M;
    let planes = &config::PLANE_ELEVATION_RAD;
    let half = config::HALF_ELEVATION_RAD;
    let len = planes.len() * ranges.len() * az.len();
    // Pure roll: every range maps to itself and the columns equal the range-free table.
    let mut general = vec![geometry::WarpEntry2d::default(); len];
    let roll = RigidTransform::roll_deg(config::ROLL_STEP_DEG);
    geometry::warp_table_general(&roll, az, ranges, planes, half, 8, &mut general).unwrap();
    for j in 0..planes.len() {
        for i in 0..ranges.len() {
            for b in 0..az.len() {
                let g = general[(j * ranges.len() + i) * az.len() + b];
                let p = config::WARP_TABLES[0][j * az.len() + b];
                assert_eq!(
                    (g.visible, g.column, g.fraction),
                    (p.visible, p.column, p.fraction)
                );
                if g.visible {
                    let pos = g.range_bin as f64 + g.range_fraction as f64 / 256.0;
                    assert!((pos - i as f64).abs() < 1e-9);
                }
            }
        }
    }
    // A 10 cm lever arm: the transformed point's range is what the table says.
    let t = RigidTransform::rolled_about_axis(config::ROLL_STEP_DEG, [0.0, 0.0, -0.1]);
    assert!(!t.preserves_range());
    geometry::warp_table_general(&t, az, ranges, planes, half, 8, &mut general).unwrap();
    let mut moved = 0;
    for j in 0..planes.len() {
        for i in 0..ranges.len() {
            for b in 0..az.len() {
                let g = general[(j * ranges.len() + i) * az.len() + b];
                if !g.visible {
                    continue;
                }
                let p = t.apply(geometry::polar_to_cartesian(Polar {
                    range: ranges[i],
                    azimuth: az[b],
                    elevation: planes[j],
                }));
                let q = geometry::cartesian_to_polar(p);
                let lo = ranges[g.range_bin as usize];
                let hi = ranges[g.range_bin as usize + 1];
                let r_table = lo + (hi - lo) * g.range_fraction as f64 / 256.0;
                assert!((r_table - q.range).abs() <= (hi - lo) / 512.0 + 1e-9);
                moved += ((q.range - ranges[i]).abs() > 1e-4) as usize;
            }
        }
    }
    assert!(moved > 0, "a lever arm must change some ranges");
    assert_eq!(
        epssn::geometry::warp_table_pure_roll(
            &t,
            az,
            planes,
            half,
            8,
            &mut [Default::default(); 256]
        ),
        Err(geometry::WarpError::NotRangePreserving)
    );
}

#[test]
fn resampling_native_frames_averages_beam_groups_and_sample_groups() {
    let beams = model_beam_centres_deg();
    let beam_rad: Vec<f64> = beams.iter().map(|d| d.to_radians()).collect();
    // An ARIS 3000 frame whose samples are exactly 3 mm apart from r_min: sample s, beam k
    // holds a value that identifies both.
    let samples = 600;
    let data: Vec<u8> = (0..samples * 128)
        .map(|i| {
            let (s, k) = (i / 128, i % 128);
            ((s * 7 + k * 13) % 251) as u8
        })
        .collect();
    let ranges = geometry::SampleRanges {
        start: config::R_MIN_M,
        step: (config::R_MAX_M - config::R_MIN_M) / 512.0,
        samples,
    };
    let grid = geometry::Grid {
        r_min: config::R_MIN_M,
        r_max: config::R_MAX_M,
        half_elevation: config::HALF_ELEVATION_RAD,
        column_azimuths: &config::INPUT_COLUMN_AZIMUTH_RAD,
    };
    let mut out = vec![0u8; config::INPUT_LEN];
    geometry::resample_to_grid(
        &data,
        ranges,
        &beam_rad,
        &grid,
        config::INPUT_RANGE_BINS,
        &mut out,
    )
    .unwrap();
    // Each bin covers `rows` samples and `group` beams (2 × 2 in EPSSN-S, 1 × 1 in EPSSN-P).
    let (rows, group) = (512 / config::INPUT_RANGE_BINS, 128 / config::INPUT_COLUMNS);
    for i in 0..config::INPUT_RANGE_BINS {
        for k in 0..config::INPUT_COLUMNS {
            let v = |s: usize, b: usize| data[s * 128 + b] as f64;
            let mut sum = 0.0;
            for s in rows * i..rows * (i + 1) {
                for b in group * k..group * (k + 1) {
                    sum += v(s, b);
                }
            }
            let mean = sum / (rows * group) as f64;
            let expect = (mean + 0.5).floor() as u8;
            assert!(
                (out[i * config::INPUT_COLUMNS + k] as i32 - expect as i32).abs() <= 1,
                "bin {i} column {k}"
            );
        }
    }
    // Bad shapes are errors, not panics.
    assert!(geometry::resample_to_grid(
        &data[1..],
        ranges,
        &beam_rad,
        &grid,
        config::INPUT_RANGE_BINS,
        &mut out
    )
    .is_err());
    let fewer_bins = config::INPUT_RANGE_BINS - 1;
    assert!(
        geometry::resample_to_grid(&data, ranges, &beam_rad, &grid, fewer_bins, &mut out).is_err()
    );
    let bad = geometry::SampleRanges {
        step: f64::NAN,
        ..ranges
    };
    assert!(geometry::resample_to_grid(
        &data,
        bad,
        &beam_rad,
        &grid,
        config::INPUT_RANGE_BINS,
        &mut out
    )
    .is_err());
}

#[test]
fn runtime_grids_equal_build_time_tables() {
    let spec: epssn::spec::ModelSpec = serde_json_from_spec();
    let g = epssn::grids::ModelGrids::derive(&spec, &model_beam_centres_deg()).unwrap();
    assert_eq!(&g.input_azimuths[..], &config::INPUT_COLUMN_AZIMUTH_RAD[..]);
    assert_eq!(&g.plane_elevations[..], &config::PLANE_ELEVATION_RAD[..]);
    for k in 1..config::MAX_VIEWS {
        assert_eq!(
            &g.warp_table(&spec, k).unwrap()[..],
            &config::WARP_TABLES[k - 1][..]
        );
    }
}

/// The spec the library was built from (`EPSSN_SPEC`, default `weights/epssn-s.json`).
fn serde_json_from_spec() -> epssn::spec::ModelSpec {
    epssn_spec::load::built_spec(config::SPEC_JSON, config::SPEC_FILE_NAME).unwrap()
}
