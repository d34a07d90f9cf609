//! ARIS reader/writer and `host-sim inspect` against the bundled real recording, synthetic
//! files and deliberately broken inputs.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use epssn_aris::aris::{
    ArisError, ArisReader, ArisWriter, FileHeader, FrameHeader, SystemType, HEADER_LEN,
};
use proptest::prelude::*;

fn real_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../data/aris1200-telephoto-6frames.aris")
}

fn real_bytes() -> Vec<u8> {
    std::fs::read(real_path()).expect("bundled recording")
}

// Independent little-endian field access on the raw file bytes (not via the header structs).
fn u32_at(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes(b[off..off + 4].try_into().unwrap())
}
fn u64_at(b: &[u8], off: usize) -> u64 {
    u64::from_le_bytes(b[off..off + 8].try_into().unwrap())
}
fn f32_at(b: &[u8], off: usize) -> f32 {
    f32::from_le_bytes(b[off..off + 4].try_into().unwrap())
}
fn put_u32(b: &mut [u8], off: usize, v: u32) {
    b[off..off + 4].copy_from_slice(&v.to_le_bytes());
}
fn put_f32(b: &mut [u8], off: usize, v: f32) {
    b[off..off + 4].copy_from_slice(&v.to_le_bytes());
}

const REAL_FRAME_LEN: usize = 1024 + 48 * 2000;
fn frame_start(i: usize) -> usize {
    1024 + i * REAL_FRAME_LEN
}

fn open_bytes(bytes: Vec<u8>) -> Result<ArisReader<Cursor<Vec<u8>>>, ArisError> {
    ArisReader::new(Cursor::new(bytes))
}

fn write_temp(bytes: &[u8]) -> tempfile::NamedTempFile {
    let f = tempfile::Builder::new().suffix(".aris").tempfile().unwrap();
    std::fs::write(f.path(), bytes).unwrap();
    f
}

/// What `host-sim inspect` would print and return, through the library (the binary only
/// prints `host-sim: error: {e:#}` on failure).
struct Output {
    success: bool,
    stdout: Vec<u8>,
    stderr: Vec<u8>,
}

fn run_cli(args: &[&str]) -> Output {
    assert_eq!(args[0], "inspect");
    let json = args.contains(&"--json");
    let file = args[1..].iter().find(|a| **a != "--json").expect("a file");
    let args = epssn_aris::inspect::InspectOptions {
        file: PathBuf::from(file),
        json,
    };
    let mut stdout = Vec::new();
    match epssn_aris::inspect::run(&args, &mut stdout) {
        Ok(()) => Output {
            success: true,
            stdout,
            stderr: Vec::new(),
        },
        Err(e) => Output {
            success: false,
            stdout: Vec::new(),
            stderr: format!("host-sim: error: {e:#}").into_bytes(),
        },
    }
}

#[test]
fn real_recording_geometry_matches_aris_md_formulas() {
    let raw = real_bytes();
    let r = ArisReader::open(real_path()).unwrap();
    assert_eq!(r.frame_count(), (raw.len() - 1024) / REAL_FRAME_LEN);
    assert_eq!(r.frame_count(), 6);
    assert_eq!((raw.len() - 1024) % REAL_FRAME_LEN, 0);
    assert_eq!(r.beams(), 48);
    assert_eq!(r.samples_per_beam(), 2000);
    assert_eq!(r.system(), SystemType::Aris1200);
    assert_eq!(r.system().name(), "ARIS 1200");
    assert!(r.telephoto());
    assert_eq!(r.beam_table().unwrap().name, "ARIS_Telephoto_48");
    let centres = r.beam_centres_rad().unwrap();
    assert_eq!(centres.len(), 48);
    assert!(centres.windows(2).all(|w| w[0] < w[1]));
    assert!(centres[0] < 0.0, "beam 0 is right-most (negative)");

    for i in 0..6 {
        let base = frame_start(i);
        let delay = f64::from(u32_at(&raw, base + 476));
        let period = f64::from(u32_at(&raw, base + 452));
        let c = f64::from(f32_at(&raw, base + 464));
        let samples = f64::from(u32_at(&raw, base + 468));
        let start = delay * 1e-6 * c / 2.0;
        let length = period * samples * 1e-6 * c / 2.0;

        let f = r.frame(i).unwrap();
        let g = f.range_geometry().unwrap();
        assert!(
            (g.start - start).abs() < 1e-9,
            "frame {i}: {} vs {start}",
            g.start
        );
        assert!((g.step - period * 1e-6 * c / 2.0).abs() < 1e-12);
        assert_eq!(g.samples, 2000);
        assert!((f.window_length_m().unwrap() - length).abs() < 1e-9);
        // The header's own WindowStart agrees within centimetres (docs/ARIS.md).
        let reported = f64::from(f32_at(&raw, base + 52));
        assert!(
            (reported - start).abs() < 0.05,
            "frame {i}: header WindowStart {reported} vs computed {start}"
        );
        // Samples are the bytes after the frame header, sample-major.
        assert_eq!(f.data, &raw[base + 1024..base + REAL_FRAME_LEN]);
        assert_eq!(f.sample(1, 0), Some(raw[base + 1024 + 48]));
        assert_eq!(f.sample(1999, 47), Some(raw[base + REAL_FRAME_LEN - 1]));
        assert_eq!(f.header.frame_time_us, u64_at(&raw, base + 4));
        assert!(f.header.sonar_roll_deg.is_nan());
    }
    // No rotator roll: the reader must say so, and flag the mismatched geometry.
    let w = r.warnings().join("\n");
    assert!(w.contains("SonarRoll is NaN"), "{w}");
    assert!(w.contains("mismatched geometry"), "{w}");
    assert!(!w.contains("truncated"), "{w}");
}

