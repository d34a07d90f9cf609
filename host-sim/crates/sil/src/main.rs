//! `epssn-sil`: the software-in-the-loop run of `host-sim sil` as a binary of its own, without
//! the training crate (no burn), so a second configuration (`EPSSN_SPEC`) can be checked in
//! its own target directory in a couple of minutes of build. Same options and report.

use clap::Parser;

/// `host-sim sil`'s options.
#[derive(Parser)]
#[command(name = "epssn-sil", version, about)]
struct Cli {
    #[command(flatten)]
    args: epssn_sil::sil::SilArgs,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    epssn_sil::sil::run(&cli.args, &mut std::io::stdout().lock())
}
