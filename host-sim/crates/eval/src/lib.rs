//! Evaluation of trained weights on held-out simulated data (`host-sim eval`) and the sample
//! folders that evaluation and training both read.
//!
//! The float depth maps come from the f64 reference network on batch-norm-folded weights
//! ([`epssn_reference::floatref`]), the int8 ones from the library itself: no training
//! framework is built for either, so `host-sim eval` is in the default build.

#![deny(missing_docs)]

pub mod data;
pub mod eval;
pub mod summary;
