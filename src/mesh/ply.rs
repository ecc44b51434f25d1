//! Binary PLY export, for viewers and DCC tools (Blender, MeshLab, trimesh), and a PLY
//! reader for scans.
//!
//! PLY here is an output format first: it stores 32-bit floats, so it is not an exact
//! exchange format (use OBJ, which round-trips `f64` bit-identically, for that).
//!
//! # Reading limits
//! Every element count of the header is checked before a row is read: all elements
//! together may declare at most [`crate::limits::MAX_PLY_ROWS`] rows, an element with rows
//! needs a property, and the rows must fit the bytes the file holds (each row takes at
//! least its scalars' sizes in binary, two bytes per value in ASCII). A list holds at most
//! 1000 items. ASCII errors name the file's line.

use std::collections::HashMap;
use std::io::{self, Write};
use std::path::Path;

use nalgebra::Point3;

use super::obj::{check_positions, write_atomically};
use super::{Mesh, MeshError};
use crate::file_error::FileError;

/// Writes `mesh` as a binary little-endian PLY 1.0 file, atomically (temporary file in
/// the same directory, then rename).
///
/// `positions` (#V) replaces the mesh's own positions when given (a shape sharing the
/// mesh's topology). Layout:
/// ```text
/// element vertex #V'      property float x, y, z
///                         property float s, t            (only with UVs)
/// element face #T         property list uchar int vertex_indices
/// ```
/// Faces are the mesh's triangulated view ([`Mesh::triangles`]: quads split along their
/// shorter diagonal in the neutral, other polygons fanned), so readers that expect one
/// face size (trimesh) read it. UVs are per vertex (`s`, `t`, the names Blender's and
/// trimesh's importers read): a vertex whose corners carry different UVs (a seam) is
/// written once per UV, the first copy at its own index, the others after the mesh's
/// vertices (`#V' ≥ #V`). Coordinates are rounded to the nearest `f32`.
///
/// # Errors
/// [`MeshError::Invalid`] (before the file is created) when `positions` has the wrong
/// length, a coordinate is not finite or too large for `f32`, or the mesh has more than
/// `i32::MAX` vertices; [`FileError::Io`] (naming `path`) when the file cannot be written.
pub fn write_ply(
    path: &Path,
    mesh: &Mesh,
    positions: Option<&[Point3<f64>]>,
) -> Result<(), MeshError> {
    let positions = positions.unwrap_or(&mesh.positions);
    check_positions(mesh, positions)?;
    let too_big = |x: f64| !(x as f32).is_finite();
    if let Some(v) = positions.iter().position(|p| p.iter().any(|&c| too_big(c))) {
        return Err(MeshError::Invalid(format!(
            "vertex {v} has a coordinate too large for a 32-bit float"
        )));
    }
    if let Some(t) = mesh.uvs.iter().position(|p| p.iter().any(|&c| too_big(c))) {
        return Err(MeshError::Invalid(format!(
            "texture coordinate {t} is too large for a 32-bit float"
        )));
    }
    let split = SeamSplit::new(mesh);
    if i32::try_from(split.vertices.len()).is_err() {
        return Err(MeshError::Invalid(format!(
            "{} vertices do not fit PLY's 32-bit signed indices",
            split.vertices.len()
        )));
    }
    write_atomically(path, |w| write_body(w, mesh, positions, &split))
}

/// The vertices of the PLY file: each a (mesh vertex, UV index) pair, and the triangles
/// in those vertices.
struct SeamSplit {
    /// Mesh vertex and UV index (None without UVs) of each written vertex.
    vertices: Vec<(u32, Option<u32>)>,
    /// Triangles, indices into `vertices`.
    triangles: Vec<[u32; 3]>,
}

