//! The command line end to end: `host-sim simulate` and `host-sim metrics` through the binary,
//! argument parsing included.

use std::path::Path;

use epssn_sim::dataset::Sample;
use epssn_sim::render::SonarSimParams;

#[test]
fn cli_simulate_three_views_and_metrics_json() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_host-sim");
    let out = dir.path().to_str().unwrap();
    let st = std::process::Command::new(exe)
        .args([
            "simulate", "--scene", "sphere", "--pairs", "2", "--seed", "5",
        ])
        .args([
            "--out",
            out,
            "--split",
            "test",
            "--views",
            "3",
            "--no-preview",
        ])
        .status()
        .unwrap();
    assert!(st.success());
    let s0 = Sample::load(&dir.path().join("test/000000")).unwrap();
    assert_eq!(s0.polar_views.len(), 3);
    assert_eq!(s0.scene.view_rolls_deg, vec![0.0, 7.0, 14.0]);
    assert!(dir.path().join("test/000000/view2.aris").exists());
    assert!(!dir.path().join("test/000000/preview.png").exists());
    // A map against itself scores zero; against another sample it does not.
    let gt = dir.path().join("test/000000/depth.npy");
    let mask = dir.path().join("test/000000/mask.npy");
    let other = dir.path().join("test/000001/depth.npy");
    let run = |pred: &Path| -> serde_json::Value {
        let o = std::process::Command::new(exe)
            .arg("metrics")
            .arg(pred)
            .arg(&gt)
            .arg("--mask")
            .arg(&mask)
            .arg("--json")
            .output()
            .unwrap();
        assert!(o.status.success());
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let same = run(&gt);
    assert_eq!(same["mae"], 0.0);
    assert_eq!(same["cd"], 0.0);
    let valid = s0.mask.iter().filter(|m| **m > 0.5).count();
    assert_eq!(same["valid_pixels"], valid);
    let diff = run(&other);
    assert!(diff["mae"].as_f64().unwrap() > 0.0);
    assert!(diff["cd"].as_f64().unwrap() > 0.0);
    // A partial params file overrides only what it names.
    let pfile = dir.path().join("p.json");
    std::fs::write(&pfile, r#"{"speckle": false, "crosstalk": 0.0}"#).unwrap();
    let out2 = dir.path().join("p");
    let st = std::process::Command::new(exe)
        .args([
            "simulate",
            "--scene",
            "sphere",
            "--pairs",
            "1",
            "--no-preview",
            "--params",
        ])
        .arg(&pfile)
        .arg("--out")
        .arg(&out2)
        .status()
        .unwrap();
    assert!(st.success());
    let used: SonarSimParams =
        serde_json::from_str(&std::fs::read_to_string(out2.join("train/sim_params.json")).unwrap())
            .unwrap();
    assert_eq!(
        used,
        SonarSimParams {
            speckle: false,
            crosstalk: 0.0,
            ..SonarSimParams::default()
        }
    );
    // Views 4 is rejected.
    let st = std::process::Command::new(exe)
        .args([
            "simulate", "--scene", "sphere", "--pairs", "1", "--out", out, "--views", "4",
        ])
        .stderr(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(!st.success());
}

/// `eval` reads a folder not yet quantised (a fit's output, an epoch `epssn-train fit
/// --keep-epochs` kept) in float, at the spec's no-return threshold, and refuses `--int8` there
/// naming the missing blob.
#[test]
fn eval_reads_an_unquantised_folder_in_float_and_refuses_int8() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let exe = env!("CARGO_BIN_EXE_host-sim");
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let st = std::process::Command::new(exe)
        .args([
            "simulate",
            "--scene",
            "artificial",
            "--pairs",
            "2",
            "--seed",
            "91006",
        ])
        .args(["--split", "test", "--no-preview", "--out"])
        .arg(&data)
        .status()
        .unwrap();
    assert!(st.success());
    // The folder of the shipped model of this build's spec, less its blob.
    let shipped = epssn_reference::weights::firmware_weights_dir().unwrap();
    let folder = dir.path().join("unquantised");
    std::fs::create_dir(&folder).unwrap();
    for f in ["model.safetensors", "spec.json", "manifest.json"] {
        std::fs::copy(shipped.join(f), folder.join(f)).unwrap();
    }
    let eval = |int8: bool| {
        let mut c = std::process::Command::new(exe);
        c.current_dir(&root)
            .arg("eval")
            .arg("--weights")
            .arg(&folder);
        c.arg("--data").arg(&data).arg("--json");
        if int8 {
            c.arg("--int8");
        }
        c.output().unwrap()
    };
    let float = eval(false);
    assert!(
        float.status.success(),
        "{}",
        String::from_utf8_lossy(&float.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&float.stdout).unwrap();
    let mae = v["float"]["mae"].as_f64().unwrap();
    assert!(mae.is_finite() && mae > 0.0, "{v}");
    let int8 = eval(true);
    assert!(!int8.status.success());
    let err = String::from_utf8_lossy(&int8.stderr);
    assert!(err.contains(epssn_reference::weights::BLOB_FILE), "{err}");
}
