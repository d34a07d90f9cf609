//! `host-sim fit-sensor`'s command line.

use std::path::PathBuf;

use epssn_sim::sensor_fit::FitSensorOptions;

use super::simulate::SceneKindArg;

/// `host-sim fit-sensor`.
#[derive(clap::Args, Debug)]
pub struct FitSensorArgs {
    /// The recording (.aris, or a ROS 2 bag of ProjectedSonarImage) whose image statistics the
    /// simulator is fitted to.
    #[arg(long)]
    pub recording: PathBuf,
    /// A bag's ProjectedSonarImage topic (default: its only one).
    #[arg(long)]
    pub topic: Option<String>,
    /// Write the fitted SonarSimParams here (JSON, for `simulate --params`).
    #[arg(long)]
    pub out: PathBuf,
    /// Base parameters (geometry, rays; JSON as `simulate --params`); default: the defaults.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Scene family the fit simulates.
    #[arg(long, value_enum, default_value_t = SceneKindArg::Artificial)]
    pub scene: SceneKindArg,
    /// Scenes the fit simulates (view 0 of each); fewer scenes let the scenes' own texture
    /// move the speckle statistics (6 scenes mistook 4 looks for 3 in the recovery test).
    #[arg(long, default_value_t = 10)]
    pub scenes: usize,
    /// Seed of those scenes.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print the report as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

impl From<FitSensorArgs> for FitSensorOptions {
    fn from(a: FitSensorArgs) -> Self {
        FitSensorOptions {
            recording: a.recording,
            topic: a.topic,
            out: a.out,
            params: a.params,
            scene: a.scene.into(),
            scenes: a.scenes,
            seed: a.seed,
            json: a.json,
        }
    }
}
