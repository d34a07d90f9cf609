//! Host tools for epssn: ARIS recordings, the sonar scene simulator, the float model and its
//! training, the quantiser, and software-in-the-loop runs of the firmware.

#![deny(missing_docs)]

pub mod aris;
pub mod beams;
pub mod bench;
pub mod budgets;
pub mod calibration;
pub mod dataset;
pub mod figure;
pub mod floatref;
pub mod groundtruth;
pub mod inspect;
pub mod int8;
pub mod intref;
pub mod metrics;
pub mod model;
pub mod npy;
pub mod polar;
pub mod preview;
pub mod qdiag;
pub mod quantise;
pub mod reference_model;
pub mod render;
pub mod run;
pub mod safetensors_io;
pub mod scene;
pub mod sil;
pub mod simulate;
pub mod spec;
pub mod synthetic;
pub mod weights;
