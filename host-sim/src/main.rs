use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "host-sim", about = "Host tools for epssn")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train the float EPSSN on simulated data.
    Train(host_sim::model::cli::TrainArgs),
    /// Evaluate float weights on a simulated test folder.
    Eval(host_sim::model::cli::EvalArgs),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Train(a) => host_sim::model::cli::train(&a),
        Command::Eval(a) => host_sim::model::cli::eval(&a),
    }
}
