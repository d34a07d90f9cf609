//! `host-sim metrics`' command line.

use std::path::PathBuf;

use epssn_sim::metrics::MetricsOptions;

/// `host-sim metrics`: compare two depth maps.
#[derive(clap::Args, Debug)]
pub struct MetricsArgs {
    /// Predicted depth map (.npy float32, E × A metres).
    pub pred: PathBuf,
    /// Ground-truth depth map (.npy float32, E × A metres).
    pub gt: PathBuf,
    /// Mask (.npy float32 0/1); default: ground-truth pixels strictly inside the window.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also write the predicted map's masked points as PLY.
    #[arg(long)]
    pub ply_pred: Option<PathBuf>,
    /// Also write the ground truth's masked points as PLY.
    #[arg(long)]
    pub ply_gt: Option<PathBuf>,
}

impl From<MetricsArgs> for MetricsOptions {
    fn from(a: MetricsArgs) -> Self {
        MetricsOptions {
            pred: a.pred,
            gt: a.gt,
            mask: a.mask,
            json: a.json,
            ply_pred: a.ply_pred,
            ply_gt: a.ply_gt,
        }
    }
}
