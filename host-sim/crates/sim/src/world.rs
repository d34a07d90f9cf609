//! The simulator's ray caster: a [`Scene`]'s objects as solids (spheres, planes, boxes,
//! arches, terrain heightfields, a site's mesh) and the first hit of a ray among them.

use epssn::geometry::{deg_to_rad, direction, RigidTransform};

use crate::ray::{cross, dot, normalise, ray_box, ray_sphere, ray_triangle, sub, T_MIN};
use crate::scene::{terrain_heights, Object, Scene};
use crate::site::{Site, SiteMesh};

/// A ray's first intersection with the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray, metres.
    pub t: f64,
    /// Unit surface normal at the hit, world frame.
    pub normal: [f64; 3],
    /// Acoustic reflectivity of the surface.
    pub reflectivity: f64,
}

/// A box or arch in its local frame: z up from the base, yawed about z.
#[derive(Clone, Debug)]
struct LocalFrame {
    base: [f64; 3],
    cos: f64,
    sin: f64,
}

impl LocalFrame {
    fn new(base: [f64; 3], yaw_deg: f64) -> Self {
        let (sin, cos) = deg_to_rad(yaw_deg).sin_cos();
        Self { base, cos, sin }
    }
    fn to_local(&self, v: [f64; 3]) -> [f64; 3] {
        [
            self.cos * v[0] + self.sin * v[1],
            -self.sin * v[0] + self.cos * v[1],
            v[2],
        ]
    }
    fn to_world(&self, v: [f64; 3]) -> [f64; 3] {
        [
            self.cos * v[0] - self.sin * v[1],
            self.sin * v[0] + self.cos * v[1],
            v[2],
        ]
    }
}

/// A heightfield ready for ray casting.
#[derive(Clone, Debug)]
struct Heightfield {
    z: Vec<f64>,
    nx: usize,
    ny: usize,
    origin: [f64; 2],
    cell: f64,
    zmin: f64,
    zmax: f64,
    reflectivity: f64,
}

impl Heightfield {
    fn at(&self, i: usize, j: usize) -> f64 {
        self.z[j * self.nx + i]
    }

    /// First hit by 2D grid traversal (Amanatides–Woo) over the cells the ray crosses,
    /// testing each cell's two triangles exactly.
    fn cast(&self, o: [f64; 3], d: [f64; 3]) -> Option<Hit> {
        let lo = [self.origin[0], self.origin[1], self.zmin];
        let hi = [
            self.origin[0] + (self.nx - 1) as f64 * self.cell,
            self.origin[1] + (self.ny - 1) as f64 * self.cell,
            self.zmax,
        ];
        let (t_in, t_out, _) = ray_box(o, d, lo, hi)?;
        let t_in = t_in.max(0.0);
        if t_out < t_in {
            return None;
        }
        let cells = [self.nx - 1, self.ny - 1];
        let p = [o[0] + d[0] * t_in, o[1] + d[1] * t_in];
        let mut ij = [0usize; 2];
        let mut step = [0i64; 2];
        let mut t_next = [f64::INFINITY; 2];
        let mut t_delta = [f64::INFINITY; 2];
        for a in 0..2 {
            let f = ((p[a] - self.origin[a]) / self.cell).floor();
            ij[a] = (f.max(0.0) as usize).min(cells[a] - 1);
            if d[a] > 0.0 {
                step[a] = 1;
                let edge = self.origin[a] + (ij[a] + 1) as f64 * self.cell;
                t_next[a] = t_in + (edge - p[a]) / d[a];
                t_delta[a] = self.cell / d[a];
            } else if d[a] < 0.0 {
                step[a] = -1;
                let edge = self.origin[a] + ij[a] as f64 * self.cell;
                t_next[a] = t_in + (edge - p[a]) / d[a];
                t_delta[a] = -self.cell / d[a];
            }
        }
        let mut t_cell = t_in;
        loop {
            let t_end = t_next[0].min(t_next[1]).min(t_out);
            let (i, j) = (ij[0], ij[1]);
            let (z00, z10, z01, z11) = (
                self.at(i, j),
                self.at(i + 1, j),
                self.at(i, j + 1),
                self.at(i + 1, j + 1),
            );
            // Skip cells the ray passes above.
            let zr = (o[2] + d[2] * t_cell).min(o[2] + d[2] * t_end);
            if zr <= z00.max(z10).max(z01).max(z11) + 1e-9 {
                let x0 = self.origin[0] + i as f64 * self.cell;
                let y0 = self.origin[1] + j as f64 * self.cell;
                let c = self.cell;
                let p00 = [x0, y0, z00];
                let p10 = [x0 + c, y0, z10];
                let p01 = [x0, y0 + c, z01];
                let p11 = [x0 + c, y0 + c, z11];
                let mut best: Option<(f64, [f64; 3])> = None;
                for tri in [[p00, p10, p11], [p00, p11, p01]] {
                    if let Some(t) = ray_triangle(o, d, tri) {
                        if best.is_none_or(|(bt, _)| t < bt) {
                            let n = normalise(cross(sub(tri[1], tri[0]), sub(tri[2], tri[0])));
                            best = Some((t, n));
                        }
                    }
                }
                if let Some((t, n)) = best {
                    return Some(Hit {
                        t,
                        normal: n,
                        reflectivity: self.reflectivity,
                    });
                }
            }
            if t_end >= t_out {
                return None;
            }
            let a = if t_next[0] < t_next[1] { 0 } else { 1 };
            let next = ij[a] as i64 + step[a];
            if next < 0 || next >= cells[a] as i64 {
                return None;
            }
            ij[a] = next as usize;
            t_cell = t_next[a];
            t_next[a] += t_delta[a];
        }
    }
}

