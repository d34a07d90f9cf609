//! `host-sim simulate`: draws scenes, renders every view as a one-frame ARIS 3000 recording
//! (one frame per ping with `SonarSimParams::ping_frames`),
//! computes the ground truth and writes the sample folders (format in docs/SIMULATOR.md):
//!
//! ```text
//! DIR/<split>/<000000>/view0.aris view1.aris [view2.aris]
//!                      polar_view0.npy … depth.npy mask.npy elevation.npy scene.json
//!                      preview.png (unless --no-preview)
//! DIR/<split>/sim_params.json   the SonarSimParams used
//! ```
//!
//! Each sample's randomness derives from (seed, scene kind, split, index) only, so the output is
//! byte-identical for the same arguments whatever the thread count.
//!
//! `--site FILE` draws the samples throughout one mesh instead (`crate::site`, docs/SITES.md);
//! `--export-mesh FILE` writes a procedural scene as such a mesh (`crate::tessellate`).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{ensure, Context, Result};
use epssn::config::{DEPTH_COLUMNS, DEPTH_ROWS, INPUT_COLUMNS, INPUT_RANGE_BINS, MAX_VIEWS};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use crate::groundtruth::{elevation_map, polar_image, reference_labels};
use crate::render::{frame_header_posed, render_view, SonarSimParams};
use crate::scene::{fix_pose, generate, Scene, SceneKind, Split};
use crate::site::{Region, Site};
use crate::world::World;
use epssn_aris::aris::write_recording;

/// Everything written for one sample.
#[derive(Clone, Debug)]
pub struct SampleData {
    /// The scene.
    pub scene: Scene,
    /// Per view, the ARIS frame (`samples[sample × 128 + beam]`).
    pub frames: Vec<Vec<u8>>,
    /// Per view, the pings that frame averages (`SonarSimParams::ping_frames`), else empty.
    pub pings: Vec<Vec<Vec<u8>>>,
    /// Per view, the model's polar input (R × B).
    pub polar_views: Vec<Vec<u8>>,
    /// Front depth map of the reference view (E × A metres).
    pub depth: Vec<f32>,
    /// Its mask (0/1).
    pub mask: Vec<f32>,
    /// Elevation map of the reference polar image (R × B radians, NaN where nothing returns).
    pub elevation: Vec<f32>,
}

/// Renders and labels a procedural scene.
pub fn simulate_scene(scene: &Scene, params: &SonarSimParams) -> Result<SampleData> {
    ensure!(
        scene.kind != SceneKind::Site,
        "a site's scene needs its mesh: simulate_site_scene"
    );
    simulate_world(scene, &World::new(scene), params)
}

/// Renders and labels a scene of `site` (the mesh its `scene.json` names).
pub fn simulate_site_scene(
    scene: &Scene,
    site: &Site,
    params: &SonarSimParams,
) -> Result<SampleData> {
    simulate_world(scene, &World::with_site(scene, site)?, params)
}

/// Renders and labels a scene whose ray-casting form is `world`.
pub fn simulate_world(scene: &Scene, world: &World, params: &SonarSimParams) -> Result<SampleData> {
    ensure!(
        (1..=MAX_VIEWS).contains(&scene.view_rolls_deg.len()),
        "a scene needs 1 to {MAX_VIEWS} views, this one has {}",
        scene.view_rolls_deg.len()
    );
    let mut frames = Vec::new();
    let mut pings = Vec::new();
    let mut polar_views = Vec::new();
    let mut elevation = Vec::new();
    for k in 0..scene.view_rolls_deg.len() {
        let view = render_view(scene, world, k, params);
        if k == 0 {
            elevation = elevation_map(&view, params);
        }
        polar_views.push(polar_image(&view.samples, params)?);
        frames.push(view.samples);
        pings.push(view.pings);
    }
    let (depth, mask) = reference_labels(scene, world);
    Ok(SampleData {
        scene: scene.clone(),
        frames,
        pings,
        polar_views,
        depth,
        mask,
        elevation,
    })
}

