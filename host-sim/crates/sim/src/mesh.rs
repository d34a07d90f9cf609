//! Triangle meshes of sites on disk: binary and ASCII STL through `stl_io`, PLY through
//! `ply-rs-bw`, OBJ by a reader of its own, and written back (binary STL, OBJ, ASCII PLY).
//!
//! A mesh is in metres, z up, its triangles in file order with f32 vertices (STL's own
//! precision), wound counter-clockwise seen from the water: the right-hand normal points away
//! from solid matter, which is how a site tells "inside an object" from "in the water". The
//! same mesh written in any of the three formats reads back as the same triangles, bit for bit,
//! so it renders the same samples.
//!
//! Every reader refuses broken, truncated or empty files and non-finite coordinates with a
//! [`MeshError`]; none panics on any input (the fuzz targets `mesh_stl`, `mesh_obj`, `mesh_ply`).

use std::collections::HashMap;
use std::io::{Cursor, Write};
use std::path::Path;

use sha2::{Digest, Sha256};

/// One triangle: three vertices, metres.
pub type Triangle = [[f32; 3]; 3];

/// A triangle mesh in file order.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    /// The triangles, wound counter-clockwise seen from the water.
    pub triangles: Vec<Triangle>,
}

/// The file formats a site can be read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// STL, binary or ASCII (told apart by the file's size and first line).
    Stl,
    /// Wavefront OBJ (polygons fanned into triangles).
    Obj,
    /// PLY, ASCII or binary (`vertex` x, y, z; `face` vertex_indices).
    Ply,
}

impl MeshFormat {
    /// The format a file name's extension names (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Self, MeshError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("stl") => Ok(Self::Stl),
            Some("obj") => Ok(Self::Obj),
            Some("ply") => Ok(Self::Ply),
            _ => Err(MeshError::UnknownFormat(path.display().to_string())),
        }
    }
}

/// Why a mesh file was refused.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The extension is none of .stl, .obj, .ply.
    #[error("{0}: unknown mesh format (expected .stl, .obj or .ply)")]
    UnknownFormat(String),
    /// The file could not be read.
    #[error("reading {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// The bytes are not a valid file of the format.
    #[error("broken {format} file: {detail}")]
    Broken {
        /// Format name.
        format: &'static str,
        /// What is wrong.
        detail: String,
    },
    /// A binary STL shorter than its triangle count says.
    #[error("truncated binary STL: the header counts {expected} triangles, the file holds {held}")]
    Truncated {
        /// Triangles the header counts.
        expected: u64,
        /// Whole triangles present.
        held: u64,
    },
    /// The file holds no triangle.
    #[error("the mesh has no triangles")]
    Empty,
    /// A coordinate is NaN or infinite.
    #[error("triangle {triangle} has a non-finite coordinate")]
    NonFinite {
        /// Index of the triangle in file order.
        triangle: usize,
    },
    /// A face names a vertex that does not exist.
    #[error("face {face} names vertex {index}, but there are {vertices} vertices")]
    BadIndex {
        /// Face index in file order.
        face: usize,
        /// The vertex index it names.
        index: i64,
        /// Vertices present.
        vertices: usize,
    },
}

fn broken(format: &'static str, detail: impl std::fmt::Display) -> MeshError {
    MeshError::Broken {
        format,
        detail: detail.to_string(),
    }
}

/// Reads a mesh file, its format from the extension.
pub fn read_mesh(path: &Path) -> Result<Mesh, MeshError> {
    let format = MeshFormat::from_path(path)?;
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_mesh(&bytes, format)
}

/// Parses a mesh from a file's bytes.
pub fn parse_mesh(bytes: &[u8], format: MeshFormat) -> Result<Mesh, MeshError> {
    let triangles = match format {
        MeshFormat::Stl => parse_stl(bytes)?,
        MeshFormat::Obj => parse_obj(bytes)?,
        MeshFormat::Ply => parse_ply(bytes)?,
    };
    checked(triangles)
}

