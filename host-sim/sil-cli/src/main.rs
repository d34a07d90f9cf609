//! `epssn-sil`: the software-in-the-loop run of `host-sim sil` as a binary of its own, without
//! the rest of host-sim, so a second configuration (`EPSSN_SPEC`) can be checked in
//! its own target directory in a couple of minutes of build. Same options and report: the
//! options are host-sim's own `sil` command line, read from its file.

use clap::Parser;

#[path = "../../src/cmd/sil.rs"]
mod sil;

/// `host-sim sil`'s options.
#[derive(Parser)]
#[command(name = "epssn-sil", version, about)]
struct Cli {
    #[command(flatten)]
    args: sil::SilArgs,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    epssn_sil_core::sil::run(&cli.args.into(), &mut std::io::stdout().lock())
}