/// Writes a view's frames (one, or its pings in order) as an ARIS 3000 recording with the
/// view's roll in SonarRoll and RollAbsPosition and its pose error `[pitch, yaw]` as the
/// platform's Pitch and Heading, the frames numbered from 0.
pub fn write_aris(
    path: &Path,
    frames: &[&[u8]],
    roll_deg: f64,
    pose_error_deg: [f64; 2],
    params: &SonarSimParams,
) -> Result<()> {
    let header = frame_header_posed(params, roll_deg, pose_error_deg)?;
    let headers: Vec<_> = (0..frames.len())
        .map(|i| {
            let mut h = header.clone();
            h.frame_index = i as u32;
            h
        })
        .collect();
    let records: Vec<_> = headers.iter().zip(frames).map(|(h, f)| (h, *f)).collect();
    write_recording(path, &records)?;
    Ok(())
}

fn to_f32(v: &[u8]) -> Vec<f32> {
    v.iter().map(|x| *x as f32).collect()
}

/// Writes a sample folder.
pub fn write_sample(
    dir: &Path,
    s: &SampleData,
    params: &SonarSimParams,
    preview: bool,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (k, frame) in s.frames.iter().enumerate() {
        // The pings when they were recorded one by one, else the frame.
        let recorded: Vec<&[u8]> = match s.pings.get(k) {
            Some(pings) if !pings.is_empty() => pings.iter().map(Vec::as_slice).collect(),
            _ => vec![frame],
        };
        write_aris(
            &dir.join(format!("view{k}.aris")),
            &recorded,
            s.scene.view_rolls_deg[k],
            s.scene
                .view_pose_errors_deg
                .get(k)
                .copied()
                .unwrap_or([0.0, 0.0]),
            params,
        )?;
    }
    let polar_shape = [INPUT_RANGE_BINS, INPUT_COLUMNS];
    for (k, p) in s.polar_views.iter().enumerate() {
        epssn_aris::npy::write_f32(
            &dir.join(format!("polar_view{k}.npy")),
            &polar_shape,
            &to_f32(p),
        )?;
    }
    let depth_shape = [DEPTH_ROWS, DEPTH_COLUMNS];
    epssn_aris::npy::write_f32(&dir.join("depth.npy"), &depth_shape, &s.depth)?;
    epssn_aris::npy::write_f32(&dir.join("mask.npy"), &depth_shape, &s.mask)?;
    epssn_aris::npy::write_f32(&dir.join("elevation.npy"), &polar_shape, &s.elevation)?;
    std::fs::write(
        dir.join("scene.json"),
        serde_json::to_string_pretty(&s.scene)? + "\n",
    )
    .with_context(|| format!("writing {}/scene.json", dir.display()))?;
    if preview {
        let img = crate::preview::sample_preview(&s.polar_views, &s.depth, &s.mask);
        crate::preview::save_png(&img, &dir.join("preview.png"))?;
    }
    Ok(())
}

/// Folder of sample `index` under `root/<split>/`.
pub fn sample_dir(root: &Path, split: Split, index: u64) -> PathBuf {
    root.join(split.name()).join(format!("{index:06}"))
}

/// `host-sim simulate`.
#[derive(Debug)]
pub struct SimulateOptions {
    /// Scene family (or `--site`).
    pub scene: Option<SceneKind>,
    /// Draw the samples throughout the site in this mesh file (.stl, .obj, .ply; metres, z up,
    /// wound counter-clockwise seen from the water): docs/SITES.md.
    pub site: Option<PathBuf>,
    /// Where in the site poses are drawn (JSON, docs/SITES.md); default: the mesh's bounds less
    /// 0.3 m, at the procedural scenes' tilts and slant ranges, any heading.
    pub region: Option<PathBuf>,
    /// Acoustic reflectivity of the site's every triangle; default 0.6.
    pub site_reflectivity: Option<f64>,
    /// Write the scene of sample 0 (of `--seed`, `--split`) as a mesh to this file (.stl
    /// binary, .obj, .ply ASCII) instead of simulating: the tank's floor and walls and its
    /// objects, in its world frame.
    pub export_mesh: Option<PathBuf>,
    /// With `--export-mesh` and `--scene artificial`: instead of sample 0's scene, a fixed tank
    /// for a site, its objects spread over the whole floor (`scene::whole_tank` of `--seed`).
    pub whole_tank: bool,
    /// Number of samples; default: the paper's size of the split (artificial 4000/2000,
    /// terrain 1000/1000, sphere 1000/500).
    pub pairs: Option<usize>,
    /// Dataset seed.
    pub seed: u64,
    /// Output root; samples go to `OUT/<split>/<000000>/`.
    pub out: Option<PathBuf>,
    /// Split.
    pub split: Split,
    /// Views per sample, reference included (2 or 3).
    pub views: u8,
    /// Skip the PNG previews.
    pub no_preview: bool,
    /// SonarSimParams as JSON (missing fields keep their defaults); default: the defaults.
    pub params: Option<PathBuf>,
    /// Tilt every source view's forward axis by exactly this many degrees in a random
    /// direction (pitch = D·cos φ, yaw = D·sin φ, φ uniform per view from the sample's seed):
    /// rendered so, and written into the view's frame header and `scene.json` (docs/POSE.md).
    pub pose_jitter_deg: f64,
    /// Which axes the pose error turns: both (a random direction), or only pitch or only yaw
    /// (the sign random), to tell their effects apart.
    pub pose_jitter_axes: JitterAxes,
    /// Study option: every terrain and tank sample seen from one pose, the middle of the drawn
    /// ranges (tilt 20°, boresight meeting flat ground at 2.75 m, heading 0); the terrain and
    /// the objects stay as drawn. Measures what the pose's spread costs (docs/ACCURACY.md).
    pub fixed_pose: bool,
}

