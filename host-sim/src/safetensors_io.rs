//! Reading trained float weights (SafeTensors, as `host-sim train` saves them) into the
//! quantiser's [`FloatWeights`].

use std::path::Path;

use anyhow::{bail, Result};

use crate::quantise::FloatWeights;

/// Loads `model.safetensors`.
pub fn load_float_weights(path: &Path) -> Result<FloatWeights> {
    bail!(
        "{}: reading trained weights needs the float model's parameter names (not wired yet)",
        path.display()
    )
}
