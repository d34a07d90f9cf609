//! `host-sim label`'s command line.

use std::path::PathBuf;

use host_sim::label::LabelOptions;

use super::pairing::PairingArgs;

/// Arguments of `host-sim label`.
#[derive(clap::Args, Debug)]
pub struct LabelArgs {
    /// ARIS recording to label.
    #[arg(long)]
    pub recording: PathBuf,
    /// The site's mesh (.stl, .obj, .ply; metres, z up: docs/SITES.md).
    #[arg(long)]
    pub site: PathBuf,
    /// The sonar's pose at each frame in the site frame (CSV: frame, x_m, y_m, z_m, roll_deg,
    /// pitch_deg, yaw_deg; docs/SITES.md).
    #[arg(long)]
    pub poses: PathBuf,
    /// Output folder for `depth_<frame>.npy` and `mask_<frame>.npy` (`run --gt DIR`).
    #[arg(long)]
    pub out: PathBuf,
    /// The weights, views and pairing `run` will be given: they decide its reference frames.
    #[command(flatten)]
    pub pairing: PairingArgs,
}

impl From<LabelArgs> for LabelOptions {
    fn from(a: LabelArgs) -> Self {
        LabelOptions {
            recording: a.recording,
            site: a.site,
            poses: a.poses.clone(),
            out: a.out,
            pairing: host_sim::pairing::PairingOptions {
                poses: Some(a.poses),
                ..host_sim::pairing::PairingOptions::from(a.pairing)
            },
        }
    }
}