/// Refuses an empty mesh or a non-finite coordinate.
fn checked(triangles: Vec<Triangle>) -> Result<Mesh, MeshError> {
    if triangles.is_empty() {
        return Err(MeshError::Empty);
    }
    if let Some(triangle) = triangles
        .iter()
        .position(|t| t.iter().flatten().any(|c| !c.is_finite()))
    {
        return Err(MeshError::NonFinite { triangle });
    }
    Ok(Mesh { triangles })
}

/// Bytes of a binary STL header plus triangle count, and of one triangle record.
const STL_HEADER: usize = 84;
const STL_RECORD: usize = 50;

/// STL through `stl_io`. A file whose size is exactly that of a binary STL of its count is
/// binary even when its header begins with `solid ` (as some exporters write), which would
/// make `stl_io` take it for ASCII: its header, which carries no geometry, is blanked first.
/// An ASCII file whose solid has no name (`solid` then a line break), which `stl_io` refuses,
/// is given the space it expects.
fn parse_stl(bytes: &[u8]) -> Result<Vec<Triangle>, MeshError> {
    let ascii = bytes.starts_with(b"solid") && bytes.get(5).is_some_and(u8::is_ascii_whitespace);
    let binary_count = (bytes.len() >= STL_HEADER)
        .then(|| u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64);
    let exact_binary = binary_count.is_some_and(|n| {
        n.checked_mul(STL_RECORD as u64) == Some((bytes.len() - STL_HEADER) as u64)
    });
    let data: std::borrow::Cow<[u8]> = if ascii && exact_binary {
        let mut copy = bytes.to_vec();
        copy[..6].fill(0);
        copy.into()
    } else if ascii && bytes[5] != b' ' {
        [b"solid ".as_slice(), &bytes[5..]].concat().into()
    } else {
        bytes.into()
    };
    if !ascii {
        let Some(expected) = binary_count else {
            return Err(broken(
                "STL",
                format!("{} bytes: shorter than a binary STL header", bytes.len()),
            ));
        };
        let held = ((bytes.len() - STL_HEADER) / STL_RECORD) as u64;
        if held < expected {
            return Err(MeshError::Truncated { expected, held });
        }
    }
    let mut cursor = Cursor::new(data.as_ref());
    let reader = stl_io::create_stl_reader(&mut cursor).map_err(|e| broken("STL", e))?;
    let mut out = Vec::new();
    for t in reader {
        let t = t.map_err(|e| broken("STL", e))?;
        out.push(t.vertices.map(|v| v.0));
    }
    Ok(out)
}

/// Wavefront OBJ, read here rather than through a crate so that every index is checked
/// before it is used: `v x y z [w]` lines give the vertices, `f` lines the polygons (each
/// corner `v`, `v/vt`, `v//vn` or `v/vt/vn`; only `v` is used), fanned into triangles from
/// their first corner. A positive index counts from 1 over the whole file; a negative one
/// counts back from the last vertex read before its face. Comments (`#`), line continuations
/// (`\`) and every other statement (texture, normal, group, material, line, point) are
/// skipped: a site has one reflectivity.
fn parse_obj(bytes: &[u8]) -> Result<Vec<Triangle>, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut vertices: Vec<[f32; 3]> = Vec::new();
    // Each polygon's corners as 0-based indices, resolved once every vertex is known.
    let mut polygons: Vec<(usize, Vec<(i64, i64)>)> = Vec::new();
    for (number, line) in logical_lines(&text) {
        let line = line.split('#').next().unwrap_or("");
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let mut p = [0f32; 3];
                for (c, axis) in p.iter_mut().zip(["x", "y", "z"]) {
                    *c = words.next().and_then(|w| w.parse().ok()).ok_or_else(|| {
                        broken(
                            "OBJ",
                            format!("line {number}: vertex has no numeric {axis}"),
                        )
                    })?;
                }
                vertices.push(p);
            }
            Some("f") => {
                let face = polygons.len();
                let corners = words
                    .map(|w| obj_corner(w, vertices.len()))
                    .collect::<Option<Vec<_>>>()
                    .ok_or_else(|| broken("OBJ", format!("line {number}: face {face} has a corner that is not a vertex index")))?;
                if corners.len() < 3 {
                    return Err(broken(
                        "OBJ",
                        format!("face {face} has fewer than 3 vertices"),
                    ));
                }
                polygons.push((face, corners));
            }
            _ => {}
        }
    }
    let mut out = Vec::new();
    for (face, corners) in &polygons {
        let corner = |&(i, written): &(i64, i64)| -> Result<[f32; 3], MeshError> {
            usize::try_from(i)
                .ok()
                .and_then(|u| vertices.get(u).copied())
                .ok_or(MeshError::BadIndex {
                    face: *face,
                    index: written,
                    vertices: vertices.len(),
                })
        };
        for k in 1..corners.len() - 1 {
            out.push([
                corner(&corners[0])?,
                corner(&corners[k])?,
                corner(&corners[k + 1])?,
            ]);
        }
    }
    Ok(out)
}

