//! Polygon meshes: the [`Mesh`] type, OBJ/PLY I/O, topology and differential operators.
//!
//! This is the lowest geometry layer of helmcap: it depends on `nalgebra`,
//! `nalgebra-sparse`, `tracing` (warnings about skipped OBJ statements) and
//! [`crate::atomic_file`], never on a higher module.
//!
//! A [`Mesh`] keeps its polygons exactly as given (quads stay quads, so exports keep the
//! artist's topology) and carries a triangulated view ([`Mesh::triangles`]) that every
//! processing step (normals, areas, Laplacians) uses. Texture coordinates are per corner,
//! as in OBJ: a pool of UVs plus one UV index per polygon corner, so UV seams survive.
//!
//! Units are whatever the caller loaded; the dataset layer converts to millimetres.

pub mod geodesic;
pub mod geometry;
pub mod laplacian;
pub mod obj;
pub mod ply;
pub mod subdivide;
pub mod topology;

use nalgebra::{Point2, Point3};

use crate::file_error::FileError;

pub use geodesic::{edge_graph_distances, update_edge_graph_distances};
pub use geometry::{
    triangle_areas, triangle_areas_of, triangle_normals, vertex_areas, vertex_normals,
    vertex_normals_of, vertex_normals_of_triangles,
};
pub use laplacian::{
    MassKind, cotangent_laplacian, cotangent_laplacian_of, mass_matrix, mass_matrix_of,
    uniform_laplacian,
};
pub use obj::{
    read_obj, read_obj_positions, read_obj_str, write_obj, write_obj_positions, write_obj_to,
};

pub use ply::{read_mesh, read_ply, read_ply_bytes, write_ply};
pub use subdivide::{Subdivision, SubdivisionScheme, subdivide_levels};
pub use topology::{Topology, boundary_loops, edges, vertex_adjacency};

/// Errors from building, reading or writing a mesh.
///
/// Every variant says what was wrong and where (file and line when known).
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be read or written, or a line of it is malformed.
    #[error(transparent)]
    File(#[from] FileError),
    /// The file holds no vertices or no faces.
    #[error("{path}: {message}")]
    Empty {
        /// The file involved.
        path: String,
        /// What is missing.
        message: String,
    },
    /// The mesh data is inconsistent (index out of range, non-finite coordinate, ...).
    #[error("invalid mesh: {0}")]
    Invalid(String),
}

/// A polygon mesh with per-corner texture coordinates and a triangulated view.
///
/// # Layout
/// Polygons are stored flat: polygon `f` has corners
/// `face_vertices[face_offsets[f]..face_offsets[f + 1]]`. When the mesh has UVs,
/// `face_uvs` runs parallel to `face_vertices` and indexes into `uvs`.
///
/// The triangulated view splits each polygon into `n - 2` triangles: quads along their
/// shorter diagonal (measured when the mesh is built), larger polygons as a fan from the
/// first corner. `triangle_face[t]` names the polygon triangle `t` came from, and
/// `triangle_uvs` (when UVs exist) carries the UV index of each triangle corner.
#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    /// Vertex positions (#V).
    pub positions: Vec<Point3<f64>>,
    /// Texture coordinate pool (#UV); empty when the mesh has no UVs.
    pub uvs: Vec<Point2<f64>>,
    /// Start of each polygon in `face_vertices` (#F + 1 entries, first 0, last = corners).
    pub face_offsets: Vec<u32>,
    /// Vertex index of every polygon corner.
    pub face_vertices: Vec<u32>,
    /// UV index of every polygon corner (parallel to `face_vertices`), or empty.
    pub face_uvs: Vec<u32>,
    /// Material library named by the source file (`mtllib`), kept for export.
    pub mtllib: Option<String>,
    /// Material runs: `(first polygon, material name)`, ascending; each run lasts until the
    /// next one starts. Kept for export only.
    pub materials: Vec<(u32, String)>,
    /// Triangulated view: vertex indices of each triangle (#T).
    pub triangles: Vec<[u32; 3]>,
    /// Polygon each triangle came from (#T).
    pub triangle_face: Vec<u32>,
    /// UV indices of each triangle corner (#T), or empty when the mesh has no UVs.
    pub triangle_uvs: Vec<[u32; 3]>,
}

