//! SafeTensors files of named f32 tensors (as `host-sim train` saves them), and reading them
//! into [`FloatWeights`]: `L.conv.weight`, `L.conv.bias` and, for layers with batch
//! norm, `L.bn.gamma`, `L.bn.beta`, `L.bn.running_mean`, `L.bn.running_var`.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{anyhow, ensure, Context, Result};
use epssn::config::LAYERS;

use crate::float::{BatchNorm, FloatLayer, FloatWeights, BN_EPSILON};

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

/// One float tensor with its shape, as stored in SafeTensors.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedTensor {
    /// Shape, outermost first.
    pub shape: Vec<usize>,
    /// Values in C order.
    pub data: Vec<f32>,
    /// The burn trainer's parameter id, in folders it wrote up to commit `5b1029e` (kept in
    /// checkpoints so the optimizer state matched on resume).
    pub id: Option<u64>,
}

/// Saves named tensors as SafeTensors (f32, little-endian) with metadata.
pub fn save_safetensors(
    path: &Path,
    tensors: &BTreeMap<String, NamedTensor>,
    mut metadata: std::collections::HashMap<String, String>,
) -> Result<()> {
    let bytes: Vec<(String, Vec<u8>, Vec<usize>)> = tensors
        .iter()
        .map(|(n, t)| {
            (
                n.clone(),
                t.data.iter().flat_map(|v| v.to_le_bytes()).collect(),
                t.shape.clone(),
            )
        })
        .collect();
    let ids: BTreeMap<&str, u64> = tensors
        .iter()
        .filter_map(|(n, t)| t.id.map(|id| (n.as_str(), id)))
        .collect();
    metadata.insert("param_ids".into(), serde_json::to_string(&ids)?);
    metadata.insert("bn_epsilon".into(), format!("{BN_EPSILON:e}"));
    metadata.insert(
        "input_scale".into(),
        "1/255 (applied inside the model)".into(),
    );
    let views = bytes
        .iter()
        .map(|(n, b, s)| {
            Ok((
                n.clone(),
                safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b)?,
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    let out = safetensors::serialize(views, Some(metadata))?;
    let tmp = path.with_extension("safetensors.tmp");
    std::fs::write(&tmp, out).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

/// Loads every f32 tensor of a SafeTensors file (with the saved parameter ids, if any).
pub fn load_safetensors(path: &Path) -> Result<BTreeMap<String, NamedTensor>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let st = safetensors::SafeTensors::deserialize(&bytes)?;
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)?;
    let ids: BTreeMap<String, u64> = meta
        .metadata()
        .as_ref()
        .and_then(|m| m.get("param_ids"))
        .map(|s| serde_json::from_str(s))
        .transpose()?
        .unwrap_or_default();
    let mut map = BTreeMap::new();
    for name in st.names() {
        let t = st.tensor(name)?;
        ensure!(
            t.dtype() == safetensors::Dtype::F32,
            "tensor {name} is not f32"
        );
        let data = t
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        map.insert(
            name.to_string(),
            NamedTensor {
                shape: t.shape().to_vec(),
                data,
                id: ids.get(name).copied(),
            },
        );
    }
    Ok(map)
}
