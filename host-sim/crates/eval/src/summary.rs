//! What a simulated split holds: the record a trained model keeps of its data, and what
//! `eval` compares with the model's.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// What a simulated split holds, from its samples' `scene.json` and their split's
/// `sim_params.json`: scene kinds, dataset seeds, sample count, views per sample and speckle
/// looks per view.
pub fn data_summary(dir: &Path) -> serde_json::Value {
    let mut kinds = BTreeSet::new();
    let mut seeds = BTreeSet::new();
    let mut views = BTreeSet::new();
    let mut splits = BTreeSet::new();
    let mut samples = 0usize;
    for d in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let Ok(text) = std::fs::read_to_string(d.path().join("scene.json")) else {
            continue;
        };
        let Ok(j) = serde_json::from_str::<serde_json::Value>(&text) else {
            continue;
        };
        samples += 1;
        kinds.insert(j["kind"].as_str().unwrap_or("?").to_string());
        seeds.insert(j["seed"].as_u64().unwrap_or(u64::MAX));
        views.insert(j["view_rolls_deg"].as_array().map_or(0, |v| v.len()));
        splits.extend(split_of_sample(&d.path()));
    }
    // Each split's sim_params.json once, not once per sample linked from it.
    let looks: BTreeSet<u64> = splits
        .iter()
        .filter_map(|s| speckle_looks_of_split(s))
        .collect();
    serde_json::json!({
        "dir": dir.display().to_string(),
        "scenes": kinds,
        "seeds": seeds,
        "samples": samples,
        "views": views,
        "speckle_looks": looks,
    })
}

/// The split folder a sample lives in, through the general mix's links.
fn split_of_sample(sample: &Path) -> Option<PathBuf> {
    Some(std::fs::canonicalize(sample).ok()?.parent()?.to_path_buf())
}

/// Speckle looks averaged per view in a simulated split (`simulate --params` `speckle_looks`,
/// docs/SIMULATOR.md), from its `sim_params.json`; absent from the file means the default, 1.
/// `None` when there is no such file (not simulated data).
fn speckle_looks_of_split(split: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(split.join("sim_params.json")).ok()?;
    let j: serde_json::Value = serde_json::from_str(&text).ok()?;
    Some(j.get("speckle_looks").and_then(|v| v.as_u64()).unwrap_or(1))
}

/// Speckle looks of the split a sample lives in (its `sim_params.json`; `None` without one).
pub fn speckle_looks_of_sample(sample: &Path) -> Option<u64> {
    speckle_looks_of_split(&split_of_sample(sample)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_summary_records_the_speckle_looks_of_each_split() {
        let root = tempfile::tempdir().unwrap();
        let sample = |split: &str, i: usize, params: Option<&str>| {
            let d = root.path().join(split).join(format!("{i:06}"));
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(
                d.join("scene.json"),
                r#"{"kind":"terrain","seed":1,"view_rolls_deg":[0.0,7.0]}"#,
            )
            .unwrap();
            if let Some(p) = params {
                std::fs::write(root.path().join(split).join("sim_params.json"), p).unwrap();
            }
            d
        };
        let four = sample("four", 0, Some(r#"{"speckle":true,"speckle_looks":4}"#));
        let one = sample("one", 0, Some(r#"{"speckle":true}"#));
        let recorded = sample("recorded", 0, None);
        assert_eq!(speckle_looks_of_sample(&four), Some(4));
        assert_eq!(
            speckle_looks_of_sample(&one),
            Some(1),
            "absent means the default"
        );
        assert_eq!(speckle_looks_of_sample(&recorded), None);
        // A mix of links to both, as scripts/train-general.sh builds, records both.
        let mix = root.path().join("mix");
        std::fs::create_dir_all(&mix).unwrap();
        std::os::unix::fs::symlink(&four, mix.join("000000")).unwrap();
        std::os::unix::fs::symlink(&one, mix.join("000001")).unwrap();
        let s = data_summary(&mix);
        assert_eq!(s["speckle_looks"], serde_json::json!([1, 4]));
        assert_eq!(s["samples"], 2);
        assert_eq!(
            data_summary(&root.path().join("recorded"))["speckle_looks"],
            serde_json::json!([])
        );
    }
}
