//! `host-sim label` end to end: site samples simulated and bundled, labelled again from the
//! bundle's `poses.csv`, give the bundle's `gt/` byte for byte, and `run` on them scores what
//! `eval` scores on the sample folders; bad input is refused and leaves no label behind.

use std::path::{Path, PathBuf};
use std::process::Command;

use epssn::attitude::Attitude;
use epssn_aris::aris::ArisReader;
use epssn_sim::poses::{self, SitePose};

const ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
const TANK: &str = "data/sites/tank.stl";

fn host_sim() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_host-sim"));
    c.current_dir(ROOT);
    c
}

/// Runs a command to success and returns its stdout.
fn ok(cmd: &mut Command) -> Vec<u8> {
    let o = cmd.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    o.stdout
}

/// Runs a command that must fail and returns its stderr.
fn fails(cmd: &mut Command) -> String {
    let o = cmd.output().unwrap();
    assert!(
        !o.status.success(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `pairs` two-view samples of the tank (test split), each source view's forward axis turned
/// by `jitter_deg`, bundled: returns (simulation root, bundle folder).
fn tank_bundle(dir: &Path, pairs: usize, jitter_deg: f64) -> (PathBuf, PathBuf) {
    let sim = dir.join("sim");
    ok(host_sim()
        .args(["simulate", "--site", TANK, "--split", "test", "--seed", "5"])
        .args(["--no-preview", "--pairs", &pairs.to_string()])
        .args(["--pose-jitter-deg", &jitter_deg.to_string(), "--out"])
        .arg(&sim));
    let rec = dir.join("rec");
    let mut bundle = host_sim();
    bundle.arg("bundle");
    for i in 0..pairs {
        bundle.arg(sim.join(format!("test/{i:06}")));
    }
    ok(bundle.arg("--out").arg(&rec));
    (sim, rec)
}

/// `label` of the bundle's recording into `out` from the poses file `poses`.
fn label(rec: &Path, poses: &Path, site: &str, out: &Path) -> Command {
    let mut c = host_sim();
    c.arg("label")
        .arg("--recording")
        .arg(rec.join("recording.aris"))
        .args(["--site", site, "--poses"])
        .arg(poses)
        .arg("--out")
        .arg(out);
    c
}

/// The files of a folder, by name, with their bytes.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn labels_from_a_bundles_poses_are_its_ground_truth_and_score_as_eval() {
    let dir = tempfile::tempdir().unwrap();
    // A source-view pose error below the gate's residual tolerance: the pairs are still used,
    // and the source rows are decomposed rotations rather than the scene's numbers.
    let jitter = 0.4 * epssn::config::PAIR_RESIDUAL_TOLERANCE_DEG;
    let (sim, rec) = tank_bundle(dir.path(), 3, jitter);
    let poses_csv = rec.join("poses.csv");
    let rows = poses::load(&poses_csv, 6).unwrap();
    assert_eq!(rows.keys().copied().collect::<Vec<_>>(), [0, 1, 2, 3, 4, 5]);

    let labels = dir.path().join("labels");
    let said = String::from_utf8(ok(&mut label(&rec, &poses_csv, TANK, &labels))).unwrap();
    assert!(said.contains("frames 0, 2, 4"), "{said}");
    let (got, want) = (files(&labels), files(&rec.join("gt")));
    assert_eq!(got.len(), 6, "a depth and a mask per reference view");
    assert_eq!(
        got.iter().map(|f| &f.0).collect::<Vec<_>>(),
        want.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    for ((name, a), (_, b)) in got.iter().zip(&want) {
        assert!(a == b, "{name} differs from the bundle's");
    }

    // The comparison can fail: the sonar 1 cm higher at frame 2 gives another depth map (its
    // mask may change too, where a ray's hit crosses the range window); the others stay.
    let moved: Vec<(usize, SitePose)> = rows
        .iter()
        .map(|(&f, &p)| {
            let mut p = p;
            if f == 2 {
                p.position_m[2] += 0.01;
            }
            (f, p)
        })
        .collect();
    let moved_csv = dir.path().join("moved.csv");
    std::fs::write(&moved_csv, poses::to_csv(&moved)).unwrap();
    let moved_dir = dir.path().join("moved");
    ok(&mut label(&rec, &moved_csv, TANK, &moved_dir));
    for (name, bytes) in files(&moved_dir) {
        let same = want.iter().any(|(n, b)| *n == name && *b == bytes);
        if name.ends_with("_0002.npy") {
            assert!(!same || name.starts_with("mask"), "{name}");
        } else {
            assert!(same, "{name}");
        }
    }

    // Each row's attitude against the frame header's (`epssn::attitude`): the relative
    // rotation of every pair is the same, roll baseline and the simulated pose error alike.
    let reader = ArisReader::open(rec.join("recording.aris")).unwrap();
    let header = |i: usize| {
        Attitude::from_array(reader.frame_header(i).unwrap().attitude().unwrap()).unwrap()
    };
    let row = |i: usize| {
        let p = rows[&i];
        Attitude::from_header_deg(
            -p.yaw_deg as f32,
            p.pitch_deg as f32,
            p.roll_deg as f32,
            0.0,
            0.0,
            0.0,
        )
        .unwrap()
    };
    for r in [0, 2, 4] {
        let (h, p) = (
            header(r).relative(&header(r + 1)),
            row(r).relative(&row(r + 1)),
        );
        assert!((h.roll_deg - 7.0).abs() < 1e-3, "{h:?}");
        assert!((h.residual_deg as f64 - jitter).abs() < 2e-3, "{h:?}");
        assert!(
            (h.roll_deg - p.roll_deg).abs() < 1e-3,
            "frame {r}: {h:?} {p:?}"
        );
        assert!(
            (h.residual_deg - p.residual_deg).abs() < 1e-3,
            "frame {r}: {h:?} {p:?}"
        );
    }

    // `run` on the recording with these labels scores exactly what `eval` scores on the
    // sample folders (the shipped weights, the views read from the sample folders).
    let run: serde_json::Value = serde_json::from_slice(&ok(host_sim()
        .arg("run")
        .arg("--recording")
        .arg(rec.join("recording.aris"))
        .arg("--gt")
        .arg(&labels)
        // The simulator compresses 70 dB into the counts (ARIS recordings: 80, the default).
        .args(["--ping-dynamic-range-db", "70", "--json", "--out"])
        .arg(dir.path().join("out"))))
    .unwrap();
    assert_eq!(run["pairs"], 3);
    assert_eq!(run["bit_exact"], true);
    let eval: serde_json::Value = serde_json::from_slice(&ok(host_sim()
        .arg("eval")
        .arg("--data")
        .arg(&sim)
        .args(["--int8", "--json"])))
    .unwrap();
    assert_eq!(eval["warnings"], serde_json::json!([]));
    for model in ["float", "int8"] {
        for metric in ["mae", "mae_masked", "cd"] {
            let (r, e) = (&run[model][metric], &eval[model][metric]);
            assert!(
                r.as_f64().is_some_and(f64::is_finite),
                "{model} {metric}: {r}"
            );
            assert_eq!(r, e, "{model} {metric}: run {r}, eval {e}");
        }
    }
}

#[test]
fn bad_input_is_refused_and_leaves_no_label() {
    let dir = tempfile::tempdir().unwrap();
    let (_, rec) = tank_bundle(dir.path(), 1, 0.0);
    let good = std::fs::read_to_string(rec.join("poses.csv")).unwrap();
    let header = poses::HEADER;
    let empty_mesh = dir.path().join("empty.obj");
    std::fs::write(&empty_mesh, "# no faces\n").unwrap();
    let empty_mesh = empty_mesh.to_str().unwrap().to_owned();
    let without_frame_0: String = good
        .lines()
        .filter(|l| !l.starts_with("0,"))
        .map(|l| format!("{l}\n"))
        .collect();
    for (i, (poses, site, want)) in [
        (
            without_frame_0,
            TANK,
            "has no row for frame(s) 0, which run uses as reference view(s)",
        ),
        (
            format!("{good}2,0,0,0,0,0,0\n"),
            TANK,
            "line 4: frame 2 is not in the recording, which has 2 frame(s)",
        ),
        (
            format!("{good}1,0,0,0,0,0,0\n"),
            TANK,
            "line 4: frame 1 has a row already (line 3)",
        ),
        (
            format!("{header}\n0,0,0,0,0,0\n"),
            TANK,
            "line 2: 6 column(s)",
        ),
        (
            format!("{header}\n0,0,0,0,0,0,0,7\n"),
            TANK,
            "line 2: 8 column(s)",
        ),
        (
            format!("{header}\n0,0,0,NaN,0,0,0\n"),
            TANK,
            "z_m is NaN, not a finite number",
        ),
        ("0,0,0,0,0,0,0\n".into(), TANK, "expected the header"),
        (good.clone(), &empty_mesh, "no triangles"),
        (good.clone(), "data/sites/none.stl", "none.stl"),
    ]
    .into_iter()
    .enumerate()
    {
        let csv = dir.path().join(format!("poses{i}.csv"));
        std::fs::write(&csv, &poses).unwrap();
        let out = dir.path().join(format!("out{i}"));
        let err = fails(&mut label(&rec, &csv, site, &out));
        assert!(err.contains(want), "case {i}: {err}");
        assert!(!out.exists(), "case {i}: {out:?} was created");
    }
    // The good file labels frame 0 and nothing else.
    let out = dir.path().join("good");
    std::fs::write(dir.path().join("good.csv"), &good).unwrap();
    ok(&mut label(&rec, &dir.path().join("good.csv"), TANK, &out));
    let names: Vec<String> = files(&out).into_iter().map(|f| f.0).collect();
    assert_eq!(names, ["depth_0000.npy", "mask_0000.npy"]);
}
