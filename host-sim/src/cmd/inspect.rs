//! `host-sim inspect`'s command line.

use std::path::PathBuf;

use epssn_aris::inspect::InspectOptions;

/// Arguments of `host-sim inspect`.
#[derive(clap::Args, Debug, Clone)]
pub struct InspectArgs {
    /// The .aris recording (or a ROS 2 bag, docs/ROS2.md).
    pub file: PathBuf,
    /// Print machine-readable JSON instead of text (NaN fields become null).
    #[arg(long)]
    pub json: bool,
    /// A bag's ProjectedSonarImage topic (default: its only one).
    #[arg(long)]
    pub topic: Option<String>,
}

impl InspectArgs {
    /// Summarises the file: a bag by `epssn_ros2::inspect`, an ARIS file as before.
    pub fn run(self, out: &mut impl std::io::Write) -> anyhow::Result<()> {
        if epssn_ros2::Recording::is_bag(&self.file) {
            epssn_ros2::inspect::run(&self.file, self.topic.as_deref(), self.json, out)
        } else {
            epssn_aris::inspect::run(&self.into(), out)
        }
    }
}

impl From<InspectArgs> for InspectOptions {
    fn from(a: InspectArgs) -> Self {
        InspectOptions {
            file: a.file,
            json: a.json,
        }
    }
}