#[derive(Clone, Debug)]
enum Solid {
    Sphere {
        c: [f64; 3],
        r: f64,
        refl: f64,
    },
    Plane {
        p: [f64; 3],
        n: [f64; 3],
        refl: f64,
    },
    Block {
        frame: LocalFrame,
        half: [f64; 2],
        height: f64,
        refl: f64,
    },
    Arch {
        frame: LocalFrame,
        half: [f64; 2],
        height: f64,
        radius: f64,
        refl: f64,
    },
    Terrain(Heightfield),
    Mesh {
        mesh: std::sync::Arc<SiteMesh>,
        refl: f64,
    },
}

impl Solid {
    fn cast(&self, o: [f64; 3], d: [f64; 3]) -> Option<Hit> {
        match self {
            Solid::Sphere { c, r, refl } => ray_sphere(o, d, *c, *r).map(|t| Hit {
                t,
                normal: normalise(sub([o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t], *c)),
                reflectivity: *refl,
            }),
            Solid::Plane { p, n, refl } => {
                let den = dot(d, *n);
                if den >= 0.0 {
                    return None; // seen from behind or parallel
                }
                let t = dot(sub(*p, o), *n) / den;
                (t > T_MIN).then_some(Hit {
                    t,
                    normal: *n,
                    reflectivity: *refl,
                })
            }
            Solid::Block {
                frame,
                half,
                height,
                refl,
            } => {
                let lo_ = frame.to_local(sub(o, frame.base));
                let ld = frame.to_local(d);
                let (t0, _, n) = ray_box(
                    lo_,
                    ld,
                    [-half[0], -half[1], 0.0],
                    [half[0], half[1], *height],
                )?;
                (t0 > T_MIN).then_some(Hit {
                    t: t0,
                    normal: frame.to_world(n),
                    reflectivity: *refl,
                })
            }
            Solid::Arch {
                frame,
                half,
                height,
                radius,
                refl,
            } => {
                let lo_ = frame.to_local(sub(o, frame.base));
                let ld = frame.to_local(d);
                let (t0, t1, n) = ray_box(
                    lo_,
                    ld,
                    [-half[0], -half[1], 0.0],
                    [half[0], half[1], *height],
                )?;
                // Infinite cylinder along local y through the base centre: x² + z² < r².
                let a = ld[0] * ld[0] + ld[2] * ld[2];
                let b = lo_[0] * ld[0] + lo_[2] * ld[2];
                let c = lo_[0] * lo_[0] + lo_[2] * lo_[2] - radius * radius;
                let hole = if a < 1e-18 {
                    // Parallel to the axis: inside the opening for all t, or never.
                    (c < 0.0).then_some((f64::NEG_INFINITY, f64::INFINITY))
                } else if b * b - a * c > 0.0 {
                    let s = (b * b - a * c).sqrt();
                    Some(((-b - s) / a, (-b + s) / a))
                } else {
                    None
                };
                // Solid = box minus cylinder: its first point is the box entry unless that lies
                // in the hole, else the hole's exit if still inside the box.
                let (t, nl) = match hole {
                    Some((c0, c1)) if t0 > c0 && t0 < c1 => {
                        if c1 >= t1 {
                            return None;
                        }
                        let px = lo_[0] + ld[0] * c1;
                        let pz = lo_[2] + ld[2] * c1;
                        // Facing into the opening, towards the axis.
                        (c1, normalise([-px, 0.0, -pz]))
                    }
                    _ => (t0, n),
                };
                (t > T_MIN).then_some(Hit {
                    t,
                    normal: frame.to_world(nl),
                    reflectivity: *refl,
                })
            }
            Solid::Terrain(h) => h.cast(o, d),
            Solid::Mesh { mesh, refl } => mesh.cast(o, d).map(|(t, normal)| Hit {
                t,
                normal,
                reflectivity: *refl,
            }),
        }
    }
}

