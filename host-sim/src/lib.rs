//! The epssn host tool's own modules: the main job (`host-sim run`, `host-sim bundle`) and its
//! depth figures. Every other subcommand lives in the host crate of its role
//! (`epssn-aris`, `epssn-sim`, `epssn-quant`, `epssn-train`, `epssn-sil`); `main.rs` only
//! dispatches.

#![deny(missing_docs)]

pub mod figure;
pub mod run;
