//! `host-sim`: command-line entry; each subcommand lives in its own library module.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "host-sim", version, about = "epssn host tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Summarise an ARIS (.aris, DDF_05) recording: geometry, frames, rolls, warnings.
    Inspect(host_sim::inspect::InspectArgs),
    /// Quantise float weights into the int8 blob the library and firmware run.
    Quantise(host_sim::quantise::QuantiseArgs),
    /// Software in the loop: boot the firmware in QEMU, stream a recording over the link,
    /// check the depth maps bit for bit against the host library; optional fuzz run.
    Sil(host_sim::sil::SilArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let stdout = std::io::stdout();
    let result = match cli.command {
        Command::Inspect(args) => host_sim::inspect::run(&args, &mut stdout.lock()),
        Command::Quantise(args) => host_sim::quantise::run(&args, &mut stdout.lock()),
        Command::Sil(args) => host_sim::sil::run(&args, &mut stdout.lock()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("host-sim: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
