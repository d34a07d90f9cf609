//! `run --frame world` on a simulated roll sweep of one scene (one terrain seen from one pose
//! at rotator rolls −14° … +14°, the headers carrying the pose as the platform's heading and
//! pitch, `--poses` its position): the merged cloud lies on the scene's surfaces as closely as
//! each pair's own cloud lies on its ground truth, and the same clouds turned the wrong way
//! (the rotation's sign flipped, or the roll's alone) miss that bound.

use std::path::Path;
use std::process::Command;

use epssn::config::{DEPTH_COLUMNS, DEPTH_ROWS};
use epssn::geometry::RigidTransform;
use epssn_aris::aris::{write_recording, FrameHeader};
use epssn_aris::npy;
use epssn_sim::metrics;
use epssn_sim::poses::{self, SitePose};
use epssn_sim::render::{frame_header, SonarSimParams};
use epssn_sim::scene::{generate, SceneKind, Split};
use epssn_sim::simulate::simulate_scene;

const ROLLS_DEG: [f64; 5] = [-14.0, -7.0, 0.0, 7.0, 14.0];

/// PLY vertices (the first three numbers of each line after the header) and, when `pair`, the
/// fourth.
fn ply(path: &Path) -> Vec<([f64; 3], Option<u32>)> {
    let text = std::fs::read_to_string(path).unwrap();
    let body = text.split("end_header\n").nth(1).unwrap();
    body.lines()
        .map(|l| {
            let v: Vec<&str> = l.split_whitespace().collect();
            let xyz = [0, 1, 2].map(|k| v[k].parse::<f64>().unwrap());
            let pair = text
                .contains("property uint pair")
                .then(|| v[3].parse().unwrap());
            (xyz, pair)
        })
        .collect()
}

