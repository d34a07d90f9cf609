//! The transforms of a bag's `/tf` and `/tf_static`, and the rotation of a frame in the fixed
//! frame at the root of its tree: the chain child → parent followed to the frame no transform
//! names as a child, each hop by the transform of that child nearest in time to the stamp
//! asked (no interpolation: a sonar's transforms are published with its pings).

use std::collections::BTreeMap;

use crate::msgs::TransformStamped;

/// Longest chain followed: a longer one is a loop in a corrupt tree.
const MAX_HOPS: usize = 64;

/// A quaternion `[x, y, z, w]`, as ROS orders it.
pub type Quat = [f64; 4];

/// `a ⊗ b`: the rotation `b`, then `a`.
pub fn mul(a: Quat, b: Quat) -> Quat {
    let [ax, ay, az, aw] = a;
    let [bx, by, bz, bw] = b;
    [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]
}

/// The quaternion `[x, y, z, w]` of a rotation matrix (row-major), by the largest of the four
/// diagonal combinations (Shepperd), so no branch divides by a small number.
pub fn quat_of_matrix(r: &[[f64; 3]; 3]) -> Quat {
    let t = r[0][0] + r[1][1] + r[2][2];
    if t > r[0][0].max(r[1][1]).max(r[2][2]) {
        let s = 2.0 * (1.0 + t).sqrt();
        [
            (r[2][1] - r[1][2]) / s,
            (r[0][2] - r[2][0]) / s,
            (r[1][0] - r[0][1]) / s,
            s / 4.0,
        ]
    } else if r[0][0] >= r[1][1] && r[0][0] >= r[2][2] {
        let s = 2.0 * (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt();
        [
            s / 4.0,
            (r[0][1] + r[1][0]) / s,
            (r[0][2] + r[2][0]) / s,
            (r[2][1] - r[1][2]) / s,
        ]
    } else if r[1][1] >= r[2][2] {
        let s = 2.0 * (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt();
        [
            (r[0][1] + r[1][0]) / s,
            s / 4.0,
            (r[1][2] + r[2][1]) / s,
            (r[0][2] - r[2][0]) / s,
        ]
    } else {
        let s = 2.0 * (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt();
        [
            (r[0][2] + r[2][0]) / s,
            (r[1][2] + r[2][1]) / s,
            s / 4.0,
            (r[1][0] - r[0][1]) / s,
        ]
    }
}

/// One transform: stamp, parent, rotation, and whether it came from `/tf_static`.
type Entry = (i64, String, Quat, bool);

/// Every transform, by child frame, each list sorted by stamp.
#[derive(Clone, Debug, Default)]
pub struct TfTree {
    by_child: BTreeMap<String, Vec<Entry>>,
}

impl TfTree {
    /// Adds the transforms of one message (non-finite rotations are dropped); `is_static` for
    /// `/tf_static`'s.
    pub fn add(&mut self, transforms: &[TransformStamped], is_static: bool) {
        for t in transforms {
            if !t.rotation.iter().all(|c| c.is_finite()) {
                continue;
            }
            let list = self.by_child.entry(t.child_frame_id.clone()).or_default();
            let at = list.partition_point(|e| e.0 <= t.header.stamp_ns);
            list.insert(
                at,
                (
                    t.header.stamp_ns,
                    t.header.frame_id.clone(),
                    t.rotation,
                    is_static,
                ),
            );
        }
    }

    /// Whether no transform was read.
    pub fn is_empty(&self) -> bool {
        self.by_child.is_empty()
    }

    /// The rotation of `frame` in its tree's root frame at `stamp_ns` (child → root), and the
    /// root's name; `None` when no transform names `frame` as a child, when the chain loops, or
    /// when every hop is static (`/tf_static`: a mount, not the sonar's motion).
    pub fn rotation_in_root(&self, frame: &str, stamp_ns: i64) -> Option<(Quat, String)> {
        let mut q = [0.0, 0.0, 0.0, 1.0];
        let mut current = frame.to_string();
        let mut moving = false;
        for _ in 0..=MAX_HOPS {
            let Some(list) = self.by_child.get(&current) else {
                return moving.then_some((q, current));
            };
            let (_, parent, r, is_static) = nearest(list, stamp_ns)?;
            q = mul(*r, q);
            moving |= !is_static;
            current = parent.clone();
        }
        None
    }
}

fn nearest(list: &[Entry], stamp_ns: i64) -> Option<&Entry> {
    list.iter()
        .min_by_key(|e| (i128::from(e.0) - i128::from(stamp_ns)).unsigned_abs())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::Header;

    fn t(parent: &str, child: &str, stamp_ns: i64, rotation: Quat) -> TransformStamped {
        TransformStamped {
            header: Header {
                stamp_ns,
                frame_id: parent.into(),
            },
            child_frame_id: child.into(),
            translation: [0.0; 3],
            rotation,
        }
    }

    #[test]
    fn a_chain_composes_to_the_root_and_picks_the_nearest_stamp() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let mut tree = TfTree::default();
        // base in odom: 90° about z at t=10, identity at t=0; sonar in base: 90° about x.
        tree.add(
            &[
                t("odom", "base", 10, [0.0, 0.0, h, h]),
                t("odom", "base", 0, [0.0, 0.0, 0.0, 1.0]),
            ],
            false,
        );
        tree.add(&[t("base", "sonar", 0, [h, 0.0, 0.0, h])], true);
        let (q, root) = tree.rotation_in_root("sonar", 9).unwrap();
        assert_eq!(root, "odom");
        let want = mul([0.0, 0.0, h, h], [h, 0.0, 0.0, h]);
        for (a, b) in q.iter().zip(want) {
            assert!((a - b).abs() < 1e-12);
        }
        let (q0, _) = tree.rotation_in_root("sonar", 1).unwrap();
        assert!((q0[0] - h).abs() < 1e-12 && q0[2].abs() < 1e-12);
        assert!(tree.rotation_in_root("odom", 0).is_none());
        assert!(tree.rotation_in_root("elsewhere", 0).is_none());
        // A chain of static transforms alone is a mount, not an attitude.
        let mut mount = TfTree::default();
        mount.add(&[t("base", "sonar", 0, [h, 0.0, 0.0, h])], true);
        assert!(mount.rotation_in_root("sonar", 0).is_none());
    }

    #[test]
    fn a_matrix_gives_back_its_quaternion() {
        // 90° about z, 120° about (1, 1, 1)/√3, 180° about x: each branch of the choice.
        let cases: [([[f64; 3]; 3], Quat); 3] = [
            (
                [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                [0.0, 0.0, 0.5f64.sqrt(), 0.5f64.sqrt()],
            ),
            (
                [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                [0.5, 0.5, 0.5, 0.5],
            ),
            (
                [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]],
                [1.0, 0.0, 0.0, 0.0],
            ),
        ];
        for (m, q) in cases {
            let got = quat_of_matrix(&m);
            let sign = if got[3] * q[3] + got[0] * q[0] < 0.0 {
                -1.0
            } else {
                1.0
            };
            for (a, b) in got.iter().zip(q) {
                assert!((a * sign - b).abs() < 1e-12, "{m:?}: {got:?} against {q:?}");
            }
        }
    }

    #[test]
    fn a_loop_is_refused() {
        let mut tree = TfTree::default();
        tree.add(
            &[
                t("a", "b", 0, [0.0, 0.0, 0.0, 1.0]),
                t("b", "a", 0, [0.0, 0.0, 0.0, 1.0]),
            ],
            false,
        );
        assert!(tree.rotation_in_root("a", 0).is_none());
    }
}