/// OBJ's lines with their 1-based numbers, a line ending in `\` joined to the next.
fn logical_lines(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut pending: Option<(usize, String)> = None;
    for (i, raw) in text.lines().enumerate() {
        let (number, mut line) = pending.take().unwrap_or((i + 1, String::new()));
        match raw.strip_suffix('\\') {
            Some(head) => {
                line.push_str(head);
                line.push(' ');
                pending = Some((number, line));
            }
            None => {
                line.push_str(raw);
                out.push((number, line));
            }
        }
    }
    out.extend(pending);
    out
}

/// A face corner's 0-based vertex index and the index as written: positive indices count
/// from 1, negative ones back from the `read` vertices so far. None for zero or a word that is
/// not an integer; an index past the end is left for the caller to refuse once the file is read.
fn obj_corner(word: &str, read: usize) -> Option<(i64, i64)> {
    let written: i64 = word.split('/').next()?.parse().ok()?;
    let resolved = match written {
        0 => return None,
        i if i > 0 => i - 1,
        i => (read as i64).checked_add(i)?,
    };
    Some((resolved, written))
}

/// PLY through `ply-rs-bw`: the `vertex` element's x, y, z (any numeric type, as f32) and the
/// `face` element's `vertex_indices` (or `vertex_index`) lists, polygons fanned.
fn parse_ply(bytes: &[u8]) -> Result<Vec<Triangle>, MeshError> {
    use ply_rs_bw::ply::{DefaultElement, Property};
    ply_counts_fit(bytes)?;
    let parser = ply_rs_bw::parser::Parser::<DefaultElement>::new();
    let ply = parser
        .read_ply(&mut Cursor::new(bytes))
        .map_err(|e| broken("PLY", e))?;
    let empty = Vec::new();
    let vertex_elements = ply.payload.get("vertex").unwrap_or(&empty);
    let mut vertices = Vec::with_capacity(vertex_elements.len());
    for (i, v) in vertex_elements.iter().enumerate() {
        let mut p = [0f32; 3];
        for (c, name) in p.iter_mut().zip(["x", "y", "z"]) {
            *c = v
                .get(name)
                .and_then(Property::to_f32_lossy)
                .ok_or_else(|| broken("PLY", format!("vertex {i} has no numeric {name}")))?;
        }
        vertices.push(p);
    }
    let faces = ply.payload.get("face").unwrap_or(&empty);
    let mut out = Vec::new();
    for (f, face) in faces.iter().enumerate() {
        let list = face
            .get("vertex_indices")
            .or_else(|| face.get("vertex_index"))
            .and_then(index_list)
            .ok_or_else(|| broken("PLY", format!("face {f} has no vertex_indices list")))?;
        if list.len() < 3 {
            return Err(broken("PLY", format!("face {f} has fewer than 3 vertices")));
        }
        let corner = |i: i64| -> Result<[f32; 3], MeshError> {
            usize::try_from(i)
                .ok()
                .and_then(|u| vertices.get(u).copied())
                .ok_or(MeshError::BadIndex {
                    face: f,
                    index: i,
                    vertices: vertices.len(),
                })
        };
        // A polygon as a fan from its first vertex, as OBJ polygons are.
        for k in 1..list.len() - 1 {
            out.push([corner(list[0])?, corner(list[k])?, corner(list[k + 1])?]);
        }
    }
    Ok(out)
}

