//! `host-sim quantise`'s command line.

use std::path::PathBuf;

use epssn_quant::calibration::SearchPixels;
use epssn_quant::quantise::QuantiseOptions;

/// `host-sim quantise`: float weights + calibration data → blob and manifest.
#[derive(clap::Args, Debug)]
pub struct QuantiseArgs {
    /// Quantise the trained model in this weights folder (`model.safetensors`); the blob and
    /// `quantisation.json` are written beside it unless `--out` says otherwise.
    #[arg(long, conflicts_with = "random_init")]
    pub weights: Option<PathBuf>,
    /// Calibration data: simulated sample folders (`DIR/train/...`); training data only, so
    /// that accuracy figures on the test split stay held-out.
    #[arg(long, requires = "weights")]
    pub calib: Option<PathBuf>,
    /// Quantise an untrained, He-initialised model with this seed (for bit-exactness runs and
    /// benchmarks before trained weights exist), calibrated on synthetic images.
    #[arg(long)]
    pub random_init: Option<u64>,
    /// Number of calibration inputs.
    #[arg(long, default_value_t = 32)]
    pub calibration_samples: usize,
    /// Activation range = this percentile of |x| over the calibration inputs (100 = max).
    #[arg(long, default_value_t = 100.0)]
    pub percentile: f64,
    /// Choose each tensor's percentile by scoring candidate blobs with the int8 library on the
    /// calibration samples (`--percentile` is the starting point); see `calibration.rs`.
    #[arg(long, requires = "weights")]
    pub search: bool,
    /// Sweeps of the per-tensor search.
    #[arg(long, default_value_t = 1)]
    pub search_passes: usize,
    /// Depth pixels the search scores |int8 − float| on: the ground-truth mask (surfaces in the
    /// window), or all pixels, as the paper's MAE counts them (rays that meet nothing too).
    #[arg(long, value_enum, default_value_t = SearchPixelsArg::Mask)]
    pub search_pixels: SearchPixelsArg,
    /// Take every activation scale from this folder's `quantisation.json` instead of
    /// calibrating: for a model trained quantisation-aware on those scales (`train
    /// --fake-quant`), whose activations were clipped and rounded to them.
    #[arg(long, requires = "weights", conflicts_with_all = ["search", "random_init"])]
    pub ranges_from: Option<PathBuf>,
    /// Output folder for the blob and `quantisation.json`.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Re-stamp the blob in this folder for the current spec instead of quantising: only the
    /// spec CRC (header offset 12) and the blob CRC change, every tensor byte stays, and
    /// `quantisation.json`'s `spec_hash` and `blob_crc32` follow. For spec edits that change
    /// no size, table or weight (e.g. a pairing tolerance); the build refuses others anyway.
    #[arg(long, conflicts_with_all = ["weights", "random_init"])]
    pub restamp: Option<PathBuf>,
    /// Write this no-return threshold τ (0 to 1; 0: no decision) into the blob in place of
    /// the spec's `no_return_mass`: a calibration of the trained model, chosen on validation
    /// data (the `no_return_sweep` example). With `--restamp`, into that folder's blob, every
    /// other tensor byte kept.
    #[arg(long, conflicts_with = "random_init")]
    pub no_return_mass: Option<f64>,
}

impl From<QuantiseArgs> for QuantiseOptions {
    fn from(a: QuantiseArgs) -> Self {
        QuantiseOptions {
            weights: a.weights,
            calib: a.calib,
            random_init: a.random_init,
            calibration_samples: a.calibration_samples,
            percentile: a.percentile,
            search: a.search,
            search_passes: a.search_passes,
            search_pixels: a.search_pixels.into(),
            ranges_from: a.ranges_from,
            out: a.out,
            restamp: a.restamp,
            no_return_mass: a.no_return_mass,
        }
    }
}

/// Which depth pixels the per-tensor search scores.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SearchPixelsArg {
    /// The ground-truth mask: rays that meet a surface inside the window.
    Mask,
    /// Every pixel of the depth map, as the paper's MAE: on sphere scenes 90 % of the rays
    /// meet nothing and read r_max, and their int8 error counts as much.
    All,
}

impl From<SearchPixelsArg> for SearchPixels {
    fn from(p: SearchPixelsArg) -> Self {
        match p {
            SearchPixelsArg::Mask => SearchPixels::Mask,
            SearchPixelsArg::All => SearchPixels::All,
        }
    }
}
