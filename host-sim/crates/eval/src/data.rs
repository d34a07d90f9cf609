//! Simulated sample folders for training and evaluation, as the network takes them.
//!
//! `DIR/<split>/<000000>/` holds `polar_view{k}.npy` (f32 R×B, values 0..=255), `depth.npy`
//! and `mask.npy` (f32 E×A). The folders are read by [`epssn_sim::dataset`] (the one reader of
//! sample folders), at the shapes of the spec being trained or evaluated; the polar images are
//! rounded and clamped to u8 on load, because the firmware only ever sees u8 images.

use std::path::{Path, PathBuf};

use anyhow::Result;
use epssn_sim::dataset::{polar_u8, sample_dirs_in, Arrays};

/// One training / evaluation sample.
#[derive(Clone, Debug)]
pub struct Sample {
    /// Polar images R×B u8, reference first.
    pub views: Vec<Vec<u8>>,
    /// Ground-truth front depth E×A, metres.
    pub depth: Vec<f32>,
    /// 1 where the first hit lies inside the window, else 0 (E×A).
    pub mask: Vec<f32>,
    /// Folder it came from.
    pub dir: PathBuf,
}

/// Loads one sample folder with `views` views (1 loads only the reference).
pub fn load_sample(
    dir: &Path,
    views: usize,
    input: (usize, usize),
    output: (usize, usize),
) -> Result<Sample> {
    let a = Arrays::load(dir, views, [input.0, input.1], [output.0, output.1])?;
    Ok(Sample {
        views: a.polar_views.iter().map(|v| polar_u8(v)).collect(),
        depth: a.depth,
        mask: a.mask,
        dir: dir.to_path_buf(),
    })
}

/// The folder of `split` under `data` (`data/<split>`), if it exists.
pub fn split_dir(data: &Path, split: &str) -> Option<PathBuf> {
    let p = data.join(split);
    p.is_dir().then_some(p)
}

/// Loads every sample of a folder (at most `limit`).
pub fn load_dir(
    dir: &Path,
    views: usize,
    input: (usize, usize),
    output: (usize, usize),
    limit: Option<usize>,
) -> Result<Vec<Sample>> {
    let mut dirs = sample_dirs_in(dir)?;
    if let Some(l) = limit {
        dirs.truncate(l);
    }
    dirs.iter()
        .map(|d| load_sample(d, views, input, output))
        .collect()
}
