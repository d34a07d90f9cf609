//! The main job end to end on the bundled demo recording, and its refusal of a recording
//! whose geometry does not fit the model.

use std::process::Command;

mod common;
use common::{demo_with_a_moved_window, jittered_recording};

fn host_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

/// Runs `host-sim run … --json` to success and checks what every run on a demo recording
/// gives: six view sets, all bit-exact against the integer reference, finite MAE and CD for
/// both models. Returns the JSON.
fn demo_run(cmd: &mut Command) -> serde_json::Value {
    let o = cmd.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["pairs"], 6);
    assert_eq!(v["bit_exact"], true);
    for model in ["float", "int8"] {
        let mae = v[model]["mae"].as_f64().unwrap();
        let cd = v[model]["cd"].as_f64().unwrap();
        assert!(
            mae.is_finite() && mae > 0.0 && cd.is_finite() && cd > 0.0,
            "{model}: {v}"
        );
    }
    v
}

/// A depth map's frame indices from `run --json`'s `details`.
fn frame_indices(detail: &serde_json::Value) -> Vec<u64> {
    detail["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_u64().unwrap())
        .collect()
}

#[test]
fn demo_run_is_bit_exact_and_scores_both_models() {
    let out = tempfile::tempdir().unwrap();
    let v = demo_run(host_sim().args(["run", "--json", "--out"]).arg(out.path()));
    assert!(v["int8_vs_float_mae"].as_f64().unwrap().is_finite());
    for f in [
        "frame0000_depth.png",
        "frame0000_int8.ply",
        "frame0000_float.ply",
        "summary.json",
    ] {
        assert!(out.path().join(f).exists(), "{f} missing");
    }
    // Frames pair at the roll baseline: each pair is (reference, reference + 1).
    for d in v["details"].as_array().unwrap() {
        let f = d["frames"].as_array().unwrap();
        assert_eq!(f[1].as_u64().unwrap(), f[0].as_u64().unwrap() + 1);
        let r = d["rolls_deg"].as_array().unwrap();
        assert!((r[1].as_f64().unwrap() - r[0].as_f64().unwrap() - 7.0).abs() < 1e-6);
    }
}

/// The three-view model (its blob says 3 views): `run` groups the three-view demo's frames in
/// threes (0, +7, +14 degrees) without `--views`, bit-exact against the integer reference; the
/// same weights refuse index pairs (two views).
#[test]
fn a_three_view_blob_runs_on_view_triples() {
    let out = tempfile::tempdir().unwrap();
    let common = [
        "run",
        "--weights",
        "weights/general-3view",
        "--recording",
        "data/demo-3view/recording.aris",
        "--gt",
        "data/demo-3view/gt",
        "--json",
    ];
    let v = demo_run(
        host_sim()
            .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
            .args(common)
            .arg("--out")
            .arg(out.path()),
    );
    for d in v["details"].as_array().unwrap() {
        let f = frame_indices(d);
        assert_eq!(f, vec![f[0], f[0] + 1, f[0] + 2], "{d}");
        assert_eq!(f[0] % 3, 0, "{d}");
    }
    let o = host_sim()
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .args(common)
        .args(["--pair", "0:1", "--out"])
        .arg(out.path())
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("take 3 views"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn real_aris1200_recording_is_refused_with_an_explanation() {
    let rec = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/aris1200-telephoto-6frames.aris"
    );
    let out = tempfile::tempdir().unwrap();
    let o = host_sim()
        .args(["run", "--recording", rec, "--pair", "0:1", "--out"])
        .arg(out.path())
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("ARIS 1200") && err.contains("telephoto"),
        "{err}"
    );
    assert!(o.stdout.is_empty());
}

/// A frame whose own window does not cover the model's is skipped by name, and the depth maps
/// of the other pairs are the demo's; `--pair` with it is refused.
#[test]
fn a_frame_outside_the_window_is_skipped_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let rec = demo_with_a_moved_window(dir.path(), 4);
    let run = |extra: &[&str], rec: Option<&std::path::Path>, out: &str| {
        let mut cmd = host_sim();
        cmd.args(["run", "--json", "--out"])
            .arg(dir.path().join(out));
        if let Some(r) = rec {
            // The demo's ground truth, which the default recording finds beside itself.
            let gt = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/demo/gt");
            cmd.arg("--recording").arg(r).args(["--gt", gt]);
        }
        cmd.args(extra).output().unwrap()
    };
    let o = run(&[], None, "demo");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let demo: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let o = run(&[], Some(&rec), "moved");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let moved: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(moved["pairs"], 5, "{moved}");
    let warned = moved["warnings"].as_array().unwrap().iter().any(|w| {
        let w = w.as_str().unwrap();
        w.contains("1 frame(s) whose own range window") && w.contains("frame 4: range window 7.")
    });
    assert!(warned, "{}", moved["warnings"]);
    let details = demo["details"].as_array().unwrap();
    for d in moved["details"].as_array().unwrap() {
        assert!(!frame_indices(d).contains(&4), "{d}");
        let same = details.iter().find(|x| x["frames"] == d["frames"]).unwrap();
        assert_eq!(same, d);
    }
    let o = run(&["--pair", "4:5"], Some(&rec), "given");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("pair 4:5: frame 4 does not fit the model"),
        "{err}"
    );
}

