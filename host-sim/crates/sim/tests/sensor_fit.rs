//! The sensor fit recovers known image-formation parameters: recordings simulated with them
//! (written as ARIS files and read back) are fitted on other scenes of the same family, and the
//! fitted parameters must land within the tolerances of docs/SITES.md ("Fitting the noise model
//! to your sonar"). Bad recordings fail with an error.

use epssn_sim::render::SonarSimParams;
use epssn_sim::scene::SceneKind;
use epssn_sim::sensor_fit::{fit, log_gamma_skewness, trigamma, Bench, FitSensorOptions};
use epssn_sim::sensor_stats::measure_recording;
use epssn_sim::simulate::write_aris;

/// Scenes per bench: the recording's (seed 1) and the fit's (seed 0) are different scenes.
const SCENES: usize = 10;

/// Tolerances: speckle looks exact; dynamic range ±5 %; gain ±2 dB; noise floor ±2 dB; floor
/// looks ±25 %. Crosstalk is not recovered (the scenes' own beam pattern swamps the leak's, see
/// docs/SITES.md): only that the fit keeps it within its search range is checked.
const DR_REL: f64 = 0.05;
const GAIN_DB: f64 = 2.0;
const FLOOR_DB: f64 = 2.0;
const NOISE_LOOKS_REL: f64 = 0.25;
const CROSSTALK_RANGE: (f64, f64) = (0.0, 0.2);

fn truth_sets() -> Vec<(&'static str, SonarSimParams)> {
    let d = SonarSimParams::default();
    vec![
        ("defaults (1 look, floor shares it)", d.clone()),
        (
            "2 looks, floor 6 looks at -54 dB",
            SonarSimParams {
                speckle_looks: 2,
                noise_looks: 6.0,
                noise_floor: 4e-6,
                gain_db: 72.0,
                dynamic_range_db: 80.0,
                crosstalk: 0.04,
                crosstalk2: 0.01,
                ..d.clone()
            },
        ),
        (
            "4 looks, floor 16 looks at -50 dB",
            SonarSimParams {
                speckle_looks: 4,
                noise_looks: 16.0,
                noise_floor: 1e-5,
                gain_db: 66.0,
                dynamic_range_db: 60.0,
                crosstalk: 0.0,
                crosstalk2: 0.0,
                ..d.clone()
            },
        ),
        (
            "2 looks, floor 3 looks at -60 dB",
            SonarSimParams {
                speckle_looks: 2,
                noise_looks: 3.0,
                noise_floor: 1e-6,
                crosstalk: 0.12,
                crosstalk2: 0.03,
                ..d
            },
        ),
    ]
}

#[test]
// Four fits of 61 simulations each: 30 s in the dev profile on the 2 shared cores.
fn the_fit_recovers_known_parameters_from_simulated_recordings() {
    let base = SonarSimParams::default();
    let recorder = Bench::new(SceneKind::Artificial, SCENES, 1, &base).unwrap();
    let bench = Bench::new(SceneKind::Artificial, SCENES, 0, &base).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    println!(
        "{:<36} {:>9} {:>13} {:>13} {:>13} {:>13} {:>13}",
        "truth", "looks", "DR dB", "gain dB", "floor dB", "floor looks", "crosstalk"
    );
    for (name, truth) in truth_sets() {
        let frames = recorder.frames(&truth);
        let refs: Vec<&[u8]> = frames.iter().map(Vec::as_slice).collect();
        let path = dir.path().join("rec.aris");
        write_aris(&path, &refs, 0.0, [0.0, 0.0], &truth).unwrap();
        let target = measure_recording(&path, None).unwrap();
        let f = fit(&target, &bench).unwrap();
        let p = &f.params;
        let floor_db = |p: &SonarSimParams| 10.0 * p.noise_floor.log10();
        let truth_noise_looks = if truth.noise_looks > 0.0 {
            truth.noise_looks
        } else {
            truth.speckle_looks as f64
        };
        println!(
            "{name:<36} {:>4} {:>4} {:>6.1} {:>6.1} {:>6.1} {:>6.1} {:>6.1} {:>6.1} {:>6.2} {:>6.2} {:>6.3} {:>6.3}",
            truth.speckle_looks,
            p.speckle_looks,
            truth.dynamic_range_db,
            p.dynamic_range_db,
            truth.gain_db,
            p.gain_db,
            floor_db(&truth),
            floor_db(p),
            truth_noise_looks,
            p.noise_looks,
            truth.crosstalk,
            p.crosstalk
        );
        let mut check = |ok: bool, what: &str| {
            if !ok {
                failures.push(format!("{name}: {what}"));
            }
        };
        check(p.speckle_looks == truth.speckle_looks, "speckle looks");
        check(
            (p.dynamic_range_db / truth.dynamic_range_db - 1.0).abs() <= DR_REL,
            "dynamic range",
        );
        check((p.gain_db - truth.gain_db).abs() <= GAIN_DB, "gain");
        check(
            (floor_db(p) - floor_db(&truth)).abs() <= FLOOR_DB,
            "noise floor",
        );
        check(
            (p.noise_looks / truth_noise_looks - 1.0).abs() <= NOISE_LOOKS_REL,
            "floor looks",
        );
        check(
            (CROSSTALK_RANGE.0..=CROSSTALK_RANGE.1).contains(&p.crosstalk),
            "crosstalk",
        );
        // The fitted file is one `simulate --params` reads, and the fitted simulation matches.
        let json = serde_json::to_string(p).unwrap();
        let back: SonarSimParams = serde_json::from_str(&json).unwrap();
        assert_eq!(&back, p);
        epssn_sim::simulate::check_params(p).unwrap();
        assert!(
            (f.fitted.dark_mean - target.dark_mean).abs() < 2.0,
            "{name}: fitted floor {} vs {}",
            f.fitted.dark_mean,
            target.dark_mean
        );
    }
    assert!(failures.is_empty(), "out of tolerance: {failures:?}");
}

