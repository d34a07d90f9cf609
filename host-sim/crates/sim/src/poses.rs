//! The sonar's pose in a site's frame, one row per recorded frame (`poses.csv`): what `bundle`
//! writes beside a recording of site samples and `label` reads to render that recording's
//! ground truth from the site's mesh (docs/SITES.md, "Labelling a real recording").
//!
//! ```text
//! frame,x_m,y_m,z_m,roll_deg,pitch_deg,yaw_deg
//! 0,1.25,-0.5,0.93,0,-20,135
//! ```
//!
//! The site frame is the mesh's (metres, z up); the sonar frame is `epssn::geometry`'s (x
//! forward, y left, z up). The angles turn the sonar frame into the site frame as
//!
//! ```text
//! site ← sonar = Rz(yaw) · Ry(−pitch) · Rx(roll)
//! ```
//!
//! yaw counter-clockwise about the site's z seen from above (0 = looking along +x, as the
//! site's region and `scene.json` count it), pitch nose up (as the ARIS header's Pitch and
//! `epssn::attitude` count it, so a sonar looking 20° down has pitch −20), roll by the right
//! hand about the forward axis (the rotator's roll). In `epssn::attitude`'s terms this is
//! `Attitude::from_header_deg(−yaw, pitch, roll, 0, 0, 0)`: heading is clockwise.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use epssn::geometry::RigidTransform;

use crate::groundtruth::reference_labels;
use crate::scene::{Object, Scene, SceneKind, SonarPose, Split};
use crate::simulate::SITE_REFLECTIVITY;
use crate::site::Site;
use crate::world::World;

/// The file's header line: its columns, in order.
pub const HEADER: &str = "frame,x_m,y_m,z_m,roll_deg,pitch_deg,yaw_deg";

/// Columns of a row.
const COLUMNS: usize = 7;

/// The sonar's pose in the site frame (the module's convention).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SitePose {
    /// Acoustic centre, metres, site frame.
    pub position_m: [f64; 3],
    /// Right-hand roll about the forward axis, degrees.
    pub roll_deg: f64,
    /// Nose-up pitch of the forward axis, degrees.
    pub pitch_deg: f64,
    /// Counter-clockwise yaw about the site's z, degrees (0 = +x).
    pub yaw_deg: f64,
}

impl SitePose {
    /// View `k` of `scene` as a pose in the scene's world frame (a site sample's world frame is
    /// the site's). Without a pose error the angles are the scene's own numbers (yaw, the tilt
    /// negated, the view's roll), so a label rendered from the row is the sample's ground truth
    /// bit for bit; a view with a pose error is decomposed from its rotation.
    pub fn of_view(scene: &Scene, k: usize) -> Self {
        let roll = scene.view_rolls_deg.get(k).copied().unwrap_or(0.0);
        let exact = match scene.view_pose_errors_deg.get(k) {
            Some(&[pitch, yaw]) => pitch == 0.0 && yaw == 0.0,
            None => true,
        };
        if exact {
            return Self {
                position_m: scene.sonar.position_m,
                roll_deg: roll,
                pitch_deg: -scene.sonar.tilt_deg,
                yaw_deg: scene.sonar.yaw_deg,
            };
        }
        let wfv = scene.world_from_view(k);
        Self::from_rotation(&wfv.rotation, wfv.translation)
    }

    /// The pose whose site ← sonar rotation is `r` (Rz(yaw) · Ry(−pitch) · Rx(roll)).
    pub fn from_rotation(r: &[[f64; 3]; 3], position_m: [f64; 3]) -> Self {
        // Third row of Rz·Ry(θ)·Rx: (−sin θ, cos θ sin roll, cos θ cos roll), θ = −pitch;
        // first column: cos θ (cos yaw, sin yaw).
        Self {
            position_m,
            roll_deg: r[2][1].atan2(r[2][2]).to_degrees(),
            pitch_deg: r[2][0].clamp(-1.0, 1.0).asin().to_degrees(),
            yaw_deg: r[1][0].atan2(r[0][0]).to_degrees(),
        }
    }