#[test]
fn pairing_by_roll_follows_the_baseline_and_tolerance() {
    use host_sim::pairing::pair_by_roll;
    let rolls = [
        Some(0.0),
        Some(7.2),
        Some(0.1),
        Some(14.0),
        None,
        Some(7.0),
        Some(6.0),
    ];
    assert_eq!(
        pair_by_roll(&rolls, 2),
        vec![vec![0, 1], vec![1, 3], vec![2, 5]]
    );
    // Views of a group need not be in time order: frame 3 (14°) serves the 0.1° reference too.
    assert_eq!(pair_by_roll(&rolls, 3), vec![vec![0, 1, 3], vec![2, 5, 3]]);
    assert!(pair_by_roll(&[None, None], 2).is_empty());
}

#[test]
fn a_truncated_recording_is_refused_with_the_readers_cause() {
    let demo = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/demo/recording.aris");
    let bytes = std::fs::read(demo).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("cut.aris");
    // The 1024-byte file header, one complete frame and 1000 bytes of the second.
    let frames = 12;
    let frame_len = (bytes.len() - 1024) / frames;
    std::fs::write(&rec, &bytes[..1024 + frame_len + 1000]).unwrap();
    for extra in [&[][..], &["--pair", "0:1"][..]] {
        let o = host_sim()
            .arg("run")
            .arg("--recording")
            .arg(&rec)
            .args(extra)
            .arg("--out")
            .arg(dir.path().join("out"))
            .output()
            .unwrap();
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("holds 1 complete frame(s), a depth map needs 2")
                && err.contains(&format!(
                    "truncated last frame: 1000 trailing bytes of a {frame_len}-byte frame \
                     ignored ({} bytes missing)",
                    frame_len - 1000
                ))
                && err.contains(
                    "FrameCount is 12, but the file holds 1 complete frames (11 missing)"
                )
                && !err.contains("give --pair"),
            "{err}"
        );
    }
}

