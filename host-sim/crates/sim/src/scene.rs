//! Simulated scenes: what the sonar looks at and how a sample's scene is drawn from its seed
//! (the exact first-hit ray casting against it is `world`).
//!
//! A [`Scene`] is plain data (serialised as each sample's `scene.json`);
//! [`World`](crate::world::World) is its ray-casting form (terrain heightfields evaluated,
//! transforms resolved). The world frame is right-handed with z up (the floor or seabed's mean
//! level is z = 0). The sonar's reference view sits at [`SonarPose::position_m`], yawed about z
//! and tilted down about its y axis; view `k` is the reference rolled by `view_rolls_deg[k]`
//! about its forward axis, with the geometry module's convention
//! (`p_view = RigidTransform::roll_deg(roll) · p_ref`).
//!
//! Sphere scenes use the identity pose, so their world frame *is* the reference sonar frame and
//! the sphere's `center_m` is given in reference sonar coordinates.

use epssn::config;
use epssn::geometry::{deg_to_rad, direction, RigidTransform};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// The three scene families of the paper.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SceneKind {
    /// One sphere at a random position inside the view, nothing else.
    Sphere,
    /// A seabed heightfield from fractal noise.
    Terrain,
    /// A water tank (floor, walls) with bricks, concrete blocks and arches.
    Artificial,
    /// A fixed site read from a mesh file (`simulate --site`), seen from poses drawn throughout
    /// it; not a value of `--scene`.
    Site,
}

impl SceneKind {
    /// The paper's (train, test) split sizes.
    pub fn paper_split_sizes(self) -> (usize, usize) {
        match self {
            // The paper's artificial set is one fixed tank seen from random poses: a site.
            SceneKind::Artificial | SceneKind::Site => (4000, 2000),
            SceneKind::Terrain => (1000, 1000),
            SceneKind::Sphere => (1000, 500),
        }
    }
}

/// Dataset split.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Training split.
    Train,
    /// Test split.
    Test,
}

impl Split {
    /// Folder name.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Test => "test",
        }
    }
}

/// Pose of the reference view in the world.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SonarPose {
    /// Acoustic centre, world metres.
    pub position_m: [f64; 3],
    /// Heading about world z, degrees (0 = along world +x).
    pub yaw_deg: f64,
    /// Downward tilt of the forward axis, degrees (positive looks down).
    pub tilt_deg: f64,
}

impl SonarPose {
    /// The identity pose: world frame = reference sonar frame.
    pub const IDENTITY: Self = Self {
        position_m: [0.0; 3],
        yaw_deg: 0.0,
        tilt_deg: 0.0,
    };

    /// Reference sonar frame → world.
    pub fn world_from_reference(&self) -> RigidTransform {
        let (sy, cy) = deg_to_rad(self.yaw_deg).sin_cos();
        let (st, ct) = deg_to_rad(self.tilt_deg).sin_cos();
        // Rz(yaw) · Ry(tilt): a positive rotation about y turns +x towards −z (looking down).
        let rz = [[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]];
        let ry = [[ct, 0.0, st], [0.0, 1.0, 0.0], [-st, 0.0, ct]];
        let mut rot = [[0.0; 3]; 3];
        for (i, row) in rot.iter_mut().enumerate() {
            for (j, cell) in row.iter_mut().enumerate() {
                *cell = (0..3).map(|k| rz[i][k] * ry[k][j]).sum();
            }
        }
        RigidTransform {
            rotation: rot,
            translation: self.position_m,
        }
    }
}

/// Which fractal builds a terrain.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fractal {
    /// Musgrave's heterogeneous terrain.
    HeteroTerrain,
    /// Musgrave's hybrid multifractal.
    HybridMultifractal,
}

