//! The quantiser of the epssn host tools: float weights and calibrated activation ranges to
//! the int8 blob the library runs ([`quantiser`]), the calibration search ([`calibration`]),
//! and the commands `host-sim quantise` ([`quantise`]) and `host-sim qdiag` ([`qdiag`], where
//! the int8 model loses accuracy). Imports run one way: the commands use the calibration,
//! the calibration uses the quantiser, the quantiser uses neither.

#![deny(missing_docs)]

pub mod calibration;
pub mod qdiag;
pub mod quantise;
pub mod quantiser;
