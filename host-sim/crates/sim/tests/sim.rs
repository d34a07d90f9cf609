//! Simulator ground truth, determinism and the sample folder format.

// Index loops over (row, column) read closer to the maths than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use std::path::Path;

use epssn::config::{
    DEPTH_COLUMNS, DEPTH_ROWS, DEPTH_ROW_ELEVATION_RAD, HALF_ELEVATION_RAD,
    INPUT_COLUMN_AZIMUTH_RAD, R_MAX_M, R_MIN_M,
};
use epssn::geometry::{cartesian_to_polar, fractional_index, polar_to_cartesian, Polar};
use epssn_sim::dataset::{sample_dirs, Sample};
use epssn_sim::groundtruth::{front_depth, polar_image};
use epssn_sim::render::SonarSimParams;
use epssn_sim::scene::{generate, SceneKind, SonarPose, Split};
use epssn_sim::simulate::{run, simulate_scene, SimulateOptions};
use epssn_sim::world::World;

/// First-hit range of the ray at (azimuth, elevation) from the origin against a sphere,
/// written out independently of the simulator.
fn analytic_sphere(az: f64, el: f64, c: [f64; 3], r: f64) -> Option<f64> {
    let d = [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()];
    let b = d[0] * c[0] + d[1] * c[1] + d[2] * c[2];
    let cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2] - r * r;
    let disc = b * b - cc;
    if disc < 0.0 {
        return None;
    }
    let t = b - disc.sqrt();
    (t > 0.0).then_some(t)
}

fn label(t: Option<f64>) -> (f64, f32) {
    match t {
        Some(t) if t < R_MIN_M => (R_MIN_M, 0.0),
        Some(t) if t <= R_MAX_M => (t, 1.0),
        _ => (R_MAX_M, 0.0),
    }
}

fn check_sphere_sample(s: &Sample) -> usize {
    assert_eq!(s.scene.sonar, SonarPose::IDENTITY);
    let (c, r) = s.scene.sphere().expect("sphere scene has a sphere");
    let mut hits = 0;
    for e in 0..DEPTH_ROWS {
        for a in 0..DEPTH_COLUMNS {
            let (want, m) = label(analytic_sphere(
                INPUT_COLUMN_AZIMUTH_RAD[a],
                DEPTH_ROW_ELEVATION_RAD[e],
                c,
                r,
            ));
            let i = e * DEPTH_COLUMNS + a;
            let got = s.depth[i] as f64;
            assert!(
                ((got - want) / want).abs() <= 1e-6,
                "sample {:?} pixel (e {e}, a {a}): depth {got} vs analytic {want}",
                s.dir
            );
            assert_eq!(s.mask[i], m, "mask at (e {e}, a {a})");
            hits += m as usize;
        }
    }
    hits
}

fn simulate(out: &Path, scene: SceneKind, pairs: usize, seed: u64, split: Split, preview: bool) {
    simulate_jittered(out, scene, pairs, seed, split, preview, 0.0);
}

fn simulate_jittered(
    out: &Path,
    scene: SceneKind,
    pairs: usize,
    seed: u64,
    split: Split,
    preview: bool,
    jitter: f64,
) {
    run(&SimulateOptions {
        scene: Some(scene),
        site: None,
        region: None,
        site_reflectivity: None,
        export_mesh: None,
        whole_tank: false,
        pairs: Some(pairs),
        seed,
        out: Some(out.to_path_buf()),
        split,
        views: 2,
        no_preview: !preview,
        params: None,
        pose_jitter_deg: jitter,
        pose_jitter_axes: epssn_sim::simulate::JitterAxes::Both,
        fixed_pose: false,
    })
    .unwrap();
}