/// A scene's ray-casting form.
#[derive(Clone, Debug)]
pub struct World {
    solids: Vec<Solid>,
}

impl World {
    /// Builds the ray-casting form of `scene` (evaluates terrain heights). A site object is
    /// left out: its mesh comes from [`World::with_site`].
    pub fn new(scene: &Scene) -> Self {
        let solids = scene
            .objects
            .iter()
            .filter_map(|o| {
                Some(match o {
                    Object::Sphere {
                        center_m,
                        radius_m,
                        reflectivity,
                    } => Solid::Sphere {
                        c: *center_m,
                        r: *radius_m,
                        refl: *reflectivity,
                    },
                    Object::Plane {
                        point_m,
                        normal,
                        reflectivity,
                        ..
                    } => Solid::Plane {
                        p: *point_m,
                        n: normalise(*normal),
                        refl: *reflectivity,
                    },
                    Object::Block {
                        base_center_m,
                        size_m,
                        yaw_deg,
                        reflectivity,
                        ..
                    } => Solid::Block {
                        frame: LocalFrame::new(*base_center_m, *yaw_deg),
                        half: [size_m[0] / 2.0, size_m[1] / 2.0],
                        height: size_m[2],
                        refl: *reflectivity,
                    },
                    Object::Arch {
                        base_center_m,
                        size_m,
                        opening_radius_m,
                        yaw_deg,
                        reflectivity,
                    } => Solid::Arch {
                        frame: LocalFrame::new(*base_center_m, *yaw_deg),
                        half: [size_m[0] / 2.0, size_m[1] / 2.0],
                        height: size_m[2],
                        radius: *opening_radius_m,
                        refl: *reflectivity,
                    },
                    Object::Terrain(spec) => {
                        let z = terrain_heights(spec);
                        let zmin = z.iter().copied().fold(f64::INFINITY, f64::min);
                        let zmax = z.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                        Solid::Terrain(Heightfield {
                            z,
                            nx: spec.points[0].max(2),
                            ny: spec.points[1].max(2),
                            origin: spec.origin_m,
                            cell: spec.cell_m,
                            zmin: zmin - 1e-6,
                            zmax: zmax + 1e-6,
                            reflectivity: spec.reflectivity,
                        })
                    }
                    Object::Site { .. } => return None,
                })
            })
            .collect();
        Self { solids }
    }

    /// The ray-casting form of a site scene: its other objects and `site`'s mesh, which must be
    /// the file its [`Object::Site`] names (same SHA-256).
    pub fn with_site(scene: &Scene, site: &Site) -> anyhow::Result<Self> {
        let mut world = Self::new(scene);
        let mut found = false;
        for o in &scene.objects {
            if let Object::Site {
                file,
                sha256,
                reflectivity,
                ..
            } = o
            {
                anyhow::ensure!(
                    *sha256 == site.sha256,
                    "the scene's site {file} has SHA-256 {sha256}, the mesh given {} has {}",
                    site.file,
                    site.sha256
                );
                world.solids.push(Solid::Mesh {
                    mesh: site.mesh.clone(),
                    refl: *reflectivity,
                });
                found = true;
            }
        }
        anyhow::ensure!(found, "the scene has no site object");
        Ok(world)
    }

