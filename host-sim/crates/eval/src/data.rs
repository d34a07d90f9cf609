//! Simulated sample folders for training and evaluation.
//!
//! `DIR/<split>/<000000>/` holds `polar_view{k}.npy` (f32 R×B, values 0..=255), `depth.npy`
//! and `mask.npy` (f32 E×A). The polar images are rounded and clamped to u8 on load, because the
//! firmware only ever sees u8 images.
//!
//! Arrays are read with [`epssn_aris::npy`].

use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};

/// Reads a little-endian f32 C-order `.npy` file: (shape, values).
pub fn read_npy_f32(path: &Path) -> Result<(Vec<usize>, Vec<f32>)> {
    let a = epssn_aris::npy::read_f32(path)?;
    Ok((a.shape, a.data))
}

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

fn load_2d(path: &Path, shape: [usize; 2]) -> Result<Vec<f32>> {
    let (s, v) = read_npy_f32(path)?;
    ensure!(
        s == shape,
        "{} has shape {s:?}, expected {shape:?}",
        path.display()
    );
    Ok(v)
}

/// Loads one sample folder with `views` views (1 loads only the reference).
pub fn load_sample(
    dir: &Path,
    views: usize,
    input: (usize, usize),
    output: (usize, usize),
) -> Result<Sample> {
    let mut imgs = Vec::new();
    for k in 0..views {
        let v = load_2d(&dir.join(format!("polar_view{k}.npy")), [input.0, input.1])?;
        imgs.push(
            v.iter()
                .map(|&x| x.round().clamp(0.0, 255.0) as u8)
                .collect(),
        );
    }
    Ok(Sample {
        views: imgs,
        depth: load_2d(&dir.join("depth.npy"), [output.0, output.1])?,
        mask: load_2d(&dir.join("mask.npy"), [output.0, output.1])?,
        dir: dir.to_path_buf(),
    })
}

/// Sample folders of `dir` (sub-folders holding `polar_view0.npy`), sorted by name.
pub fn sample_dirs(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot list {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("polar_view0.npy").is_file())
        .collect();
    v.sort();
    Ok(v)
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
    let mut dirs = sample_dirs(dir)?;
    if let Some(l) = limit {
        dirs.truncate(l);
    }
    dirs.iter()
        .map(|d| load_sample(d, views, input, output))
        .collect()
}
