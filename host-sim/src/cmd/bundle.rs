//! `host-sim bundle`'s command line.

use std::path::PathBuf;

use host_sim::run::BundleOptions;

/// Arguments of `host-sim bundle`.
#[derive(clap::Args, Debug)]
pub struct BundleArgs {
    /// Simulated sample folders (`DIR/<split>/<index>/`), in the order to record them.
    #[arg(required = true)]
    pub samples: Vec<PathBuf>,
    /// Output folder: `recording.aris`, `gt/` and, for samples of one site, `poses.csv`.
    #[arg(long)]
    pub out: PathBuf,
}

impl From<BundleArgs> for BundleOptions {
    fn from(a: BundleArgs) -> Self {
        BundleOptions {
            samples: a.samples,
            out: a.out,
        }
    }
}
