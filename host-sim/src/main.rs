//! `host-sim`: the command line. Each subcommand's arguments are parsed here (`cmd/`, one file
//! a command) into the plain options of the library function that runs it, in the host crate
//! of its role.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cmd;

#[derive(Parser)]
#[command(name = "host-sim", version, about = "epssn host tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Summarise an ARIS (.aris, DDF_05) recording, or a ROS 2 bag's sonar topic: geometry,
    /// frames, rolls, warnings.
    Inspect(cmd::inspect::InspectArgs),
    /// Quantise float weights into the int8 blob the library and firmware run.
    Quantise(cmd::quantise::QuantiseArgs),
    /// Where the int8 model loses accuracy: each tensor rounded alone, and all but it.
    Qdiag(cmd::qdiag::QdiagArgs),
    /// The main job: pair a recording's frames by roll, run the int8 library and the float
    /// model, check bit-exactness, score against ground truth, write PNG and PLY.
    Run(cmd::run::RunArgs),
    /// Concatenate simulated samples into one recording with ground truth (the demo data).
    Bundle(cmd::bundle::BundleArgs),
    /// Ground truth for a recording from its site's mesh and the sonar's pose at each frame,
    /// for every reference view `run` forms (what `run --gt` reads).
    Label(cmd::label::LabelArgs),
    /// Simulate sonar scenes with exact ground truth into sample folders.
    Simulate(cmd::simulate::SimulateArgs),
    /// Fit the simulator's noise model (speckle looks, floor, gain, dynamic range,
    /// crosstalk) to a recording's image statistics; writes a `simulate --params` file.
    FitSensor(cmd::fit_sensor::FitSensorArgs),
    /// MAE and chamfer distance between two depth maps (.npy).
    Metrics(cmd::metrics::MetricsArgs),
    /// Software in the loop: boot the firmware in QEMU, stream a recording over the link,
    /// check the depth maps bit for bit against the host library; optional fuzz run.
    Sil(cmd::sil::SilArgs),
    /// Per-layer MACs and QEMU Cortex-M7 instructions of the firmware.
    Bench(cmd::bench::BenchArgs),
    /// Evaluate weights on a simulated test folder: the f64 reference network and, with
    /// `--int8`, the int8 library (MAE and CD as in the paper).
    Eval(cmd::eval::EvalArgs),
    /// A new Ed25519 key pair for signed model updates: DIR/private, DIR/public.
    Keygen(cmd::update::KeygenArgs),
    /// Sign a weight blob as a model version: the update image a device takes over the link.
    Sign(cmd::update::SignArgs),
    /// Upload a signed update image to a device (a board's serial port, or QEMU) and commit it.
    Push(cmd::update::PushArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let stdout = std::io::stdout();
    let result = match cli.command {
        Command::Inspect(args) => args.run(&mut stdout.lock()),
        Command::Quantise(args) => epssn_quant::quantise::run(&args.into(), &mut stdout.lock()),
        Command::Qdiag(args) => epssn_quant::qdiag::run(&args.into()),
        Command::Run(args) => host_sim::run::run(&args.into(), &mut stdout.lock()),
        Command::Bundle(args) => host_sim::run::bundle(&args.into(), &mut stdout.lock()),
        Command::Label(args) => host_sim::label::label(&args.into(), &mut stdout.lock()),
        Command::Simulate(args) => epssn_sim::simulate::run(&args.into()),
        Command::FitSensor(args) => epssn_sim::sensor_fit::run(&args.into(), &mut stdout.lock()),
        Command::Metrics(args) => epssn_sim::metrics::run(&args.into()),
        Command::Sil(args) => epssn_sil_core::sil::run(&args.into(), &mut stdout.lock()),
        Command::Bench(args) => epssn_sil_core::bench::run(&args.into(), &mut stdout.lock()),
        Command::Eval(args) => epssn_eval::eval::run(&args.into()),
        Command::Keygen(args) => host_sim::update::keygen(&args.into(), &mut stdout.lock()),
        Command::Sign(args) => host_sim::update::sign(&args.into(), &mut stdout.lock()),
        Command::Push(args) => epssn_sil_core::update::push(&args.into(), &mut stdout.lock()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("host-sim: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