#[test]
fn pose_jitter_is_rendered_and_recorded_in_the_headers() {
    use epssn::attitude::Attitude;
    use epssn_aris::aris::ArisReader;
    let plain = tempfile::tempdir().unwrap();
    let jittered = tempfile::tempdir().unwrap();
    simulate(plain.path(), SceneKind::Terrain, 3, 5, Split::Test, false);
    simulate_jittered(
        jittered.path(),
        SceneKind::Terrain,
        3,
        5,
        Split::Test,
        false,
        0.5,
    );
    let attitude = |dir: &Path, k: usize| {
        let r = ArisReader::open(dir.join(format!("view{k}.aris"))).unwrap();
        Attitude::from_array(r.frame_header(0).unwrap().attitude().unwrap()).unwrap()
    };
    for (p, j) in sample_dirs(plain.path(), Split::Test)
        .unwrap()
        .iter()
        .zip(sample_dirs(jittered.path(), Split::Test).unwrap())
    {
        let (sp, sj) = (Sample::load(p).unwrap(), Sample::load(&j).unwrap());
        // Only the pose differs: the same terrain, the same reference image and labels.
        assert_eq!(sp.scene.objects, sj.scene.objects);
        assert_eq!(sp.polar_views[0], sj.polar_views[0]);
        assert_eq!(sp.depth, sj.depth);
        assert_ne!(sp.polar_views[1], sj.polar_views[1]);
        let [pitch, yaw] = sj.scene.view_pose_errors_deg[1];
        assert!(((pitch * pitch + yaw * yaw).sqrt() - 0.5).abs() < 1e-9);
        // The headers' attitudes give the baseline roll and the jitter as the residual.
        let rel = attitude(&j, 0).relative(&attitude(&j, 1));
        assert!((rel.roll_deg - 7.0).abs() < 0.01, "{rel:?}");
        assert!((rel.residual_deg - 0.5).abs() < 0.01, "{rel:?}");
        let rel = attitude(p, 0).relative(&attitude(p, 1));
        assert!(rel.residual_deg < 1e-4 && (rel.roll_deg - 7.0).abs() < 1e-4);
    }
}

#[test]
fn every_sphere_sample_matches_the_analytic_distance() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path(), SceneKind::Sphere, 12, 3, Split::Test, false);
    let dirs = sample_dirs(dir.path(), Split::Test).unwrap();
    assert_eq!(dirs.len(), 12);
    for d in &dirs {
        let s = Sample::load(d).unwrap();
        let hits = check_sphere_sample(&s);
        assert!(hits > 0, "{d:?}: the sphere is not seen in the window");
    }
}

