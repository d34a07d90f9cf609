//! A procedural scene as a triangle mesh (`simulate --export-mesh FILE`): the tank's floor and
//! walls, its bricks, blocks and arches, a terrain's heightfield, a sphere, in the world frame,
//! wound counter-clockwise seen from the water (the site convention of [`crate::mesh`]).
//!
//! Flat faces are exact up to f32 rounding (0.24 µm at 4 m), a terrain is its renderer's own
//! triangles; only curved surfaces carry a tessellation error: an arch's opening of radius r
//! with [`ARCH_SEGMENTS`] chords lies at most r·(1 − cos(π / 2·ARCH_SEGMENTS)) inside the
//! circle (28 µm at the largest opening the tank draws, 0.21 m).

use anyhow::{bail, Result};
use epssn::geometry::deg_to_rad;

use crate::mesh::{Mesh, Triangle};
use crate::scene::{terrain_heights, Object, Scene};

/// Height of exported walls above the floor, metres: the analytic walls are infinite planes,
/// and every point the sonar can reach in its window (tank poses sit at most 1.27 m up, the
/// window ends at 3.54 m) lies below this.
pub const WALL_HEIGHT_M: f64 = 5.0;

/// Chords across an arch's half-circle opening.
pub const ARCH_SEGMENTS: usize = 96;

/// Rings (pole to pole) and segments (around) of an exported sphere.
pub const SPHERE_RINGS: usize = 96;
/// Segments around an exported sphere.
pub const SPHERE_SEGMENTS: usize = 192;

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Collects triangles, each turned so that its right-hand normal points along the side it
/// faces (so no face's winding has to be worked out by hand).
#[derive(Default)]
struct Builder {
    triangles: Vec<Triangle>,
}

impl Builder {
    fn triangle(&mut self, mut t: [[f64; 3]; 3], facing: [f64; 3]) {
        if dot(cross(sub(t[1], t[0]), sub(t[2], t[0])), facing) < 0.0 {
            t.swap(1, 2);
        }
        self.triangles.push(t.map(|v| v.map(|c| c as f32)));
    }

    /// A planar convex quad, corners in order around it.
    fn quad(&mut self, q: [[f64; 3]; 4], facing: [f64; 3]) {
        self.triangle([q[0], q[1], q[2]], facing);
        self.triangle([q[0], q[2], q[3]], facing);
    }
}

/// A box or arch's frame: local (x, y, z) → world, yawed about z at its base centre.
struct Frame {
    base: [f64; 3],
    cos: f64,
    sin: f64,
}

impl Frame {
    fn new(base: [f64; 3], yaw_deg: f64) -> Self {
        let (sin, cos) = deg_to_rad(yaw_deg).sin_cos();
        Self { base, cos, sin }
    }
    fn dir(&self, v: [f64; 3]) -> [f64; 3] {
        [
            self.cos * v[0] - self.sin * v[1],
            self.sin * v[0] + self.cos * v[1],
            v[2],
        ]
    }
    fn point(&self, v: [f64; 3]) -> [f64; 3] {
        let d = self.dir(v);
        [
            d[0] + self.base[0],
            d[1] + self.base[1],
            d[2] + self.base[2],
        ]
    }
}

/// The six faces of the box `[−hx, hx] × [−hy, hy] × [0, h]` of `frame`, facing out.
fn block(b: &mut Builder, frame: &Frame, hx: f64, hy: f64, h: f64) {
    let p = |x: f64, y: f64, z: f64| frame.point([x, y, z]);
    let faces = [
        (
            [p(hx, -hy, 0.0), p(hx, hy, 0.0), p(hx, hy, h), p(hx, -hy, h)],
            [1.0, 0.0, 0.0],
        ),
        (
            [
                p(-hx, -hy, 0.0),
                p(-hx, hy, 0.0),
                p(-hx, hy, h),
                p(-hx, -hy, h),
            ],
            [-1.0, 0.0, 0.0],
        ),
        (
            [p(-hx, hy, 0.0), p(hx, hy, 0.0), p(hx, hy, h), p(-hx, hy, h)],
            [0.0, 1.0, 0.0],
        ),
        (
            [
                p(-hx, -hy, 0.0),
                p(hx, -hy, 0.0),
                p(hx, -hy, h),
                p(-hx, -hy, h),
            ],
            [0.0, -1.0, 0.0],
        ),
        (
            [p(-hx, -hy, h), p(hx, -hy, h), p(hx, hy, h), p(-hx, hy, h)],
            [0.0, 0.0, 1.0],
        ),
        (
            [
                p(-hx, -hy, 0.0),
                p(hx, -hy, 0.0),
                p(hx, hy, 0.0),
                p(-hx, hy, 0.0),
            ],
            [0.0, 0.0, -1.0],
        ),
    ];
    for (q, n) in faces {
        b.quad(q, frame.dir(n));
    }
}