/// Parameters of a fractal-noise heightfield; the heights are a pure function of these.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TerrainSpec {
    /// Fractal family.
    pub fractal: Fractal,
    /// Seed of the gradient-noise permutation.
    pub noise_seed: u64,
    /// Offset of the noise domain (train and test draw from disjoint regions).
    pub noise_offset: [f64; 2],
    /// Base spatial frequency, cycles per metre.
    pub frequency_per_m: f64,
    /// Octaves.
    pub octaves: u32,
    /// Frequency ratio between octaves.
    pub lacunarity: f64,
    /// Fractal increment H (roughness falls as H grows).
    pub h: f64,
    /// Musgrave's offset.
    pub offset: f64,
    /// Peak-to-peak height after normalisation, metres.
    pub amplitude_m: f64,
    /// World (x, y) of grid point (0, 0), metres.
    pub origin_m: [f64; 2],
    /// Grid points along x and y.
    pub points: [usize; 2],
    /// Grid spacing, metres.
    pub cell_m: f64,
    /// Acoustic reflectivity.
    pub reflectivity: f64,
}

/// One object of a scene, world coordinates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Object {
    /// A sphere.
    Sphere {
        /// Centre, world metres (= reference sonar frame in sphere scenes).
        center_m: [f64; 3],
        /// Radius, metres.
        radius_m: f64,
        /// Acoustic reflectivity.
        reflectivity: f64,
    },
    /// An infinite plane seen from the side its normal points to (tank floor and walls).
    Plane {
        /// What it is (`floor`, `wall`).
        name: String,
        /// A point on the plane.
        point_m: [f64; 3],
        /// Unit normal towards the water.
        normal: [f64; 3],
        /// Acoustic reflectivity.
        reflectivity: f64,
    },
    /// A box standing on its base (bricks, concrete blocks).
    Block {
        /// What it is (`brick`, `concrete_block`).
        name: String,
        /// Centre of the base, world metres.
        base_center_m: [f64; 3],
        /// Length (local x), width (local y), height (z), metres.
        size_m: [f64; 3],
        /// Rotation about z, degrees.
        yaw_deg: f64,
        /// Acoustic reflectivity.
        reflectivity: f64,
    },
    /// A box with a half-cylinder opening through its base along local y: an arch.
    Arch {
        /// Centre of the base, world metres.
        base_center_m: [f64; 3],
        /// Span (local x), depth (local y), height (z), metres.
        size_m: [f64; 3],
        /// Radius of the opening, whose axis runs along local y through the base centre.
        opening_radius_m: f64,
        /// Rotation about z, degrees.
        yaw_deg: f64,
        /// Acoustic reflectivity.
        reflectivity: f64,
    },
    /// A fractal seabed heightfield.
    Terrain(TerrainSpec),
    /// A site's triangle mesh (`simulate --site`), in the world frame; the mesh itself is
    /// given to [`World::with_site`](crate::world::World::with_site), which checks it is this file.
    Site {
        /// The mesh file's name (no folder).
        file: String,
        /// SHA-256 of the file's bytes, lower-case hex.
        sha256: String,
        /// Triangles in the mesh.
        triangles: usize,
        /// Acoustic reflectivity of every triangle.
        reflectivity: f64,
    },
}

/// A sample's scene: everything needed to regenerate it exactly.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// Scene family.
    pub kind: SceneKind,
    /// Split the sample belongs to.
    pub split: Split,
    /// Index within the split.
    pub index: u64,
    /// Dataset seed given to `host-sim simulate`.
    pub seed: u64,
    /// Per-sample seed derived from (seed, split, index); also seeds the rendering noise.
    pub sample_seed: u64,
    /// Pose of the reference view.
    pub sonar: SonarPose,
    /// Roll of each view about the forward axis, degrees (view 0 = reference = 0).
    pub view_rolls_deg: Vec<f64>,
    /// Pose error of each view, `[pitch, yaw]` degrees (docs/POSE.md's convention): view `k`'s
    /// attitude in the reference frame is `Rz(−yaw) · Ry(−pitch) · Rx(roll)` instead of the
    /// pure roll. Empty (the default, and every scene before `--pose-jitter-deg`) = none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub view_pose_errors_deg: Vec<[f64; 2]>,
    /// The objects.
    pub objects: Vec<Object>,
}

