//! Reading trained float weights (SafeTensors, as `host-sim train` saves them) into the
//! quantiser's [`FloatWeights`]: `L.conv.weight`, `L.conv.bias` and, for layers with batch
//! norm, `L.bn.gamma`, `L.bn.beta`, `L.bn.running_mean`, `L.bn.running_var`.

use std::path::Path;

use anyhow::{anyhow, Result};
use epssn::config::LAYERS;

use crate::model::{load_safetensors, BN_EPSILON};
use crate::quantise::{BatchNorm, FloatLayer, FloatWeights};

/// Loads `model.safetensors` for the compiled configuration's layers.
pub fn load_float_weights(path: &Path) -> Result<FloatWeights> {
    let tensors = load_safetensors(path)?;
    let get = |name: String| -> Result<Vec<f32>> {
        tensors
            .get(&name)
            .map(|t| t.data.clone())
            .ok_or_else(|| anyhow!("{}: no tensor {name}", path.display()))
    };
    let mut out = FloatWeights::new();
    for l in LAYERS.iter() {
        let n = l.name;
        let bn = if tensors.contains_key(&format!("{n}.bn.gamma")) {
            Some(BatchNorm {
                gamma: get(format!("{n}.bn.gamma"))?,
                beta: get(format!("{n}.bn.beta"))?,
                mean: get(format!("{n}.bn.running_mean"))?,
                var: get(format!("{n}.bn.running_var"))?,
                eps: BN_EPSILON,
            })
        } else {
            None
        };
        out.insert(
            n.to_string(),
            FloatLayer {
                weight: get(format!("{n}.conv.weight"))?,
                bias: get(format!("{n}.conv.bias"))?,
                bn,
            },
        );
    }
    Ok(out)
}