#[test]
fn terrain_reference_points_land_where_the_source_view_sees_them() {
    let mut checked = 0;
    for index in 0..3 {
        let scene = generate(SceneKind::Terrain, Split::Test, 11, index, 2);
        let world = World::new(&scene);
        let (dref, mref) = front_depth(&scene, &world, 0);
        let (dsrc, msrc) = front_depth(&scene, &world, 1);
        let to_src = scene.view_from_reference(1);
        let wfv1 = scene.world_from_view(1);
        let mut grid_err = Vec::new();
        let mut wrong_sign_err = Vec::new();
        for e in 0..DEPTH_ROWS {
            for a in 0..DEPTH_COLUMNS {
                let i = e * DEPTH_COLUMNS + a;
                if !mref[i] {
                    continue;
                }
                let p = polar_to_cartesian(Polar {
                    range: dref[i],
                    azimuth: INPUT_COLUMN_AZIMUTH_RAD[a],
                    elevation: DEPTH_ROW_ELEVATION_RAD[e],
                });
                let q = cartesian_to_polar(to_src.apply(p));
                // Roll about the acoustic centre keeps the range.
                assert!((q.range - dref[i]).abs() < 1e-9);
                if q.elevation.abs() > HALF_ELEVATION_RAD {
                    continue;
                }
                let Some((ca, fa)) = fractional_index(&INPUT_COLUMN_AZIMUTH_RAD, q.azimuth) else {
                    continue;
                };
                // The source view's ray towards the point meets the surface exactly there.
                let hit = world
                    .first_hit_in_view(&wfv1, q.azimuth, q.elevation)
                    .expect("the source view sees the reference point");
                assert!(
                    (hit.t - q.range).abs() < 1e-7,
                    "source ray reads {} where the reference point lies at {}",
                    hit.t,
                    q.range
                );
                checked += 1;
                // And the source view's GT grid agrees (bilinear between its four rays).
                let (ce, fe) = fractional_index(&DEPTH_ROW_ELEVATION_RAD, q.elevation).unwrap();
                let idx = |e: usize, a: usize| e * DEPTH_COLUMNS + a;
                let quad = [
                    idx(ce, ca),
                    idx(ce, ca + 1),
                    idx(ce + 1, ca),
                    idx(ce + 1, ca + 1),
                ];
                if quad.iter().all(|&j| msrc[j]) {
                    let top = dsrc[quad[0]] * (1.0 - fa) + dsrc[quad[1]] * fa;
                    let bot = dsrc[quad[2]] * (1.0 - fa) + dsrc[quad[3]] * fa;
                    grid_err.push((top * (1.0 - fe) + bot * fe - q.range).abs());
                }
                // Negative control: the opposite roll must not line up.
                let qw = cartesian_to_polar(scene.view_from_reference(1).inverse().apply(p));
                if let (Some((ca, fa)), Some((ce, fe))) = (
                    fractional_index(&INPUT_COLUMN_AZIMUTH_RAD, qw.azimuth),
                    fractional_index(&DEPTH_ROW_ELEVATION_RAD, qw.elevation),
                ) {
                    let quad = [
                        idx(ce, ca),
                        idx(ce, ca + 1),
                        idx(ce + 1, ca),
                        idx(ce + 1, ca + 1),
                    ];
                    if quad.iter().all(|&j| msrc[j]) {
                        let top = dsrc[quad[0]] * (1.0 - fa) + dsrc[quad[1]] * fa;
                        let bot = dsrc[quad[2]] * (1.0 - fa) + dsrc[quad[3]] * fa;
                        wrong_sign_err.push((top * (1.0 - fe) + bot * fe - qw.range).abs());
                    }
                }
            }
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(|a, b| a.total_cmp(b));
            v[v.len() / 2]
        };
        assert!(grid_err.len() > 200, "only {} grid checks", grid_err.len());
        let m = median(&mut grid_err);
        let m_wrong = median(&mut wrong_sign_err);
        assert!(m < 0.003, "median grid disagreement {m} m");
        assert!(
            m_wrong > 5.0 * m,
            "wrong roll sign agrees too well: {m_wrong} vs {m}"
        );
    }
    assert!(checked > 500, "only {checked} points checked");
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn same_seed_same_bytes_and_scene_json_regenerates() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    for kind in [SceneKind::Artificial, SceneKind::Terrain] {
        simulate(a.path(), kind, 2, 9, Split::Train, true);
        simulate(b.path(), kind, 2, 9, Split::Train, true);
        let fa = files(a.path());
        let fb = files(b.path());
        // Nine files per sample and the split's sim_params.json.
        assert_eq!(fa.len(), 2 * 9 + 1, "{} files", fa.len());
        assert_eq!(fa.len(), fb.len());
        for ((na, da), (nb, db)) in fa.iter().zip(&fb) {
            assert_eq!(na, nb);
            assert!(da == db, "{na} differs between two runs with the same seed");
        }
        // The scene JSON alone regenerates the sample.
        let s = Sample::load(&a.path().join("train/000001")).unwrap();
        let again = simulate_scene(&s.scene, &SonarSimParams::default()).unwrap();
        assert_eq!(again.depth, s.depth);
        assert_eq!(again.mask, s.mask);
        for (k, v) in again.polar_views.iter().enumerate() {
            let f: Vec<f32> = v.iter().map(|x| *x as f32).collect();
            assert_eq!(f, s.polar_views[k]);
        }
        assert!(
            s.mask.iter().any(|m| *m > 0.5),
            "{kind:?}: nothing in the window"
        );
    }
    // A different seed gives a different scene.
    let c = tempfile::tempdir().unwrap();
    simulate(c.path(), SceneKind::Artificial, 1, 10, Split::Train, false);
    let s0 = Sample::load(&a.path().join("train/000000")).unwrap();
    let s1 = Sample::load(&c.path().join("train/000000")).unwrap();
    assert_ne!(s0.depth, s1.depth);
}

#[test]
fn polar_views_come_from_the_aris_files_through_resample_to_grid() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path(), SceneKind::Artificial, 1, 4, Split::Test, false);
    let d = dir.path().join("test/000000");
    let s = Sample::load(&d).unwrap();
    let params = SonarSimParams::default();
    for k in 0..2 {
        let reader = epssn_aris::aris::ArisReader::open(d.join(format!("view{k}.aris"))).unwrap();
        assert_eq!(reader.frame_count(), 1);
        assert_eq!(reader.beams(), 128);
        let frame = reader.frame(0).unwrap();
        let roll = 7.0 * k as f32;
        assert_eq!(frame.header.sonar_roll_deg, roll);
        assert_eq!(frame.header.roll_abs_position_deg, roll);
        let ranges = frame.range_geometry().unwrap();
        assert!(ranges.start <= R_MIN_M);
        assert!(ranges.start + ranges.step * (ranges.samples - 1) as f64 >= R_MAX_M);
        // What any reader of the file gets (its beam table and range geometry).
        let polar = epssn_aris::polar::frame_to_polar(&frame).unwrap();
        let f: Vec<f32> = polar.iter().map(|x| *x as f32).collect();
        assert_eq!(f, s.polar_views[k], "view {k}");
        assert_eq!(polar_image(&frame.data, &params).unwrap(), polar);
    }
    // The elevation map holds elevations inside the aperture where anything returns.
    let finite: Vec<f32> = s
        .elevation
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    assert!(!finite.is_empty());
    assert!(finite
        .iter()
        .all(|v| v.abs() as f64 <= HALF_ELEVATION_RAD + 1e-6));
}