impl SeamSplit {
    fn new(mesh: &Mesh) -> Self {
        let v_count = mesh.vertex_count();
        if !mesh.has_uvs() || mesh.triangle_uvs.len() != mesh.triangles.len() {
            return Self {
                vertices: (0..v_count as u32).map(|v| (v, None)).collect(),
                triangles: mesh.triangles.clone(),
            };
        }
        let mut vertices: Vec<(u32, Option<u32>)> =
            (0..v_count as u32).map(|v| (v, None)).collect();
        let mut extra: HashMap<(u32, u32), u32> = HashMap::new();
        let mut triangles = Vec::with_capacity(mesh.triangles.len());
        for (tri, uv) in mesh.triangles.iter().zip(&mesh.triangle_uvs) {
            let mut out = [0u32; 3];
            for k in 0..3 {
                let (v, t) = (tri[k], uv[k]);
                out[k] = match vertices[v as usize].1 {
                    None => {
                        vertices[v as usize].1 = Some(t);
                        v
                    }
                    Some(first) if first == t => v,
                    Some(_) => *extra.entry((v, t)).or_insert_with(|| {
                        vertices.push((v, Some(t)));
                        (vertices.len() - 1) as u32
                    }),
                };
            }
            triangles.push(out);
        }
        Self {
            vertices,
            triangles,
        }
    }
}

/// The PLY header and binary body; inputs were checked by [`write_ply`].
fn write_body<W: Write>(
    w: &mut W,
    mesh: &Mesh,
    positions: &[Point3<f64>],
    split: &SeamSplit,
) -> io::Result<()> {
    let has_uvs = mesh.has_uvs();
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\ncomment written by helmcap\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
        split.vertices.len()
    )?;
    if has_uvs {
        w.write_all(b"property float s\nproperty float t\n")?;
    }
    write!(
        w,
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        split.triangles.len()
    )?;
    for &(v, t) in &split.vertices {
        for c in positions[v as usize].iter() {
            w.write_all(&(*c as f32).to_le_bytes())?;
        }
        if has_uvs {
            // A vertex on no face has no UV: (0, 0).
            let uv = t
                .and_then(|t| mesh.uvs.get(t as usize))
                .copied()
                .unwrap_or_default();
            w.write_all(&(uv.x as f32).to_le_bytes())?;
            w.write_all(&(uv.y as f32).to_le_bytes())?;
        }
    }
    for tri in &split.triangles {
        w.write_all(&[3u8])?;
        for &v in tri {
            // The count was range-checked by `write_ply`.
            w.write_all(&(v as i32).to_le_bytes())?;
        }
    }
    Ok(())
}

/// Most items a list property of a PLY row may have (a face's corners).
const MAX_LIST_ITEMS: f64 = 1000.0;

/// Scalar types of PLY properties.
#[derive(Debug, Clone, Copy, PartialEq)]
enum PlyScalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl PlyScalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// Decodes one value from exactly `self.size()` bytes.
    fn decode(self, b: &[u8], little: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                (if little {
                    <$t>::from_le_bytes(a)
                } else {
                    <$t>::from_be_bytes(a)
                }) as f64
            }};
        }
        match self {
            Self::I8 => num!(i8, 1),
            Self::U8 => num!(u8, 1),
            Self::I16 => num!(i16, 2),
            Self::U16 => num!(u16, 2),
            Self::I32 => num!(i32, 4),
            Self::U32 => num!(u32, 4),
            Self::F32 => num!(f32, 4),
            Self::F64 => num!(f64, 8),
        }
    }
}

/// One property of a PLY element: a scalar, or a list (count type, item type).
#[derive(Debug, Clone)]
struct PlyProperty {
    name: String,
    scalar: PlyScalar,
    list_count: Option<PlyScalar>,
}

#[derive(Debug, Clone)]
struct PlyElement {
    name: String,
    count: usize,
    properties: Vec<PlyProperty>,
    /// Header line of the element (for errors).
    line: usize,
}

impl PlyElement {
    /// Fewest bytes one row takes: binary, the scalars' sizes and the lists' counts; ASCII,
    /// two per value (a digit and a separator).
    fn min_row_bytes(&self, binary: bool) -> u64 {
        self.properties
            .iter()
            .map(|p| match (binary, p.list_count) {
                (true, Some(c)) => c.size() as u64,
                (true, None) => p.scalar.size() as u64,
                (false, _) => 2,
            })
            .sum()
    }
}