/// Mean distance from each of `from` to the nearest of `to`, metres.
fn mean_nearest(from: &[[f64; 3]], to: &[[f64; 3]]) -> f64 {
    let d2 = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>();
    let sum: f64 = from
        .iter()
        .map(|p| {
            to.iter()
                .map(|q| d2(p, q))
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .sum();
    sum / from.len() as f64
}

/// Rotation transposed (the inverse turn), translation kept: a cloud placed with the sign of
/// every angle flipped.
fn flipped(t: &RigidTransform) -> RigidTransform {
    let r = t.rotation;
    RigidTransform {
        rotation: [0, 1, 2].map(|i| [0, 1, 2].map(|j| r[j][i])),
        translation: t.translation,
    }
}

/// `t` with the rotator's roll counted the wrong way: world ← sonar = W · Rx(roll) becomes
/// W · Rx(−roll) = t · Rx(−2·roll).
fn roll_flipped(t: &RigidTransform, roll_deg: f64) -> RigidTransform {
    // RigidTransform::roll_deg(ρ) is Rx(−ρ).
    t.compose(&RigidTransform::roll_deg(2.0 * roll_deg))
}

#[test]
fn the_merged_sweep_lies_on_the_scene_and_a_flipped_rotation_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let gt_dir = dir.path().join("gt");
    std::fs::create_dir_all(&gt_dir).unwrap();
    let params = SonarSimParams::default();
    let base = generate(SceneKind::Terrain, Split::Test, 11, 0, 1);
    let (yaw, tilt) = (base.sonar.yaw_deg, base.sonar.tilt_deg);
    let mut frames: Vec<(FrameHeader, Vec<u8>)> = Vec::new();
    let mut pose_rows = Vec::new();
    let mut truth_world = Vec::new();
    let mut truth_sonar = Vec::new();
    let mut world_from_view = Vec::new();
    for (i, &roll) in ROLLS_DEG.iter().enumerate() {
        let mut scene = base.clone();
        scene.view_rolls_deg = vec![roll];
        let s = simulate_scene(&scene, &params).unwrap();
        // The pose as an AUV would record it: heading clockwise (−yaw), pitch nose up (−tilt).
        let mut h = frame_header(&params, roll)
            .unwrap()
            .with_platform_attitude_deg((-yaw).rem_euclid(360.0) as f32, -tilt as f32, 0.0);
        h.frame_index = i as u32;
        h.frame_time_us = 1_700_000_000_000_000 + i as u64 * 100_000;
        frames.push((h, s.frames[0].clone()));
        pose_rows.push((i, SitePose::of_view(&scene, 0)));
        let shape = [DEPTH_ROWS, DEPTH_COLUMNS];
        npy::write_f32(&gt_dir.join(format!("depth_{i:04}.npy")), &shape, &s.depth).unwrap();
        npy::write_f32(&gt_dir.join(format!("mask_{i:04}.npy")), &shape, &s.mask).unwrap();
        let pts = metrics::depth_points(&s.depth, &metrics::mask_from_f32(&s.mask)).unwrap();
        let wfv = scene.world_from_view(0);
        truth_world.extend(pts.iter().map(|p| wfv.apply(*p)));
        truth_sonar.push(pts);
        world_from_view.push(wfv);
    }
    let rec = dir.path().join("sweep.aris");
    let refs: Vec<(&FrameHeader, &[u8])> = frames.iter().map(|(h, d)| (h, d.as_slice())).collect();
    write_recording(&rec, &refs).unwrap();
    let poses_csv = dir.path().join("poses.csv");
    std::fs::write(&poses_csv, poses::to_csv(&pose_rows)).unwrap();

    let out = dir.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .args(["run", "--json", "--frame", "world", "--recording"])
        .arg(&rec)
        .arg("--gt")
        .arg(&gt_dir)
        .arg("--poses")
        .arg(&poses_csv)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["pairs"], 4, "{v}");
    let warnings = v["warnings"].to_string();
    assert!(
        !warnings.contains("world-frame") && !warnings.contains("poses file"),
        "{warnings}"
    );

    // Each pair's cloud against its own ground truth, in its sonar frame; and placed wrongly.
    let (mut per_pair_sum, mut per_pair_n) = (0.0, 0);
    let mut wrong = Vec::new();
    let mut wrong_roll = Vec::new();
    for (k, d) in v["details"].as_array().unwrap().iter().enumerate() {
        let reference = d["frames"][0].as_u64().unwrap() as usize;
        assert_eq!(reference, k);
        let pts: Vec<[f64; 3]> = ply(&out.join(format!("frame{reference:04}_int8.ply")))
            .into_iter()
            .map(|(p, _)| p)
            .collect();
        per_pair_sum += mean_nearest(&pts, &truth_sonar[reference]) * pts.len() as f64;
        per_pair_n += pts.len();
        let bad = flipped(&world_from_view[reference]);
        wrong.extend(pts.iter().map(|p| bad.apply(*p)));
        let bad_roll = roll_flipped(&world_from_view[reference], ROLLS_DEG[reference]);
        wrong_roll.extend(pts.iter().map(|p| bad_roll.apply(*p)));
    }
    let per_pair = per_pair_sum / per_pair_n as f64;
    let merged = ply(&out.join("world.ply"));
    assert_eq!(merged.len(), per_pair_n, "every pair's points, once");
    let pairs: std::collections::BTreeSet<u32> = merged.iter().map(|(_, p)| p.unwrap()).collect();
    assert_eq!(pairs.into_iter().collect::<Vec<_>>(), vec![0, 1, 2, 3]);
    let merged: Vec<[f64; 3]> = merged.into_iter().map(|(p, _)| p).collect();
    let merged_figure = mean_nearest(&merged, &truth_world);
    let wrong_figure = mean_nearest(&wrong, &truth_world);
    let wrong_roll_figure = mean_nearest(&wrong_roll, &truth_world);
    // The nearest truth of any pair is no farther than the pair's own: the merged figure is at
    // most the per-pair one, up to the PLY's rounding, if every cloud was placed right.
    let bound = per_pair * 1.02 + 1e-4;
    eprintln!(
        "mean distance to the nearest true point: per pair {:.2} mm, merged {:.2} mm, \
         rotation flipped {:.2} mm, roll alone flipped {:.2} mm (bound {:.2} mm; {} points)",
        per_pair * 1e3,
        merged_figure * 1e3,
        wrong_figure * 1e3,
        wrong_roll_figure * 1e3,
        bound * 1e3,
        per_pair_n
    );
    assert!(per_pair > 0.0 && per_pair < 0.1, "per pair {per_pair}");
    assert!(merged_figure <= bound, "merged {merged_figure} > {bound}");
    assert!(
        wrong_figure > bound,
        "a flipped rotation passes: {wrong_figure} <= {bound}"
    );
}
