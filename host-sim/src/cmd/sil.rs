//! `host-sim sil`'s command line, and the cores as `--target` names them (`bench` takes it
//! too). The `epssn-sil` binary (host-sim/sil-cli) parses the same options from this
//! file.

use std::path::PathBuf;

use epssn_sil_core::sil::SilOptions;
use epssn_sil_core::target::Target;

/// Arguments of `host-sim sil`.
#[derive(clap::Args, Debug, Clone)]
pub struct SilArgs {
    /// The recording to stream (default: the bundled simulated demo, `data/demo/`).
    #[arg(long)]
    pub recording: Option<PathBuf>,
    /// A bag's ProjectedSonarImage topic (default: its only one).
    #[arg(long)]
    pub topic: Option<String>,
    /// Print machine-readable JSON.
    #[arg(long)]
    pub json: bool,
    /// The firmware ELF (default: build the target's firmware crate in release and use it).
    #[arg(long)]
    pub firmware: Option<PathBuf>,
    /// The core to run on: `m7` (QEMU mps2-an500, `firmware/`) or `m55` (QEMU mps3-an547,
    /// `boards/mps3-an547`, budgets `weights/budgets-m55.json`).
    #[arg(long, value_enum, default_value_t = TargetArg::M7)]
    pub target: TargetArg,
    /// Stream at most this many frames.
    #[arg(long)]
    pub frames: Option<usize>,
    /// After the frames, send this many malformed messages (with status requests between).
    #[arg(long, default_value_t = 0)]
    pub fuzz: usize,
    /// Fault campaign (docs/LINK.md, "Fault campaign"): rounds per fault class, each fault checked
    /// against the library decoder's verdict, then a hello and valid frames checked bit for bit.
    #[arg(long, default_value_t = 2)]
    pub faults: usize,
    /// Soak (docs/LINK.md): instead of the fault campaign, at least this many messages (N ≥
    /// 5,000 for the soak), valid and faulty: blocks of one round of every fault class
    /// followed by a hello and valid frames whose depth maps must be bit-exact; the stack
    /// high-water must end where it began.
    #[arg(long, default_value_t = 0)]
    pub soak: usize,
    /// Seed of the fuzz run and the fault campaign.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Seconds to wait for any one reply.
    #[arg(long, default_value_t = 120)]
    pub timeout: u64,
    /// The budgets file (default: the target's, `weights/budgets.json` for the M7).
    #[arg(long)]
    pub budgets: Option<PathBuf>,
    /// Talk to a real board on this serial port (e.g. `/dev/ttyACM0`, the ST-LINK's virtual
    /// COM port) instead of booting the firmware in QEMU. Sizes come from `--firmware`
    /// (default: the STM32H743 board's release ELF, if built); budgets are not applied.
    #[arg(long)]
    pub serial: Option<PathBuf>,
    /// The serial port's baud rate (the board's `LINK_BAUD`).
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
    /// Device resets (docs/LINK.md, "Resets"): builds the firmware with its test-only feature
    /// `reset-faults` and provokes a hang, a panic and a stack overflow this many rounds each
    /// (seeded order), checking each reset's cause and fault record and the depth maps after
    /// it bit for bit.
    #[arg(long, default_value_t = 0)]
    pub reset_faults: usize,
    /// Also write what the device returned as an MCAP file of ROS 2 messages (docs/MCAP.md):
    /// every frame streamed and every depth map the device sent back, with its points.
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// A signed update image (docs/UPDATE.md): after the other checks, blobs the device must
    /// refuse (each with its code), then this one uploaded and committed, and every streamed
    /// depth map bit-exact with the host library running its blob.
    #[arg(long)]
    pub update: Option<PathBuf>,
    /// With `--update`: resets at this many seeded points of the upload and the commit, after
    /// each of which the old model (until the commit) must serve bit for bit.
    #[arg(long, default_value_t = 0, requires = "update")]
    pub update_faults: usize,
}

impl From<SilArgs> for SilOptions {
    fn from(a: SilArgs) -> Self {
        SilOptions {
            recording: a.recording,
            topic: a.topic,
            json: a.json,
            firmware: a.firmware,
            target: a.target.into(),
            frames: a.frames,
            fuzz: a.fuzz,
            faults: a.faults,
            soak: a.soak,
            seed: a.seed,
            timeout: a.timeout,
            budgets: a.budgets,
            serial: a.serial,
            baud: a.baud,
            reset_faults: a.reset_faults,
            mcap: a.mcap,
            update: a.update,
            update_faults: a.update_faults,
        }
    }
}

/// A core and its board under QEMU, as `--target` names it.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TargetArg {
    /// Cortex-M7 on QEMU `mps2-an500` (`firmware/`).
    #[default]
    M7,
    /// Cortex-M55 on QEMU `mps3-an547` (`boards/mps3-an547`).
    M55,
}

impl From<TargetArg> for Target {
    fn from(t: TargetArg) -> Self {
        match t {
            TargetArg::M7 => Target::M7,
            TargetArg::M55 => Target::M55,
        }
    }
}