/// Angles from π down to 0 across an arch's opening: [`ARCH_SEGMENTS`] equal steps plus the
/// directions of the box's top corners, so the outer outline keeps its corners.
fn arch_angles(hx: f64, h: f64) -> Vec<f64> {
    let corner = h.atan2(hx);
    let mut a: Vec<f64> = (0..=ARCH_SEGMENTS)
        .map(|i| std::f64::consts::PI * (1.0 - i as f64 / ARCH_SEGMENTS as f64))
        .chain([std::f64::consts::PI - corner, corner])
        .collect();
    a.sort_by(|x, y| y.total_cmp(x));
    a.dedup_by(|x, y| (*x - *y).abs() < 1e-12);
    a
}

/// The box `[−hx, hx] × [−hy, hy] × [0, h]` less the cylinder x² + z² < r² along local y.
fn arch(b: &mut Builder, frame: &Frame, [hx, hy, h]: [f64; 3], r: f64) {
    let angles = arch_angles(hx, h);
    // Outline points in the x–z plane: on the opening's circle, and where the same direction
    // leaves the box (its sides or top).
    let inner = |t: f64| [r * t.cos(), r * t.sin().max(0.0)];
    let outer = |t: f64| {
        let (s, c) = t.sin_cos();
        let mut k = f64::INFINITY;
        if c.abs() > 1e-15 {
            k = k.min(hx / c.abs());
        }
        if s > 1e-15 {
            k = k.min(h / s);
        }
        [k * c, (k * s).max(0.0)]
    };
    let p = |xz: [f64; 2], y: f64| frame.point([xz[0], y, xz[1]]);
    for w in angles.windows(2) {
        let (a0, a1, o0, o1) = (inner(w[0]), inner(w[1]), outer(w[0]), outer(w[1]));
        for (y, n) in [(hy, 1.0), (-hy, -1.0)] {
            b.quad(
                [p(a0, y), p(o0, y), p(o1, y), p(a1, y)],
                frame.dir([0.0, n, 0.0]),
            );
        }
        // The opening's surface faces its axis.
        let mid = 0.5 * (w[0] + w[1]);
        b.quad(
            [p(a0, -hy), p(a1, -hy), p(a1, hy), p(a0, hy)],
            frame.dir([-mid.cos(), 0.0, -mid.sin()]),
        );
    }
    let q = |x: f64, y: f64, z: f64| frame.point([x, y, z]);
    b.quad(
        [q(-hx, -hy, h), q(hx, -hy, h), q(hx, hy, h), q(-hx, hy, h)],
        frame.dir([0.0, 0.0, 1.0]),
    );
    for (x, n) in [(hx, 1.0), (-hx, -1.0)] {
        b.quad(
            [q(x, -hy, 0.0), q(x, hy, 0.0), q(x, hy, h), q(x, -hy, h)],
            frame.dir([n, 0.0, 0.0]),
        );
    }
    for (x0, x1) in [(-hx, -r), (r, hx)] {
        b.quad(
            [
                q(x0, -hy, 0.0),
                q(x1, -hy, 0.0),
                q(x1, hy, 0.0),
                q(x0, hy, 0.0),
            ],
            frame.dir([0.0, 0.0, -1.0]),
        );
    }
}

/// Bounds of the water that a scene's axis-aligned planes enclose: `[axis][low, high]`, a
/// plane whose normal is +axis bounding it below. Open sides stay infinite.
fn water_box(planes: &[([f64; 3], [f64; 3])]) -> Result<[[f64; 2]; 3]> {
    let mut bounds = [[f64::NEG_INFINITY, f64::INFINITY]; 3];
    for (point, n) in planes {
        let len = dot(*n, *n).sqrt();
        let Some(axis) = (0..3).find(|&k| (n[k].abs() - len).abs() <= 1e-12 * len) else {
            bail!("only planes along the axes can be exported, not one of normal {n:?}");
        };
        let c = point[axis];
        if n[axis] > 0.0 {
            bounds[axis][0] = bounds[axis][0].max(c);
        } else {
            bounds[axis][1] = bounds[axis][1].min(c);
        }
    }
    Ok(bounds)
}

