//! Reading simulated sample folders (written by `host-sim simulate`, format in docs/SIMULATOR.md).
//!
//! ```no_run
//! use epssn_sim::dataset::{sample_dirs, Sample};
//! use epssn_sim::scene::Split;
//!
//! for dir in sample_dirs("data/sim/sphere".as_ref(), Split::Train)? {
//!     let s = Sample::load(&dir)?;
//!     assert_eq!(s.polar_views.len(), s.scene.view_rolls_deg.len());
//!     let _input_u8 = s.polar_views_u8(); // what the firmware sees
//! }
//! # Ok::<(), anyhow::Error>(())
//! ```

use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use epssn::config::{DEPTH_COLUMNS, DEPTH_ROWS, INPUT_COLUMNS, INPUT_RANGE_BINS};

use crate::scene::{Scene, Split};
use epssn_aris::npy::read_f32;

/// The bundled demo: a simulated ARIS 3000 recording and its ground truth.
pub fn demo_dir() -> PathBuf {
    epssn_spec::load::repo_root().join("data/demo")
}

/// One loaded sample.
#[derive(Clone, Debug)]
pub struct Sample {
    /// Folder it was read from.
    pub dir: PathBuf,
    /// The scene (`scene.json`), including each view's roll.
    pub scene: Scene,
    /// Per view (reference first), the polar input image R × B (`img[i × B + k]`), values
    /// 0..=255 as f32.
    pub polar_views: Vec<Vec<f32>>,
    /// Front depth map of the reference view, E × A metres (`depth[e × A + a]`).
    pub depth: Vec<f32>,
    /// Mask, E × A, 1.0 where the first hit lies inside the window.
    pub mask: Vec<f32>,
    /// Elevation map, R × B radians (NaN where nothing returns).
    pub elevation: Vec<f32>,
}

/// Reads a sample's 2-D f32 array, refused unless its shape is `shape`.
pub fn load_checked(path: &Path, shape: [usize; 2]) -> Result<Vec<f32>> {
    let a = read_f32(path)?;
    ensure!(
        a.shape == shape,
        "{}: shape {:?}, expected {:?}",
        path.display(),
        a.shape,
        shape
    );
    Ok(a.data)
}

impl Sample {
    /// Loads a sample folder, checking every array's shape against the compiled configuration.
    pub fn load(dir: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(dir.join("scene.json"))
            .with_context(|| format!("reading {}/scene.json", dir.display()))?;
        let scene: Scene = serde_json::from_str(&text)
            .with_context(|| format!("parsing {}/scene.json", dir.display()))?;
        let polar_shape = [INPUT_RANGE_BINS, INPUT_COLUMNS];
        let depth_shape = [DEPTH_ROWS, DEPTH_COLUMNS];
        let arrays = Arrays::load(dir, scene.view_rolls_deg.len(), polar_shape, depth_shape)?;
        Ok(Self {
            dir: dir.to_path_buf(),
            polar_views: arrays.polar_views,
            depth: arrays.depth,
            mask: arrays.mask,
            elevation: load_checked(&dir.join("elevation.npy"), polar_shape)?,
            scene,
        })
    }

    /// The polar views as u8 (the model's integer input).
    pub fn polar_views_u8(&self) -> Vec<Vec<u8>> {
        self.polar_views.iter().map(|v| polar_u8(v)).collect()
    }

    /// The mask as booleans.
    pub fn mask_bool(&self) -> Vec<bool> {
        crate::metrics::mask_from_f32(&self.mask)
    }
}

/// A sample folder's model arrays: its first views' polar images, the reference view's depth
/// and mask, each checked against the shapes given (the build's, or a training spec's).
#[derive(Clone, Debug)]
pub struct Arrays {
    /// Polar images R × B, values 0..=255 as f32, reference first.
    pub polar_views: Vec<Vec<f32>>,
    /// Front depth map E × A, metres.
    pub depth: Vec<f32>,
    /// Mask E × A, 1.0 where the first hit lies inside the window.
    pub mask: Vec<f32>,
}

impl Arrays {
    /// Loads `polar_view{k}.npy` for k < `views` (1 loads only the reference), `depth.npy` and
    /// `mask.npy` from `dir`.
    pub fn load(dir: &Path, views: usize, polar: [usize; 2], depth: [usize; 2]) -> Result<Self> {
        let polar_views = (0..views)
            .map(|k| load_checked(&dir.join(format!("polar_view{k}.npy")), polar))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            polar_views,
            depth: load_checked(&dir.join("depth.npy"), depth)?,
            mask: load_checked(&dir.join("mask.npy"), depth)?,
        })
    }
}

/// A polar image as the model's u8 input: rounded and clamped, as the firmware only ever sees
/// u8 images.
pub fn polar_u8(v: &[f32]) -> Vec<u8> {
    v.iter()
        .map(|x| x.round().clamp(0.0, 255.0) as u8)
        .collect()
}

/// Sample folders of `root/<split>/`, sorted by index (six-digit names only).
pub fn sample_dirs(root: &Path, split: Split) -> Result<Vec<PathBuf>> {
    let dir = root.join(split.name());
    let mut out = Vec::new();
    for entry in std::fs::read_dir(&dir).with_context(|| format!("listing {}", dir.display()))? {
        let entry = entry?;
        let name = entry.file_name();
        let name = name.to_string_lossy();
        // `Path::is_dir` follows symbolic links: a mixed dataset links other splits' samples.
        if entry.path().is_dir() && name.len() == 6 && name.bytes().all(|b| b.is_ascii_digit()) {
            out.push(entry.path());
        }
    }
    out.sort();
    Ok(out)
}

/// Sample folders of `dir` (sub-folders holding `polar_view0.npy`, whatever their names),
/// sorted by name.
pub fn sample_dirs_in(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot list {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("polar_view0.npy").is_file())
        .collect();
    v.sort();
    Ok(v)
}
