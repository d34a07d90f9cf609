//! The epssn host tool's own modules: the main job (`host-sim run`, `host-sim bundle`), how a
//! recording's frames are paired into views (`pairing`, which `run` and `label` share), the
//! labels of a recording from its site (`host-sim label`), the depth figures, the run as an MCAP
//! file of ROS 2 messages (`mcap_out`), the sweep's clouds in one frame (`sweep`) and the keys
//! and signed images of model updates (`update`: `host-sim keygen`, `host-sim sign`). Every other
//! subcommand lives in the host crate of its role (`epssn-aris`, `epssn-sim`, `epssn-quant`,
//! `epssn-eval`, `epssn-sil-core`). Each takes plain options: the command line
//! (clap) is the binary's alone (`main.rs`, `cmd/`).

#![deny(missing_docs)]

pub mod figure;
pub mod label;
pub mod mcap_out;
pub mod pairing;
pub mod run;
pub mod sweep;
pub mod update;
