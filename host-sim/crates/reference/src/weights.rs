//! Weights folders (`weights/<name>/`): the int8 blob the library runs and the float weights it
//! was quantised from, which the float reference runs.
//!
//! The float weights are `model.safetensors` (a trained model) or, for an untrained bring-up
//! model, a `float_source` entry `{"random_init": seed}` in `quantisation.json`.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};

use crate::float::FloatWeights;

/// File name of the blob inside a weights folder of the build's spec (`epssn-s.q8.bin`).
pub const BLOB_FILE: &str = epssn::config::BLOB_FILE_NAME;

/// The blob the firmware embeds: `EPSSN_BLOB` if set, else the one `weights/FIRMWARE_WEIGHTS`
/// names for the build's spec (the same rule as the boards' self-test build script).
pub fn firmware_blob_path() -> Result<PathBuf> {
    if let Ok(p) = std::env::var("EPSSN_BLOB") {
        return Ok(PathBuf::from(p));
    }
    let root = epssn_spec::load::repo_root();
    epssn_spec::load::firmware_blob(&root, epssn::config::SPEC_FILE_NAME).map_err(|e| anyhow!(e))
}

/// The folder of the blob the firmware embeds.
pub fn firmware_weights_dir() -> Result<PathBuf> {
    let blob = firmware_blob_path()?;
    blob.parent()
        .map(Path::to_path_buf)
        .ok_or_else(|| anyhow!("{} names no folder", blob.display()))
}

/// A loaded weights folder.
pub struct Bundle {
    /// The int8 blob (not yet verified: `Model::from_blob` does that).
    pub blob: Vec<u8>,
    /// The float weights it was quantised from.
    pub float: FloatWeights,
    /// Where the float weights came from.
    pub description: String,
}

/// Loads `dir`'s blob and float weights.
pub fn load(dir: &Path) -> Result<Bundle> {
    let blob = read_blob(dir)?;
    let (float, description) = load_float(dir)?;
    Ok(Bundle {
        blob,
        float,
        description,
    })
}

/// Reads `dir`'s blob (`BLOB_FILE`), naming the file when it cannot.
pub fn read_blob(dir: &Path) -> Result<Vec<u8>> {
    let path = dir.join(BLOB_FILE);
    std::fs::read(&path).with_context(|| format!("reading {}", path.display()))
}

/// Loads `dir`'s float weights alone (a folder not yet quantised may have no blob), and where
/// they came from.
pub fn load_float(dir: &Path) -> Result<(FloatWeights, String)> {
    let st = dir.join("model.safetensors");
    if st.exists() {
        return Ok((
            crate::safetensors_io::load_float_weights(&st)?,
            format!("trained, {}", st.display()),
        ));
    }
    let q = dir.join("quantisation.json");
    let text = std::fs::read_to_string(&q).with_context(|| format!("reading {}", q.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)?;
    match v
        .pointer("/float_source/random_init")
        .and_then(|s| s.as_u64())
    {
        Some(seed) => Ok((
            crate::float::random_float_weights(seed),
            format!("UNTRAINED: He-initialised float weights, seed {seed}"),
        )),
        None => bail!(
            "{}: no model.safetensors and no float_source in quantisation.json",
            dir.display()
        ),
    }
}

/// Views a trained model was trained with (`views` in its `manifest.json`, 1..=MAX_VIEWS, 1
/// being the reference as its own source; the spec's without one): `eval` feeds it by default.
pub fn trained_views(dir: &Path) -> Result<usize> {
    let path = dir.join("manifest.json");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(epssn::config::VIEWS);
    };
    let j: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    match j.get("views").and_then(|v| v.as_u64()) {
        Some(v) if (1..=epssn::config::MAX_VIEWS as u64).contains(&v) => Ok(v as usize),
        Some(v) => bail!(
            "{}: views {v}, the model runs 1..={}",
            path.display(),
            epssn::config::MAX_VIEWS
        ),
        None => Ok(epssn::config::VIEWS),
    }
}

/// Pings per view a model was trained on: the speckle looks of its training data
/// (`data.train.speckle_looks` in its `manifest.json`, docs/SIMULATOR.md). `None` for models
/// whose manifest predates the record or whose data mix several counts.
pub fn trained_pings_per_view(dir: &Path) -> Option<u32> {
    let text = std::fs::read_to_string(dir.join("manifest.json")).ok()?;
    let j: serde_json::Value = serde_json::from_str(&text).ok()?;
    match j["data"]["train"]["speckle_looks"].as_array()?.as_slice() {
        [one] => one.as_u64().and_then(|v| u32::try_from(v).ok()),
        _ => None,
    }
}

