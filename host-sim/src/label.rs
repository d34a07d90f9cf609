//! `host-sim label`: ground truth for a recording from the mesh of its site and the sonar's pose
//! at every frame (`poses.csv`, `epssn_sim::poses`). For every group `run` forms from the
//! recording it writes the reference view's depth and mask as `run --gt` reads them
//! (`DIR/depth_<frame>.npy`, `DIR/mask_<frame>.npy`), rendered by the code that labels a
//! simulated sample (docs/SITES.md, "Labelling a real recording").

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use epssn::config;
use epssn_aris::npy;
use epssn_sim::poses;
use epssn_sim::site::Site;

use crate::pairing::{blob_views, pair_recording, PairingOptions};

/// Options of `host-sim label`.
#[derive(Debug)]
pub struct LabelOptions {
    /// ARIS recording to label.
    pub recording: PathBuf,
    /// The site's mesh (.stl, .obj, .ply; metres, z up: docs/SITES.md).
    pub site: PathBuf,
    /// The sonar's pose at each frame in the site frame (CSV: frame, x_m, y_m, z_m, roll_deg,
    /// pitch_deg, yaw_deg; docs/SITES.md).
    pub poses: PathBuf,
    /// Output folder for `depth_<frame>.npy` and `mask_<frame>.npy` (`run --gt DIR`).
    pub out: PathBuf,
    /// The weights, views and pairing `run` will be given: they decide its reference frames.
    pub pairing: PairingOptions,
}

/// One reference frame's label, named as `run --gt` looks it up.
struct Label {
    frame: usize,
    depth: Vec<f32>,
    mask: Vec<f32>,
}

/// Runs `host-sim label`.
pub fn label(args: &LabelOptions, out: &mut impl Write) -> Result<()> {
    let weights_dir = args.pairing.weights_dir()?;
    let pairing = pair_recording(
        &args.pairing,
        blob_views(&weights_dir)?,
        &weights_dir,
        &args.recording,
    )?;
    let rows = poses::load(&args.poses, pairing.reader.frame_count())?;
    let site = Site::load(&args.site)?;
    let references: Vec<usize> = pairing.groups.iter().map(|g| g[0]).collect();
    let missing: Vec<String> = references
        .iter()
        .filter(|f| !rows.contains_key(f))
        .map(usize::to_string)
        .collect();
    ensure!(
        missing.is_empty(),
        "{} has no row for frame(s) {}, which run uses as reference view(s) of {}",
        args.poses.display(),
        missing.join(", "),
        args.recording.display()
    );
    let mut labels = Vec::with_capacity(references.len());
    for &frame in &references {
        let (depth, mask) = rows[&frame]
            .label(&site)
            .with_context(|| format!("labelling frame {frame}"))?;
        labels.push(Label { frame, depth, mask });
    }
    write_labels(&args.out, &labels)?;
    for w in &pairing.warnings {
        writeln!(out, "warning: {w}")?;
    }
    writeln!(
        out,
        "labelled {} reference view(s) of {} (frames {}) from site {} ({} triangles) into {}",
        labels.len(),
        args.recording.display(),
        references
            .iter()
            .map(usize::to_string)
            .collect::<Vec<_>>()
            .join(", "),
        site.file,
        site.mesh.len(),
        args.out.display()
    )?;
    Ok(())
}

/// Writes every label under a temporary name, then renames them all: a failed run leaves no
/// file under a name `run --gt` reads.
fn write_labels(dir: &Path, labels: &[Label]) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let shape = [config::DEPTH_ROWS, config::DEPTH_COLUMNS];
    let mut staged = Vec::new();
    let result = (|| -> Result<()> {
        for l in labels {
            for (name, data) in [("depth", &l.depth), ("mask", &l.mask)] {
                let file = format!("{name}_{:04}.npy", l.frame);
                let tmp = dir.join(format!(".{file}.partial"));
                staged.push((tmp.clone(), dir.join(&file)));
                npy::write_f32(&tmp, &shape, data)
                    .with_context(|| format!("writing {}", tmp.display()))?;
            }
        }
        Ok(())
    })();
    if let Err(e) = result {
        for (tmp, _) in &staged {
            let _ = std::fs::remove_file(tmp);
        }
        return Err(e);
    }
    for (tmp, file) in &staged {
        std::fs::rename(tmp, file).with_context(|| format!("writing {}", file.display()))?;
    }
    Ok(())
}
