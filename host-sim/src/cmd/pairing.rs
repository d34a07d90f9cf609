//! What decides the depth maps a recording gives, as `run` and `label` take it.

use std::path::PathBuf;

use host_sim::pairing::PairingOptions;

/// What decides the depth maps a recording gives: `run` and `label` share it, so `label`
/// labels exactly the reference views `run` forms.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct PairingArgs {
    /// Weights folder (`epssn-s.q8.bin` + `manifest.json`); default: the firmware's weights.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Views per depth map (2 or 3); default: the count the weights were trained for (the
    /// blob's `views`, else the spec's).
    #[arg(long)]
    pub views: Option<usize>,
    /// Pair frames by index instead of by roll, `REF:SRC` (repeatable), for recordings
    /// without rotator roll. The roll between them is assumed to be the baseline.
    #[arg(long = "pair", value_parser = parse_pair)]
    pub pairs: Vec<(usize, usize)>,
    /// Pings averaged per view (`epssn::ping_average`): each run of this many consecutive
    /// frames at one roll (within the pair tolerance) becomes one frame, named by its first;
    /// frames left over are skipped with a warning. Default: the pings per view the weights
    /// were trained on (their manifest's `speckle_looks`), else 1.
    #[arg(long)]
    pub pings_per_view: Option<u32>,
    /// The ProjectedSonarImage topic of a ROS 2 bag given as the recording (default: the
    /// bag's only one; docs/ROS2.md).
    #[arg(long)]
    pub topic: Option<String>,
}

impl From<PairingArgs> for PairingOptions {
    fn from(a: PairingArgs) -> Self {
        PairingOptions {
            weights: a.weights,
            views: a.views,
            pairs: a.pairs,
            pings_per_view: a.pings_per_view,
            topic: a.topic,
            // `run` and `label` give their own --poses.
            poses: None,
        }
    }
}

/// `REF:SRC`, two frame indices.
fn parse_pair(s: &str) -> Result<(usize, usize), String> {
    let (a, b) = s.split_once(':').ok_or("expected REF:SRC")?;
    Ok((
        a.trim()
            .parse()
            .map_err(|_| format!("bad frame index {a}"))?,
        b.trim()
            .parse()
            .map_err(|_| format!("bad frame index {b}"))?,
    ))
}
