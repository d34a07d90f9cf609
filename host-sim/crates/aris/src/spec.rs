//! The model spec (`weights/*.json`) at run time, through the one loader
//! ([`epssn_spec::load`]), and everything derived from it.

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use epssn::grids::ModelGrids;
use epssn::spec::ModelSpec;

use crate::beams;

/// The spec the library was built from (`weights/epssn-s.json` unless `EPSSN_SPEC` named
/// another at build time).
pub fn built_spec() -> Result<ModelSpec> {
    epssn_spec::load::parse_spec(epssn::config::SPEC_JSON.as_bytes())
        .map_err(|e| anyhow!("the built spec {}: {e}", epssn::config::SPEC_FILE_NAME))
}

/// Parses a model spec file.
pub fn load_spec(path: &Path) -> Result<ModelSpec> {
    Ok(epssn_spec::load::load_spec(path)
        .map_err(|e| anyhow!(e))?
        .spec)
}

/// CRC-32 of the spec file's bytes, as weight blobs and manifests record it.
pub fn spec_hash(path: &Path) -> Result<u32> {
    Ok(epssn_spec::load::load_spec(path)
        .map_err(|e| anyhow!(e))?
        .hash)
}

/// The grids of `spec`, through the library's one derivation, with the spec's beam table.
pub fn grids(spec: &ModelSpec) -> Result<ModelGrids> {
    let table = beams::table_by_name(spec.sonar.beam_table.as_str())
        .with_context(|| format!("beam table {}", spec.sonar.beam_table.as_str()))?;
    ModelGrids::derive(spec, &table.centre_deg).map_err(|e| {
        anyhow!(
            "model spec {} does not give valid grids: {e:?}",
            spec.name.as_str()
        )
    })
}
