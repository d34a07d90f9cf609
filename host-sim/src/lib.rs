//! Host tools for epssn: ARIS recordings, the sonar scene simulator, the float model and its
//! training, the quantiser, and software-in-the-loop runs of the firmware.

#![deny(missing_docs)]

pub mod model;
