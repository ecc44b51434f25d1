//! Binary PLY export, for viewers (MeshLab, Blender, CloudCompare).
//!
//! PLY here is an output format only: it stores 32-bit floats, so it is not an exact
//! exchange format (use OBJ, which round-trips `f64` bit-identically, for that).

use std::io::{self, Write};
use std::path::Path;

use nalgebra::Point3;

use super::obj::{check_positions, write_atomically};
use super::{Mesh, MeshError};

/// Writes `mesh` as a binary little-endian PLY 1.0 file, atomically (temporary file in
/// the same directory, then rename).
///
/// `positions` (#V) replaces the mesh's own positions when given (a shape sharing the
/// mesh's topology). Layout:
/// ```text
/// element vertex #V       property float x, y, z
/// element face #F         property list uchar int vertex_indices
///                         property list uchar float texcoord     (only with UVs)
/// ```
/// Polygons are written as given (quads stay quads). `texcoord` is MeshLab's per-face
/// wedge convention: `2 n` floats `u0 v0 u1 v1 …`, one `(u, v)` pair per corner in the
/// polygon's corner order. Coordinates are rounded to the nearest `f32`.
///
/// # Errors
/// [`MeshError::Invalid`] (before the file is created) when `positions` has the wrong
/// length, a coordinate is not finite or too large for `f32`, a polygon has more than 255
/// corners, or the mesh has more than `i32::MAX` vertices; [`MeshError::Io`] (naming
/// `path`) when the file cannot be written.
pub fn write_ply(
    path: &Path,
    mesh: &Mesh,
    positions: Option<&[Point3<f64>]>,
) -> Result<(), MeshError> {
    let positions = positions.unwrap_or(&mesh.positions);
    check_positions(mesh, positions)?;
    if i32::try_from(mesh.vertex_count()).is_err() {
        return Err(MeshError::Invalid(format!(
            "{} vertices do not fit PLY's 32-bit signed indices",
            mesh.vertex_count()
        )));
    }
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
    if let Some(f) = mesh.faces().position(|f| f.len() > usize::from(u8::MAX)) {
        return Err(MeshError::Invalid(format!(
            "polygon {f} has {} corners; PLY's uchar count holds at most 255",
            mesh.face(f).len()
        )));
    }
    write_atomically(path, |w| write_body(w, mesh, positions))
}

/// The PLY header and binary body; inputs were checked by [`write_ply`].
fn write_body<W: Write>(w: &mut W, mesh: &Mesh, positions: &[Point3<f64>]) -> io::Result<()> {
    let has_uvs = mesh.has_uvs();
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\ncomment written by helmcap\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\n",
        positions.len(),
        mesh.face_count()
    )?;
    if has_uvs {
        w.write_all(b"property list uchar float texcoord\n")?;
    }
    w.write_all(b"end_header\n")?;
    for p in positions {
        for c in p.iter() {
            w.write_all(&(*c as f32).to_le_bytes())?;
        }
    }
    for f in 0..mesh.face_count() {
        let corners = mesh.face(f);
        // Lengths and indices were range-checked by `write_ply`.
        w.write_all(&[corners.len() as u8])?;
        for &v in corners {
            w.write_all(&(v as i32).to_le_bytes())?;
        }
        if has_uvs {
            w.write_all(&[(2 * corners.len()) as u8])?;
            for &t in mesh.face_uv(f) {
                let uv = mesh.uvs[t as usize];
                w.write_all(&(uv.x as f32).to_le_bytes())?;
                w.write_all(&(uv.y as f32).to_le_bytes())?;
            }
        }
    }
    Ok(())
}

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
}

/// Reads a PLY mesh (ASCII, binary little- or big-endian): the `vertex` element's `x y z`
/// (any scalar type) and the `face` element's `vertex_indices` (or `vertex_index`) lists;
/// other properties and elements are skipped. Scans from most scanners and tools load.
/// Units are the file's (PLY declares none).
///
/// # Errors
/// [`MeshError::Io`] when the file cannot be read, [`MeshError::Parse`] (line 0 for the
/// binary body) for a malformed header or body, [`MeshError::Empty`] without vertices or
/// faces, [`MeshError::Invalid`] for a bad index.
pub fn read_ply(path: &Path) -> Result<Mesh, MeshError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
        path: name.clone(),
        source,
    })?;
    read_ply_bytes(&bytes, &name)
}