    /// A one-view scene of `site` seen from this pose: the reference view of a scene whose
    /// sonar sits at the pose's position, yawed and tilted (tilt = −pitch), the view rolled by
    /// the pose's roll, so the scene's own world ← view transform is the pose's.
    pub fn scene(&self, site: &Site) -> Scene {
        Scene {
            objects: vec![Object::Site {
                file: site.file.clone(),
                sha256: site.sha256.clone(),
                triangles: site.mesh.len(),
                reflectivity: SITE_REFLECTIVITY,
            }],
            ..self.bare_scene()
        }
    }

    /// Sonar frame → site frame.
    pub fn site_from_sonar(&self) -> RigidTransform {
        self.bare_scene().world_from_view(0)
    }

    /// [`SitePose::scene`] without the mesh.
    fn bare_scene(&self) -> Scene {
        Scene {
            kind: SceneKind::Site,
            split: Split::Test,
            index: 0,
            seed: 0,
            sample_seed: 0,
            sonar: SonarPose {
                position_m: self.position_m,
                yaw_deg: self.yaw_deg,
                tilt_deg: -self.pitch_deg,
            },
            view_rolls_deg: vec![self.roll_deg],
            view_pose_errors_deg: Vec::new(),
            objects: Vec::new(),
        }
    }

    /// The depth (metres) and mask (0/1) of the view from this pose in `site`, by the very
    /// code that labels a simulated sample ([`reference_labels`]).
    pub fn label(&self, site: &Site) -> Result<(Vec<f32>, Vec<f32>)> {
        let scene = self.scene(site);
        Ok(reference_labels(&scene, &World::with_site(&scene, site)?))
    }
}

/// Writes rows as the file's text: the header, then one row per frame in the order given, each
/// number in Rust's shortest form that reads back to the same f64.
pub fn to_csv(rows: &[(usize, SitePose)]) -> String {
    let mut out = String::from(HEADER);
    out.push('\n');
    for (frame, p) in rows {
        let [x, y, z] = p.position_m;
        out.push_str(&format!(
            "{frame},{x},{y},{z},{},{},{}\n",
            p.roll_deg, p.pitch_deg, p.yaw_deg
        ));
    }
    out
}

/// Parses the file's text for a recording of `frames` frames: the header first (blank lines
/// and lines starting with `#` are skipped anywhere), then one row per frame, each frame at
/// most once and below `frames`, every number finite.
pub fn parse(text: &str, frames: usize) -> Result<BTreeMap<usize, SitePose>> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let names: Vec<&str> = HEADER.split(',').collect();
    match lines.next() {
        Some((_, l)) if l.split(',').map(str::trim).eq(names.iter().copied()) => {}
        Some((n, l)) => bail!("line {n}: expected the header `{HEADER}`, found `{l}`"),
        None => bail!("no header: the file must begin with `{HEADER}`"),
    }
    let mut rows = BTreeMap::new();
    let mut seen: BTreeMap<usize, usize> = BTreeMap::new();
    for (n, l) in lines {
        let cells: Vec<&str> = l.split(',').map(str::trim).collect();
        ensure!(
            cells.len() == COLUMNS,
            "line {n}: {} column(s), a row has {COLUMNS} ({HEADER})",
            cells.len()
        );
        let frame: usize = cells[0]
            .parse()
            .map_err(|_| anyhow::anyhow!("line {n}: frame `{}` is not a frame index", cells[0]))?;
        ensure!(
            frame < frames,
            "line {n}: frame {frame} is not in the recording, which has {frames} frame(s)"
        );
        if let Some(first) = seen.insert(frame, n) {
            bail!("line {n}: frame {frame} has a row already (line {first})");
        }
        let mut v = [0.0f64; COLUMNS - 1];
        for (k, slot) in v.iter_mut().enumerate() {
            let cell = cells[k + 1];
            let x: f64 = cell.parse().map_err(|_| {
                anyhow::anyhow!("line {n}: {} `{cell}` is not a number", names[k + 1])
            })?;
            ensure!(
                x.is_finite(),
                "line {n}: {} is {cell}, not a finite number",
                names[k + 1]
            );
            *slot = x;
        }
        rows.insert(
            frame,
            SitePose {
                position_m: [v[0], v[1], v[2]],
                roll_deg: v[3],
                pitch_deg: v[4],
                yaw_deg: v[5],
            },
        );
    }
    Ok(rows)
}