#[test]
fn a_jittered_recording_pairs_exactly_the_pairs_within_the_residual_tolerance() {
    let tol = epssn::config::PAIR_RESIDUAL_TOLERANCE_DEG;
    let dir = tempfile::tempdir().unwrap();
    let rec = jittered_recording(dir.path(), 0.5 * tol, 2.0 * tol);
    let o = host_sim()
        .args(["run", "--json", "--recording"])
        .arg(&rec)
        .arg("--gt")
        .arg(dir.path().join("rec/gt"))
        .arg("--out")
        .arg(dir.path().join("out"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let c = v["candidates"].as_array().unwrap();
    // Frames 0,1 (low), 2,3 (high), 4,5 (low), ...: every even pair accepted, every odd one
    // rejected for its residual, each with the residual the simulator put in.
    let frames: Vec<u64> = c.iter().map(|x| x["frames"][0].as_u64().unwrap()).collect();
    assert_eq!(frames, [0, 2, 4, 6, 8, 10]);
    for (i, x) in c.iter().enumerate() {
        let low = i % 2 == 0;
        assert_eq!(x["accepted"], low, "{x}");
        assert_eq!(x["reason"], if low { "ok" } else { "residual" }, "{x}");
        let want = if low { 0.5 * tol } else { 2.0 * tol };
        assert!(
            (x["residual_deg"].as_f64().unwrap() - want).abs() < 1e-3,
            "{x}"
        );
        assert!((x["roll_deg"].as_f64().unwrap() - 7.0).abs() < 1e-3, "{x}");
    }
    assert_eq!(v["pairs"], 3);
    assert_eq!(v["bit_exact"], true);
    let used: Vec<u64> = v["details"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["frames"][0].as_u64().unwrap())
        .collect();
    assert_eq!(used, [0, 4, 8]);
}

#[test]
fn ping_bursts_are_runs_of_frames_at_one_roll() {
    use host_sim::pairing::ping_bursts;
    let rolls = [
        Some(0.0),
        Some(0.1),
        Some(0.0),
        Some(7.0),
        Some(7.2),
        None,
        Some(7.0),
        Some(7.0),
        Some(14.0),
    ];
    let b = |pings| ping_bursts(&rolls, pings).into_values().collect::<Vec<_>>();
    assert_eq!(b(2), vec![vec![0, 1], vec![3, 4], vec![6, 7]]);
    assert_eq!(b(3), vec![vec![0, 1, 2]]);
    assert_eq!(b(1).len(), 8, "every frame with a roll");
    assert!(ping_bursts(&rolls, 10).is_empty());
}

/// The demo with every frame recorded three times (three identical pings per view): averaging
/// identical pings gives the frame back, so `--pings-per-view 3` computes the very depth maps of
/// the single-ping run, named by each burst's first frame; single pings refuse to be averaged.
#[test]
fn averaged_identical_pings_give_the_single_ping_depth_maps() {
    let demo = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/demo/recording.aris");
    let bytes = std::fs::read(demo).unwrap();
    let frames = 12;
    let frame_len = (bytes.len() - 1024) / frames;
    let mut tripled = bytes[..1024].to_vec();
    tripled[4..8].copy_from_slice(&(3 * frames as u32).to_le_bytes()); // FrameCount
    for i in 0..frames {
        for _ in 0..3 {
            tripled.extend_from_slice(&bytes[1024 + i * frame_len..1024 + (i + 1) * frame_len]);
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("tripled.aris");
    std::fs::write(&rec, &tripled).unwrap();
    let run = |recording: &std::path::Path, extra: &[&str], out: &str| {
        host_sim()
            .args(["run", "--json", "--recording"])
            .arg(recording)
            .args(extra)
            .arg("--out")
            .arg(dir.path().join(out))
            .output()
            .unwrap()
    };
    let single = run(std::path::Path::new(demo), &[], "single");
    assert!(
        single.status.success(),
        "{}",
        String::from_utf8_lossy(&single.stderr)
    );
    let single: serde_json::Value = serde_json::from_slice(&single.stdout).unwrap();
    let three = run(&rec, &["--pings-per-view", "3"], "three");
    assert!(
        three.status.success(),
        "{}",
        String::from_utf8_lossy(&three.stderr)
    );
    let three: serde_json::Value = serde_json::from_slice(&three.stdout).unwrap();
    assert_eq!(three["pings_per_view"], 3);
    assert_eq!(three["pairs"], single["pairs"]);
    assert_eq!(three["bit_exact"], true);
    for (s, t) in single["details"]
        .as_array()
        .unwrap()
        .iter()
        .zip(three["details"].as_array().unwrap())
    {
        let (f, g) = (frame_indices(s), frame_indices(t));
        assert_eq!(g, f.iter().map(|i| 3 * i).collect::<Vec<_>>());
        assert_eq!(
            t["pings"][0],
            serde_json::json!([3 * f[0], 3 * f[0] + 1, 3 * f[0] + 2])
        );
        assert_eq!(t["int8_vs_float_mae"], s["int8_vs_float_mae"]);
        let ply = |run: &str, frame: u64| {
            std::fs::read(
                dir.path()
                    .join(run)
                    .join(format!("frame{frame:04}_int8.ply")),
            )
            .unwrap()
        };
        assert_eq!(ply("three", g[0]), ply("single", f[0]));
    }
    // The single-ping demo holds no two consecutive frames at one roll.
    let refused = run(
        std::path::Path::new(demo),
        &["--pings-per-view", "2"],
        "refused",
    );
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        err.contains("no run of 2 consecutive frames at one roll"),
        "{err}"
    );
}

/// A simulated four-ping recording end to end: `simulate` with `ping_frames` records every ping,
/// `bundle` keeps them in a row, and `run --pings-per-view 4` averages each burst back into
/// the very inputs `eval` reads from the sample folder: the same int8 and float accuracy.
#[test]
fn a_four_ping_recording_runs_to_the_sample_folders_accuracy() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
    let dir = tempfile::tempdir().unwrap();
    let sim = dir.path().join("sim");
    let ok = |cmd: &mut Command| {
        let o = cmd.current_dir(root).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        o.stdout
    };
    ok(host_sim()
        .args([
            "simulate", "--scene", "terrain", "--pairs", "1", "--seed", "2026",
        ])
        .args([
            "--split",
            "test",
            "--views",
            "3",
            "--no-preview",
            "--params",
        ])
        .arg("scripts/sim-params/looks-4-frames.json")
        .arg("--out")
        .arg(&sim));
    let rec = dir.path().join("rec");
    ok(host_sim()
        .arg("bundle")
        .arg(sim.join("test/000000"))
        .arg("--out")
        .arg(&rec));
    let weights = ["--weights", "weights/general-3view-looks4"];
    let run: serde_json::Value = serde_json::from_slice(&ok(host_sim()
        .arg("run")
        .args(weights)
        .arg("--recording")
        .arg(rec.join("recording.aris"))
        .arg("--gt")
        .arg(rec.join("gt"))
        // The simulator compresses 70 dB into the counts (ARIS recordings: 80, the default).
        .args(["--ping-dynamic-range-db", "70", "--json", "--out"])
        .arg(dir.path().join("out"))))
    .unwrap();
    assert_eq!(run["pings_per_view"], 4);
    assert_eq!(run["pairs"], 1);
    assert_eq!(run["bit_exact"], true);
    assert_eq!(
        run["details"][0]["pings"],
        serde_json::json!([[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]])
    );
    let eval: serde_json::Value = serde_json::from_slice(&ok(host_sim()
        .arg("eval")
        .args(weights)
        .arg("--data")
        .arg(&sim)
        .args(["--int8", "--json"])))
    .unwrap();
    assert_eq!(eval["warnings"], serde_json::json!([]));
    for model in ["float", "int8"] {
        for metric in ["mae", "mae_masked", "cd"] {
            let (r, e) = (
                run[model][metric].as_f64().unwrap(),
                eval[model][metric].as_f64().unwrap(),
            );
            assert!(
                (r - e).abs() <= 1e-9 * e,
                "{model} {metric}: run {r}, eval {e}"
            );
        }
    }
}
