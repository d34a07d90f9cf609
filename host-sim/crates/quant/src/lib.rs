//! The quantiser of the epssn host tools: float weights and calibrated activation ranges to
//! the int8 blob the library runs (`host-sim quantise`), the calibration search, and
//! `host-sim qdiag` (where the int8 model loses accuracy).

#![deny(missing_docs)]

pub mod calibration;
pub mod qdiag;
pub mod quantise;