impl Mesh {
    /// Builds a mesh from positions and polygons, validating every index and coordinate.
    ///
    /// `polygons` holds one vertex-index list per polygon (at least 3 corners each);
    /// `polygon_uvs`, when given, holds the matching UV-index lists.
    ///
    /// # Errors
    /// [`MeshError::Invalid`] for a polygon with fewer than 3 corners, an index out of
    /// range, a polygon repeating a vertex, mismatched UV lists or a non-finite coordinate.
    pub fn new(
        positions: Vec<Point3<f64>>,
        polygons: &[Vec<u32>],
        uvs: Vec<Point2<f64>>,
        polygon_uvs: Option<&[Vec<u32>]>,
    ) -> Result<Self, MeshError> {
        let mut face_offsets = Vec::with_capacity(polygons.len() + 1);
        let mut face_vertices = Vec::new();
        let mut face_uvs = Vec::new();
        face_offsets.push(0u32);
        if let Some(puv) = polygon_uvs
            && puv.len() != polygons.len()
        {
            return Err(MeshError::Invalid(format!(
                "{} polygons but {} UV polygons",
                polygons.len(),
                puv.len()
            )));
        }
        for (f, poly) in polygons.iter().enumerate() {
            face_vertices.extend_from_slice(poly);
            if let Some(puv) = polygon_uvs {
                let uv = &puv[f];
                if uv.len() != poly.len() {
                    return Err(MeshError::Invalid(format!(
                        "polygon {f} has {} corners but {} UV indices",
                        poly.len(),
                        uv.len()
                    )));
                }
                face_uvs.extend_from_slice(uv);
            }
            let end = u32::try_from(face_vertices.len())
                .map_err(|_| MeshError::Invalid("too many polygon corners".into()))?;
            face_offsets.push(end);
        }
        Self::from_flat(
            positions,
            uvs,
            face_offsets,
            face_vertices,
            face_uvs,
            None,
            Vec::new(),
        )
    }

