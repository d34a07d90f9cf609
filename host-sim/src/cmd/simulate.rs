//! `host-sim simulate`'s command line, and the scene families and splits as `--scene` and
//! `--split` name them (`fit-sensor` takes them too).

use std::path::PathBuf;

use epssn_sim::scene::{SceneKind, Split};
use epssn_sim::simulate::{JitterAxes, SimulateOptions};

/// `host-sim simulate`.
#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Scene family (or `--site`).
    #[arg(long, value_enum, required_unless_present = "site")]
    pub scene: Option<SceneKindArg>,
    /// Draw the samples throughout the site in this mesh file (.stl, .obj, .ply; metres, z up,
    /// wound counter-clockwise seen from the water): docs/SITES.md.
    #[arg(long, conflicts_with_all = ["scene", "fixed_pose"])]
    pub site: Option<PathBuf>,
    /// Where in the site poses are drawn (JSON, docs/SITES.md); default: the mesh's bounds less
    /// 0.3 m, at the procedural scenes' tilts and slant ranges, any heading.
    #[arg(long, requires = "site")]
    pub region: Option<PathBuf>,
    /// Acoustic reflectivity of the site's every triangle; default 0.6.
    #[arg(long, requires = "site")]
    pub site_reflectivity: Option<f64>,
    /// Write the scene of sample 0 (of `--seed`, `--split`) as a mesh to this file (.stl
    /// binary, .obj, .ply ASCII) instead of simulating: the tank's floor and walls and its
    /// objects, in its world frame.
    #[arg(long, requires = "scene")]
    pub export_mesh: Option<PathBuf>,
    /// With `--export-mesh` and `--scene artificial`: instead of sample 0's scene, a fixed tank
    /// for a site, its objects spread over the whole floor (`scene::whole_tank` of `--seed`).
    #[arg(long, requires = "export_mesh")]
    pub whole_tank: bool,
    /// Number of samples; default: the paper's size of the split (artificial 4000/2000,
    /// terrain 1000/1000, sphere 1000/500).
    #[arg(long)]
    pub pairs: Option<usize>,
    /// Dataset seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output root; samples go to `OUT/<split>/<000000>/`.
    #[arg(long, required_unless_present = "export_mesh")]
    pub out: Option<PathBuf>,
    /// Split.
    #[arg(long, value_enum, default_value_t = SplitArg::Train)]
    pub split: SplitArg,
    /// Views per sample, reference included (2 or 3).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(2..=3))]
    pub views: u8,
    /// Skip the PNG previews.
    #[arg(long)]
    pub no_preview: bool,
    /// SonarSimParams as JSON (missing fields keep their defaults); default: the defaults.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Tilt every source view's forward axis by exactly this many degrees in a random
    /// direction (pitch = D·cos φ, yaw = D·sin φ, φ uniform per view from the sample's seed):
    /// rendered so, and written into the view's frame header and `scene.json` (docs/POSE.md).
    #[arg(long, default_value_t = 0.0)]
    pub pose_jitter_deg: f64,
    /// Which axes the pose error turns: both (a random direction), or only pitch or only yaw
    /// (the sign random), to tell their effects apart.
    #[arg(long, value_enum, default_value_t = JitterAxesArg::Both)]
    pub pose_jitter_axes: JitterAxesArg,
    /// Study option: every terrain and tank sample seen from one pose, the middle of the drawn
    /// ranges (tilt 20°, boresight meeting flat ground at 2.75 m, heading 0); the terrain and
    /// the objects stay as drawn. Measures what the pose's spread costs (docs/ACCURACY.md).
    #[arg(long)]
    pub fixed_pose: bool,
}

impl From<SimulateArgs> for SimulateOptions {
    fn from(a: SimulateArgs) -> Self {
        SimulateOptions {
            scene: a.scene.map(Into::into),
            site: a.site,
            region: a.region,
            site_reflectivity: a.site_reflectivity,
            export_mesh: a.export_mesh,
            whole_tank: a.whole_tank,
            pairs: a.pairs,
            seed: a.seed,
            out: a.out,
            split: a.split.into(),
            views: a.views,
            no_preview: a.no_preview,
            params: a.params,
            pose_jitter_deg: a.pose_jitter_deg,
            pose_jitter_axes: a.pose_jitter_axes.into(),
            fixed_pose: a.fixed_pose,
        }
    }
}

/// The scene families `--scene` names (a site is `--site`, not a family).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SceneKindArg {
    /// One sphere at a random position inside the view, nothing else.
    Sphere,
    /// A seabed heightfield from fractal noise.
    Terrain,
    /// A water tank (floor, walls) with bricks, concrete blocks and arches.
    Artificial,
}

impl From<SceneKindArg> for SceneKind {
    fn from(k: SceneKindArg) -> Self {
        match k {
            SceneKindArg::Sphere => SceneKind::Sphere,
            SceneKindArg::Terrain => SceneKind::Terrain,
            SceneKindArg::Artificial => SceneKind::Artificial,
        }
    }
}

/// Dataset split.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SplitArg {
    /// Training split.
    Train,
    /// Test split.
    Test,
}

impl From<SplitArg> for Split {
    fn from(s: SplitArg) -> Self {
        match s {
            SplitArg::Train => Split::Train,
            SplitArg::Test => Split::Test,
        }
    }
}

/// Axes of `--pose-jitter-deg`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum JitterAxesArg {
    /// Pitch and yaw, direction uniform.
    Both,
    /// Pitch only.
    Pitch,
    /// Yaw only.
    Yaw,
}

impl From<JitterAxesArg> for JitterAxes {
    fn from(a: JitterAxesArg) -> Self {
        match a {
            JitterAxesArg::Both => JitterAxes::Both,
            JitterAxesArg::Pitch => JitterAxes::Pitch,
            JitterAxesArg::Yaw => JitterAxes::Yaw,
        }
    }
}
