//! `host-sim train`'s command line (with `--features train`).

use std::path::PathBuf;

use epssn_train::cli::TrainOptions;

/// Arguments of `host-sim train`.
#[derive(clap::Args, Debug, Clone)]
pub struct TrainArgs {
    /// Scene name (sphere, terrain, artificial); names the default output folder.
    #[arg(long)]
    pub scene: String,
    /// Simulated data folder with `train/` (and optionally `val/`) sample folders.
    #[arg(long)]
    pub data: PathBuf,
    /// Epochs over the training split.
    #[arg(long, default_value_t = 60)]
    pub epochs: usize,
    /// Batch size (default: the spec's).
    #[arg(long)]
    pub batch: Option<usize>,
    /// Continue from `OUT/checkpoint/`, or, when a finished run left none, from `OUT`'s weights
    /// and loss history with a fresh optimizer state (to train a finished run further).
    #[arg(long)]
    pub resume: bool,
    /// Output folder (default `weights/<scene>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Model spec (default: the one this build was generated from, `weights/epssn-s.json`
    /// unless `EPSSN_SPEC` named another; the quantiser and the library follow the build's).
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Views (default: the spec's; 1 = reference as its own source).
    #[arg(long)]
    pub views: Option<usize>,
    /// Seed of weight initialisation and shuffling.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Minutes between checkpoints inside an epoch (a checkpoint is also written every epoch).
    #[arg(long, default_value_t = 5.0)]
    pub checkpoint_minutes: f64,
    /// Use at most this many training samples.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Use at most this many validation samples.
    #[arg(long, default_value_t = 200)]
    pub val_limit: usize,
    /// Only time this many training steps (after one warm-up step) and exit without saving.
    #[arg(long)]
    pub bench_steps: Option<usize>,
    /// Start from the weights of another trained model (its `model.safetensors`) with the same
    /// layers: convolution weights do not depend on the image size, so a model of EPSSN-S
    /// starts EPSSN-P (docs/PAPER.md). Fresh optimizer state and schedule; ignored on --resume
    /// from a checkpoint.
    #[arg(long, conflicts_with = "bench_steps")]
    pub init_from: Option<PathBuf>,
    /// Learning rate before the halving (default: the spec's `training.lr`). A lower rate
    /// fine-tunes a trained model (`--init-from`) without first undoing it; the manifest records
    /// the rate used, and a resumed run must pass the same one.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Weight of a two-hot cross-entropy term on the range bins beside the paper's L1 loss
    /// (train.rs; 0: L1 alone). Validation loss stays the L1 term. A resumed run must pass the
    /// same weight.
    #[arg(long, default_value_t = 0.0)]
    pub ce_weight: f64,
    /// Weight of the no-return term (train.rs): the binary cross-entropy of each ray's last
    /// (first) bin mass against "met nothing" ("met something nearer") in its label; with it
    /// the two-hot labels of out-of-window pixels sit on the end bins. 0: no such term. A
    /// resumed run must pass the same weight.
    #[arg(long, default_value_t = 0.0)]
    pub no_return_weight: f64,
    /// Quantisation-aware training: round every activation, in each forward pass, to the int8
    /// grid of the activation scales in this folder's `quantisation.json` (a quantised model of
    /// the same spec, usually the one `--init-from` names), the gradient passing the rounding
    /// unchanged. A resumed run must pass the same scales.
    #[arg(long)]
    pub fake_quant: Option<PathBuf>,
}

impl From<TrainArgs> for TrainOptions {
    fn from(a: TrainArgs) -> Self {
        TrainOptions {
            scene: a.scene,
            data: a.data,
            epochs: a.epochs,
            batch: a.batch,
            resume: a.resume,
            out: a.out,
            spec: a.spec,
            views: a.views,
            seed: a.seed,
            checkpoint_minutes: a.checkpoint_minutes,
            limit: a.limit,
            val_limit: a.val_limit,
            bench_steps: a.bench_steps,
            init_from: a.init_from,
            lr: a.lr,
            ce_weight: a.ce_weight,
            no_return_weight: a.no_return_weight,
            fake_quant: a.fake_quant,
        }
    }
}