impl Scene {
    /// Reference frame → frame of view `k` (the geometry module's roll convention), with the
    /// view's pose error if it has one.
    pub fn view_from_reference(&self, k: usize) -> RigidTransform {
        let roll = RigidTransform::roll_deg(self.view_rolls_deg.get(k).copied().unwrap_or(0.0));
        match self.view_pose_errors_deg.get(k) {
            Some(&[pitch, yaw]) if pitch != 0.0 || yaw != 0.0 => {
                // reference ← view = E · Rx(roll) with E = Rz(−yaw) · Ry(−pitch); its inverse
                // is view ← reference = Rx(−roll) · Eᵀ = roll_deg(roll) · Eᵀ.
                let e = pose_error_rotation(pitch, yaw);
                roll.compose(&e.inverse())
            }
            _ => roll,
        }
    }

    /// Frame of view `k` → world.
    pub fn world_from_view(&self, k: usize) -> RigidTransform {
        self.sonar
            .world_from_reference()
            .compose(&self.view_from_reference(k).inverse())
    }

    /// The sphere (centre in world = reference frame for sphere scenes, radius), if any.
    pub fn sphere(&self) -> Option<([f64; 3], f64)> {
        self.objects.iter().find_map(|o| match o {
            Object::Sphere {
                center_m, radius_m, ..
            } => Some((*center_m, *radius_m)),
            _ => None,
        })
    }
}

/// The pose error `E = Rz(−yaw) · Ry(−pitch)` of docs/POSE.md (x forward, y left, z up:
/// a positive pitch raises the forward axis, a positive yaw turns it to the right, as the ARIS
/// header's Pitch and Heading count).
pub fn pose_error_rotation(pitch_deg: f64, yaw_deg: f64) -> RigidTransform {
    let (sp, cp) = (-deg_to_rad(pitch_deg)).sin_cos();
    let (sy, cy) = (-deg_to_rad(yaw_deg)).sin_cos();
    let rz = [[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]];
    let ry = [[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]];
    let mut rot = [[0.0; 3]; 3];
    for (i, row) in rot.iter_mut().enumerate() {
        for (j, cell) in row.iter_mut().enumerate() {
            *cell = (0..3).map(|k| rz[i][k] * ry[k][j]).sum();
        }
    }
    RigidTransform {
        rotation: rot,
        translation: [0.0; 3],
    }
}

/// SplitMix64's state increment (the golden-ratio constant).
pub const SPLITMIX_GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// SplitMix64 step as a hash: advances `z` by [`SPLITMIX_GAMMA`] and applies the finaliser.
/// The generators in `synthetic` and `model` draw from it.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(SPLITMIX_GAMMA);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Seed of sample `index` of `split` in the dataset drawn with `seed`: independent of the
/// order or thread in which samples are generated.
pub fn sample_seed(seed: u64, kind: SceneKind, split: Split, index: u64) -> u64 {
    let k = match kind {
        SceneKind::Sphere => 1,
        SceneKind::Terrain => 2,
        SceneKind::Artificial => 3,
        SceneKind::Site => 4,
    };
    let s = match split {
        Split::Train => 0x7472_6169_6e00_0000u64,
        Split::Test => 0x7465_7374_0000_0000u64,
    };
    mix64(mix64(mix64(seed) ^ s ^ k) ^ index)
}

/// The roll of each of `views` views: the spec's roll step apart, the reference first.
pub fn view_rolls_deg(views: usize) -> Vec<f64> {
    (0..views)
        .map(|k| config::ROLL_STEP_DEG * k as f64)
        .collect()
}