#[test]
fn the_moment_relations_are_those_of_log_gamma_speckle() {
    // ψ'(1) = π²/6, ψ'(2) = π²/6 − 1; skewness of ln Gamma(1) = −2ζ(3) / (π²/6)^1.5.
    let z = std::f64::consts::PI.powi(2) / 6.0;
    assert!((trigamma(1.0) - z).abs() < 1e-9);
    assert!((trigamma(2.0) - (z - 1.0)).abs() < 1e-9);
    let zeta3 = 1.202_056_903_159_594;
    assert!((log_gamma_skewness(1.0) + 2.0 * zeta3 / z.powf(1.5)).abs() < 1e-6);
    assert!(log_gamma_skewness(2.0) > log_gamma_skewness(1.0));
    assert!(log_gamma_skewness(4.0) > log_gamma_skewness(2.0));
}

fn fit_file(bytes: &[u8]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("bad.aris");
    std::fs::write(&rec, bytes).unwrap();
    let args = FitSensorOptions {
        recording: rec,
        topic: None,
        out: dir.path().join("p.json"),
        params: None,
        scene: SceneKind::Artificial,
        scenes: 1,
        seed: 0,
        json: false,
    };
    let e = epssn_sim::sensor_fit::run(&args, &mut Vec::new()).unwrap_err();
    assert!(!dir.path().join("p.json").exists());
    format!("{e:#}")
}

fn recording_of(frame: &[u8], frames: usize) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("r.aris");
    let refs = vec![frame; frames];
    write_aris(&path, &refs, 0.0, [0.0, 0.0], &SonarSimParams::default()).unwrap();
    std::fs::read(path).unwrap()
}

#[test]
fn bad_recordings_are_errors_not_panics() {
    let e = fit_file(&[]);
    assert!(e.contains("opening"), "{e}");
    let good = recording_of(&vec![100u8; 520 * 128], 1);
    let e = fit_file(&good[..1024 + 500]);
    assert!(e.contains("opening") || e.contains("reading"), "{e}");
    let e = fit_file(&recording_of(&vec![0u8; 520 * 128], 2));
    assert!(e.contains("dark windows read 0"), "{e}");
    let e = fit_file(&recording_of(&vec![100u8; 520 * 128], 2));
    assert!(e.contains("no bright windows"), "{e}");
}

/// The texture parameters' statistics on a small bench (2 artificial scenes, seed 3).
fn texture_stats(bench: &Bench, p: &SonarSimParams) -> epssn_sim::sensor_stats::ImageStats {
    bench.stats(p).unwrap()
}

#[test]
fn each_texture_parameter_moves_its_statistic() {
    let base = SonarSimParams::default();
    let bench = Bench::new(SceneKind::Artificial, 2, 3, &base).unwrap();
    let at = texture_stats(&bench, &base);
    // A shorter pulse (range PSF) decorrelates the returns' rise and fall along range; without
    // speckle that is all the texture there is.
    let quiet = SonarSimParams {
        speckle: false,
        ..base.clone()
    };
    let long = texture_stats(&bench, &quiet);
    let short = texture_stats(
        &bench,
        &SonarSimParams {
            pulse_sigma_samples: 0.35,
            ..quiet.clone()
        },
    );
    assert!(
        short.lag1_range < long.lag1_range - 0.1,
        "pulse 0.35: {} against 1.0: {}",
        short.lag1_range,
        long.lag1_range
    );
    // Far side lobes leak the returns into every beam: the floor rises.
    let lobes = texture_stats(
        &bench,
        &SonarSimParams {
            sidelobe: 1.0,
            ..base.clone()
        },
    );
    assert!(
        lobes.dark_mean > at.dark_mean + 3.0,
        "{} {}",
        lobes.dark_mean,
        at.dark_mean
    );
    // A floor rising with range (all of the window lies beyond the 2 m reference) rises.
    let tvg = texture_stats(
        &bench,
        &SonarSimParams {
            noise_floor_db_per_m: 10.0,
            ..base.clone()
        },
    );
    assert!(
        tvg.dark_mean > at.dark_mean + 3.0,
        "{} {}",
        tvg.dark_mean,
        at.dark_mean
    );
    // A floor of many looks has fewer fades clipped to 0.
    let smooth = texture_stats(
        &bench,
        &SonarSimParams {
            noise_looks: 8.0,
            ..base.clone()
        },
    );
    assert!(smooth.zero_fraction < at.zero_fraction / 2.0);
}