/// Reads and parses a poses file ([`parse`]).
pub fn load(path: &Path, frames: usize) -> Result<BTreeMap<usize, SitePose>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    parse(&text, frames).with_context(|| format!("{}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use epssn::attitude::Attitude;
    use rand::{RngExt, SeedableRng};

    fn err(text: &str) -> String {
        format!("{:#}", parse(text, 10).unwrap_err())
    }

    #[test]
    fn rows_read_back_exactly_as_written() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut rows = Vec::new();
        for frame in [0usize, 3, 1, 9] {
            let mut r = || rng.random::<f64>() * 720.0 - 360.0;
            rows.push((
                frame,
                SitePose {
                    position_m: [r() / 100.0, r() * 1e-9, r()],
                    roll_deg: r(),
                    pitch_deg: -0.0,
                    yaw_deg: r() * 1e12,
                },
            ));
        }
        let back = parse(&to_csv(&rows), 10).unwrap();
        assert_eq!(back.len(), rows.len());
        for (frame, pose) in &rows {
            let b = back[frame];
            // Bit for bit, the sign of zero included.
            assert_eq!(format!("{b:?}"), format!("{pose:?}"));
        }
    }

    #[test]
    fn comments_blank_lines_spaces_and_crlf_are_read() {
        let text = "# poses\r\n frame , x_m,y_m,z_m,roll_deg,pitch_deg,yaw_deg\r\n\r\n# f2\r\n2, 1.5,0,0.25 ,7,-20,90\r\n";
        let rows = parse(text, 3).unwrap();
        assert_eq!(
            rows[&2],
            SitePose {
                position_m: [1.5, 0.0, 0.25],
                roll_deg: 7.0,
                pitch_deg: -20.0,
                yaw_deg: 90.0
            }
        );
    }

    #[test]
    fn bad_files_are_refused_naming_the_line_and_the_fault() {
        let h = HEADER;
        for (text, want) in [
            ("", "no header"),
            ("0,0,0,0,0,0,0\n", "line 1: expected the header"),
            (
                "frame,x_m,y_m,z_m,roll_deg,pitch_deg\n",
                "expected the header",
            ),
            (
                &format!("{h}\n0,0,0,0,0,0\n"),
                "line 2: 6 column(s), a row has 7",
            ),
            (&format!("{h}\n0,0,0,0,0,0,0,0\n"), "line 2: 8 column(s)"),
            (
                &format!("{h}\n0,0,0,0,0,0,\n"),
                "line 2: yaw_deg `` is not a number",
            ),
            (
                &format!("{h}\n-1,0,0,0,0,0,0\n"),
                "frame `-1` is not a frame index",
            ),
            (
                &format!("{h}\n1.5,0,0,0,0,0,0\n"),
                "frame `1.5` is not a frame index",
            ),
            (
                &format!("{h}\n0,0,x,0,0,0,0\n"),
                "line 2: y_m `x` is not a number",
            ),
            (
                &format!("{h}\n0,NaN,0,0,0,0,0\n"),
                "x_m is NaN, not a finite number",
            ),
            (
                &format!("{h}\n0,0,0,inf,0,0,0\n"),
                "z_m is inf, not a finite number",
            ),
            (
                &format!("{h}\n0,0,0,0,0,-infinity,0\n"),
                "pitch_deg is -infinity",
            ),
            (&format!("{h}\n0,0,0,0,1e999,0,0\n"), "roll_deg is 1e999"),
            (
                &format!("{h}\n10,0,0,0,0,0,0\n"),
                "frame 10 is not in the recording, which has 10",
            ),
            (
                &format!("{h}\n4,0,0,0,0,0,0\n\n4,1,0,0,0,0,0\n"),
                "line 4: frame 4 has a row already (line 2)",
            ),
        ] {
            let e = err(text);
            assert!(e.contains(want), "{text:?}: {e}");
        }
        // A header alone is a valid (empty) table: `label` names the frames it lacks.
        assert!(parse(&format!("{h}\n"), 10).unwrap().is_empty());
    }

    /// The rotation a row stands for, as `epssn::attitude` builds it from a header:
    /// Attitude::from_header_deg(−yaw, pitch, roll, 0, 0, 0), turned into a matrix.
    fn attitude_matrix(p: &SitePose) -> [[f64; 3]; 3] {
        let q = Attitude::from_header_deg(
            -p.yaw_deg as f32,
            p.pitch_deg as f32,
            p.roll_deg as f32,
            0.0,
            0.0,
            0.0,
        )
        .unwrap();
        RigidTransform::from_quaternion(q.to_array(), [0.0; 3]).rotation
    }

    fn max_diff(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> f64 {
        (0..9)
            .map(|i| (a[i / 3][i % 3] - b[i / 3][i % 3]).abs())
            .fold(0.0, f64::max)
    }

    /// The CSV's angles are `epssn::attitude`'s: a row's site ← sonar rotation (built by the
    /// scene code `label` renders with) is the attitude of a header with Heading −yaw, Pitch
    /// pitch and Roll roll; and a sonar yawed 90° looks along +y, one pitched −20° looks down.
    #[test]
    fn the_convention_is_epssn_attitudes() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for _ in 0..2000 {
            let p = SitePose {
                position_m: [1.0, 2.0, 3.0],
                roll_deg: rng.random::<f64>() * 360.0 - 180.0,
                pitch_deg: rng.random::<f64>() * 170.0 - 85.0,
                yaw_deg: rng.random::<f64>() * 720.0 - 360.0,
            };
            let m = p.site_from_sonar();
            assert!(max_diff(&m.rotation, &attitude_matrix(&p)) < 2e-6, "{p:?}");
            assert_eq!(m.translation, p.position_m);
            // And the decomposition gives the angles back.
            let back = SitePose::from_rotation(&m.rotation, m.translation);
            assert!(max_diff(&back.site_from_sonar().rotation, &m.rotation) < 1e-12);
            assert!(
                (back.pitch_deg - p.pitch_deg).abs() < 1e-9,
                "{p:?} {back:?}"
            );
        }
        let forward = |p: SitePose| p.site_from_sonar().rotate([1.0, 0.0, 0.0]);
        let at = |roll_deg, pitch_deg, yaw_deg| SitePose {
            position_m: [0.0; 3],
            roll_deg,
            pitch_deg,
            yaw_deg,
        };
        let f = forward(at(0.0, 0.0, 90.0));
        assert!((f[1] - 1.0).abs() < 1e-12, "{f:?}");
        let f = forward(at(0.0, -20.0, 0.0));
        assert!(
            f[2] < 0.0 && (f[2] + 20f64.to_radians().sin()).abs() < 1e-12,
            "{f:?}"
        );
        // A right-hand roll of 90° turns the sonar's left axis (y) up.
        let left = at(90.0, 0.0, 0.0).site_from_sonar().rotate([0.0, 1.0, 0.0]);
        assert!((left[2] - 1.0).abs() < 1e-12, "{left:?}");
    }

    /// A scene's views as rows: without a pose error the scene's own numbers (so the label is
    /// exact), with one the decomposition of the view's rotation; both give the view's
    /// world ← view transform.
    #[test]
    fn a_scenes_views_become_rows_with_their_roll() {
        let mut scene = crate::scene::generate(SceneKind::Artificial, Split::Test, 4, 0, 3);
        scene.view_pose_errors_deg = vec![[0.0, 0.0], [0.3, -0.2], [0.0, 0.0]];
        for k in 0..3 {
            let row = SitePose::of_view(&scene, k);
            let want = scene.world_from_view(k);
            let got = row.site_from_sonar();
            assert!(max_diff(&got.rotation, &want.rotation) < 1e-12, "view {k}");
            assert_eq!(got.translation, want.translation);
        }
        let r2 = SitePose::of_view(&scene, 2);
        assert_eq!(r2.roll_deg, 14.0);
        assert_eq!(r2.pitch_deg, -scene.sonar.tilt_deg);
        assert_eq!(r2.yaw_deg, scene.sonar.yaw_deg);
    }
}