/// Draws the scene of one sample (a site's scenes are drawn by `site::generate`, which needs
/// the mesh: here a site kind gives an empty scene at the identity pose).
pub fn generate(kind: SceneKind, split: Split, seed: u64, index: u64, views: usize) -> Scene {
    let sample_seed = sample_seed(seed, kind, split, index);
    let mut rng = ChaCha8Rng::seed_from_u64(sample_seed);
    let (sonar, objects) = match kind {
        SceneKind::Sphere => (SonarPose::IDENTITY, vec![draw_sphere(&mut rng)]),
        SceneKind::Terrain => draw_terrain(&mut rng, split),
        SceneKind::Artificial => draw_tank(&mut rng),
        SceneKind::Site => (SonarPose::IDENTITY, Vec::new()),
    };
    Scene {
        kind,
        split,
        index,
        seed,
        sample_seed,
        sonar,
        view_rolls_deg: view_rolls_deg(views),
        view_pose_errors_deg: Vec::new(),
        objects,
    }
}

/// Uniform in `[lo, hi)` from one draw of `rng`.
pub fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

fn draw_sphere(rng: &mut ChaCha8Rng) -> Object {
    let radius = uniform(rng, 0.08, 0.3);
    // Centre inside the aperture and the front surface inside the window.
    let range = uniform(rng, config::R_MIN_M + radius + 0.05, config::R_MAX_M - 0.1);
    let azimuth = deg_to_rad(uniform(rng, -12.0, 12.0));
    let elevation = deg_to_rad(uniform(rng, -5.5, 5.5));
    let d = direction(azimuth, elevation);
    Object::Sphere {
        center_m: [d[0] * range, d[1] * range, d[2] * range],
        radius_m: radius,
        reflectivity: uniform(rng, 0.8, 1.0),
    }
}

/// Downward tilt of terrain and tank poses, degrees: drawn uniformly in this range.
pub const TILT_RANGE_DEG: (f64, f64) = (15.0, 25.0);
/// Range at which the boresight meets flat ground, metres: drawn uniformly in this range.
pub const SLANT_RANGE_M: (f64, f64) = (2.5, 3.0);

impl SonarPose {
    /// Looking down `tilt_deg` from the height at which the boresight meets flat ground at
    /// `slant_m`, headed `yaw_deg`.
    fn looking_down(tilt_deg: f64, slant_m: f64, yaw_deg: f64) -> Self {
        Self {
            position_m: [0.0, 0.0, slant_m * deg_to_rad(tilt_deg).sin()],
            yaw_deg,
            tilt_deg,
        }
    }
}

/// A pose drawn from the tilt and slant ranges, heading within ±`yaw_range` degrees.
fn looking_down(rng: &mut ChaCha8Rng, yaw_range: f64) -> SonarPose {
    let tilt = uniform(rng, TILT_RANGE_DEG.0, TILT_RANGE_DEG.1);
    let slant = uniform(rng, SLANT_RANGE_M.0, SLANT_RANGE_M.1);
    SonarPose::looking_down(tilt, slant, uniform(rng, -yaw_range, yaw_range))
}

/// `simulate --fixed-pose` (a study option): a terrain or tank scene seen from the middle of
/// the drawn ranges (tilt 20°, slant 2.75 m, heading 0), its terrain and objects as drawn.
/// Spheres keep their identity pose.
pub fn fix_pose(scene: &mut Scene) {
    // A sphere's pose is the identity; a site's poses are drawn throughout it.
    if matches!(scene.kind, SceneKind::Sphere | SceneKind::Site) {
        return;
    }
    let middle = |(lo, hi): (f64, f64)| (lo + hi) / 2.0;
    scene.sonar = SonarPose::looking_down(middle(TILT_RANGE_DEG), middle(SLANT_RANGE_M), 0.0);
}