#[test]
fn inspect_json_reports_the_real_recording() {
    let raw = real_bytes();
    let out = run_cli(&["inspect", real_path().to_str().unwrap(), "--json"]);
    assert!(out.success, "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["frame_count"], 6);
    assert_eq!(v["beams"], 48);
    assert_eq!(v["samples_per_beam"], 2000);
    assert_eq!(v["system"], "ARIS 1200");
    assert_eq!(v["telephoto"], true);
    assert_eq!(v["beam_table"], "ARIS_Telephoto_48");
    let base = frame_start(0);
    let c = f64::from(f32_at(&raw, base + 464));
    assert_eq!(v["sound_speed_m_s"].as_f64().unwrap(), c);
    assert_eq!(v["sample_period_us"], u32_at(&raw, base + 452));
    let start = f64::from(u32_at(&raw, base + 476)) * 1e-6 * c / 2.0;
    let length = f64::from(u32_at(&raw, base + 452)) * 2000.0 * 1e-6 * c / 2.0;
    assert!((v["window_start_m"].as_f64().unwrap() - start).abs() < 1e-9);
    assert!((v["window_length_m"].as_f64().unwrap() - length).abs() < 1e-9);
    let frames = v["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 6);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f["index"], i);
        assert_eq!(f["time_us"], u64_at(&raw, frame_start(i) + 4));
        assert!(f["sonar_roll_deg"].is_null(), "NaN must serialise as null");
        assert_eq!(
            f["roll_abs_position_deg"].as_f64().unwrap(),
            f64::from(f32_at(&raw, frame_start(i) + 640))
        );
        assert!(f.get("platform_roll_deg").is_some());
    }
    assert!(!v["warnings"].as_array().unwrap().is_empty());

    let text = run_cli(&["inspect", real_path().to_str().unwrap()]);
    assert!(text.success);
    let text = String::from_utf8(text.stdout).unwrap();
    assert!(
        text.contains("ARIS 1200") && text.contains("ARIS_Telephoto_48"),
        "{text}"
    );
}

fn copy_through(reader: &ArisReader<impl std::io::Read + std::io::Seek>) -> Vec<u8> {
    let mut w = ArisWriter::new(Cursor::new(Vec::new()), reader.file_header()).unwrap();
    for f in reader.frames() {
        let f = f.unwrap();
        w.write_frame(&f.header, &f.data).unwrap();
    }
    w.finish().unwrap().into_inner()
}

#[test]
fn real_recording_round_trips_byte_for_byte() {
    let raw = real_bytes();
    let r = ArisReader::open(real_path()).unwrap();
    assert_eq!(copy_through(&r), raw);
    // Through a real file too.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("copy.aris");
    let mut w = ArisWriter::create(&path, r.file_header()).unwrap();
    for i in 0..r.frame_count() {
        let f = r.frame(i).unwrap();
        w.write_frame(&f.header, &f.data).unwrap();
    }
    w.finish().unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), raw);
}

