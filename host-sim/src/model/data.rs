//! Simulated sample folders for training and evaluation.
//!
//! `DIR/<split>/<000000>/` holds `polar_view{k}.npy` (f32 R×B, values 0..=255), `depth.npy`
//! and `mask.npy` (f32 E×A). The polar images are rounded and clamped to u8 on load, because the
//! firmware only ever sees u8 images.
//!
//! The `.npy` reader here is a minimal `<f4` C-order reader (NumPy format 1.0–3.0).
// TODO(dedupe): replace with `host_sim::npy` once the simulator branch lands.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, ensure, Context, Result};

/// Reads a little-endian f32 C-order `.npy` file: (shape, values).
pub fn read_npy_f32(path: &Path) -> Result<(Vec<usize>, Vec<f32>)> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse_npy_f32(&bytes).with_context(|| format!("{} is not a <f4 npy file", path.display()))
}

/// Parses the bytes of a little-endian f32 C-order `.npy` file.
pub fn parse_npy_f32(bytes: &[u8]) -> Result<(Vec<usize>, Vec<f32>)> {
    ensure!(
        bytes.len() >= 10 && &bytes[..6] == b"\x93NUMPY",
        "bad magic"
    );
    let (hlen, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            ensure!(bytes.len() >= 12, "truncated header");
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => bail!("unsupported npy version {v}"),
    };
    let header = bytes
        .get(start..start + hlen)
        .ok_or_else(|| anyhow!("truncated header"))?;
    let header = std::str::from_utf8(header)?;
    let field = |key: &str| -> Result<&str> {
        let at = header
            .find(&format!("'{key}'"))
            .ok_or_else(|| anyhow!("header has no {key}"))?;
        let rest = &header[at + key.len() + 2..];
        let colon = rest.find(':').ok_or_else(|| anyhow!("bad header"))?;
        Ok(rest[colon + 1..].trim_start())
    };
    let descr = field("descr")?;
    ensure!(descr.starts_with("'<f4'"), "dtype is not <f4: {descr}");
    ensure!(
        field("fortran_order")?.starts_with("False"),
        "Fortran order"
    );
    let shape_text = field("shape")?;
    let open = shape_text.find('(').ok_or_else(|| anyhow!("bad shape"))?;
    let close = shape_text.find(')').ok_or_else(|| anyhow!("bad shape"))?;
    let shape = shape_text[open + 1..close]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|e| anyhow!("bad shape {s}: {e}"))
        })
        .collect::<Result<Vec<_>>>()?;
    let count: usize = shape.iter().product();
    let data = &bytes[start + hlen..];
    ensure!(
        data.len() == count * 4,
        "{} data bytes for shape {shape:?}",
        data.len()
    );
    let values = data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((shape, values))
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

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(shape: &[usize], values: &[f32]) -> Vec<u8> {
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        let tuple = if dims.len() == 1 {
            format!("({},)", dims[0])
        } else {
            format!("({})", dims.join(", "))
        };
        let mut h = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {tuple}, }}");
        while (10 + h.len() + 1) % 64 != 0 {
            h.push(' ');
        }
        h.push('\n');
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        b.extend((h.len() as u16).to_le_bytes());
        b.extend(h.as_bytes());
        for v in values {
            b.extend(v.to_le_bytes());
        }
        b
    }

    #[test]
    fn npy_round_trip() {
        let vals: Vec<f32> = (0..6).map(|i| i as f32 * 0.5 - 1.0).collect();
        let (s, v) = parse_npy_f32(&npy(&[2, 3], &vals)).unwrap();
        assert_eq!(s, vec![2, 3]);
        assert_eq!(v, vals);
        let (s, _) = parse_npy_f32(&npy(&[6], &vals)).unwrap();
        assert_eq!(s, vec![6]);
    }

    #[test]
    fn npy_rejects_bad_input() {
        let good = npy(&[2, 3], &[0.0; 6]);
        assert!(parse_npy_f32(&good[..good.len() - 1]).is_err());
        assert!(parse_npy_f32(b"\x93NUMPX\x01\x00").is_err());
        let f8 = String::from_utf8_lossy(&good).replace("<f4", "<f8");
        assert!(parse_npy_f32(f8.as_bytes()).is_err());
    }
}
