//! Host tools for epssn: ARIS recordings, the sonar scene simulator, the float model and its
//! training, the quantiser, and software-in-the-loop runs of the firmware.

#![deny(missing_docs)]

pub mod aris;
pub mod beams;
pub mod floatref;
pub mod inspect;
pub mod intref;
pub mod polar;
pub mod quantise;
pub mod reference_model;
pub mod sil;
pub mod spec;
pub mod synthetic;
