//! The site mesh reader for OBJ files (`epssn_sim::mesh`) on arbitrary bytes: a broken,
//! truncated or empty file must come back as an error, never a panic.
#![no_main]

use epssn_sim::mesh::{parse_mesh, MeshFormat};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(mesh) = parse_mesh(data, MeshFormat::Obj) {
        assert!(!mesh.triangles.is_empty());
        assert!(mesh.triangles.iter().flatten().flatten().all(|c| c.is_finite()));
    }
});
