//! The clouds of a sweep in one frame (`run --frame world`): each pair's points turned from its
//! reference frame's sonar frame into the world by that frame's attitude (`epssn::attitude`,
//! the very quaternion the pose gate reads) and, with `--poses`, moved by the frame's position
//! from the poses file (`epssn_sim::poses`), then merged, each point keeping its pair.
//!
//! The world frame is the attitude's level frame (x along heading 0, y left of it, z up); with
//! a poses file its origin is the site's (docs/MCAP.md).

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};
use epssn::attitude::Attitude;
use epssn::geometry::RigidTransform;
use epssn_mcap::msgs::SonarPoint;
use epssn_sim::poses::SitePose;

/// The frame `run` writes its clouds in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CloudFrame {
    /// Each pair in its reference view's own sonar frame (a PLY per pair).
    #[default]
    Sonar,
    /// Also every pair merged in the world frame (`world.ply`).
    World,
}

/// Poses' rotations further than this from the attitude's are reported: the file and the
/// headers then describe different motions, and the attitude is the one used.
pub const POSE_DISAGREEMENT_DEG: f64 = 1.0;

/// World ← sonar of a frame: its attitude's rotation, its position (metres) as translation.
pub fn world_from_sonar(attitude: &Attitude, position_m: [f64; 3]) -> RigidTransform {
    RigidTransform::from_quaternion(attitude.to_array(), position_m)
}

/// Angle between two rotations, degrees.
pub fn rotation_angle_deg(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> f64 {
    // trace(aᵀ b) = 1 + 2 cos θ.
    let trace: f64 = (0..3)
        .map(|i| (0..3).map(|k| a[k][i] * b[k][i]).sum::<f64>())
        .sum();
    ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

/// Where each reference frame of a sweep sits in the world, or why it cannot be placed.
pub struct Placement {
    /// World ← sonar per frame that can be placed.
    pub transforms: BTreeMap<usize, RigidTransform>,
    /// Frames that cannot, with the reason.
    pub missing: BTreeMap<usize, String>,
    /// Disagreements between the poses file and the headers.
    pub warnings: Vec<String>,
}

/// Places `frames` by their attitudes and, when given, the poses file's positions.
pub fn place(
    frames: &[usize],
    attitudes: &[Option<Attitude>],
    poses: Option<&BTreeMap<usize, SitePose>>,
) -> Placement {
    let mut p = Placement {
        transforms: BTreeMap::new(),
        missing: BTreeMap::new(),
        warnings: Vec::new(),
    };
    let mut worst: Option<(usize, f64)> = None;
    for &f in frames {
        let Some(att) = attitudes.get(f).copied().flatten() else {
            p.missing
                .insert(f, "its header has no attitude (docs/POSE.md)".into());
            continue;
        };
        let mut t = world_from_sonar(&att, [0.0; 3]);
        if let Some(rows) = poses {
            let Some(row) = rows.get(&f) else {
                p.missing
                    .insert(f, "the poses file has no row for it".into());
                continue;
            };
            let off = rotation_angle_deg(&row.site_from_sonar().rotation, &t.rotation);
            if worst.is_none_or(|(_, w)| off > w) {
                worst = Some((f, off));
            }
            t.translation = row.position_m;
        }
        p.transforms.insert(f, t);
    }
    if let Some((f, off)) = worst.filter(|&(_, off)| off > POSE_DISAGREEMENT_DEG) {
        p.warnings.push(format!(
            "the poses file's rotation differs from the header attitude by up to {off:.2}° \
             (frame {f}): the clouds are turned by the attitude, moved by the file's positions"
        ));
    }
    p
}

/// The clouds of the placed pairs in the world frame, merged: `clouds` holds each pair's
/// reference frame and its points in that frame's sonar frame; each merged point keeps its
/// range and intensity and is given its pair's index in `clouds` (the run's `details`).
pub fn merge(clouds: &[(usize, Vec<SonarPoint>)], placement: &Placement) -> Vec<SonarPoint> {
    let mut out = Vec::new();
    for (pair, (frame, points)) in clouds.iter().enumerate() {
        let Some(t) = placement.transforms.get(frame) else {
            continue;
        };
        out.extend(points.iter().map(|p| SonarPoint {
            xyz: t.apply(p.xyz.map(f64::from)).map(|v| v as f32),
            pair: Some(pair as u32),
            ..*p
        }));
    }
    out
}

/// Writes the merged cloud as an ASCII PLY with a `pair` property per vertex.
pub fn write_merged_ply(path: &Path, points: &[SonarPoint]) -> Result<()> {
    let mut s = String::new();
    s.push_str("ply\nformat ascii 1.0\n");
    s.push_str("comment epssn host-sim run --frame world: world frame (docs/MCAP.md), metres\n");
    s.push_str(&format!("element vertex {}\n", points.len()));
    s.push_str("property float x\nproperty float y\nproperty float z\nproperty uint pair\n");
    s.push_str("end_header\n");
    for p in points {
        let [x, y, z] = p.xyz;
        s.push_str(&format!("{x} {y} {z} {}\n", p.pair.unwrap_or(0)));
    }
    std::fs::File::create(path)
        .and_then(|mut f| f.write_all(s.as_bytes()))
        .with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The quaternion's matrix is the attitude's composition of axis rotations (docs/POSE.md):
    /// heading 90° clockwise turns forward (x) to the right (−y); a 7° roll then turns left (y)
    /// up by 7°.
    #[test]
    fn attitude_rotations_turn_the_axes_as_the_header_says() {
        let a = Attitude::from_header_deg(90.0, 0.0, 0.0, 0.0, 0.0, 7.0).unwrap();
        let t = world_from_sonar(&a, [1.0, 2.0, 3.0]);
        let fwd = t.rotate([1.0, 0.0, 0.0]);
        assert!(
            (fwd[0]).abs() < 1e-6 && (fwd[1] + 1.0).abs() < 1e-6,
            "{fwd:?}"
        );
        let left = t.rotate([0.0, 1.0, 0.0]);
        let s7 = 7f64.to_radians().sin();
        assert!((left[2] - s7).abs() < 1e-6, "{left:?}");
        assert_eq!(t.apply([0.0; 3]), [1.0, 2.0, 3.0]);
    }

    #[test]
    fn a_frame_without_attitude_or_pose_row_is_missing_with_its_reason() {
        let a = Attitude::from_header_deg(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let atts = vec![a, None, a];
        let mut rows = BTreeMap::new();
        let pose = SitePose {
            position_m: [1.0, 0.0, 0.0],
            roll_deg: 0.0,
            pitch_deg: 0.0,
            yaw_deg: 30.0,
        };
        rows.insert(0, pose);
        let p = place(&[0, 1, 2], &atts, Some(&rows));
        assert_eq!(p.transforms.keys().copied().collect::<Vec<_>>(), vec![0]);
        assert!(p.missing[&1].contains("no attitude"));
        assert!(p.missing[&2].contains("no row"));
        // The file's yaw 30° against a heading of 0: reported.
        assert!(p.warnings[0].contains("30.00°"), "{:?}", p.warnings);
    }
}