/// Axes of `--pose-jitter-deg`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JitterAxes {
    /// Pitch and yaw, direction uniform.
    Both,
    /// Pitch only.
    Pitch,
    /// Yaw only.
    Yaw,
}

/// Adds `jitter_deg` of pose error about `axes` to every source view of `scene` (none when 0).
pub fn jitter_pose(scene: &mut Scene, jitter_deg: f64, axes: JitterAxes) {
    if jitter_deg == 0.0 {
        return;
    }
    use rand::{RngExt, SeedableRng};
    // A stream of its own, so the scene and the rendering noise stay those of the unjittered
    // sample: only the pose differs between jitter levels.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(crate::scene::mix64(
        scene.sample_seed ^ 0x706f_7365_0000_0000,
    ));
    scene.view_pose_errors_deg = (0..scene.view_rolls_deg.len())
        .map(|k| {
            let mut phi = std::f64::consts::TAU * rng.random::<f64>();
            // One axis: the same draw picks the sign.
            let half = if phi.cos() >= 0.0 {
                0.0
            } else {
                std::f64::consts::PI
            };
            match axes {
                JitterAxes::Both => {}
                JitterAxes::Pitch => phi = half,
                JitterAxes::Yaw => phi = half + std::f64::consts::FRAC_PI_2,
            }
            if k == 0 {
                [0.0, 0.0]
            } else {
                [jitter_deg * phi.cos(), jitter_deg * phi.sin()]
            }
        })
        .collect();
}

/// Reflectivity of a site's triangles without `--site-reflectivity`: between the tank's floor
/// (0.25–0.45) and its objects (0.7–1.0).
pub const SITE_REFLECTIVITY: f64 = 0.6;

/// `simulate --export-mesh FILE`: writes sample 0's scene as a mesh.
fn export_mesh(kind: SceneKind, args: &SimulateOptions, path: &Path) -> Result<()> {
    let format = crate::mesh::MeshFormat::from_path(path)?;
    let scene = if args.whole_tank {
        ensure!(
            kind == SceneKind::Artificial,
            "--whole-tank exports the artificial generator's tank: give --scene artificial"
        );
        crate::scene::whole_tank(args.seed)
    } else {
        generate(kind, args.split, args.seed, 0, args.views as usize)
    };
    let mesh = crate::tessellate::scene_mesh(&scene)?;
    let bytes = crate::mesh::to_bytes(&mesh, format);
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::write(path, &bytes).with_context(|| format!("writing {}", path.display()))?;
    let what = if args.whole_tank {
        format!("the whole tank of seed {}", args.seed)
    } else {
        format!("{kind:?} seed {} {} sample 0", args.seed, args.split.name())
    };
    eprintln!(
        "wrote {} triangles ({} bytes, SHA-256 {}) of {what} to {}",
        mesh.triangles.len(),
        bytes.len(),
        crate::mesh::content_hash(&bytes),
        path.display()
    );
    Ok(())
}