    /// Builds a mesh from the flat polygon layout (see the type's docs), validating it.
    ///
    /// # Errors
    /// As [`Mesh::new`].
    pub fn from_flat(
        positions: Vec<Point3<f64>>,
        uvs: Vec<Point2<f64>>,
        face_offsets: Vec<u32>,
        face_vertices: Vec<u32>,
        face_uvs: Vec<u32>,
        mtllib: Option<String>,
        materials: Vec<(u32, String)>,
    ) -> Result<Self, MeshError> {
        if face_offsets.first() != Some(&0)
            || face_offsets.last().map(|&x| x as usize) != Some(face_vertices.len())
        {
            return Err(MeshError::Invalid(
                "polygon offsets do not cover the corners".into(),
            ));
        }
        if !face_uvs.is_empty() && face_uvs.len() != face_vertices.len() {
            return Err(MeshError::Invalid(format!(
                "{} polygon corners but {} corner UVs",
                face_vertices.len(),
                face_uvs.len()
            )));
        }
        if let Some(v) = positions
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(MeshError::Invalid(format!(
                "vertex {v} has a non-finite coordinate"
            )));
        }
        if let Some(t) = uvs
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(MeshError::Invalid(format!(
                "texture coordinate {t} is not finite"
            )));
        }
        let nv = positions.len();
        let nuv = uvs.len();
        for f in 0..face_offsets.len() - 1 {
            let (a, b) = (face_offsets[f] as usize, face_offsets[f + 1] as usize);
            if b < a + 3 {
                return Err(MeshError::Invalid(format!(
                    "polygon {f} has {} corners (at least 3 needed)",
                    b.saturating_sub(a)
                )));
            }
            if b > face_vertices.len() {
                return Err(MeshError::Invalid(format!(
                    "polygon {f} ends at corner {b}, past the {} corners",
                    face_vertices.len()
                )));
            }
            let corners = &face_vertices[a..b];
            for &v in corners {
                if v as usize >= nv {
                    return Err(MeshError::Invalid(format!(
                        "polygon {f} uses vertex {v} but the mesh has {nv} vertices"
                    )));
                }
            }
            for (i, &v) in corners.iter().enumerate() {
                if corners[i + 1..].contains(&v) {
                    return Err(MeshError::Invalid(format!(
                        "polygon {f} repeats vertex {v}"
                    )));
                }
            }
            if !face_uvs.is_empty() {
                for &t in &face_uvs[a..b] {
                    if t as usize >= nuv {
                        return Err(MeshError::Invalid(format!(
                            "polygon {f} uses texture coordinate {t} but the mesh has {nuv}"
                        )));
                    }
                }
            }
        }
        let mut mesh = Mesh {
            positions,
            uvs,
            face_offsets,
            face_vertices,
            face_uvs,
            mtllib,
            materials,
            triangles: Vec::new(),
            triangle_face: Vec::new(),
            triangle_uvs: Vec::new(),
        };
        mesh.triangulate();
        Ok(mesh)
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of polygons as given (not triangles).
    pub fn face_count(&self) -> usize {
        self.face_offsets.len() - 1
    }

    /// Whether the mesh carries texture coordinates.
    pub fn has_uvs(&self) -> bool {
        !self.face_uvs.is_empty()
    }

    /// Vertex indices of polygon `f`.
    ///
    /// # Panics
    /// If `f >= self.face_count()` (a caller bug).
    pub fn face(&self, f: usize) -> &[u32] {
        &self.face_vertices[self.face_offsets[f] as usize..self.face_offsets[f + 1] as usize]
    }

    /// UV indices of polygon `f`; empty when the mesh has no UVs.
    pub fn face_uv(&self, f: usize) -> &[u32] {
        if self.face_uvs.is_empty() {
            return &[];
        }
        &self.face_uvs[self.face_offsets[f] as usize..self.face_offsets[f + 1] as usize]
    }

    /// Iterates over the polygons' vertex-index slices.
    pub fn faces(&self) -> impl Iterator<Item = &[u32]> + '_ {
        self.face_offsets
            .windows(2)
            .map(|w| &self.face_vertices[w[0] as usize..w[1] as usize])
    }

    /// A copy of this mesh (same topology, UVs, materials) with other vertex positions.
    ///
    /// The triangulated view is kept as it is, so every shape of a dataset shares the
    /// neutral's triangles.
    ///
    /// # Errors
    /// [`MeshError::Invalid`] when the vertex count differs or a coordinate is not finite.
    pub fn with_positions(&self, positions: Vec<Point3<f64>>) -> Result<Self, MeshError> {
        if positions.len() != self.positions.len() {
            return Err(MeshError::Invalid(format!(
                "{} positions given for a mesh of {} vertices",
                positions.len(),
                self.positions.len()
            )));
        }
        if let Some(v) = positions
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(MeshError::Invalid(format!(
                "vertex {v} has a non-finite coordinate"
            )));
        }
        Ok(Mesh {
            positions,
            ..self.clone()
        })
    }

    /// Scales every position by `factor` (unit conversion).
    pub fn scale(&mut self, factor: f64) {
        for p in &mut self.positions {
            p.coords *= factor;
        }
    }

    /// Recomputes the triangulated view from the polygons and current positions.
    ///
    /// Quads are split along their shorter diagonal (the better-shaped pair of triangles
    /// for cotangent weights); other polygons are fanned from their first corner.
    pub fn triangulate(&mut self) {
        let mut triangles = Vec::with_capacity(self.face_vertices.len());
        let mut triangle_face = Vec::with_capacity(self.face_vertices.len());
        let mut triangle_uvs = Vec::new();
        let has_uv = self.has_uvs();
        for f in 0..self.face_count() {
            let vs = self.face(f);
            let ts = self.face_uv(f);
            let n = vs.len();
            let mut push = |i: usize, j: usize, k: usize| {
                triangles.push([vs[i], vs[j], vs[k]]);
                triangle_face.push(f as u32);
                if has_uv {
                    triangle_uvs.push([ts[i], ts[j], ts[k]]);
                }
            };
            if n == 4 {
                let p = |i: usize| self.positions[vs[i] as usize];
                let d02 = (p(0) - p(2)).norm_squared();
                let d13 = (p(1) - p(3)).norm_squared();
                if d02 <= d13 {
                    push(0, 1, 2);
                    push(0, 2, 3);
                } else {
                    push(0, 1, 3);
                    push(1, 2, 3);
                }
            } else {
                for k in 1..n - 1 {
                    push(0, k, k + 1);
                }
            }
        }
        self.triangles = triangles;
        self.triangle_face = triangle_face;
        self.triangle_uvs = triangle_uvs;
    }

    /// Per-vertex UV: the texture coordinate of the vertex's first corner in polygon order.
    ///
    /// On a UV seam a vertex has several texture coordinates; this picks one
    /// deterministically. Returns `None` when the mesh has no UVs; vertices used by no
    /// polygon get `(NaN, NaN)`.
    pub fn vertex_uvs(&self) -> Option<Vec<Point2<f64>>> {
        if !self.has_uvs() {
            return None;
        }
        let mut out = vec![Point2::new(f64::NAN, f64::NAN); self.vertex_count()];
        let mut set = vec![false; self.vertex_count()];
        for (&v, &t) in self.face_vertices.iter().zip(&self.face_uvs) {
            if !set[v as usize] {
                set[v as usize] = true;
                out[v as usize] = self.uvs[t as usize];
            }
        }
        Some(out)
    }

    /// Axis-aligned bounding box `(min, max)` of the positions; `None` for an empty mesh.
    pub fn bounding_box(&self) -> Option<(Point3<f64>, Point3<f64>)> {
        let first = *self.positions.first()?;
        Some(
            self.positions
                .iter()
                .fold((first, first), |(lo, hi), p| (lo.inf(p), hi.sup(p))),
        )
    }
}

