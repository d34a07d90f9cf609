//! Sites: one fixed triangle mesh (the paper's CAD tank, a harbour wall) that samples are drawn
//! throughout (`simulate --site FILE [--region FILE]`).
//!
//! The mesh is cast against through a BVH (the `bvh` crate, f64 boxes) with the same exact
//! Möller–Trumbore test the heightfields use, so a site is one more surface of the scene's
//! [`World`](crate::world::World): views, ground-truth depth and mask come out of the same
//! code as for the procedural scenes. Each sample's pose is drawn from its own seed (as the
//! procedural scenes' are) within a [`Region`], and redrawn while it lies inside geometry or
//! its range window meets nothing.

use std::path::Path;
use std::sync::Arc;

use anyhow::{ensure, Context, Result};
use bvh::aabb::{Aabb, Bounded};
use bvh::bounding_hierarchy::BHShape;
use bvh::bvh::Bvh;
use bvh::ray::Ray;
use epssn::config::{DEPTH_ROW_ELEVATION_RAD, INPUT_COLUMN_AZIMUTH_RAD, R_MAX_M, R_MIN_M};
use epssn::geometry::{deg_to_rad, direction};
use nalgebra::{Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::mesh::{content_hash, parse_mesh, Mesh, MeshFormat};
use crate::ray::ray_triangle;
use crate::scene::{
    sample_seed, uniform, view_rolls_deg, Object, Scene, SceneKind, SonarPose, Split,
    SLANT_RANGE_M, TILT_RANGE_DEG,
};

/// Padding of each triangle's box, metres: a flat triangle's box has no thickness, and the
/// BVH's slab test then must not lose it to rounding.
const BOX_PAD_M: f64 = 1e-6;

/// One triangle's box in the BVH.
#[derive(Clone, Debug)]
struct TriangleBox {
    aabb: Aabb<f64, 3>,
    triangle: usize,
    node: usize,
}

impl Bounded<f64, 3> for TriangleBox {
    fn aabb(&self) -> Aabb<f64, 3> {
        self.aabb
    }
}

impl BHShape<f64, 3> for TriangleBox {
    fn set_bh_node_index(&mut self, node: usize) {
        self.node = node;
    }
    fn bh_node_index(&self) -> usize {
        self.node
    }
}

/// A mesh ready for first-hit ray casting.
#[derive(Debug)]
pub struct SiteMesh {
    triangles: Vec<[[f64; 3]; 3]>,
    /// Right-hand unit normal of each triangle (towards the water), zero if degenerate.
    normals: Vec<[f64; 3]>,
    boxes: Vec<TriangleBox>,
    bvh: Bvh<f64, 3>,
    /// Smallest and largest corner of the mesh's bounds, metres.
    pub bounds: [[f64; 3]; 2],
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Right-hand unit normal of a triangle, zero for a degenerate one.
fn normal(t: &[[f64; 3]; 3]) -> [f64; 3] {
    let (a, b) = (sub(t[1], t[0]), sub(t[2], t[0]));
    let n = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let len = dot(n, n).sqrt();
    if len > 0.0 {
        n.map(|c| c / len)
    } else {
        [0.0; 3]
    }
}

impl SiteMesh {
    /// Builds the BVH over a (non-empty, finite: `mesh::parse_mesh` checks) mesh.
    pub fn new(mesh: &Mesh) -> Self {
        let triangles: Vec<[[f64; 3]; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|v| v.map(f64::from)))
            .collect();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let mut boxes: Vec<TriangleBox> = triangles
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let mut a = [f64::INFINITY; 3];
                let mut b = [f64::NEG_INFINITY; 3];
                for v in t {
                    for k in 0..3 {
                        a[k] = a[k].min(v[k]);
                        b[k] = b[k].max(v[k]);
                        lo[k] = lo[k].min(v[k]);
                        hi[k] = hi[k].max(v[k]);
                    }
                }
                TriangleBox {
                    aabb: Aabb::with_bounds(
                        Point3::from(a.map(|c| c - BOX_PAD_M)),
                        Point3::from(b.map(|c| c + BOX_PAD_M)),
                    ),
                    triangle: i,
                    node: 0,
                }
            })
            .collect();
        let bvh = Bvh::build(&mut boxes);
        Self {
            normals: triangles.iter().map(normal).collect(),
            triangles,
            boxes,
            bvh,
            bounds: [lo, hi],
        }
    }

    /// Triangles in the mesh.
    pub fn len(&self) -> usize {
        self.triangles.len()
    }

    /// Whether the mesh has no triangle (never, for a mesh that was read).
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// First hit of the ray from `o` along unit `d`: distance and the triangle's right-hand
    /// normal (pointing back along the ray when the triangle is seen from the water).
    ///
    /// The BVH hands out triangles in non-decreasing order of their boxes' entry distance, so
    /// the search stops at the first box that starts beyond the nearest hit found.
    pub fn cast(&self, o: [f64; 3], d: [f64; 3]) -> Option<(f64, [f64; 3])> {
        let ray = Ray::new(Point3::from(o), Vector3::from(d));
        let mut best: Option<(f64, usize)> = None;
        for b in self.bvh.nearest_traverse_iterator(&ray, &self.boxes) {
            if let Some((t_best, _)) = best {
                match ray.intersection_slice_for_aabb(&b.aabb) {
                    Some((entry, _)) if entry > t_best => break,
                    _ => {}
                }
            }
            if let Some(t) = ray_triangle(o, d, self.triangles[b.triangle]) {
                if best.is_none_or(|(bt, bi)| t < bt || (t == bt && b.triangle < bi)) {
                    best = Some((t, b.triangle));
                }
            }
        }
        best.map(|(t, i)| (t, self.normals[i]))
    }

    /// First hit by testing every triangle: what [`SiteMesh::cast`] must agree with.
    pub fn cast_brute_force(&self, o: [f64; 3], d: [f64; 3]) -> Option<(f64, [f64; 3])> {
        let mut best: Option<(f64, usize)> = None;
        for (i, t) in self.triangles.iter().enumerate() {
            if let Some(t) = ray_triangle(o, d, *t) {
                if best.is_none_or(|(bt, _)| t < bt) {
                    best = Some((t, i));
                }
            }
        }
        best.map(|(t, i)| (t, self.normals[i]))
    }
}

