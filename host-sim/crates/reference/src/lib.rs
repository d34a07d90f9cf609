//! The references the int8 library is checked against: the independent integer reference
//! (written from docs/QUANTISATION.md alone), the float reference, the float weights
//! (SafeTensors, batch-norm folding, random bring-up weights), weights folders, and the
//! library's depth in metres for scoring.

#![deny(missing_docs)]

pub mod float;
pub mod floatref;
pub mod int8;
pub mod intref;
pub mod reference_model;
pub mod rng;
pub mod safetensors_io;
pub mod weights;
