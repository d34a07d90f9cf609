//! `host-sim bench`'s command line.

use epssn_sil_core::bench::BenchOptions;

use super::sil::TargetArg;

/// Arguments of `host-sim bench`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Firmware ELF (default: build the target's firmware crate in release).
    #[arg(long)]
    pub firmware: Option<std::path::PathBuf>,
    /// The core: `m7` (QEMU mps2-an500) or `m55` (QEMU mps3-an547).
    #[arg(long, value_enum, default_value_t = TargetArg::M7)]
    pub target: TargetArg,
}

impl From<BenchArgs> for BenchOptions {
    fn from(a: BenchArgs) -> Self {
        BenchOptions {
            firmware: a.firmware,
            target: a.target.into(),
        }
    }
}