    /// First hit of the ray from `o` along unit `d` (world frame), over every object.
    pub fn first_hit(&self, o: [f64; 3], d: [f64; 3]) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        for s in &self.solids {
            if let Some(h) = s.cast(o, d) {
                if best.is_none_or(|b| h.t < b.t) {
                    best = Some(h);
                }
            }
        }
        best
    }

    /// First hit of the ray at (azimuth, elevation) of a view whose frame maps to the world by
    /// `world_from_view`.
    pub fn first_hit_in_view(
        &self,
        world_from_view: &RigidTransform,
        azimuth: f64,
        elevation: f64,
    ) -> Option<Hit> {
        let d = world_from_view.rotate(direction(azimuth, elevation));
        self.first_hit(world_from_view.translation, d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{uniform, Fractal, SceneKind, SonarPose, Split, TerrainSpec};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn box_and_arch_hits() {
        let block = Solid::Block {
            frame: LocalFrame::new([3.0, 0.0, 0.0], 0.0),
            half: [0.5, 0.5],
            height: 1.0,
            refl: 1.0,
        };
        let h = block.cast([0.0, 0.0, 0.5], [1.0, 0.0, 0.0]).unwrap();
        assert!((h.t - 2.5).abs() < 1e-12);
        assert_eq!(h.normal, [-1.0, 0.0, 0.0]);
        // An arch seen through its opening along local y: a low ray passes under it, a high
        // one hits the face.
        let arch = Solid::Arch {
            frame: LocalFrame::new([0.0, 3.0, 0.0], 0.0),
            half: [0.5, 0.1],
            height: 0.6,
            radius: 0.3,
            refl: 1.0,
        };
        assert!(arch.cast([0.0, 0.0, 0.1], [0.0, 1.0, 0.0]).is_none());
        let h = arch.cast([0.0, 0.0, 0.5], [0.0, 1.0, 0.0]).unwrap();
        assert!((h.t - 2.9).abs() < 1e-12);
        // Down through the top of the opening: meets the inner curved surface at z = 0.3.
        let h = arch.cast([0.0, 3.0, 1.0], [0.0, 0.0, -1.0]).unwrap();
        assert!((h.t - 0.4).abs() < 1e-9, "{h:?}");
        assert!((h.normal[2] - 1.0).abs() < 1e-9);
        // Down at x = 0.2: top face at 0.6.
        let h = arch.cast([0.45, 3.0, 1.0], [0.0, 0.0, -1.0]).unwrap();
        assert!((h.t - 0.4).abs() < 1e-9);
    }

    #[test]
    fn heightfield_matches_brute_force() {
        let spec = TerrainSpec {
            fractal: Fractal::HybridMultifractal,
            noise_seed: 9,
            noise_offset: [10.0, 20.0],
            frequency_per_m: 1.0,
            octaves: 5,
            lacunarity: 2.0,
            h: 0.8,
            offset: 0.8,
            amplitude_m: 0.5,
            origin_m: [0.5, -1.0],
            points: [41, 31],
            cell_m: 0.05,
            reflectivity: 0.7,
        };
        let z = terrain_heights(&spec);
        let hf = match &World::new(&Scene {
            kind: SceneKind::Terrain,
            split: Split::Train,
            index: 0,
            seed: 0,
            sample_seed: 0,
            sonar: SonarPose::IDENTITY,
            view_rolls_deg: vec![0.0],
            view_pose_errors_deg: Vec::new(),
            objects: vec![Object::Terrain(spec.clone())],
        })
        .solids[0]
        {
            Solid::Terrain(h) => h.clone(),
            _ => unreachable!(),
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut hits = 0;
        for _ in 0..300 {
            let o = [
                0.0,
                uniform(&mut rng, -0.3, 0.3),
                uniform(&mut rng, 0.4, 0.8),
            ];
            let d = normalise([
                1.0,
                uniform(&mut rng, -0.3, 0.3),
                uniform(&mut rng, -0.8, 0.0),
            ]);
            let fast = hf.cast(o, d).map(|h| h.t);
            // Brute force over every triangle.
            let mut best: Option<f64> = None;
            for j in 0..spec.points[1] - 1 {
                for i in 0..spec.points[0] - 1 {
                    let nx = spec.points[0];
                    let c = spec.cell_m;
                    let x0 = spec.origin_m[0] + i as f64 * c;
                    let y0 = spec.origin_m[1] + j as f64 * c;
                    let p00 = [x0, y0, z[j * nx + i]];
                    let p10 = [x0 + c, y0, z[j * nx + i + 1]];
                    let p01 = [x0, y0 + c, z[(j + 1) * nx + i]];
                    let p11 = [x0 + c, y0 + c, z[(j + 1) * nx + i + 1]];
                    for tri in [[p00, p10, p11], [p00, p11, p01]] {
                        if let Some(t) = ray_triangle(o, d, tri) {
                            best = Some(best.map_or(t, |b: f64| b.min(t)));
                        }
                    }
                }
            }
            match (fast, best) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() < 1e-9, "{a} vs {b}");
                    hits += 1;
                }
                (None, None) => {}
                other => panic!("traversal and brute force disagree: {other:?}"),
            }
        }
        assert!(hits > 100, "only {hits} rays met the terrain");
    }
}