/// Refuses a PLY header whose element counts exceed the bytes after it: every entry takes at
/// least one byte in any format, and the reader would otherwise build that many entries first
/// (an element without properties reads none, so a count of 10^12 would fill memory with
/// empty entries). A header without `end_header` is left for the reader to refuse.
fn ply_counts_fit(bytes: &[u8]) -> Result<(), MeshError> {
    const END: &[u8] = b"end_header";
    let Some(at) = bytes.windows(END.len()).position(|w| w == END) else {
        return Ok(());
    };
    let body_start = bytes[at..]
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |n| at + n + 1);
    let body = (bytes.len() - body_start) as u64;
    for line in String::from_utf8_lossy(&bytes[..at]).lines() {
        let mut words = line.split_whitespace();
        if words.next() != Some("element") {
            continue;
        }
        let (Some(name), Some(Ok(count))) = (words.next(), words.next().map(str::parse::<u64>))
        else {
            continue;
        };
        if count > body {
            return Err(broken(
                "PLY",
                format!("element {name} declares {count} entries; the {body} bytes after the header cannot hold them"),
            ));
        }
    }
    Ok(())
}

/// A PLY integer list property as i64 indices (None for floats and scalars).
fn index_list(p: &ply_rs_bw::ply::Property) -> Option<Vec<i64>> {
    use ply_rs_bw::ply::Property::*;
    Some(match p {
        ListChar(v) => v.iter().map(|&x| x as i64).collect(),
        ListUChar(v) => v.iter().map(|&x| x as i64).collect(),
        ListShort(v) => v.iter().map(|&x| x as i64).collect(),
        ListUShort(v) => v.iter().map(|&x| x as i64).collect(),
        ListInt(v) => v.iter().map(|&x| x as i64).collect(),
        ListUInt(v) => v.iter().map(|&x| x as i64).collect(),
        _ => return None,
    })
}