/// A site: its mesh ready for casting and what `scene.json` records of its file.
#[derive(Clone, Debug)]
pub struct Site {
    /// The file's name, no folder.
    pub file: String,
    /// SHA-256 of the file's bytes, lower-case hex.
    pub sha256: String,
    /// The mesh, shared by every sample's world.
    pub mesh: Arc<SiteMesh>,
}

impl Site {
    /// Reads a site from an STL, OBJ or PLY file (format from the extension).
    pub fn load(path: &Path) -> Result<Self> {
        let format = MeshFormat::from_path(path)?;
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let mesh = parse_mesh(&bytes, format).with_context(|| format!("{}", path.display()))?;
        Ok(Self {
            file: path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            sha256: content_hash(&bytes),
            mesh: Arc::new(SiteMesh::new(&mesh)),
        })
    }
}

/// Where poses are drawn in a site (`simulate --region FILE`, JSON; every field optional).
///
/// Without `z_m`, the sonar sits where the procedural scenes put it: at the height above the
/// site's floor (its lowest point) from which its boresight meets the floor at the drawn slant
/// range, `z = floor + slant · sin(tilt)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Region {
    /// Range of x, metres, site frame. Default: the mesh's bounds less [`WALL_MARGIN_M`].
    pub x_m: Option<[f64; 2]>,
    /// Range of y, metres. Default: the mesh's bounds less [`WALL_MARGIN_M`].
    pub y_m: Option<[f64; 2]>,
    /// Range of z, metres. Default: from the slant range and tilt (above).
    pub z_m: Option<[f64; 2]>,
    /// Downward tilt, degrees. Default 15–25 (the procedural scenes').
    pub tilt_deg: [f64; 2],
    /// Slant range at which the boresight meets the floor, metres (used without `z_m`).
    /// Default 2.5–3.0.
    pub slant_m: [f64; 2],
    /// Heading about z, degrees. Default 0–360.
    pub yaw_deg: [f64; 2],
    /// Poses drawn per sample before giving up. Default 1000.
    pub max_attempts: u32,
}