#[test]
fn synthetic_aris3000_round_trips() {
    let (beams, samples) = (128, 64);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sim.aris");
    let fh = FileHeader::new(beams as u32, samples as u32);
    let mut w = ArisWriter::create(&path, &fh).unwrap();
    let mut written = Vec::new();
    for k in 0..3u32 {
        let mut h = FrameHeader::new_aris3000(beams, samples, 4, 2667, 1500.0)
            .unwrap()
            .with_roll_deg(7.0 * k as f32);
        h.frame_index = k;
        h.frame_time_us = 1_700_000_000_000_000 + u64::from(k);
        let data: Vec<u8> = (0..beams * samples)
            .map(|i| ((i as u32 * 13 + k * 5) % 251) as u8)
            .collect();
        w.write_frame(&h, &data).unwrap();
        written.push(data);
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(bytes.len(), 1024 + 3 * (1024 + beams * samples));
    // The file header was fixed at finish.
    assert_eq!(u32_at(&bytes, 4), 3);
    assert_eq!(u64_at(&bytes, 424), bytes.len() as u64);

    let r = ArisReader::open(&path).unwrap();
    assert_eq!(
        (r.beams(), r.samples_per_beam(), r.frame_count()),
        (128, 64, 3)
    );
    assert_eq!(r.system(), SystemType::Aris3000);
    assert_eq!(r.beam_table().unwrap().name, "ARIS3000_128");
    for (k, data) in written.iter().enumerate() {
        let f = r.frame(k).unwrap();
        assert_eq!(&f.data, data);
        assert_eq!(f.header.sonar_roll_deg, 7.0 * k as f32);
        assert_eq!(f.header.roll_abs_position_deg, 7.0 * k as f32);
        assert_eq!(u32_at(&bytes, 1024 + k * (1024 + 128 * 64) + 516), 1);
        let g = f.range_geometry().unwrap();
        assert!((g.start - 2667e-6 * 1500.0 / 2.0).abs() < 1e-9);
    }
    // A clean simulated file raises no warning: rolls, counts, sizes and geometry all agree.
    assert!(r.warnings().is_empty(), "{:?}", r.warnings());
    assert_eq!(copy_through(&r), bytes);
}

#[test]
fn wrong_signature_is_rejected_with_the_bytes_found() {
    let mut b = real_bytes();
    b[0..4].copy_from_slice(b"RIFF");
    let e = open_bytes(b).unwrap_err();
    assert!(
        matches!(&e, ArisError::BadSignature { found, .. } if found == b"RIFF"),
        "{e}"
    );
    let msg = e.to_string();
    assert!(
        msg.contains("RIFF") && msg.contains("52, 49, 46, 46"),
        "{msg}"
    );

    let mut b = real_bytes();
    b[1024 + 12] = 0;
    assert!(matches!(
        open_bytes(b).unwrap_err(),
        ArisError::BadSignature { .. }
    ));
}

#[test]
fn truncated_headers_are_rejected() {
    let b = real_bytes();
    for len in [0, 3, 500, 1023] {
        let e = open_bytes(b[..len].to_vec()).unwrap_err();
        assert!(
            matches!(e, ArisError::TruncatedHeader { offset: 0, .. }),
            "{len}: {e}"
        );
    }
    for len in [1024, 1500, 2047] {
        let e = open_bytes(b[..len].to_vec()).unwrap_err();
        assert!(
            matches!(e, ArisError::TruncatedHeader { offset: 1024, .. }),
            "{len}: {e}"
        );
    }
}

#[test]
fn truncated_last_frame_keeps_complete_frames_and_warns() {
    let b = real_bytes();
    let r = open_bytes(b[..b.len() - 1000].to_vec()).unwrap();
    assert_eq!(r.frame_count(), 5);
    let w = r.warnings().join("\n");
    assert!(w.contains("truncated last frame"), "{w}");
    assert!(w.contains("FrameCount is 6"), "{w}");
    assert!(w.contains("FileSize"), "{w}");
    for i in 0..5 {
        r.frame(i).unwrap();
    }
    assert!(matches!(
        r.frame(5),
        Err(ArisError::FrameIndexOutOfRange { index: 5, count: 5 })
    ));
    // Only a frame header left of the first frame: zero frames, still no error.
    let r = open_bytes(b[..2048 + 10].to_vec()).unwrap();
    assert_eq!(r.frame_count(), 0);
    assert!(r.frame(0).is_err());
}

#[test]
fn ping_mode_contradicting_the_beam_count() {
    let mut b = real_bytes();
    put_u32(&mut b, 1024 + 436, 9); // 128 beams, file header says 48
    let e = open_bytes(b).unwrap_err();
    assert!(
        matches!(
            e,
            ArisError::PingModeMismatch {
                ping_mode: 9,
                ping_beams: 128,
                header_beams: 48
            }
        ),
        "{e}"
    );
    // In a later frame it is a warning: the layout is fixed by frame 0.
    let mut b = real_bytes();
    put_u32(&mut b, frame_start(3) + 436, 7);
    let r = open_bytes(b).unwrap();
    let w = r.warnings().join("\n");
    assert!(w.contains("frame 3: PingMode 7 implies 64 beams"), "{w}");
    assert!(
        !w.contains("FrameTime"),
        "the real recording's clock is monotonic: {w}"
    );
}

#[test]
fn later_frame_anomalies_are_warnings_naming_the_frame() {
    let mut b = real_bytes();
    put_u32(&mut b, frame_start(2) + 468, 1999); // SamplesPerBeam
    put_u32(&mut b, frame_start(4), 40); // FrameIndex
    let t3 = u64_at(&b, frame_start(3) + 4);
    b[frame_start(5) + 4..frame_start(5) + 12].copy_from_slice(&(t3 - 1).to_le_bytes());
    put_u32(&mut b, frame_start(1) + 516, 0); // ReorderedSamples
    let r = open_bytes(b).unwrap();
    assert_eq!(r.frame_count(), 6);
    let w = r.warnings().join("\n");
    assert!(w.contains("frame 2: SamplesPerBeam 1999 differs"), "{w}");
    assert!(w.contains("frame 4: FrameIndex does not match"), "{w}");
    assert!(w.contains("frame 5: FrameTime goes backwards"), "{w}");
    assert!(w.contains("frame 1: ReorderedSamples is 0"), "{w}");
}

#[test]
fn zero_or_absurd_samples_and_beams_are_rejected() {
    for samples in [0u32, 100_001, u32::MAX] {
        let mut b = real_bytes();
        put_u32(&mut b, 1024 + 468, samples);
        let e = open_bytes(b).unwrap_err();
        assert!(
            matches!(e, ArisError::BadSampleCount { samples: s, .. } if s == samples),
            "{e}"
        );
    }
    let mut b = real_bytes();
    put_u32(&mut b, 16, 1000); // NumRawBeams
    put_u32(&mut b, 1024 + 436, 0); // PingMode: none
    let e = open_bytes(b).unwrap_err();
    assert!(
        matches!(
            e,
            ArisError::BadBeamCount {
                ping_mode: 0,
                num_raw_beams: 1000
            }
        ),
        "{e}"
    );
    // With a valid PingMode an absurd NumRawBeams only warns.
    let mut b = real_bytes();
    put_u32(&mut b, 16, 1000);
    let r = open_bytes(b).unwrap();
    assert_eq!(r.beams(), 48);
    assert!(r
        .warnings()
        .iter()
        .any(|w| w.contains("NumRawBeams is 1000")));
}

#[test]
fn nan_fields_warn_and_serialise_as_null() {
    let mut b = real_bytes();
    put_f32(&mut b, frame_start(0) + 464, f32::NAN); // SoundSpeed
    put_f32(&mut b, frame_start(3) + 144, f32::NAN); // platform Roll
    put_f32(&mut b, frame_start(4) + 640, f32::NAN); // RollAbsPosition
    let r = open_bytes(b.clone()).unwrap();
    let w = r.warnings().join("\n");
    assert!(w.contains("frame 0: SoundSpeed is NaN"), "{w}");
    assert!(w.contains("frame 0: range geometry unavailable"), "{w}");
    assert!(w.contains("frame 3: Roll is NaN"), "{w}");
    assert!(w.contains("frame 4: RollAbsPosition is NaN"), "{w}");
    assert!(matches!(
        r.frame(0).unwrap().range_geometry(),
        Err(ArisError::RangeGeometry(_))
    ));
    assert!(r.frame(1).unwrap().range_geometry().is_ok());

    let tmp = write_temp(&b);
    let out = run_cli(&["inspect", "--json", tmp.path().to_str().unwrap()]);
    assert!(out.success, "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["sound_speed_m_s"].is_null());
    assert!(v["window_start_m"].is_null());
    assert!(v["window_length_m"].is_null());
    assert!(v["frames"][3]["platform_roll_deg"].is_null());
    assert!(v["frames"][2]["platform_roll_deg"].is_number());
    assert!(v["frames"][4]["roll_abs_position_deg"].is_null());
    assert!(v["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .any(|w| w.as_str().unwrap().contains("SoundSpeed is NaN")));
}

#[test]
fn cli_fails_cleanly_on_unusable_files() {
    let mut bad_sig = real_bytes();
    bad_sig[0] = b'X';
    let mut zero_samples = real_bytes();
    put_u32(&mut zero_samples, 1024 + 468, 0);
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (bad_sig, "not an ARIS DDF_05 file"),
        (real_bytes()[..700].to_vec(), "truncated file header"),
        (zero_samples, "samples per beam 0"),
    ];
    for (bytes, expect) in cases {
        let tmp = write_temp(&bytes);
        for json in [false, true] {
            let mut args = vec!["inspect", tmp.path().to_str().unwrap()];
            if json {
                args.push("--json");
            }
            let out = run_cli(&args);
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(!out.success, "{expect}");
            assert!(err.contains(expect), "expected {expect:?} in {err}");
            assert!(!err.contains("panicked"), "{err}");
            assert!(out.stdout.is_empty());
        }
    }
    let out = run_cli(&["inspect", "/nonexistent/file.aris"]);
    assert!(!out.success);
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot open"));
}

/// Byte positions biased towards the headers, where a mutation changes how the rest is read.
fn position() -> impl Strategy<Value = usize> {
    let len = 1024 + 6 * REAL_FRAME_LEN;
    prop_oneof![
        3 => 0..HEADER_LEN,
        3 => 1024..1024 + HEADER_LEN,
        2 => (0..6usize, 0..HEADER_LEN).prop_map(|(f, o)| frame_start(f) + o),
        1 => 0..len,
    ]
}

/// Writes interesting values (0, all ones, NaN, small) as well as random bytes.
fn mutation() -> impl Strategy<Value = (usize, [u8; 4])> {
    (
        position(),
        prop_oneof![
            Just([0u8; 4]),
            Just([0xff; 4]),
            Just([0, 0, 0xc0, 0x7f]), // NaN
            any::<[u8; 4]>(),
            (0u32..200).prop_map(|v| v.to_le_bytes()),
        ],
    )
}

fn mutate(mutations: Vec<(usize, [u8; 4])>, truncate: Option<usize>) -> Vec<u8> {
    let mut b = real_bytes();
    for (pos, bytes) in mutations {
        for (k, v) in bytes.iter().enumerate() {
            if let Some(slot) = b.get_mut(pos + k) {
                *slot = *v;
            }
        }
    }
    if let Some(t) = truncate {
        b.truncate(t);
    }
    b
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn mutated_or_truncated_recordings_never_panic(
        mutations in prop::collection::vec(mutation(), 0..8),
        truncate in prop::option::of(0usize..1024 + 6 * REAL_FRAME_LEN),
    ) {
        if let Ok(r) = open_bytes(mutate(mutations, truncate)) {
            // Whatever was accepted must be self-consistent.
            prop_assert!(r.beams() * r.samples_per_beam() > 0);
            for i in 0..r.frame_count() + 1 {
                match r.frame(i) {
                    Ok(f) => {
                        prop_assert_eq!(f.data.len(), r.beams() * r.samples_per_beam());
                        let _ = f.range_geometry();
                        let _ = f.window_length_m();
                        let _ = f.beam_centres_rad();
                        prop_assert_eq!(f.sample(f.samples_per_beam, 0), None);
                    }
                    Err(_) => prop_assert_eq!(i, r.frame_count()),
                }
            }
            let _ = r.beam_table();
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn inspect_report_never_panics_on_mutated_files(
        mutations in prop::collection::vec(mutation(), 1..6),
        truncate in prop::option::of(0usize..1024 + 6 * REAL_FRAME_LEN),
    ) {
        let tmp = write_temp(&mutate(mutations, truncate));
        if let Ok(report) = epssn_aris::inspect::report(tmp.path()) {
            // JSON must always be producible (no NaN leaks into it).
            prop_assert!(serde_json::to_string(&report).is_ok());
            let mut text = Vec::new();
            prop_assert!(epssn_aris::inspect::write_text(&report, &mut text).is_ok());
        }
    }
}