#[test]
fn sphere_returns_appear_at_the_ground_truth_range() {
    // Without speckle, jitter and crosstalk, the first strong return of each polar column lies
    // at the nearest surface point inside that column's beams (the image integrates over
    // elevation), found here by dense ray casting through the ground-truth caster.
    let params = SonarSimParams {
        speckle: false,
        range_jitter_m: 0.0,
        crosstalk: 0.0,
        crosstalk2: 0.0,
        ..SonarSimParams::default()
    };
    let bin = (R_MAX_M - R_MIN_M) / 256.0;
    let beams: Vec<f64> = epssn::config::BEAM_CENTRES_DEG
        .iter()
        .map(|d| d.to_radians())
        .collect();
    for index in 0..4 {
        let scene = generate(SceneKind::Sphere, Split::Train, 21, index, 2);
        let world = World::new(&scene);
        let wfv = scene.world_from_view(0);
        let data = simulate_scene(&scene, &params).unwrap();
        let polar = &data.polar_views[0];
        let background = *polar.iter().min().unwrap() as u32;
        let mut checked = 0;
        for a in 0..DEPTH_COLUMNS {
            // The column's two beams, each ± half its spacing.
            let lo = beams[2 * a] - (beams[2 * a + 1] - beams[2 * a]) / 2.0;
            let hi = beams[2 * a + 1] + (beams[2 * a + 1] - beams[2 * a]) / 2.0;
            let (mut nearest, mut facing) = (f64::INFINITY, 0.0);
            for i in 0..=8 {
                let az = lo + (hi - lo) * i as f64 / 8.0;
                for j in 0..=700 {
                    let el = -HALF_ELEVATION_RAD + 2.0 * HALF_ELEVATION_RAD * j as f64 / 700.0;
                    if let Some(h) = world.first_hit_in_view(&wfv, az, el) {
                        if h.t < nearest {
                            let d = wfv.rotate(epssn::geometry::direction(az, el));
                            nearest = h.t;
                            facing =
                                -(d[0] * h.normal[0] + d[1] * h.normal[1] + d[2] * h.normal[2]);
                        }
                    }
                }
            }
            if !(nearest > R_MIN_M + 0.02 && nearest < R_MAX_M - 0.02) {
                continue;
            }
            let Some(first) = (0..256).find(|&i| polar[i * 64 + a] as u32 > background + 60) else {
                continue; // a grazing sliver of the sphere too faint to stand out
            };
            let r = R_MIN_M + (first as f64 + 0.5) * bin;
            // Never a return where there is no surface (pulse spread and bin width aside) ...
            assert!(
                r > nearest - 0.012,
                "column {a}: first return at {r} m, before the nearest surface {nearest} m"
            );
            // ... and where the nearest surface faces the sonar, the return is right there
            // (grazing slivers at the silhouette are too faint to be the first strong return).
            if facing > 0.5 {
                assert!(
                    (r - nearest).abs() < 0.012,
                    "column {a}: first return at {r} m, nearest surface {nearest} m"
                );
                checked += 1;
            }
        }
        assert!(checked > 3, "only {checked} columns checked");
    }
}

#[test]
fn rendering_does_not_depend_on_the_thread_count() {
    let scene = generate(SceneKind::Artificial, Split::Train, 2, 5, 3);
    let params = SonarSimParams::default();
    let many = simulate_scene(&scene, &params).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let one = pool.install(|| simulate_scene(&scene, &params).unwrap());
    assert_eq!(many.frames.len(), 3);
    assert_eq!(many.frames, one.frames);
    assert_eq!(many.depth, one.depth);
}