fn draw_terrain(rng: &mut ChaCha8Rng, split: Split) -> (SonarPose, Vec<Object>) {
    let pose = looking_down(rng, 0.0);
    // Train and test read disjoint regions of the noise domain (and different permutations,
    // since the sample seed includes the split), so they never share a terrain.
    let base = match split {
        Split::Train => 0.0,
        Split::Test => 50_000.0,
    };
    let fractal = if rng.random::<bool>() {
        Fractal::HeteroTerrain
    } else {
        Fractal::HybridMultifractal
    };
    let spec = TerrainSpec {
        fractal,
        noise_seed: rng.random::<u64>(),
        noise_offset: [
            base + uniform(rng, 0.0, 10_000.0),
            uniform(rng, 0.0, 10_000.0),
        ],
        frequency_per_m: uniform(rng, 0.4, 1.2),
        octaves: 6,
        lacunarity: 2.0,
        h: uniform(rng, 0.6, 1.0),
        offset: uniform(rng, 0.7, 1.0),
        amplitude_m: uniform(rng, 0.15, 0.5),
        origin_m: [0.3, -2.0],
        points: [236, 201],
        cell_m: 0.02,
        reflectivity: uniform(rng, 0.5, 0.8),
    };
    (pose, vec![Object::Terrain(spec)])
}

fn draw_tank(rng: &mut ChaCha8Rng) -> (SonarPose, Vec<Object>) {
    let pose = looking_down(rng, 10.0);
    let h = pose.position_m[2];
    let far = uniform(rng, 3.0, 5.5);
    let left = uniform(rng, 1.2, 3.0);
    let right = uniform(rng, 1.2, 3.0);
    let wall = |x: f64, y: f64, n: [f64; 3], r: f64| Object::Plane {
        name: "wall".into(),
        point_m: [x, y, 0.0],
        normal: n,
        reflectivity: r,
    };
    let mut objects = vec![
        Object::Plane {
            name: "floor".into(),
            point_m: [0.0; 3],
            normal: [0.0, 0.0, 1.0],
            reflectivity: uniform(rng, 0.25, 0.45),
        },
        wall(far, 0.0, [-1.0, 0.0, 0.0], uniform(rng, 0.5, 0.7)),
        wall(-1.0, 0.0, [1.0, 0.0, 0.0], 0.5),
        wall(0.0, left, [0.0, -1.0, 0.0], uniform(rng, 0.5, 0.7)),
        wall(0.0, -right, [0.0, 1.0, 0.0], uniform(rng, 0.5, 0.7)),
    ];
    let count = rng.random_range(4..=10);
    for _ in 0..count {
        // A spot on the floor inside the footprint of the range window.
        let slant = uniform(rng, config::R_MIN_M + 0.05, config::R_MAX_M - 0.1);
        let ground = (slant * slant - h * h).max(0.25).sqrt();
        let az = deg_to_rad(pose.yaw_deg + uniform(rng, -13.0, 13.0));
        let (x, y) = (ground * az.cos(), ground * az.sin());
        if x > far - 0.3 || y > left - 0.3 || y < -right + 0.3 {
            continue;
        }
        objects.push(draw_tank_object(rng, x, y));
    }
    (pose, objects)
}

/// One of the tank's objects (brick, concrete block or arch) standing on the floor at (x, y),
/// any heading.
fn draw_tank_object(rng: &mut ChaCha8Rng, x: f64, y: f64) -> Object {
    let yaw = uniform(rng, 0.0, 180.0);
    let pick = rng.random::<f64>();
    if pick < 0.4 {
        let s = uniform(rng, 0.9, 1.1);
        let size = if rng.random::<bool>() {
            [0.22 * s, 0.11 * s, 0.065 * s] // flat
        } else {
            [0.22 * s, 0.065 * s, 0.11 * s] // on edge
        };
        Object::Block {
            name: "brick".into(),
            base_center_m: [x, y, 0.0],
            size_m: size,
            yaw_deg: yaw,
            reflectivity: uniform(rng, 0.7, 0.9),
        }
    } else if pick < 0.75 {
        let size = if rng.random::<bool>() {
            [0.39, 0.19, 0.19]
        } else {
            [uniform(rng, 0.25, 0.45), uniform(rng, 0.25, 0.4), 0.15]
        };
        Object::Block {
            name: "concrete_block".into(),
            base_center_m: [x, y, 0.0],
            size_m: size,
            yaw_deg: yaw,
            reflectivity: uniform(rng, 0.8, 1.0),
        }
    } else {
        let span = uniform(rng, 0.35, 0.6);
        let height = uniform(rng, 0.25, 0.4);
        Object::Arch {
            base_center_m: [x, y, 0.0],
            size_m: [span, uniform(rng, 0.15, 0.3), height],
            opening_radius_m: (span / 2.0).min(height) * uniform(rng, 0.5, 0.7),
            yaw_deg: yaw,
            reflectivity: uniform(rng, 0.8, 1.0),
        }
    }
}