/// [`trained_views`] for the int8 model, which runs 2..=MAX_VIEWS: calibration sees the
/// variance statistics the model will run on, and the blob records the count
/// ([`epssn::model::VIEWS_TENSOR`]).
pub fn int8_views(dir: &Path) -> Result<usize> {
    let views = trained_views(dir)?;
    if views < 2 {
        bail!(
            "{}: trained on {views} view, the int8 model runs 2..={}",
            dir.join("manifest.json").display(),
            epssn::config::MAX_VIEWS
        );
    }
    Ok(views)
}

/// The activation scales a quantised folder records (`quantisation.activation_scales` of its
/// `quantisation.json`), by tensor name, the input's excepted (always 1/255): what `train
/// --fake-quant` rounds to and `quantise --ranges-from` takes.
pub fn activation_scales(dir: &Path) -> Result<std::collections::BTreeMap<String, f64>> {
    let path = dir.join("quantisation.json");
    let text = std::fs::read(&path).with_context(|| format!("{}", path.display()))?;
    let v: serde_json::Value =
        serde_json::from_slice(&text).with_context(|| format!("parsing {}", path.display()))?;
    let table = v["quantisation"]["activation_scales"]
        .as_object()
        .with_context(|| format!("{} has no quantisation.activation_scales", path.display()))?;
    let mut scales = std::collections::BTreeMap::new();
    for (name, s) in table.iter().filter(|(n, _)| n.as_str() != "input") {
        let s = s
            .as_f64()
            .filter(|s| s.is_finite() && *s > 0.0)
            .with_context(|| {
                format!(
                    "{}: the scale of {name} is not a positive number",
                    path.display()
                )
            })?;
        scales.insert(name.clone(), s);
    }
    if scales.is_empty() {
        bail!("{} lists no activation scales", path.display());
    }
    Ok(scales)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scratch folder of this test process.
    fn scratch(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("epssn-weights-{}-{name}", std::process::id()))
    }

    #[test]
    fn pings_per_view_come_from_the_training_data_record() {
        let dir = scratch("pings");
        std::fs::create_dir_all(&dir).unwrap();
        let write = |j: serde_json::Value| {
            std::fs::write(dir.join("manifest.json"), j.to_string()).unwrap();
        };
        write(serde_json::json!({ "data": { "train": { "speckle_looks": [4] } } }));
        assert_eq!(trained_pings_per_view(&dir), Some(4));
        write(serde_json::json!({ "data": { "train": { "speckle_looks": [1, 4] } } }));
        assert_eq!(trained_pings_per_view(&dir), None, "a mix has no one count");
        write(serde_json::json!({ "data": { "train": { "views": [2] } } }));
        assert_eq!(trained_pings_per_view(&dir), None, "older manifests");
        std::fs::remove_dir_all(&dir).unwrap();
        // The shipped models record theirs.
        let root = epssn_spec::load::repo_root();
        assert_eq!(
            trained_pings_per_view(&root.join("weights/general")),
            Some(1)
        );
    }

    /// A scratch folder whose manifest says `views` (or has none).
    fn folder(name: &str, views: Option<u64>) -> PathBuf {
        let dir = scratch(name);
        std::fs::create_dir_all(&dir).unwrap();
        let manifest = match views {
            Some(v) => serde_json::json!({ "views": v }),
            None => serde_json::json!({}),
        };
        std::fs::write(dir.join("manifest.json"), manifest.to_string()).unwrap();
        dir
    }

    #[test]
    fn views_from_the_manifest_float_and_int8() {
        let spec = epssn::config::VIEWS;
        for (name, views, float, int8) in [
            ("views-none", None, Some(spec), Some(spec)),
            ("views-1", Some(1), Some(1), None),
            ("views-3", Some(3), Some(3), Some(3)),
            ("views-0", Some(0), None, None),
            ("views-4", Some(4), None, None),
        ] {
            let dir = folder(name, views);
            assert_eq!(trained_views(&dir).ok(), float, "{name}");
            assert_eq!(int8_views(&dir).ok(), int8, "{name}");
        }
        assert_eq!(trained_views(&scratch("views-no-folder")).unwrap(), spec);
        for name in ["views-none", "views-1", "views-3", "views-0", "views-4"] {
            let _ = std::fs::remove_dir_all(scratch(name));
        }
    }
}