/// [`read_ply`] on the bytes of a file; `name` is used in errors.
///
/// # Errors
/// As [`read_ply`].
pub fn read_ply_bytes(bytes: &[u8], name: &str) -> Result<Mesh, MeshError> {
    let parse = |line: usize, message: String| MeshError::Parse {
        path: name.to_string(),
        line,
        message,
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
    for (i, line) in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", f, _] => format = Some(f.to_string()),
            ["element", n, c] => elements.push(PlyElement {
                name: n.to_string(),
                count: c
                    .parse()
                    .map_err(|_| parse(i + 1, format!("bad element count {c:?}")))?,
                properties: Vec::new(),
            }),
            ["property", "list", c, t, n] => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| parse(i + 1, "property before any element".into()))?;
                e.properties.push(PlyProperty {
                    name: n.to_string(),
                    scalar: PlyScalar::parse(t)
                        .ok_or_else(|| parse(i + 1, format!("unknown type {t:?}")))?,
                    list_count: Some(
                        PlyScalar::parse(c)
                            .ok_or_else(|| parse(i + 1, format!("unknown type {c:?}")))?,
                    ),
                });
            }
            ["property", t, n] => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| parse(i + 1, "property before any element".into()))?;
                e.properties.push(PlyProperty {
                    name: n.to_string(),
                    scalar: PlyScalar::parse(t)
                        .ok_or_else(|| parse(i + 1, format!("unknown type {t:?}")))?,
                    list_count: None,
                });
            }
            [] | ["comment", ..] | ["obj_info", ..] => {}
            _ => return Err(parse(i + 1, format!("unexpected header line {line:?}"))),
        }
    }
    let little = match format.as_deref() {
        Some("ascii") => None,
        Some("binary_little_endian") => Some(true),
        Some("binary_big_endian") => Some(false),
        other => return Err(parse(2, format!("unsupported format {other:?}"))),
    };
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
    let mut tokens = text_body.map(|t| t.split_whitespace());
    let mut offset = body;
    let mut next_value = |scalar: PlyScalar| -> Result<f64, MeshError> {
        match (&mut tokens, little) {
            (Some(t), _) => {
                let tok = t
                    .next()
                    .ok_or_else(|| parse(0, "the body ends early".into()))?;
                tok.parse::<f64>()
                    .map_err(|_| parse(0, format!("bad number {tok:?}")))
            }
            (None, Some(le)) => {
                let size = scalar.size();
                let b = bytes
                    .get(offset..offset + size)
                    .ok_or_else(|| parse(0, "the binary body ends early".into()))?;
                offset += size;
                Ok(scalar.decode(b, le))
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
            for p in &e.properties {
                match p.list_count {
                    None => row.push(vec![next_value(p.scalar)?]),
                    Some(c) => {
                        let k = next_value(c)?;
                        if !(0.0..=1.0e6).contains(&k) {
                            return Err(parse(0, format!("bad list length {k}")));
                        }
                        let mut items = Vec::with_capacity(k as usize);
                        for _ in 0..k as usize {
                            items.push(next_value(p.scalar)?);
                        }
                        row.push(items);
                    }
                }
            }
            if e.name == "vertex" {
                let mut c = [0.0; 3];
                for (k, idx) in xyz.iter().enumerate() {
                    let idx =
                        idx.ok_or_else(|| parse(0, "vertex element without x, y, z".into()))?;
                    c[k] = row[idx][0];
                }
                positions.push(Point3::new(c[0], c[1], c[2]));
            } else if e.name == "face" {
                let idx = e
                    .properties
                    .iter()
                    .position(|p| p.name == "vertex_indices" || p.name == "vertex_index")
                    .ok_or_else(|| parse(0, "face element without vertex_indices".into()))?;
                let poly = row[idx]
                    .iter()
                    .map(|&v| {
                        if v >= 0.0 && v <= u32::MAX as f64 && v.fract() == 0.0 {
                            Ok(v as u32)
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
        faces: Vec<Vec<i32>>,
        texcoords: Vec<Vec<f32>>,
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
        let has_tex = header
            .iter()
            .any(|l| l == "property list uchar float texcoord");
        let mut body = &bytes[body_start..];
        let mut take = |n: usize| {
            let (head, rest) = body.split_at(n);
            body = rest;
            head.to_vec()
        };
        let f32_at = |b: &[u8]| f32::from_le_bytes(b.try_into().unwrap());
        let vertices = (0..count("vertex"))
            .map(|_| {
                let b = take(12);
                [f32_at(&b[0..4]), f32_at(&b[4..8]), f32_at(&b[8..12])]
            })
            .collect();
        let mut faces = Vec::new();
        let mut texcoords = Vec::new();
        for _ in 0..count("face") {
            let n = take(1)[0] as usize;
            let b = take(4 * n);
            faces.push(
                b.chunks(4)
                    .map(|c| i32::from_le_bytes(c.try_into().unwrap()))
                    .collect(),
            );
            if has_tex {
                let n = take(1)[0] as usize;
                texcoords.push(take(4 * n).chunks(4).map(f32_at).collect());
            }
        }
        assert!(body.is_empty(), "{} trailing bytes", body.len());
        Ply {
            header,
            vertices,
            faces,
            texcoords,
        }
    }

    #[test]
    fn grid_with_uvs_reads_back() {
        let mut mesh = grid(2, 0.5);
        // Give one corner of the last quad a different UV, as on a seam.
        mesh.uvs.push(Point2::new(0.25, 0.75));
        let last = mesh.face_uvs.len() - 1;
        mesh.face_uvs[last] = (mesh.uvs.len() - 1) as u32;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid.ply");
        write_ply(&path, &mesh, None).unwrap();
        let ply = read_back(&path);

        assert_eq!(ply.header[0], "ply");
        assert_eq!(ply.header[1], "format binary_little_endian 1.0");
        assert!(ply.header.contains(&"element vertex 9".to_string()));
        assert!(ply.header.contains(&"element face 4".to_string()));
        assert_eq!(ply.vertices.len(), 9);
        for (v, p) in ply.vertices.iter().zip(&mesh.positions) {
            assert_eq!(*v, [p.x as f32, p.y as f32, p.z as f32]);
        }
        assert_eq!(ply.vertices[4], [0.5, 0.5, 0.0]);
        for (f, face) in ply.faces.iter().enumerate() {
            let expected: Vec<i32> = mesh.face(f).iter().map(|&v| v as i32).collect();
            assert_eq!(*face, expected);
            let uvs: Vec<f32> = mesh
                .face_uv(f)
                .iter()
                .flat_map(|&t| [mesh.uvs[t as usize].x as f32, mesh.uvs[t as usize].y as f32])
                .collect();
            assert_eq!(ply.texcoords[f], uvs);
        }
        assert_eq!(ply.texcoords[3][6..], [0.25, 0.75]);
    }

    #[test]
    fn other_positions_without_uvs() {
        let mesh = tetrahedron();
        let moved: Vec<_> = mesh.positions.iter().map(|p| p * 2.0).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tet.ply");
        write_ply(&path, &mesh, Some(&moved)).unwrap();
        let ply = read_back(&path);
        assert!(!ply.header.iter().any(|l| l.contains("texcoord")));
        assert!(ply.texcoords.is_empty());
        assert_eq!(ply.vertices[3], [0.0, 0.0, 2.0]);
        assert_eq!(
            ply.faces,
            vec![vec![0, 2, 1], vec![0, 1, 3], vec![0, 3, 2], vec![1, 2, 3]]
        );
    }

    #[test]
    fn rejects_what_ply_cannot_hold() {
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
        let err = write_ply(&path, &disc, None).unwrap_err();
        assert!(err.to_string().contains("256 corners"), "{err}");
        assert!(!path.exists());
        let err = write_ply(&dir.path().join("missing/bad.ply"), &mesh, None).unwrap_err();
        assert!(matches!(err, MeshError::Io { .. }), "{err}");
    }

    #[test]
    fn read_ply_round_trips_binary_and_reads_ascii() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("g.ply");
        let m = grid(4, 1.5);
        write_ply(&path, &m, None).unwrap();
        let back = read_ply(&path).unwrap();
        assert_eq!(back.face_vertices, m.face_vertices);
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
