//! `host-sim eval`'s command line.

use std::path::PathBuf;

use epssn_eval::eval::EvalOptions;

/// Arguments of `host-sim eval`.
#[derive(clap::Args, Debug, Clone)]
pub struct EvalArgs {
    /// Weights folder (`model.safetensors`, `spec.json`); default: the model the firmware ships
    /// (`weights/FIRMWARE_WEIGHTS`).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Simulated data folder (its `test/` split if present, else the folder itself).
    #[arg(long)]
    pub data: PathBuf,
    /// Views fed to the model (1 = the reference as its own source); default: the views it was
    /// trained on (`views` in the weights folder's `manifest.json`, else the spec's).
    #[arg(long)]
    pub views: Option<usize>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Use at most this many samples.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Also run the int8 library on the blob in the weights folder (`epssn-s.q8.bin`): its
    /// accuracy and its mean absolute depth difference from the float model.
    #[arg(long)]
    pub int8: bool,
    /// Also report where the all-pixel error comes from: surface, silhouette, empty far and
    /// empty near rays, pooled over the maps (`epssn_sim::metrics::ErrorBreakdown`).
    #[arg(long)]
    pub breakdown: bool,
    /// Also write each sample's float depth map (the f64 reference network's) to
    /// `<DIR>/<sample>/depth_float.npy`: f32 metres, elevation rows × azimuth columns, the
    /// layout `epssn-train predict` writes, so the two float networks can be compared.
    #[arg(long, value_name = "DIR")]
    pub save_depth: Option<PathBuf>,
}

impl From<EvalArgs> for EvalOptions {
    fn from(a: EvalArgs) -> Self {
        EvalOptions {
            weights: a.weights,
            data: a.data,
            views: a.views,
            json: a.json,
            limit: a.limit,
            int8: a.int8,
            breakdown: a.breakdown,
            save_depth: a.save_depth,
        }
    }
}
