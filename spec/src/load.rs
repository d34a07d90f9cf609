//! Files: the one spec loader and the one beam-table parser (`std` feature), at build time
//! and at run time.

use std::format;
use std::path::{Path, PathBuf};
use std::string::String;
use std::vec::Vec;

use crate::grids::ModelGrids;
use crate::spec::ModelSpec;

/// A model spec read from its file.
#[derive(Clone, Debug)]
pub struct LoadedSpec {
    /// The parsed spec.
    pub spec: ModelSpec,
    /// CRC-32 of the file's bytes ([`crate::crc32::crc32`]): weight blobs and manifests record
    /// it, so a blob can never run against another spec.
    pub hash: u32,
}

/// The repository's root folder, where `weights/` and `data/` are: the parent of this crate's
/// folder, with no `..` in it (paths built from it print and store cleanly).
pub fn repo_root() -> PathBuf {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.parent().unwrap_or(here).to_path_buf()
}

/// Parses a model spec from its JSON bytes.
pub fn parse_spec(bytes: &[u8]) -> Result<ModelSpec, String> {
    serde_json::from_slice(bytes).map_err(|e| format!("model spec is not valid: {e}"))
}

/// Reads and parses the model spec at `path`, with its hash.
pub fn load_spec(path: &Path) -> Result<LoadedSpec, String> {
    let bytes = std::fs::read(path)
        .map_err(|e| format!("cannot read model spec {}: {e}", path.display()))?;
    let spec = parse_spec(&bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(LoadedSpec {
        spec,
        hash: crate::crc32::crc32(&bytes),
    })
}

/// The spec a library build was generated from, parsed from its text: `json` and `file_name`
/// are the build's `epssn::config::SPEC_JSON` and `SPEC_FILE_NAME` (`weights/epssn-s.json`
/// unless `EPSSN_SPEC` named another at build time).
pub fn built_spec(json: &str, file_name: &str) -> Result<ModelSpec, String> {
    parse_spec(json.as_bytes()).map_err(|e| format!("the built spec {file_name}: {e}"))
}

/// The grids of `spec` with `table`, its sonar's beam table, through the one derivation.
pub fn spec_grids(spec: &ModelSpec, table: &BeamTable) -> Result<ModelGrids, String> {
    ModelGrids::derive(spec, &table.centre_deg).map_err(|e| {
        format!(
            "model spec {} does not give valid grids with beam table {}: {e:?}",
            spec.name.as_str(),
            table.name
        )
    })
}

/// The bundled beam-table file of a table name: `<root>/data/aris-beam-widths/<name>.csv`.
pub fn beam_table_path(root: &Path, name: &str) -> PathBuf {
    root.join("data/aris-beam-widths")
        .join(format!("{name}.csv"))
}

/// One ARIS beam-angle table: per beam, the centre and the two edges, in degrees.
///
/// Beam 0 is the right-most beam (negative angle); the centres ascend with the beam index.
#[derive(Clone, Debug, PartialEq)]
pub struct BeamTable {
    /// Table name as in the SDK, e.g. `ARIS3000_128`.
    pub name: String,
    /// Beam centre angles, degrees, ascending.
    pub centre_deg: Vec<f64>,
    /// Left edge of each beam, degrees (as published).
    pub left_deg: Vec<f64>,
    /// Right edge of each beam, degrees (as published).
    pub right_deg: Vec<f64>,
}

impl BeamTable {
    /// Number of beams.
    pub fn beams(&self) -> usize {
        self.centre_deg.len()
    }

    /// Beam centres in radians, ascending (beam 0 first, right-most, negative).
    pub fn centres_rad(&self) -> Vec<f64> {
        self.centre_deg
            .iter()
            .map(|&d| crate::geometry::deg_to_rad(d))
            .collect()
    }

    /// (first, last) beam centre, degrees.
    pub fn centre_span_deg(&self) -> (f64, f64) {
        (
            self.centre_deg.first().copied().unwrap_or(f64::NAN),
            self.centre_deg.last().copied().unwrap_or(f64::NAN),
        )
    }
}

/// Parses one table's CSV (`beam,center_deg,left_deg,right_deg` with a header line).
///
/// Checks that beams are numbered 0, 1, 2, … and that the centres strictly ascend, because
/// the resampler relies on both.
pub fn parse_beam_table(name: &str, csv: &str) -> Result<BeamTable, String> {
    let mut table = BeamTable {
        name: name.into(),
        centre_deg: Vec::new(),
        left_deg: Vec::new(),
        right_deg: Vec::new(),
    };
    for (line_no, line) in csv.lines().enumerate().skip(1) {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != 4 {
            return Err(format!(
                "{name}: line {}: expected 4 fields, found {}",
                line_no + 1,
                fields.len()
            ));
        }
        let beam: usize = fields[0]
            .parse()
            .map_err(|e| format!("{name}: line {}: beam index: {e}", line_no + 1))?;
        if beam != table.centre_deg.len() {
            return Err(format!(
                "{name}: line {}: beam {beam} out of order (expected {})",
                line_no + 1,
                table.centre_deg.len()
            ));
        }
        let mut angles = [0.0f64; 3];
        for (slot, text) in angles.iter_mut().zip(&fields[1..]) {
            *slot = text
                .parse()
                .map_err(|e| format!("{name}: line {}: angle {text:?}: {e}", line_no + 1))?;
            if !slot.is_finite() {
                return Err(format!("{name}: line {}: angle is not finite", line_no + 1));
            }
        }
        table.centre_deg.push(angles[0]);
        table.left_deg.push(angles[1]);
        table.right_deg.push(angles[2]);
    }
    if table.centre_deg.len() < 2 {
        return Err(format!("{name}: fewer than two beams"));
    }
    if table.centre_deg.windows(2).any(|w| w[1] <= w[0]) {
        return Err(format!("{name}: beam centres do not strictly ascend"));
    }
    Ok(table)
}

/// Reads and parses the bundled beam table `name` below the repository `root`.
pub fn load_beam_table(root: &Path, name: &str) -> Result<BeamTable, String> {
    let path = beam_table_path(root, name);
    let csv = std::fs::read_to_string(&path)
        .map_err(|e| format!("cannot read beam table {}: {e}", path.display()))?;
    parse_beam_table(name, &csv)
}

/// The spec file a build is generated from: `EPSSN_SPEC` when set (relative paths from the
/// repository root `root`), else `<root>/weights/epssn-s.json`. Build scripts call this (after
/// `cargo:rerun-if-env-changed=EPSSN_SPEC`), so every crate of a build agrees on the spec.
pub fn build_spec_path(root: &Path) -> PathBuf {
    match std::env::var_os("EPSSN_SPEC") {
        Some(p) => root.join(p),
        None => root.join("weights").join(DEFAULT_SPEC_FILE),
    }
}

/// The default spec's file name in `weights/`: EPSSN-S, the Cortex-M7 configuration.
pub const DEFAULT_SPEC_FILE: &str = "epssn-s.json";

/// Every spec file in `weights/` a build can be generated from: EPSSN-S (Cortex-M7), EPSSN-P
/// (the paper's size, Cortex-M55) and EPSSN-PW (EPSSN-P with a 32-channel bottleneck).
pub const BUILD_SPECS: [&str; 3] = ["epssn-s.json", "epssn-p.json", "epssn-pw.json"];

/// A file kept per configuration, in `dir`: `<name>.<ext>` for the default spec (EPSSN-S's
/// `memory.x`, `budgets.json`), `<name>-<spec file stem>.<ext>` for any other
/// (`memory-epssn-p.x`, `budgets-epssn-p.json`).
pub fn per_spec_file(dir: &Path, name: &str, ext: &str, spec_file: &str) -> PathBuf {
    dir.join(format!("{}.{ext}", per_spec_name(name, spec_file)))
}

/// A name kept per configuration: `name` for the default spec, `name-<spec file stem>` for any
/// other (the demo's ground truth: `gt/`, `gt-epssn-p/`).
pub fn per_spec_name(name: &str, spec_file: &str) -> String {
    match non_default_stem(spec_file) {
        None => name.into(),
        Some(stem) => format!("{name}-{stem}"),
    }
}

/// A directory kept per configuration below `dir`: `dir` itself for the default spec,
/// `dir/<spec file stem>` for any other. Cargo target directories: the Cortex-M7 firmware of
/// EPSSN-S builds in `boards/mps2-an500/target`, EPSSN-P's in
/// `boards/mps2-an500/target/epssn-p`, so neither build rebuilds the other's artefacts.
pub fn per_spec_dir(dir: &Path, spec_file: &str) -> PathBuf {
    match non_default_stem(spec_file) {
        None => dir.to_path_buf(),
        Some(stem) => dir.join(stem),
    }
}

/// The stem that tells a configuration's files apart, `None` for the default spec (whose files
/// keep the plain names): the one test of "default or not" behind the `per_spec_*` names.
fn non_default_stem(spec_file: &str) -> Option<&str> {
    (spec_file != DEFAULT_SPEC_FILE).then(|| spec_stem(spec_file))
}

/// A spec file's name without `.json`: `epssn-p` for `epssn-p.json`.
pub fn spec_stem(spec_file: &str) -> &str {
    spec_file.strip_suffix(".json").unwrap_or(spec_file)
}

/// The weight blob the firmware of a build embeds, relative to `root`: `weights/FIRMWARE_WEIGHTS`
/// maps each spec file (its name in `weights/`) to the blob built for it, one
/// `<spec file> <blob path>` per line (`#` starts a comment). The one reader of that file: the
/// boards' self-test build script, the host tools and the examples all ask here.
pub fn firmware_blob(root: &Path, spec_file: &str) -> Result<PathBuf, String> {
    let pointer = root.join("weights/FIRMWARE_WEIGHTS");
    let text = std::fs::read_to_string(&pointer)
        .map_err(|e| format!("cannot read {}: {e}", pointer.display()))?;
    firmware_blob_in(&text, spec_file)
        .map(|rel| root.join(rel))
        .ok_or_else(|| {
            format!(
                "{} names no blob for the spec {spec_file} (add a line `{spec_file} <blob path>`)",
                pointer.display()
            )
        })
}

/// The blob path `text` (the contents of `weights/FIRMWARE_WEIGHTS`) gives for `spec_file`.
pub fn firmware_blob_in<'a>(text: &'a str, spec_file: &str) -> Option<&'a str> {
    text.lines()
        .map(|l| l.split('#').next().unwrap_or_default())
        .filter_map(|l| {
            let mut words = l.split_whitespace();
            Some((words.next()?, words.next()?))
        })
        .find_map(|(spec, blob)| (spec == spec_file).then_some(blob))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn firmware_pointer_lines_map_spec_files_to_blobs() {
        let text = "# spec -> blob\nepssn-s.json weights/general/epssn-s.q8.bin\n\n  epssn-p.json   weights/paper/epssn-p.q8.bin # the paper's size\n";
        assert_eq!(
            firmware_blob_in(text, "epssn-s.json"),
            Some("weights/general/epssn-s.q8.bin")
        );
        assert_eq!(
            firmware_blob_in(text, "epssn-p.json"),
            Some("weights/paper/epssn-p.q8.bin")
        );
        assert_eq!(firmware_blob_in(text, "other.json"), None);
        assert_eq!(firmware_blob_in("epssn-s.json\n", "epssn-s.json"), None);
    }

    #[test]
    fn per_spec_files_keep_the_default_names_for_epssn_s() {
        let d = Path::new("w");
        assert_eq!(
            per_spec_file(d, "budgets", "json", "epssn-s.json"),
            d.join("budgets.json")
        );
        assert_eq!(
            per_spec_file(d, "memory", "x", "epssn-p.json"),
            d.join("memory-epssn-p.x")
        );
    }

    #[test]
    fn per_spec_dirs_keep_the_default_dir_for_epssn_s() {
        let d = Path::new("boards/mps2-an500/target");
        assert_eq!(per_spec_dir(d, DEFAULT_SPEC_FILE), d);
        assert_eq!(per_spec_dir(d, "epssn-p.json"), d.join("epssn-p"));
        // The same rule as the names: the default keeps the plain one, others add the stem.
        assert_eq!(per_spec_name("gt", DEFAULT_SPEC_FILE), "gt");
        assert_eq!(per_spec_name("gt", "epssn-p.json"), "gt-epssn-p");
    }

    /// Every spec file below `dir` (JSON with a `spec_version`), recursively.
    fn spec_files(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                spec_files(&p, out);
            } else if p.extension().is_some_and(|x| x == "json")
                && std::fs::read_to_string(&p).is_ok_and(|t| t.contains("\"spec_version\""))
            {
                out.push(p);
            }
        }
    }

    #[test]
    fn unknown_fields_are_refused_by_name() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let good = std::fs::read_to_string(root.join("weights/epssn-s.json")).unwrap();
        assert!(parse_spec(good.as_bytes()).is_ok());
        for (from, to, field) in [
            (
                "\"mean_channels\"",
                "\"difference_channels\": 4, \"mean_channels\"",
                "difference_channels",
            ),
            (
                "\"planes\"",
                "\"plane_count\": 16, \"planes\"",
                "plane_count",
            ),
            (
                "\"relu\": true",
                "\"relu\": true, \"plane_bias\": true",
                "plane_bias",
            ),
        ] {
            assert!(good.contains(from), "{from}");
            let bad = good.replacen(from, to, 1);
            let err = parse_spec(bad.as_bytes()).unwrap_err();
            assert!(err.contains(field), "{field}: {err}");
        }
    }

    #[test]
    fn every_bundled_spec_parses() {
        // The build specs and every shipped model folder's spec.json (the options studied and
        // reverted are refused by name: `unknown_fields_are_refused_by_name`).
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let mut files = Vec::new();
        spec_files(&root.join("weights"), &mut files);
        let folders = ["general/spec.json", "paper/spec.json"];
        for name in BUILD_SPECS.iter().chain(&folders) {
            let path = root.join("weights").join(name);
            assert!(
                files.contains(&path),
                "{} not found among {files:?}",
                path.display()
            );
        }
        for f in &files {
            if let Err(e) = load_spec(f) {
                panic!("{}: {e}", f.display());
            }
        }
    }

    #[test]
    fn the_shipped_pointer_names_a_blob_for_every_bundled_spec() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        for spec in BUILD_SPECS {
            let blob = firmware_blob(&root, spec).unwrap();
            assert!(blob.is_file(), "{}", blob.display());
        }
    }
}