#[test]
fn elevation_map_puts_floor_returns_on_the_floor() {
    // A bare floor seen from 1 m up, tilted 20° down: every (range, azimuth) cell has one
    // elevation, so the mean elevation of each pixel must reconstruct a point at z = 0.
    let scene = epssn_sim::scene::Scene {
        kind: SceneKind::Artificial,
        split: Split::Test,
        index: 0,
        seed: 0,
        sample_seed: 77,
        sonar: SonarPose {
            position_m: [0.0, 0.0, 1.0],
            yaw_deg: 0.0,
            tilt_deg: 20.0,
        },
        view_rolls_deg: vec![0.0, 7.0],
        view_pose_errors_deg: Vec::new(),
        objects: vec![epssn_sim::scene::Object::Plane {
            name: "floor".into(),
            point_m: [0.0; 3],
            normal: [0.0, 0.0, 1.0],
            reflectivity: 0.4,
        }],
    };
    let data = simulate_scene(&scene, &SonarSimParams::default()).unwrap();
    let wfr = scene.sonar.world_from_reference();
    let bin = (R_MAX_M - R_MIN_M) / 256.0;
    let mut checked = 0;
    for i in 0..256 {
        for k in 0..64 {
            let el = data.elevation[i * 64 + k];
            if !el.is_finite() {
                continue;
            }
            let p = wfr.apply(polar_to_cartesian(Polar {
                range: R_MIN_M + (i as f64 + 0.5) * bin,
                azimuth: INPUT_COLUMN_AZIMUTH_RAD[k],
                elevation: el as f64,
            }));
            assert!(p[2].abs() < 0.01, "pixel ({i}, {k}): z = {}", p[2]);
            checked += 1;
        }
    }
    // The floor fills the lower part of the aperture across the window.
    assert!(checked > 256 * 64 / 4, "only {checked} pixels with returns");
}

/// Mean |view − speckle-free view| in counts over pixels well above the noise floor (speckle-free
/// count above 120): the log-compressed speckle's spread.
fn speckle_spread(view: &[u8], clean: &[u8]) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (v, c) in view.iter().zip(clean) {
        if *c > 120 {
            sum += (*v as f64 - *c as f64).abs();
            n += 1;
        }
    }
    assert!(n > 100, "the view has returns ({n} pixels)");
    sum / n as f64
}

