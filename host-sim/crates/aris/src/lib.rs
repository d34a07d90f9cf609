//! ARIS sonar files for the epssn host tools: recordings (DDF_05) read and written, the ARIS
//! beam-angle tables, frames resampled onto the model's polar grid (and the check that a
//! recording fits the model), NPY arrays, and `host-sim inspect` (the model spec is loaded by
//! `epssn_spec::load`). No simulator: everything that only reads or writes files.

#![deny(missing_docs)]

pub mod aris;
pub mod beams;
pub mod inspect;
pub mod npy;
pub mod polar;