#[test]
fn forming_with_the_traced_pulse_is_the_tracing_and_the_defaults_serialise_as_before() {
    // A bench traced with another pulse and formed with the default one gives the default
    // bench's frames bit for bit: the rays are deposited again by the same rule.
    let base = SonarSimParams::default();
    let traced_default = Bench::new(SceneKind::Artificial, 1, 4, &base).unwrap();
    let other = SonarSimParams {
        pulse_sigma_samples: 0.5,
        ..base.clone()
    };
    let traced_other = Bench::new(SceneKind::Artificial, 1, 4, &other).unwrap();
    assert_eq!(traced_other.frames(&base), traced_default.frames(&base));
    assert_ne!(traced_other.frames(&other), traced_default.frames(&base));
    // The new fields stay out of a default sim_params.json.
    let json = serde_json::to_string(&base).unwrap();
    for key in ["sidelobe", "noise_floor_db_per_m"] {
        assert!(!json.contains(key), "{json}");
    }
}

#[test]
// One fit of the bundled ARIS 1200 recording: about a minute in the dev profile.
fn the_fit_matches_the_aris1200_recordings_texture() {
    let rec = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../data/aris1200-telephoto-6frames.aris");
    let target = measure_recording(&rec, None).unwrap();
    let bench = Bench::new(SceneKind::Artificial, SCENES, 0, &SonarSimParams::default()).unwrap();
    let f = fit(&target, &bench).unwrap().fitted;
    println!(
        "lag1 range {:.3} / {:.3}, beams {:.3} / {:.3}, contrast {:.3} / {:.3}, modes {} / {}",
        f.lag1_range,
        target.lag1_range,
        f.lag1_beam,
        target.lag1_beam,
        f.bright_contrast,
        target.bright_contrast,
        f.histogram_modes,
        target.histogram_modes
    );
    assert!((f.lag1_range - target.lag1_range).abs() <= 0.1);
    assert!((f.lag1_beam - target.lag1_beam).abs() <= 0.1);
    assert!((f.bright_contrast - target.bright_contrast).abs() <= 0.02);
    assert_eq!(f.histogram_modes, 1);
    assert_eq!(target.histogram_modes, 1);
    assert!((f.dark_mean - target.dark_mean).abs() < 1.0);
}

/// A bag with two ProjectedSonarImage topics: without a topic the fit names both and asks for
/// `--topic`; with one it reads that topic's pings (flat here, so it stops at "no bright
/// windows", past the choice of topic).
#[test]
fn a_bag_topic_is_chosen_by_name() {
    use epssn_ros2::encode::{bag, cdr, even_azimuths, level_ping, Compression, Entry};
    use epssn_ros2::msgs::PROJECTED_SONAR_IMAGE;
    let (beams, bins) = (48usize, 200usize);
    let ranges: Vec<f32> = (0..bins).map(|r| 1.0 + 0.01 * r as f32).collect();
    let flat = vec![60; beams * bins];
    let ping = level_ping(1, &even_azimuths(beams, 0.5), &ranges, 1500.0, 0, flat);
    let img = cdr::sonar_image(&ping);
    let entry = |topic, log_time| Entry {
        topic,
        schema: PROJECTED_SONAR_IMAGE,
        log_time,
        data: &img,
    };
    let entries: Vec<Entry> = (0..3)
        .flat_map(|t| [entry("/port", t), entry("/starboard", t)])
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two.mcap");
    std::fs::write(&path, bag(&entries, Compression::None)).unwrap();

    let err = format!("{:#}", measure_recording(&path, None).unwrap_err());
    assert!(
        err.contains("/port, /starboard") && err.contains("--topic"),
        "{err}"
    );
    let err = format!(
        "{:#}",
        measure_recording(&path, Some("/starboard")).unwrap_err()
    );
    assert!(err.contains("no bright windows"), "{err}");
}
