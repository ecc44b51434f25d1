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
}