/// How far inside the mesh's bounds the default region keeps the sonar, metres.
pub const WALL_MARGIN_M: f64 = 0.3;

impl Default for Region {
    fn default() -> Self {
        Self {
            x_m: None,
            y_m: None,
            z_m: None,
            tilt_deg: [TILT_RANGE_DEG.0, TILT_RANGE_DEG.1],
            slant_m: [SLANT_RANGE_M.0, SLANT_RANGE_M.1],
            yaw_deg: [0.0, 360.0],
            max_attempts: 1000,
        }
    }
}

/// Refuses a range that is not finite or runs backwards.
fn check_range(name: &str, r: [f64; 2]) -> Result<()> {
    ensure!(
        r[0].is_finite() && r[1].is_finite() && r[0] <= r[1],
        "region: {name} must be two finite numbers, the smaller first (got {r:?})"
    );
    Ok(())
}

impl Region {
    /// Reads a region file.
    pub fn load(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let region: Self =
            serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
        region.check()?;
        Ok(region)
    }

    /// Refuses ranges that cannot be drawn from.
    pub fn check(&self) -> Result<()> {
        for (name, r) in [("x_m", self.x_m), ("y_m", self.y_m), ("z_m", self.z_m)] {
            if let Some(r) = r {
                check_range(name, r)?;
            }
        }
        check_range("tilt_deg", self.tilt_deg)?;
        check_range("slant_m", self.slant_m)?;
        check_range("yaw_deg", self.yaw_deg)?;
        ensure!(
            self.tilt_deg[0] >= -90.0 && self.tilt_deg[1] <= 90.0,
            "region: tilt_deg must lie within -90..=90"
        );
        ensure!(self.slant_m[0] > 0.0, "region: slant_m must be positive");
        ensure!(
            (1..=1_000_000).contains(&self.max_attempts),
            "region: max_attempts must be within 1..=1000000"
        );
        Ok(())
    }

    /// The x and y ranges in force for `mesh`: given, or its bounds less the wall margin.
    fn xy(&self, mesh: &SiteMesh) -> Result<[[f64; 2]; 2]> {
        let [lo, hi] = mesh.bounds;
        let mut out = [[0.0; 2]; 2];
        for (k, (given, name)) in [(self.x_m, "x"), (self.y_m, "y")].into_iter().enumerate() {
            out[k] = match given {
                Some(r) => r,
                None => {
                    let r = [lo[k] + WALL_MARGIN_M, hi[k] - WALL_MARGIN_M];
                    ensure!(
                        r[0] <= r[1],
                        "the site is under {} m across in {name}: give the region's {name}_m",
                        2.0 * WALL_MARGIN_M
                    );
                    r
                }
            };
        }
        Ok(out)
    }
}

