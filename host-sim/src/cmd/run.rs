//! `host-sim run`'s command line, and the frames of its clouds as `--frame` names them.

use std::path::PathBuf;

use host_sim::pairing::PairingOptions;
use host_sim::run::RunOptions;
use host_sim::sweep::CloudFrame;

use super::pairing::PairingArgs;

/// Arguments of `host-sim run`.
#[derive(clap::Args, Debug)]
pub struct RunArgs {
    /// ARIS recording (default: the bundled simulated demo, `data/demo/recording.aris`).
    #[arg(long)]
    pub recording: Option<PathBuf>,
    /// Ground-truth folder with `depth_<frame>.npy` and `mask_<frame>.npy` per reference
    /// frame (default: `gt/` beside the bundled demo recording; `gt-<spec>/` for another spec).
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Weights, views and how frames are grouped.
    #[command(flatten)]
    pub pairing: PairingArgs,
    /// Dynamic range of the recording's 0–255 counts, dB, for averaging pings in intensity
    /// (80 for ARIS files, docs/ARIS.md; 70 for the simulator's default).
    #[arg(long, default_value_t = 80.0)]
    pub ping_dynamic_range_db: f32,
    /// Output folder for PNGs, PLYs and `summary.json`.
    #[arg(long, default_value = "out/run")]
    pub out: PathBuf,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
    /// Also write the run as ROS 2 messages (CDR) in this MCAP file: images, depth maps,
    /// point clouds, the sonar's transforms, the pair checks and the summary (docs/MCAP.md).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Frame of the clouds: `sonar`, each pair in its reference view's sonar frame; `world`
    /// also merges every pair by its reference frame's attitude (and `--poses` positions) into
    /// `world.ply` and, with `--mcap`, one merged cloud.
    #[arg(long, value_enum, default_value_t = CloudFrameArg::Sonar)]
    pub frame: CloudFrameArg,
    /// Each frame's position in the site (`frame,x_m,y_m,z_m,roll_deg,pitch_deg,yaw_deg`, as
    /// `bundle` writes and `label` reads): moves the world-frame clouds and the transforms.
    #[arg(long)]
    pub poses: Option<PathBuf>,
}

impl From<RunArgs> for RunOptions {
    fn from(a: RunArgs) -> Self {
        RunOptions {
            recording: a.recording,
            gt: a.gt,
            pairing: PairingOptions {
                poses: a.poses.clone(),
                ..PairingOptions::from(a.pairing)
            },
            ping_dynamic_range_db: a.ping_dynamic_range_db,
            out: a.out,
            json: a.json,
            mcap: a.mcap,
            frame: a.frame.into(),
            poses: a.poses,
        }
    }
}

/// The frame `run` writes its clouds in, as `--frame` names it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum CloudFrameArg {
    /// Each pair in its reference view's own sonar frame (a PLY per pair).
    #[default]
    Sonar,
    /// Also every pair merged in the world frame (`world.ply`).
    World,
}

impl From<CloudFrameArg> for CloudFrame {
    fn from(f: CloudFrameArg) -> Self {
        match f {
            CloudFrameArg::Sonar => CloudFrame::Sonar,
            CloudFrameArg::World => CloudFrame::World,
        }
    }
}