/// Reads a PLY mesh (ASCII, binary little- or big-endian): the `vertex` element's `x y z`
/// (any scalar type) and the `face` element's `vertex_indices` (or `vertex_index`) lists;
/// other properties and elements are skipped. Scans from most scanners and tools load.
/// Units are the file's (PLY declares none).
///
/// # Errors
/// [`FileError::Io`] when the file cannot be read, [`FileError::Parse`] (line 0 for the
/// binary body) for a malformed header or body, [`MeshError::Empty`] without vertices or
/// faces, [`MeshError::Invalid`] for a bad index.
pub fn read_ply(path: &Path) -> Result<Mesh, MeshError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| {
        MeshError::File(FileError::Io {
            path: name.clone(),
            source,
        })
    })?;
    read_ply_bytes(&bytes, &name)
}

/// [`read_ply`] on the bytes of a file; `name` is used in errors.
///
/// # Errors
/// As [`read_ply`].
pub fn read_ply_bytes(bytes: &[u8], name: &str) -> Result<Mesh, MeshError> {
    let parse = |line: usize, message: String| {
        MeshError::File(FileError::Parse {
            path: name.to_string(),
            line,
            message,
        })
    };
    let end = b"end_header";
    let header_end = bytes
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| parse(1, "no end_header".into()))?;
    let mut body = header_end + end.len();
    while body < bytes.len() && bytes[body] != b'\n' {
        body += 1;
    }
    body += 1;
    let header = std::str::from_utf8(&bytes[..header_end])
        .map_err(|_| parse(1, "header is not text".into()))?;
    let mut lines = header.lines().enumerate();
    if lines.next().map(|(_, l)| l.trim()) != Some("ply") {
        return Err(parse(1, "not a PLY file (first line is not `ply`)".into()));
    }
    let mut format = None;
    let mut elements: Vec<PlyElement> = Vec::new();
    let mut declared_rows = 0u64;
    for (i, line) in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", f, _] => format = Some(f.to_string()),
            ["element", n, c] => {
                let count: u64 = c.parse().map_err(|_| {
                    parse(
                        i + 1,
                        format!("bad element count {}", crate::limits::quoted(c)),
                    )
                })?;
                declared_rows = declared_rows.saturating_add(count);
                if declared_rows > crate::limits::MAX_PLY_ROWS {
                    return Err(parse(
                        i + 1,
                        format!(
                            "element {} declares {count} rows; a PLY file may hold at most {} \
                             rows in all",
                            crate::limits::quoted(n),
                            crate::limits::MAX_PLY_ROWS
                        ),
                    ));
                }
                elements.push(PlyElement {
                    name: n.to_string(),
                    count: count as usize,
                    properties: Vec::new(),
                    line: i + 1,
                });
            }
            ["property", "list", c, t, n] => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| parse(i + 1, "property before any element".into()))?;
                e.properties.push(PlyProperty {
                    name: n.to_string(),
                    scalar: PlyScalar::parse(t).ok_or_else(|| {
                        parse(i + 1, format!("unknown type {}", crate::limits::quoted(t)))
                    })?,
                    list_count: Some(PlyScalar::parse(c).ok_or_else(|| {
                        parse(i + 1, format!("unknown type {}", crate::limits::quoted(c)))
                    })?),
                });
            }
            ["property", t, n] => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| parse(i + 1, "property before any element".into()))?;
                e.properties.push(PlyProperty {
                    name: n.to_string(),
                    scalar: PlyScalar::parse(t).ok_or_else(|| {
                        parse(i + 1, format!("unknown type {}", crate::limits::quoted(t)))
                    })?,
                    list_count: None,
                });
            }
            [] | ["comment", ..] | ["obj_info", ..] => {}
            _ => {
                return Err(parse(
                    i + 1,
                    format!("unexpected header line {}", crate::limits::quoted(line)),
                ));
            }
        }
    }
    let little = match format.as_deref() {
        Some("ascii") => None,
        Some("binary_little_endian") => Some(true),
        Some("binary_big_endian") => Some(false),
        other => return Err(parse(2, format!("unsupported format {other:?}"))),
    };
    // Every element's rows must fit the bytes the file holds before any is read: a
    // header cannot make the reader loop or allocate for rows that are not there.
    let body_bytes = bytes.len().saturating_sub(body) as u64;
    let mut needed = 0u64;
    for e in &elements {
        if e.properties.is_empty() && e.count > 0 {
            return Err(parse(
                e.line,
                format!(
                    "element {} declares {} rows but no property",
                    crate::limits::quoted(&e.name),
                    e.count
                ),
            ));
        }
        needed = needed
            .saturating_add((e.count as u64).saturating_mul(e.min_row_bytes(little.is_some())));
        if needed > body_bytes + 1 {
            return Err(parse(
                e.line,
                format!(
                    "element {} declares {} rows, more than the file's {body_bytes} bytes of \
                     data can hold",
                    crate::limits::quoted(&e.name),
                    e.count
                ),
            ));
        }
    }
    // Reads the values of one element row: scalars as one-element lists.
    let mut positions = Vec::new();
    let mut polygons: Vec<Vec<u32>> = Vec::new();
    let text_body = if little.is_none() {
        Some(
            std::str::from_utf8(&bytes[body.min(bytes.len())..])
                .map_err(|_| parse(0, "ASCII body is not text".into()))?,
        )
    } else {
        None
    };
    // ASCII tokens with their 1-based file line (the header's lines come first).
    let header_lines = 1 + bytes[..body.min(bytes.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count();
    let mut tokens = text_body.map(|t| {
        t.lines()
            .enumerate()
            .flat_map(move |(k, l)| l.split_whitespace().map(move |w| (header_lines + k, w)))
    });
    let mut last_line = header_lines;
    let mut offset = body;
    let mut next_value = |scalar: PlyScalar| -> Result<(f64, usize), MeshError> {
        match (&mut tokens, little) {
            (Some(t), _) => {
                let (line, tok) = t
                    .next()
                    .ok_or_else(|| parse(last_line, "the body ends early".into()))?;
                last_line = line;
                tok.parse::<f64>()
                    .map(|v| (v, line))
                    .map_err(|_| parse(line, format!("bad number {}", crate::limits::quoted(tok))))
            }
            (None, Some(le)) => {
                let size = scalar.size();
                let b = bytes
                    .get(offset..offset + size)
                    .ok_or_else(|| parse(0, "the binary body ends early".into()))?;
                offset += size;
                Ok((scalar.decode(b, le), 0))
            }
            (None, None) => Err(parse(0, "no body".into())),
        }
    };
    for e in &elements {
        let xyz: Vec<Option<usize>> = ["x", "y", "z"]
            .iter()
            .map(|c| e.properties.iter().position(|p| p.name == *c))
            .collect();
        for _ in 0..e.count {
            let mut row: Vec<Vec<f64>> = Vec::with_capacity(e.properties.len());
            let mut row_line = 0;
            for p in &e.properties {
                match p.list_count {
                    None => {
                        let (v, line) = next_value(p.scalar)?;
                        row_line = line;
                        row.push(vec![v]);
                    }
                    Some(c) => {
                        let (k, line) = next_value(c)?;
                        row_line = line;
                        // A polygon of more than 1000 corners is no mesh face; the items
                        // are read one by one (no allocation sized by the file).
                        if !(0.0..=MAX_LIST_ITEMS).contains(&k) || k.fract() != 0.0 {
                            return Err(parse(
                                line,
                                format!("bad list length {k} (0 to {MAX_LIST_ITEMS})"),
                            ));
                        }
                        let mut items = Vec::with_capacity(k as usize);
                        for _ in 0..k as usize {
                            items.push(next_value(p.scalar)?.0);
                        }
                        row.push(items);
                    }
                }
            }
            if e.name == "vertex" {
                let mut c = [0.0; 3];
                for (k, idx) in xyz.iter().enumerate() {
                    let idx =
                        idx.ok_or_else(|| parse(e.line, "vertex element without x, y, z".into()))?;
                    c[k] = row[idx][0];
                }
                positions.push(Point3::new(c[0], c[1], c[2]));
            } else if e.name == "face" {
                let idx = e
                    .properties
                    .iter()
                    .position(|p| p.name == "vertex_indices" || p.name == "vertex_index")
                    .ok_or_else(|| parse(e.line, "face element without vertex_indices".into()))?;
                let poly = row[idx]
                    .iter()
                    .map(|&v| {
                        if v >= 0.0 && v <= u32::MAX as f64 && v.fract() == 0.0 {
                            Ok(v as u32)
                        } else if row_line > 0 {
                            Err(parse(row_line, format!("bad vertex index {v}")))
                        } else {
                            Err(MeshError::Invalid(format!("{name}: bad vertex index {v}")))
                        }
                    })
                    .collect::<Result<Vec<u32>, _>>()?;
                polygons.push(poly);
            }
        }
    }
    if positions.is_empty() || polygons.is_empty() {
        return Err(MeshError::Empty {
            path: name.to_string(),
            message: "no vertices or no faces".into(),
        });
    }
    Mesh::new(positions, &polygons, Vec::new(), None)
}

/// Reads a mesh by its extension: `.ply` with [`read_ply`], anything else as OBJ.
///
/// # Errors
/// As the reader used.
pub fn read_mesh(path: &Path) -> Result<Mesh, MeshError> {
    let is_ply = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"));
    if is_ply {
        read_ply(path)
    } else {
        super::read_obj(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_meshes::{grid, tetrahedron};
    use nalgebra::Point2;

    /// A PLY file read back by an independent little parser.
    struct Ply {
        header: Vec<String>,
        vertices: Vec<[f32; 3]>,
        st: Vec<[f32; 2]>,
        faces: Vec<Vec<i32>>,
    }

    fn read_back(path: &Path) -> Ply {
        let bytes = std::fs::read(path).unwrap();
        let end = b"end_header\n";
        let body_start = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
        let header: Vec<String> = std::str::from_utf8(&bytes[..body_start])
            .unwrap()
            .lines()
            .map(str::to_string)
            .collect();
        let count = |element: &str| -> usize {
            let prefix = format!("element {element} ");
            header
                .iter()
                .find_map(|l| l.strip_prefix(&prefix))
                .unwrap()
                .parse()
                .unwrap()
        };
        let has_st = header.iter().any(|l| l == "property float s");
        let mut body = &bytes[body_start..];
        let mut take = |n: usize| {
            let (head, rest) = body.split_at(n);
            body = rest;
            head.to_vec()
        };
        let f32_at = |b: &[u8]| f32::from_le_bytes(b.try_into().unwrap());
        let mut vertices = Vec::new();
        let mut st = Vec::new();
        for _ in 0..count("vertex") {
            let b = take(12);
            vertices.push([f32_at(&b[0..4]), f32_at(&b[4..8]), f32_at(&b[8..12])]);
            if has_st {
                let b = take(8);
                st.push([f32_at(&b[0..4]), f32_at(&b[4..8])]);
            }
        }
        let mut faces = Vec::new();
        for _ in 0..count("face") {
            let n = take(1)[0] as usize;
            let b = take(4 * n);
            faces.push(
                b.chunks(4)
                    .map(|c| i32::from_le_bytes(c.try_into().unwrap()))
                    .collect(),
            );
        }
        assert!(body.is_empty(), "{} trailing bytes", body.len());
        Ply {
            header,
            vertices,
            st,
            faces,
        }
    }

    #[test]
    fn grid_with_uvs_reads_back_with_uvs_per_vertex_split_on_seams() {
        let mut mesh = grid(2, 0.5);
        // Give one corner of the last quad a different UV, as on a seam.
        mesh.uvs.push(Point2::new(0.25, 0.75));
        let last = mesh.face_uvs.len() - 1;
        mesh.face_uvs[last] = (mesh.uvs.len() - 1) as u32;
        mesh.triangulate();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid.ply");
        write_ply(&path, &mesh, None).unwrap();
        let ply = read_back(&path);

        assert_eq!(ply.header[0], "ply");
        assert_eq!(ply.header[1], "format binary_little_endian 1.0");
        // 9 vertices, one of them twice (the seam corner); 4 quads as 8 triangles.
        assert!(ply.header.contains(&"element vertex 10".to_string()));
        assert!(ply.header.contains(&"element face 8".to_string()));
        assert!(ply.header.contains(&"property float t".to_string()));
        for (v, p) in ply.vertices.iter().zip(&mesh.positions) {
            assert_eq!(*v, [p.x as f32, p.y as f32, p.z as f32]);
        }
        assert_eq!(ply.vertices[4], [0.5, 0.5, 0.0]);
        // Every triangle corner has its mesh vertex's position and its own UV.
        assert_eq!(ply.faces.len(), mesh.triangles.len());
        for ((face, tri), uv) in ply
            .faces
            .iter()
            .zip(&mesh.triangles)
            .zip(&mesh.triangle_uvs)
        {
            assert_eq!(face.len(), 3);
            for k in 0..3 {
                let w = face[k] as usize;
                let p = mesh.positions[tri[k] as usize];
                assert_eq!(ply.vertices[w], [p.x as f32, p.y as f32, p.z as f32]);
                let t = mesh.uvs[uv[k] as usize];
                assert_eq!(ply.st[w], [t.x as f32, t.y as f32]);
            }
        }
        assert!(ply.st.contains(&[0.25, 0.75]));
    }

    #[test]
    fn other_positions_without_uvs() {
        let mesh = tetrahedron();
        let moved: Vec<_> = mesh.positions.iter().map(|p| p * 2.0).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tet.ply");
        write_ply(&path, &mesh, Some(&moved)).unwrap();
        let ply = read_back(&path);
        assert!(!ply.header.iter().any(|l| l.contains("property float s")));
        assert!(ply.st.is_empty());
        assert_eq!(ply.vertices[3], [0.0, 0.0, 2.0]);
        assert_eq!(
            ply.faces,
            vec![vec![0, 2, 1], vec![0, 1, 3], vec![0, 3, 2], vec![1, 2, 3]]
        );
    }

    #[test]
    fn rejects_what_ply_cannot_hold_and_triangulates_big_polygons() {
        let mesh = tetrahedron();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.ply");
        let err = write_ply(&path, &mesh, Some(&mesh.positions[..3])).unwrap_err();
        assert!(matches!(err, MeshError::Invalid(_)), "{err}");
        let mut big = mesh.positions.clone();
        big[2].y = 1e39;
        let err = write_ply(&path, &mesh, Some(&big)).unwrap_err();
        assert!(err.to_string().contains("vertex 2"), "{err}");
        assert!(!path.exists());
        let ring: Vec<_> = (0..256)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / 256.0;
                Point3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let disc = Mesh::new(ring, &[(0..256).collect()], Vec::new(), None).unwrap();
        write_ply(&path, &disc, None).unwrap();
        assert_eq!(read_back(&path).faces.len(), 254);
        let err = write_ply(&dir.path().join("missing/bad.ply"), &mesh, None).unwrap_err();
        assert!(
            matches!(err, MeshError::File(FileError::Io { .. })),
            "{err}"
        );
    }

    /// Reproducers of the hardening issue: headers that declare huge element counts are
    /// refused before a row is read (one with no properties used to loop forever), and
    /// ASCII errors name the line.
    #[test]
    fn huge_declared_counts_are_refused_at_once_and_ascii_errors_name_the_line() {
        let t = std::time::Instant::now();
        let junk = "ply\nformat ascii 1.0\nelement junk 1000000000000000000\nend_header\n";
        let e = read_ply_bytes(junk.as_bytes(), "j.ply")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("j.ply:3: element \"junk\" declares"), "{e}");
        let empty_props = "ply\nformat binary_little_endian 1.0\nelement junk 5\nelement vertex 1\n\
                           property float x\nproperty float y\nproperty float z\nend_header\n";
        let e = read_ply_bytes(empty_props.as_bytes(), "j.ply")
            .unwrap_err()
            .to_string();
        assert!(e.contains("no property"), "{e}");
        let many = "ply\nformat binary_little_endian 1.0\nelement vertex 100000000\n\
                    property float x\nproperty float y\nproperty float z\nend_header\n\0\0";
        let e = read_ply_bytes(many.as_bytes(), "m.ply")
            .unwrap_err()
            .to_string();
        assert!(e.contains("more than the file's 2 bytes"), "{e}");
        let over =
            "ply\nformat ascii 1.0\nelement vertex 200000000\nproperty float x\nend_header\n";
        let e = read_ply_bytes(over.as_bytes(), "o.ply")
            .unwrap_err()
            .to_string();
        assert!(e.contains("at most 100000000 rows"), "{e}");
        assert!(t.elapsed().as_secs_f64() < 1.0);
        let bad = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                   property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                   end_header\n0 0 0\n1 zero 0\n3 0 1 1\n";
        let e = read_ply_bytes(bad.as_bytes(), "b.ply")
            .unwrap_err()
            .to_string();
        assert_eq!(e, "b.ply:11: bad number \"zero\"");
        let long = format!(
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
             property float z\nend_header\n0 {} 0\n",
            "9".repeat(100) + &"x".repeat(1_000_000)
        );
        let e = read_ply_bytes(long.as_bytes(), "l.ply")
            .unwrap_err()
            .to_string();
        assert!(e.len() < 200, "{}", e.len());
    }

    /// trimesh (the project's Python environment, when installed) reads a PLY of quads and
    /// triangles with UVs: every face a triangle, one UV per vertex, the seam split.
    #[test]
    fn trimesh_reads_mixed_polygons_and_uvs() {
        let env = std::env::var("HELMCAP_PYTHON_ENV")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|_| {
                std::path::PathBuf::from(std::env::var("HOME").unwrap_or_default())
                    .join(".cache/helmcap-python")
            });
        let python = env.join("bin/python");
        let probe = std::process::Command::new(&python)
            .args(["-c", "import trimesh"])
            .output();
        if !probe.is_ok_and(|o| o.status.success()) {
            println!(
                "skipping the trimesh check: no trimesh in {}",
                env.display()
            );
            return;
        }
        let mesh = crate::mesh::read_obj_str(
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\n\
             vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\nvt 0.9 0.1\n\
             f 1/1 2/2 3/3 4/4\nf 2/6 5/5 3/3\n",
            "m.obj",
        )
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.ply");
        write_ply(&path, &mesh, None).unwrap();
        let script = format!(
            "import trimesh\nm = trimesh.load({:?}, process=False)\n\
             print(len(m.vertices), len(m.faces), m.visual.uv.shape[0], \
             round(float(m.visual.uv[5][0]), 3), round(float(m.visual.uv[5][1]), 3))\n",
            path.to_str().unwrap()
        );
        let out = std::process::Command::new(&python)
            .args(["-c", &script])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        // 5 vertices + vertex 2 again with the other quad's UV; 1 quad + 1 triangle = 3
        // triangles; the extra vertex carries UV 6 (0.9, 0.1).
        assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), "6 3 6 0.9 0.1");
    }

    #[test]
    fn read_ply_round_trips_binary_and_reads_ascii() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("g.ply");
        let m = grid(4, 1.5);
        write_ply(&path, &m, None).unwrap();
        let back = read_ply(&path).unwrap();
        assert_eq!(back.triangles, m.triangles);
        for (a, b) in back.positions.iter().zip(&m.positions) {
            assert!((a - b).norm() < 1e-5);
        }
        let ascii = "ply\nformat ascii 1.0\ncomment x\nelement vertex 3\nproperty double x\n\
                     property double y\nproperty double z\nproperty uchar red\n\
                     element face 1\nproperty list uchar int vertex_index\nend_header\n\
                     0 0 0 255\n1 0 0 0\n0 1 0.5 9\n3 0 1 2\n";
        let t = read_ply_bytes(ascii.as_bytes(), "t.ply").unwrap();
        assert_eq!(t.positions[2], Point3::new(0.0, 1.0, 0.5));
        assert_eq!(t.triangles, vec![[0, 1, 2]]);
        let bad = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                   property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                   end_header\n0 0 0\n1 0 0\n";
        assert!(read_ply_bytes(bad.as_bytes(), "bad.ply").is_err());
    }
}