/// The planes (floor, walls, a ceiling if any) as the faces of their water box; walls end
/// [`WALL_HEIGHT_M`] above the floor when there is no ceiling.
fn tank(b: &mut Builder, planes: &[([f64; 3], [f64; 3])]) -> Result<()> {
    let mut w = water_box(planes)?;
    if !w[2][0].is_finite() {
        bail!("a tank without a floor cannot be exported");
    }
    if !w[2][1].is_finite() {
        w[2][1] = w[2][0] + WALL_HEIGHT_M;
    }
    if w.iter()
        .any(|r| !r[0].is_finite() || !r[1].is_finite() || r[0] >= r[1])
    {
        bail!("the planes do not enclose a bounded tank: {w:?}");
    }
    let [[x0, x1], [y0, y1], [z0, z1]] = w;
    for (point, n) in planes {
        let axis = (0..3).find(|&k| n[k] != 0.0).unwrap_or(2);
        let up = n[axis] > 0.0;
        let c = if up { w[axis][0] } else { w[axis][1] };
        // Only the innermost plane of a side is a face of the box.
        if point[axis] != c {
            continue;
        }
        let q = match axis {
            0 => [[c, y0, z0], [c, y1, z0], [c, y1, z1], [c, y0, z1]],
            1 => [[x0, c, z0], [x1, c, z0], [x1, c, z1], [x0, c, z1]],
            _ => [[x0, y0, c], [x1, y0, c], [x1, y1, c], [x0, y1, c]],
        };
        let mut facing = [0.0; 3];
        facing[axis] = if up { 1.0 } else { -1.0 };
        b.quad(q, facing);
    }
    Ok(())
}

/// A UV sphere, facing out.
fn sphere(b: &mut Builder, c: [f64; 3], r: f64) {
    let at = |i: usize, j: usize| {
        let th = std::f64::consts::PI * i as f64 / SPHERE_RINGS as f64;
        let ph = std::f64::consts::TAU * j as f64 / SPHERE_SEGMENTS as f64;
        [
            c[0] + r * th.sin() * ph.cos(),
            c[1] + r * th.sin() * ph.sin(),
            c[2] + r * th.cos(),
        ]
    };
    for i in 0..SPHERE_RINGS {
        for j in 0..SPHERE_SEGMENTS {
            let (p00, p01, p10, p11) = (at(i, j), at(i, j + 1), at(i + 1, j), at(i + 1, j + 1));
            let mid = {
                let th = std::f64::consts::PI * (i as f64 + 0.5) / SPHERE_RINGS as f64;
                let ph = std::f64::consts::TAU * (j as f64 + 0.5) / SPHERE_SEGMENTS as f64;
                [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]
            };
            // The rings at the poles have one triangle per segment.
            if i + 1 < SPHERE_RINGS {
                b.triangle([p00, p10, p11], mid);
            }
            if i > 0 {
                b.triangle([p00, p11, p01], mid);
            }
        }
    }
}

/// A terrain as the renderer's own triangles (two per grid cell), facing up.
fn terrain(b: &mut Builder, spec: &crate::scene::TerrainSpec) {
    let z = terrain_heights(spec);
    let [nx, ny] = spec.points;
    let c = spec.cell_m;
    for j in 0..ny.saturating_sub(1) {
        for i in 0..nx.saturating_sub(1) {
            let x0 = spec.origin_m[0] + i as f64 * c;
            let y0 = spec.origin_m[1] + j as f64 * c;
            let p00 = [x0, y0, z[j * nx + i]];
            let p10 = [x0 + c, y0, z[j * nx + i + 1]];
            let p01 = [x0, y0 + c, z[(j + 1) * nx + i]];
            let p11 = [x0 + c, y0 + c, z[(j + 1) * nx + i + 1]];
            b.triangle([p00, p10, p11], [0.0, 0.0, 1.0]);
            b.triangle([p00, p11, p01], [0.0, 0.0, 1.0]);
        }
    }
}

/// The scene's objects as one mesh in its world frame: the tank first, then the objects in
/// the scene's order.
pub fn scene_mesh(scene: &Scene) -> Result<Mesh> {
    let mut b = Builder::default();
    let planes: Vec<([f64; 3], [f64; 3])> = scene
        .objects
        .iter()
        .filter_map(|o| match o {
            Object::Plane {
                point_m, normal, ..
            } => Some((*point_m, *normal)),
            _ => None,
        })
        .collect();
    if !planes.is_empty() {
        tank(&mut b, &planes)?;
    }
    for o in &scene.objects {
        match o {
            Object::Plane { .. } => {}
            Object::Sphere {
                center_m, radius_m, ..
            } => sphere(&mut b, *center_m, *radius_m),
            Object::Block {
                base_center_m,
                size_m,
                yaw_deg,
                ..
            } => block(
                &mut b,
                &Frame::new(*base_center_m, *yaw_deg),
                size_m[0] / 2.0,
                size_m[1] / 2.0,
                size_m[2],
            ),
            Object::Arch {
                base_center_m,
                size_m,
                opening_radius_m,
                yaw_deg,
                ..
            } => arch(
                &mut b,
                &Frame::new(*base_center_m, *yaw_deg),
                [size_m[0] / 2.0, size_m[1] / 2.0, size_m[2]],
                *opening_radius_m,
            ),
            Object::Terrain(spec) => terrain(&mut b, spec),
            Object::Site { file, .. } => bail!("the scene is already the site {file}"),
        }
    }
    if b.triangles.is_empty() {
        bail!("the scene has nothing to export");
    }
    Ok(Mesh {
        triangles: b.triangles,
    })
}