/// Directions probed from a drawn position: the six axes and the eight diagonals.
fn probe_directions() -> Vec<[f64; 3]> {
    let mut out = vec![
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let s = 1.0 / 3f64.sqrt();
    for x in [-s, s] {
        for y in [-s, s] {
            for z in [-s, s] {
                out.push([x, y, z]);
            }
        }
    }
    out
}

/// Whether a position is in the water: no probe ray first meets the back of a triangle
/// (which it would from inside a solid or outside the walls), and the ray straight down meets
/// a surface (a floor below).
pub fn in_water(mesh: &SiteMesh, p: [f64; 3]) -> bool {
    let mut floor = false;
    for d in probe_directions() {
        match mesh.cast(p, d) {
            Some((_, n)) if dot(n, d) > 0.0 => return false,
            Some(_) if d == [0.0, 0.0, -1.0] => floor = true,
            _ => {}
        }
    }
    floor
}

/// Whether some ray of the reference view's depth grid meets the mesh inside the range window.
pub fn window_meets_surface(mesh: &SiteMesh, pose: &SonarPose) -> bool {
    let wfr = pose.world_from_reference();
    DEPTH_ROW_ELEVATION_RAD.iter().any(|&el| {
        INPUT_COLUMN_AZIMUTH_RAD.iter().any(|&az| {
            let d = wfr.rotate(direction(az, el));
            mesh.cast(wfr.translation, d)
                .is_some_and(|(t, _)| (R_MIN_M..=R_MAX_M).contains(&t))
        })
    })
}

/// One pose drawn from the region (tilt, slant, heading, x, y, then z if given, in that order
/// from `rng`).
fn draw_pose(rng: &mut ChaCha8Rng, region: &Region, xy: [[f64; 2]; 2], floor_z: f64) -> SonarPose {
    let tilt = uniform(rng, region.tilt_deg[0], region.tilt_deg[1]);
    let slant = uniform(rng, region.slant_m[0], region.slant_m[1]);
    let yaw = uniform(rng, region.yaw_deg[0], region.yaw_deg[1]);
    let x = uniform(rng, xy[0][0], xy[0][1]);
    let y = uniform(rng, xy[1][0], xy[1][1]);
    let z = match region.z_m {
        Some([lo, hi]) => uniform(rng, lo, hi),
        None => floor_z + slant * deg_to_rad(tilt).sin(),
    };
    SonarPose {
        position_m: [x, y, z],
        yaw_deg: yaw,
        tilt_deg: tilt,
    }
}

/// Draws the scene of sample `index` of a site: poses from the sample's seed until one is in
/// the water and its window meets the mesh, at most `region.max_attempts`.
pub fn generate(
    site: &Site,
    region: &Region,
    reflectivity: f64,
    split: Split,
    seed: u64,
    index: u64,
    views: usize,
) -> Result<Scene> {
    region.check()?;
    let xy = region.xy(&site.mesh)?;
    let sample_seed = sample_seed(seed, SceneKind::Site, split, index);
    let mut rng = ChaCha8Rng::seed_from_u64(sample_seed);
    let floor_z = site.mesh.bounds[0][2];
    let sonar = (0..region.max_attempts)
        .map(|_| draw_pose(&mut rng, region, xy, floor_z))
        .find(|pose| {
            in_water(&site.mesh, pose.position_m) && window_meets_surface(&site.mesh, pose)
        })
        .with_context(|| {
            format!(
                "site {}: none of {} poses drawn for sample {index} is in the water with a \
                 surface in its range window (is the mesh wound counter-clockwise seen from the \
                 water, and does the region lie inside it?)",
                site.file, region.max_attempts
            )
        })?;
    Ok(Scene {
        kind: SceneKind::Site,
        split,
        index,
        seed,
        sample_seed,
        sonar,
        view_rolls_deg: view_rolls_deg(views),
        view_pose_errors_deg: Vec::new(),
        objects: vec![Object::Site {
            file: site.file.clone(),
            sha256: site.sha256.clone(),
            triangles: site.mesh.len(),
            reflectivity,
        }],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Odd meshes build and cast without panicking: one triangle, many copies of one, zero-area
    /// ones, huge coordinates.
    #[test]
    fn odd_meshes_build_and_cast() {
        let t = [[0.0, -1.0, -1.0], [0.0, 1.0, -1.0], [0.0, 0.0, 1.0]];
        let meshes = [
            vec![t],
            vec![t; 200],
            vec![
                [[0.0; 3]; 3],
                [[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]],
                t,
            ],
            vec![[[-3e38, 0.0, 0.0], [3e38, 1.0, 0.0], [0.0, 3e38, 1.0]], t],
        ];
        for triangles in meshes {
            let mesh = SiteMesh::new(&Mesh { triangles });
            let o = [-1.0, 0.0, 0.0];
            for d in probe_directions() {
                assert_eq!(mesh.cast(o, d), mesh.cast_brute_force(o, d));
            }
            let hit = mesh.cast(o, [1.0, 0.0, 0.0]);
            assert!(hit.is_some_and(|(t, _)| (t - 1.0).abs() < 1e-12), "{hit:?}");
            let _ = in_water(&mesh, [f64::NAN, 0.0, 0.0]);
        }
    }
}
