//! `host-sim inspect`'s command line.

use std::path::PathBuf;

use epssn_aris::inspect::InspectOptions;

/// Arguments of `host-sim inspect`.
#[derive(clap::Args, Debug, Clone)]
pub struct InspectArgs {
    /// The .aris recording.
    pub file: PathBuf,
    /// Print machine-readable JSON instead of text (NaN fields become null).
    #[arg(long)]
    pub json: bool,
}

impl From<InspectArgs> for InspectOptions {
    fn from(a: InspectArgs) -> Self {
        InspectOptions {
            file: a.file,
            json: a.json,
        }
    }
}