#[test]
fn speckle_looks_shrink_the_speckle_and_one_look_is_the_old_draw() {
    // The same terrain view rendered without speckle, with one look and with eight: on pixels
    // well above the noise floor the log-compressed speckle's spread (|L looks − no speckle|)
    // shrinks with the looks (about 5.6 dB for one look, 1.6 dB for eight).
    let scene = generate(SceneKind::Terrain, Split::Test, 3, 0, 2);
    let render = |params: SonarSimParams| simulate_scene(&scene, &params).unwrap().polar_views;
    let clean = render(SonarSimParams {
        speckle: false,
        ..SonarSimParams::default()
    });
    let spread = |looks: u32| {
        let views = render(SonarSimParams {
            speckle_looks: looks,
            ..SonarSimParams::default()
        });
        speckle_spread(&views[0], &clean[0])
    };
    let (one, eight) = (spread(1), spread(8));
    assert!(eight < 0.5 * one, "8 looks {eight:.2} vs 1 look {one:.2}");
    // One look is the default and is not written to sim_params.json.
    let default = serde_json::to_string(&SonarSimParams::default()).unwrap();
    assert!(!default.contains("speckle_looks"));
    let four: SonarSimParams = serde_json::from_str(r#"{"speckle_looks": 4}"#).unwrap();
    assert_eq!(four.speckle_looks, 4);
}

#[test]
fn pings_averaged_as_frames_shrink_the_speckle_like_looks_in_intensity() {
    // `ping_frames`: each look compressed on its own and averaged by `epssn::ping_average`, as
    // a host averages recorded pings. Same draws as the intensity looks, so the two renders
    // differ only by the per-ping quantisation: close on average, not byte-identical.
    let scene = generate(SceneKind::Terrain, Split::Test, 3, 0, 2);
    let render = |params: SonarSimParams| simulate_scene(&scene, &params).unwrap().polar_views;
    let base = SonarSimParams::default();
    let clean = render(SonarSimParams {
        speckle: false,
        ..base.clone()
    });
    let one = render(base.clone());
    let looks = |ping_frames| {
        render(SonarSimParams {
            speckle_looks: 4,
            ping_frames,
            ..base.clone()
        })
    };
    let (intensity, frames) = (looks(false), looks(true));
    let spread = |views: &[Vec<u8>]| speckle_spread(&views[0], &clean[0]);
    let (s1, si, sf) = (spread(&one), spread(&intensity), spread(&frames));
    assert!(sf < 0.7 * s1, "4 pings as frames {sf:.2} vs 1 ping {s1:.2}");
    assert!(
        (sf - si).abs() < 0.25 * si,
        "frames {sf:.2} vs intensity looks {si:.2}"
    );
    assert_ne!(frames, intensity);
    let mean_gap = frames[0]
        .iter()
        .zip(&intensity[0])
        .map(|(a, b)| (*a as f64 - *b as f64).abs())
        .sum::<f64>()
        / frames[0].len() as f64;
    assert!(
        mean_gap < 1.5,
        "mean |frames − intensity| {mean_gap:.2} counts"
    );
    // Off by default and not written then.
    assert!(!serde_json::to_string(&base)
        .unwrap()
        .contains("ping_frames"));
}

#[test]
fn ping_frames_are_written_as_frames_whose_average_is_the_view() {
    // With `ping_frames` every view file records its L pings; averaging them with the library
    // (what `host-sim run --pings-per-view L` does) and resampling gives the sample's polar view
    // byte for byte: a bundled recording carries exactly what the model was trained on.
    use epssn::ping_average::IntensityTable;
    let dir = tempfile::tempdir().unwrap();
    let params = SonarSimParams {
        speckle_looks: 4,
        ping_frames: true,
        ..SonarSimParams::default()
    };
    let params_file = dir.path().join("params.json");
    std::fs::write(&params_file, serde_json::to_string(&params).unwrap()).unwrap();
    run(&SimulateOptions {
        scene: Some(SceneKind::Artificial),
        site: None,
        region: None,
        site_reflectivity: None,
        export_mesh: None,
        whole_tank: false,
        pairs: Some(1),
        seed: 4,
        out: Some(dir.path().join("out")),
        split: Split::Test,
        views: 3,
        no_preview: true,
        params: Some(params_file),
        pose_jitter_deg: 0.0,
        pose_jitter_axes: epssn_sim::simulate::JitterAxes::Both,
        fixed_pose: false,
    })
    .unwrap();
    let d = dir.path().join("out/test/000000");
    let s = Sample::load(&d).unwrap();
    let table = IntensityTable::new(params.dynamic_range_db as f32).unwrap();
    for k in 0..3 {
        let reader = epssn_aris::aris::ArisReader::open(d.join(format!("view{k}.aris"))).unwrap();
        assert_eq!(reader.frame_count(), 4, "view {k}");
        let first = reader.frame(0).unwrap();
        for i in 0..4 {
            let ping = reader.frame(i).unwrap();
            assert_eq!(ping.header.frame_index, i as u32);
            assert_eq!(ping.header.sonar_roll_deg, 7.0 * k as f32);
            if i > 0 {
                assert_ne!(ping.data, first.data, "ping {i} of view {k} is a new draw");
            }
        }
        // Averaged as `host-sim run --pings-per-view 4` averages them.
        let average = epssn_aris::polar::average_pings(&reader, &[0, 1, 2, 3], &table).unwrap();
        let polar = epssn_aris::polar::frame_to_polar(&average).unwrap();
        let f: Vec<f32> = polar.iter().map(|x| *x as f32).collect();
        assert_eq!(f, s.polar_views[k], "view {k}");
    }
}

#[test]
fn fixed_pose_moves_the_sonar_and_keeps_the_scene() {
    // `--fixed-pose` (a study option): one pose for every terrain and tank sample, the terrain
    // and objects as drawn; spheres keep their identity pose.
    use epssn_sim::scene::fix_pose;
    for kind in [SceneKind::Terrain, SceneKind::Artificial] {
        let poses: Vec<_> = (0..3)
            .map(|i| {
                let drawn = generate(kind, Split::Test, 5, i, 2);
                let mut fixed = drawn.clone();
                fix_pose(&mut fixed);
                assert_ne!(fixed.sonar, drawn.sonar);
                assert_eq!(fixed.objects, drawn.objects);
                assert!((fixed.sonar.tilt_deg - 20.0).abs() < 1e-12);
                // The boresight meets flat ground at 2.75 m.
                let slant = fixed.sonar.position_m[2] / fixed.sonar.tilt_deg.to_radians().sin();
                assert!((slant - 2.75).abs() < 1e-12);
                fixed.sonar
            })
            .collect();
        assert!(poses.windows(2).all(|w| w[0] == w[1]), "{kind:?}");
    }
    let sphere = generate(SceneKind::Sphere, Split::Test, 5, 0, 2);
    let mut fixed = sphere.clone();
    fix_pose(&mut fixed);
    assert_eq!(fixed, sphere);
}
