//! Helpers shared by the integration tests.

use std::process::Command;

fn host_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

/// A recording of 6 pairs alternating two pose jitters, `low` (within the spec's residual
/// tolerance) and `high` (beyond it): simulate twice, bundle interleaved.
pub fn jittered_recording(dir: &std::path::Path, low: f64, high: f64) -> std::path::PathBuf {
    for (name, d) in [("low", low), ("high", high)] {
        let o = host_sim()
            .args([
                "simulate", "--scene", "terrain", "--split", "test", "--seed", "3",
            ])
            .args([
                "--pairs",
                "3",
                "--no-preview",
                "--pose-jitter-deg",
                &d.to_string(),
            ])
            .arg("--out")
            .arg(dir.join(name))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let mut bundle = host_sim();
    bundle.arg("bundle");
    for i in 0..3 {
        for name in ["low", "high"] {
            bundle.arg(dir.join(name).join(format!("test/{i:06}")));
        }
    }
    let o = bundle.arg("--out").arg(dir.join("rec")).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    dir.join("rec/recording.aris")
}

/// The demo recording with frame `k`'s window moved to start at 7.5 m (SampleStartDelay
/// 10,000 µs, offset 476 of its frame header), as an operator's range change would.
pub fn demo_with_a_moved_window(dir: &std::path::Path, k: usize) -> std::path::PathBuf {
    let demo = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/demo/recording.aris");
    let mut bytes = std::fs::read(demo).unwrap();
    let frames = 12;
    let frame_len = (bytes.len() - 1024) / frames;
    let at = 1024 + k * frame_len + 476;
    bytes[at..at + 4].copy_from_slice(&10_000u32.to_le_bytes());
    let rec = dir.join("moved.aris");
    std::fs::write(&rec, bytes).unwrap();
    rec
}