/// SHA-256 of a file's bytes, lower-case hex: what `scene.json` records of the site.
pub fn content_hash(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The right-hand unit normal of a triangle (zero for a degenerate one), f32 for STL.
fn face_normal(t: &Triangle) -> [f32; 3] {
    let e1 = [t[1][0] - t[0][0], t[1][1] - t[0][1], t[1][2] - t[0][2]];
    let e2 = [t[2][0] - t[0][0], t[2][1] - t[0][1], t[2][2] - t[0][2]];
    let n = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if len > 0.0 {
        n.map(|c| c / len)
    } else {
        [0.0; 3]
    }
}

/// The mesh as binary STL bytes (header text `epssn site, binary STL, metres, z up`).
pub fn to_stl(mesh: &Mesh) -> Vec<u8> {
    let mut out = Vec::with_capacity(STL_HEADER + STL_RECORD * mesh.triangles.len());
    let mut header = [b' '; 80];
    let text = b"epssn site, binary STL, metres, z up";
    header[..text.len()].copy_from_slice(text);
    out.extend_from_slice(&header);
    out.extend_from_slice(&(mesh.triangles.len() as u32).to_le_bytes());
    for t in &mesh.triangles {
        for c in face_normal(t).iter().chain(t.iter().flatten()) {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.extend_from_slice(&[0, 0]);
    }
    out
}

/// Distinct vertices in order of first use and each triangle's indices into them: OBJ and
/// PLY share vertices, and f32 bit patterns keep every value exact.
fn indexed(mesh: &Mesh) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let mut index: HashMap<[u32; 3], usize> = HashMap::new();
    let mut vertices = Vec::new();
    let faces = mesh
        .triangles
        .iter()
        .map(|t| {
            t.map(|v| {
                *index.entry(v.map(f32::to_bits)).or_insert_with(|| {
                    vertices.push(v);
                    vertices.len() - 1
                })
            })
        })
        .collect();
    (vertices, faces)
}

/// The mesh as OBJ text (f32 values in their shortest exact decimal form).
pub fn to_obj(mesh: &Mesh) -> Vec<u8> {
    let (vertices, faces) = indexed(mesh);
    let mut out = Vec::new();
    let _ = writeln!(out, "# epssn site: metres, z up");
    for v in &vertices {
        let _ = writeln!(out, "v {} {} {}", v[0], v[1], v[2]);
    }
    for f in &faces {
        let _ = writeln!(out, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    out
}

/// The mesh as ASCII PLY text (f32 values in their shortest exact decimal form).
pub fn to_ply(mesh: &Mesh) -> Vec<u8> {
    let (vertices, faces) = indexed(mesh);
    let mut out = Vec::new();
    let _ = write!(
        out,
        "ply\nformat ascii 1.0\ncomment epssn site: metres, z up\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n",
        vertices.len(),
        faces.len()
    );
    for v in &vertices {
        let _ = writeln!(out, "{} {} {}", v[0], v[1], v[2]);
    }
    for f in &faces {
        let _ = writeln!(out, "3 {} {} {}", f[0], f[1], f[2]);
    }
    out
}

/// The mesh in `format`'s bytes.
pub fn to_bytes(mesh: &Mesh, format: MeshFormat) -> Vec<u8> {
    match format {
        MeshFormat::Stl => to_stl(mesh),
        MeshFormat::Obj => to_obj(mesh),
        MeshFormat::Ply => to_ply(mesh),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> Mesh {
        Mesh {
            triangles: vec![
                [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]],
                [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.1, 1.0 / 3.0, 1e-7]],
            ],
        }
    }

    #[test]
    fn a_ply_count_past_the_file_is_refused_before_reading() {
        // Found by the mesh_ply fuzz target: an element without properties and a count of
        // 10^12 made the reader build that many empty entries (out of memory).
        let fuzzed = b"ply\nformat binary_little_endian 1.0\nelement veccccccccex 1111111111111\nend_header\nrope\0x\0\0";
        let e = parse_mesh(fuzzed, MeshFormat::Ply).unwrap_err().to_string();
        assert!(e.contains("1111111111111 entries"), "{e}");
        // The same for a vertex count a binary body cannot hold.
        let mut short = to_bytes(&square(), MeshFormat::Ply);
        let text = String::from_utf8_lossy(&short).into_owned();
        let at = text.find("element vertex ").unwrap();
        let end = at + text[at..].find('\n').unwrap();
        short.splice(at..end, b"element vertex 99999999".iter().copied());
        assert!(parse_mesh(&short, MeshFormat::Ply).is_err());
    }

    #[test]
    fn every_format_reads_back_the_same_triangles() {
        let mesh = square();
        for format in [MeshFormat::Stl, MeshFormat::Obj, MeshFormat::Ply] {
            let back = parse_mesh(&to_bytes(&mesh, format), format).unwrap();
            assert_eq!(back, mesh, "{format:?}");
        }
        // ASCII STL, and a binary STL whose header begins with "solid ".
        let ascii = "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n\
                     vertex 1 1 0\nendloop\nendfacet\nendsolid s\n";
        let m = parse_mesh(ascii.as_bytes(), MeshFormat::Stl).unwrap();
        assert_eq!(m.triangles, mesh.triangles[..1]);
        let unnamed = ascii.replacen("solid s\n", "solid\r\n", 1);
        assert_eq!(parse_mesh(unnamed.as_bytes(), MeshFormat::Stl).unwrap(), m);
        let mut stl = to_stl(&mesh);
        stl[..6].copy_from_slice(b"solid ");
        assert_eq!(parse_mesh(&stl, MeshFormat::Stl).unwrap(), mesh);
    }

    #[test]
    fn broken_truncated_empty_and_non_finite_files_are_refused() {
        let stl = to_stl(&square());
        let err = |bytes: &[u8], f| parse_mesh(bytes, f).unwrap_err().to_string();
        assert!(err(&stl[..stl.len() - 1], MeshFormat::Stl).contains("truncated"));
        assert!(err(&stl[..40], MeshFormat::Stl).contains("shorter"));
        assert!(err(&stl[..84], MeshFormat::Stl).contains("truncated"));
        let mut none = stl[..84].to_vec();
        none[80..84].fill(0);
        assert!(err(&none, MeshFormat::Stl).contains("no triangles"));
        let mut nan = stl.clone();
        nan[84 + 12..84 + 16].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(err(&nan, MeshFormat::Stl).contains("non-finite"));
        assert!(err(
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n",
            MeshFormat::Stl
        )
        .contains("broken STL"));
        assert!(err(b"", MeshFormat::Obj).contains("no triangles"));
        assert!(err(b"v 0 0 0\nv 1 0 0\nf 1 2 9\n", MeshFormat::Obj).contains("vertex 9"));
        assert!(err(b"v 0 0 0\nv 1 0 0\nf 1 2 -3\n", MeshFormat::Obj).contains("vertex -3"));
        assert!(err(b"v 0 0 0\nv 1 0 0\nf 1 2 0\n", MeshFormat::Obj).contains("broken OBJ"));
        assert!(err(b"v 0 0\nf 1 1 1\n", MeshFormat::Obj).contains("numeric z"));
        assert!(err(b"v 0 0 0\nf 1 1\n", MeshFormat::Obj).contains("fewer than 3"));
        assert!(
            err(b"v 0 0 inf\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", MeshFormat::Obj).contains("non-finite")
        );
        let ply = to_ply(&square());
        assert!(err(&ply[..ply.len() - 8], MeshFormat::Ply).contains("PLY"));
        assert!(
            err(b"ply\nformat ascii 1.0\nend_header\n", MeshFormat::Ply).contains("no triangles")
        );
        let bad_index = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n\
            property float y\nproperty float z\nelement face 1\n\
            property list uchar int vertex_indices\nend_header\n0 0 0\n3 0 0 5\n";
        assert!(err(bad_index, MeshFormat::Ply).contains("vertex 5"));
        assert!(read_mesh(Path::new("site.dxf")).is_err());
    }

    /// What exporters write beyond `v` and `f` lines: texture and normal indices, negative
    /// (relative) indices, quads, groups, comments and continued lines, all read as the same
    /// two triangles.
    #[test]
    fn obj_as_exporters_write_it_reads_as_the_same_triangles() {
        let plain = parse_mesh(
            b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
            MeshFormat::Obj,
        )
        .unwrap();
        let written = b"# exported\nmtllib site.mtl\no tank\ng wall\nv 0 0 0\nv 1 0 0 1.0\n\
            v 1 1 0\nv 0 1 0 # corner\nvt 0 0\nvn 0 0 1\nusemtl steel\ns off\n\
            f -4/1/1 -3/1/1 \\\n -2//1 -1/1\nl 1 2\np 3\n";
        assert_eq!(parse_mesh(written, MeshFormat::Obj).unwrap(), plain);
        assert_eq!(plain.triangles.len(), 2);
        assert_eq!(
            plain.triangles[1],
            [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
        );
    }

    /// Inputs the fuzz target found, kept so that they stay errors.
    #[test]
    fn obj_fuzz_findings_are_refused() {
        // A texture index far past the end with a vertex index past i64's range of products.
        let huge = b"vt 0 0\nf 1/ 2/-2161 5 6 2\nf -21/1  0 1 0\nv 0 0 1\nf -1 -2 -7\n";
        assert!(parse_mesh(huge, MeshFormat::Obj).is_err());
        let beyond = format!("v 0 0 0\nf 1 1 -{}\n", u64::MAX);
        assert!(parse_mesh(beyond.as_bytes(), MeshFormat::Obj).is_err());
        let far = format!("v 0 0 0\nf 1 1 {}\n", i64::MAX);
        assert!(parse_mesh(far.as_bytes(), MeshFormat::Obj).is_err());
    }

    /// Every prefix and many one-byte changes of valid files: errors or meshes, never a panic
    /// (the fuzz targets go further).
    #[test]
    fn cut_and_corrupted_files_never_panic() {
        let mesh = square();
        for format in [MeshFormat::Stl, MeshFormat::Obj, MeshFormat::Ply] {
            let bytes = to_bytes(&mesh, format);
            for n in 0..bytes.len() {
                let _ = parse_mesh(&bytes[..n], format);
            }
            for i in 0..bytes.len() {
                for v in [0u8, b'-', b'9', 0xff] {
                    let mut b = bytes.clone();
                    b[i] = v;
                    if let Ok(m) = parse_mesh(&b, format) {
                        assert!(m
                            .triangles
                            .iter()
                            .flatten()
                            .flatten()
                            .all(|c| c.is_finite()));
                    }
                }
            }
        }
    }
}