/// The checks `simulate` makes on a parameter file before rendering anything.
pub fn check_params(params: &SonarSimParams) -> Result<()> {
    ensure!(
        params.samples_per_beam > 0 && params.sample_period_us > 0,
        "sim params: samples_per_beam and sample_period_us must be positive"
    );
    ensure!(
        params.dynamic_range_db.is_finite()
            && params.dynamic_range_db > 0.0
            && params.dynamic_range_db <= 200.0,
        "sim params: dynamic_range_db must be within (0, 200]"
    );
    ensure!(
        params.noise_looks.is_finite() && (0.0..=1e6).contains(&params.noise_looks),
        "sim params: noise_looks must be within 0..=1e6 (0: the floor shares speckle_looks)"
    );
    ensure!(
        params.pulse_sigma_samples.is_finite() && params.pulse_sigma_samples > 0.0,
        "sim params: pulse_sigma_samples must be positive"
    );
    ensure!(
        params.sidelobe.is_finite() && (0.0..=10.0).contains(&params.sidelobe),
        "sim params: sidelobe must be within 0..=10"
    );
    ensure!(
        params.noise_floor_db_per_m.is_finite() && params.noise_floor_db_per_m.abs() <= 100.0,
        "sim params: noise_floor_db_per_m must be within -100..=100"
    );
    ensure!(
        params.noise_looks == 0.0 || !params.ping_frames,
        "sim params: noise_looks cannot be combined with ping_frames"
    );
    Ok(())
}

/// Runs `host-sim simulate`.
pub fn run(args: &SimulateOptions) -> Result<()> {
    let site = args.site.as_deref().map(Site::load).transpose()?;
    let kind = match (&site, args.scene) {
        (Some(_), _) => SceneKind::Site,
        (None, Some(kind)) => kind,
        (None, None) => anyhow::bail!("give --scene or --site"),
    };
    if let Some(path) = &args.export_mesh {
        return export_mesh(kind, args, path);
    }
    ensure!(
        site.is_some() || (args.region.is_none() && args.site_reflectivity.is_none()),
        "--region and --site-reflectivity need --site"
    );
    let region = match &args.region {
        Some(p) => Region::load(p)?,
        None => Region::default(),
    };
    let site_reflectivity = args.site_reflectivity.unwrap_or(SITE_REFLECTIVITY);
    ensure!(
        site_reflectivity.is_finite() && site_reflectivity > 0.0 && site_reflectivity <= 1.0,
        "--site-reflectivity must be within (0, 1]"
    );
    let out = args.out.as_deref().context("give --out")?;
    let (train, test) = kind.paper_split_sizes();
    let pairs = args.pairs.unwrap_or(match args.split {
        Split::Train => train,
        Split::Test => test,
    });
    let params: SonarSimParams = match &args.params {
        Some(p) => serde_json::from_str(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
        )
        .with_context(|| format!("parsing {}", p.display()))?,
        None => SonarSimParams::default(),
    };
    ensure!(
        args.pose_jitter_deg.is_finite() && (0.0..=30.0).contains(&args.pose_jitter_deg),
        "--pose-jitter-deg must be within 0..=30"
    );
    check_params(&params)?;
    let split_dir = out.join(args.split.name());
    std::fs::create_dir_all(&split_dir)
        .with_context(|| format!("creating {}", split_dir.display()))?;
    std::fs::write(
        split_dir.join("sim_params.json"),
        serde_json::to_string_pretty(&params)? + "\n",
    )?;
    let pb = ProgressBar::new(pairs as u64);
    pb.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} samples  {elapsed_precise} eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let start = std::time::Instant::now();
    let done = AtomicUsize::new(0);
    (0..pairs as u64)
        .into_par_iter()
        .try_for_each(|i| -> Result<()> {
            let views = args.views as usize;
            let mut scene = match &site {
                Some(site) => crate::site::generate(
                    site,
                    &region,
                    site_reflectivity,
                    args.split,
                    args.seed,
                    i,
                    views,
                )?,
                None => generate(kind, args.split, args.seed, i, views),
            };
            jitter_pose(&mut scene, args.pose_jitter_deg, args.pose_jitter_axes);
            if args.fixed_pose {
                fix_pose(&mut scene);
            }
            let data = match &site {
                Some(site) => simulate_site_scene(&scene, site, &params)?,
                None => simulate_scene(&scene, &params)?,
            };
            write_sample(
                &sample_dir(out, args.split, i),
                &data,
                &params,
                !args.no_preview,
            )?;
            done.fetch_add(1, Ordering::Relaxed);
            pb.inc(1);
            Ok(())
        })?;
    pb.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    eprintln!(
        "wrote {} {:?} samples to {} in {:.2} s ({:.1} samples/s)",
        done.load(Ordering::Relaxed),
        kind,
        split_dir.display(),
        secs,
        pairs as f64 / secs.max(1e-9)
    );
    Ok(())
}