/// Floor of the fixed tank `simulate --export-mesh --whole-tank` writes: x, y extent, metres.
pub const WHOLE_TANK_FLOOR_M: [[f64; 2]; 2] = [[-1.0, 6.0], [-3.0, 3.0]];
/// Objects on that floor.
pub const WHOLE_TANK_OBJECTS: usize = 48;
/// Least distance between two objects' centres and from an object's centre to a wall, metres.
pub const WHOLE_TANK_SPACING_M: f64 = 0.6;

/// A fixed tank for a site (`simulate --export-mesh --whole-tank`): the artificial generator's
/// floor, walls and objects, the objects spread over the whole floor rather than inside one
/// sample's range window, so that poses drawn anywhere in the tank see some of them.
pub fn whole_tank(seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(mix64(seed ^ 0x7a4e_5175_7e11_7a2c));
    let [[x0, x1], [y0, y1]] = WHOLE_TANK_FLOOR_M;
    let wall = |point_m: [f64; 3], normal: [f64; 3], reflectivity: f64| Object::Plane {
        name: "wall".into(),
        point_m,
        normal,
        reflectivity,
    };
    let mut objects = vec![
        Object::Plane {
            name: "floor".into(),
            point_m: [0.0; 3],
            normal: [0.0, 0.0, 1.0],
            reflectivity: uniform(&mut rng, 0.25, 0.45),
        },
        wall(
            [x1, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            uniform(&mut rng, 0.5, 0.7),
        ),
        wall([x0, 0.0, 0.0], [1.0, 0.0, 0.0], uniform(&mut rng, 0.5, 0.7)),
        wall(
            [0.0, y1, 0.0],
            [0.0, -1.0, 0.0],
            uniform(&mut rng, 0.5, 0.7),
        ),
        wall([0.0, y0, 0.0], [0.0, 1.0, 0.0], uniform(&mut rng, 0.5, 0.7)),
    ];
    let d = WHOLE_TANK_SPACING_M;
    let mut spots: Vec<[f64; 2]> = Vec::new();
    // Rejection sampling; the floor holds several times the objects at this spacing, so the
    // attempt bound is never the limit in practice, only a guard.
    for _ in 0..100_000 {
        if spots.len() == WHOLE_TANK_OBJECTS {
            break;
        }
        let p = [
            uniform(&mut rng, x0 + d, x1 - d),
            uniform(&mut rng, y0 + d, y1 - d),
        ];
        if spots.iter().all(|q| (p[0] - q[0]).hypot(p[1] - q[1]) >= d) {
            spots.push(p);
        }
    }
    for [x, y] in spots {
        objects.push(draw_tank_object(&mut rng, x, y));
    }
    Scene {
        kind: SceneKind::Artificial,
        split: Split::Train,
        index: 0,
        seed,
        sample_seed: 0,
        sonar: SonarPose::IDENTITY,
        view_rolls_deg: view_rolls_deg(1),
        view_pose_errors_deg: Vec::new(),
        objects,
    }
}

// ---------------------------------------------------------------------------------------------
// Fractal noise

/// 2D gradient (Perlin) noise with a seeded permutation; values roughly in [−1, 1].
#[derive(Clone, Debug)]
pub struct Perlin {
    perm: [u8; 512],
}

impl Perlin {
    /// A noise field whose permutation is shuffled from `seed`.
    pub fn new(seed: u64) -> Self {
        let mut p: Vec<u8> = (0..=255u8).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        for i in (1..256).rev() {
            let j = rng.random_range(0..=i);
            p.swap(i, j);
        }
        let mut perm = [0u8; 512];
        for i in 0..512 {
            perm[i] = p[i & 255];
        }
        Self { perm }
    }

    /// Noise at (x, y).
    pub fn noise(&self, x: f64, y: f64) -> f64 {
        let (fx, fy) = (x.floor(), y.floor());
        let (xi, yi) = ((fx as i64 & 255) as usize, (fy as i64 & 255) as usize);
        let (xf, yf) = (x - fx, y - fy);
        let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
        let (u, v) = (fade(xf), fade(yf));
        let p = &self.perm;
        let h = |i: usize, j: usize| p[p[xi + i] as usize + yi + j];
        let grad = |hash: u8, x: f64, y: f64| match hash & 7 {
            0 => x + y,
            1 => -x + y,
            2 => x - y,
            3 => -x - y,
            4 => x,
            5 => -x,
            6 => y,
            _ => -y,
        };
        let n00 = grad(h(0, 0), xf, yf);
        let n10 = grad(h(1, 0), xf - 1.0, yf);
        let n01 = grad(h(0, 1), xf, yf - 1.0);
        let n11 = grad(h(1, 1), xf - 1.0, yf - 1.0);
        let a = n00 + u * (n10 - n00);
        let b = n01 + u * (n11 - n01);
        a + v * (b - a)
    }
}

/// Musgrave's heterogeneous terrain at (x, y).
pub fn hetero_terrain(n: &Perlin, x: f64, y: f64, s: &TerrainSpec) -> f64 {
    let (mut x, mut y) = (x, y);
    let mut value = s.offset + n.noise(x, y);
    for i in 1..s.octaves {
        x *= s.lacunarity;
        y *= s.lacunarity;
        let increment = (n.noise(x, y) + s.offset) * s.lacunarity.powf(-s.h * i as f64) * value;
        value += increment;
    }
    value
}

/// Musgrave's hybrid multifractal at (x, y).
pub fn hybrid_multifractal(n: &Perlin, x: f64, y: f64, s: &TerrainSpec) -> f64 {
    let (mut x, mut y) = (x, y);
    let mut result = n.noise(x, y) + s.offset;
    let mut weight = result;
    for i in 1..s.octaves {
        x *= s.lacunarity;
        y *= s.lacunarity;
        weight = weight.min(1.0);
        let signal = (n.noise(x, y) + s.offset) * s.lacunarity.powf(-s.h * i as f64);
        result += weight * signal;
        weight *= signal;
    }
    result
}

/// Heights of a terrain's grid, `z[j × points_x + i]` at world
/// `(origin_x + i·cell, origin_y + j·cell)`, normalised to `amplitude_m` peak to peak around 0.
pub fn terrain_heights(s: &TerrainSpec) -> Vec<f64> {
    let n = Perlin::new(s.noise_seed);
    let [nx, ny] = s.points;
    let mut z = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            let wx = (s.origin_m[0] + i as f64 * s.cell_m) * s.frequency_per_m + s.noise_offset[0];
            let wy = (s.origin_m[1] + j as f64 * s.cell_m) * s.frequency_per_m + s.noise_offset[1];
            z.push(match s.fractal {
                Fractal::HeteroTerrain => hetero_terrain(&n, wx, wy, s),
                Fractal::HybridMultifractal => hybrid_multifractal(&n, wx, wy, s),
            });
        }
    }
    let lo = z.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = z.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let span = if hi > lo { hi - lo } else { 1.0 };
    for v in &mut z {
        *v = s.amplitude_m * ((*v - lo) / span - 0.5);
    }
    z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scenes_are_deterministic_and_split_dependent() {
        for kind in [SceneKind::Sphere, SceneKind::Terrain, SceneKind::Artificial] {
            let a = generate(kind, Split::Train, 5, 3, 2);
            let b = generate(kind, Split::Train, 5, 3, 2);
            assert_eq!(a, b);
            let c = generate(kind, Split::Test, 5, 3, 2);
            assert_ne!(a.sample_seed, c.sample_seed);
            let json = serde_json::to_string(&a).unwrap();
            let back: Scene = serde_json::from_str(&json).unwrap();
            assert_eq!(back, a);
        }
    }

    #[test]
    fn train_and_test_terrains_differ() {
        let terrain = |split, index| match generate(SceneKind::Terrain, split, 1, index, 2)
            .objects
            .remove(0)
        {
            Object::Terrain(t) => t,
            other => panic!("not a terrain: {other:?}"),
        };
        for index in 0..5 {
            let (a, b) = (terrain(Split::Train, index), terrain(Split::Test, index));
            assert!(a.noise_offset[0] < 10_000.0 && b.noise_offset[0] >= 50_000.0);
            let (za, zb) = (terrain_heights(&a), terrain_heights(&b));
            assert_eq!(za.len(), zb.len());
            let diff = za
                .iter()
                .zip(&zb)
                .filter(|(x, y)| (*x - *y).abs() > 1e-3)
                .count();
            assert!(diff > za.len() / 2, "terrains {index} nearly equal");
            // Normalised to the drawn amplitude.
            let lo = za.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = za.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert!((hi - lo - a.amplitude_m).abs() < 1e-9);
        }
    }

    #[test]
    fn pose_tilts_down_and_yaws_left() {
        let pose = SonarPose {
            position_m: [0.0, 0.0, 1.0],
            yaw_deg: 90.0,
            tilt_deg: 30.0,
        };
        let f = pose.world_from_reference().rotate([1.0, 0.0, 0.0]);
        assert!(f[0].abs() < 1e-12 && f[1] > 0.8 && (f[2] + 0.5).abs() < 1e-12);
        let up = pose.world_from_reference().rotate([0.0, 0.0, 1.0]);
        assert!(up[2] > 0.8);
    }

    #[test]
    fn whole_tank_spreads_its_objects_over_the_floor() {
        let tank = whole_tank(1);
        assert_eq!(tank, whole_tank(1), "a seed gives one tank");
        assert_ne!(tank.objects, whole_tank(2).objects);
        let spots: Vec<[f64; 2]> = tank
            .objects
            .iter()
            .filter_map(|o| match o {
                Object::Block { base_center_m, .. } | Object::Arch { base_center_m, .. } => {
                    Some([base_center_m[0], base_center_m[1]])
                }
                _ => None,
            })
            .collect();
        assert_eq!(spots.len(), WHOLE_TANK_OBJECTS);
        let [[x0, x1], [y0, y1]] = WHOLE_TANK_FLOOR_M;
        let d = WHOLE_TANK_SPACING_M;
        for (i, p) in spots.iter().enumerate() {
            assert!(p[0] >= x0 + d && p[0] <= x1 - d && p[1] >= y0 + d && p[1] <= y1 - d);
            for q in &spots[..i] {
                assert!((p[0] - q[0]).hypot(p[1] - q[1]) >= d);
            }
        }
        // Spread, not clustered: every quarter of the floor holds some of them.
        let (xm, ym) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
        for (east, north) in [(false, false), (false, true), (true, false), (true, true)] {
            let n = spots
                .iter()
                .filter(|p| (p[0] > xm) == east && (p[1] > ym) == north)
                .count();
            assert!(
                n >= WHOLE_TANK_OBJECTS / 8,
                "quarter ({east}, {north}) holds {n}"
            );
        }
    }
}