#[cfg(test)]
pub(crate) mod test_meshes {
    //! Small meshes shared by the mesh tests.
    use super::*;

    /// A regular `n × n` grid of unit squares in the z = 0 plane, as quads, with UVs.
    pub fn grid(n: usize, spacing: f64) -> Mesh {
        let mut positions = Vec::new();
        let mut uvs = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                positions.push(Point3::new(i as f64 * spacing, j as f64 * spacing, 0.0));
                uvs.push(Point2::new(i as f64 / n as f64, j as f64 / n as f64));
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let mut quads = Vec::new();
        for j in 0..n {
            for i in 0..n {
                quads.push(vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        Mesh::new(positions, &quads, uvs, Some(&quads)).unwrap()
    }

    /// A closed tetrahedron.
    pub fn tetrahedron() -> Mesh {
        let positions = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
        ];
        let faces = vec![vec![0, 2, 1], vec![0, 1, 3], vec![0, 3, 2], vec![1, 2, 3]];
        Mesh::new(positions, &faces, Vec::new(), None).unwrap()
    }
}

#[cfg(test)]
mod tests {
    use super::test_meshes::*;
    use super::*;

    #[test]
    fn quads_split_along_shorter_diagonal() {
        let positions = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(3.0, 0.0, 0.0),
            Point3::new(3.2, 1.0, 0.0),
            Point3::new(0.2, 1.0, 0.0),
        ];
        // Diagonal 0-2 is longer than 1-3 here, so the split uses 1-3.
        let mesh = Mesh::new(positions, &[vec![0, 1, 2, 3]], Vec::new(), None).unwrap();
        assert_eq!(mesh.triangles, vec![[0, 1, 3], [1, 2, 3]]);
        assert_eq!(mesh.triangle_face, vec![0, 0]);
    }

    #[test]
    fn rejects_bad_polygons() {
        let p = vec![Point3::origin(); 3];
        assert!(Mesh::new(p.clone(), &[vec![0, 1]], Vec::new(), None).is_err());
        assert!(Mesh::new(p.clone(), &[vec![0, 1, 3]], Vec::new(), None).is_err());
        assert!(Mesh::new(p.clone(), &[vec![0, 1, 1]], Vec::new(), None).is_err());
        let mut nan = p;
        nan[1].x = f64::NAN;
        assert!(Mesh::new(nan, &[vec![0, 1, 2]], Vec::new(), None).is_err());
    }

    #[test]
    fn rejects_offsets_past_the_corners() {
        // A middle offset beyond the corner list used to panic on slicing.
        let p = vec![Point3::origin(); 6];
        let r = Mesh::from_flat(
            p,
            vec![],
            vec![0, 9, 6],
            (0..6).collect(),
            vec![],
            None,
            vec![],
        );
        assert!(matches!(r, Err(MeshError::Invalid(_))), "{r:?}");
    }

    #[test]
    fn grid_has_expected_counts() {
        let g = grid(4, 1.0);
        assert_eq!(g.vertex_count(), 25);
        assert_eq!(g.face_count(), 16);
        assert_eq!(g.triangles.len(), 32);
        assert_eq!(g.triangle_uvs.len(), 32);
        let uv = g.vertex_uvs().unwrap();
        assert_eq!(uv[24], Point2::new(1.0, 1.0));
    }
}
