//! `host-sim qdiag`'s command line.

use std::path::PathBuf;

use epssn_quant::qdiag::QdiagOptions;

/// `host-sim qdiag`.
#[derive(clap::Args, Debug)]
pub struct QdiagArgs {
    /// Weights folder: `model.safetensors`, `quantisation.json` (the activation scales) and the
    /// blob `epssn-s.q8.bin`.
    #[arg(long)]
    pub weights: PathBuf,
    /// Simulated data folder; its `test/` split is used (held out from training and calibration).
    #[arg(long)]
    pub data: PathBuf,
    /// Samples to use (evenly spread over the split).
    #[arg(long, default_value_t = 24)]
    pub limit: usize,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

impl From<QdiagArgs> for QdiagOptions {
    fn from(a: QdiagArgs) -> Self {
        QdiagOptions {
            weights: a.weights,
            data: a.data,
            limit: a.limit,
            json: a.json,
        }
    }
}
