//! Polygon subdivision (Catmull and Clark 1978, or its linear variant) as a linear stencil,
//! so one subdivision of a neutral mesh applies to every shape of a dataset.
//!
//! Each polygon of `n` corners becomes `n` quads through its face point and the edge points
//! of its sides. New vertices are numbered: the original vertices first (same indices, so
//! marker layouts stay valid), then one per edge, then one per polygon. Texture
//! coordinates are subdivided linearly per corner (seams stay seams).
//!
//! Catmull-Clark rules: face point `F` = mean of the corners; interior edge point
//! `(a + b + F₁ + F₂)/4`; interior vertex `(Q + 2R + (n − 3)P)/n` with `Q` the mean of the
//! adjacent face points, `R` the mean of the incident edge midpoints, `n` the valence.
//! Boundary (and non-manifold) edges are creases: their edge point is the midpoint, and a
//! vertex with exactly two crease edges follows the cubic B-spline rule
//! `3/4·P + 1/8·(a + b)`; a vertex on any other number of creases (a corner) stays put.

use std::collections::HashMap;

use nalgebra::{Point2, Point3};

use super::{Mesh, MeshError};

/// How new positions are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SubdivisionScheme {
    /// Catmull-Clark smoothing (the default: what "subdivided twice" means to an artist).
    #[default]
    CatmullClark,
    /// Midpoints and face centres only; original vertices keep their positions.
    Linear,
}

/// One level of subdivision: the refined topology and the stencil mapping coarse positions
/// to fine ones.
#[derive(Debug, Clone)]
pub struct Subdivision {
    /// The refined mesh (positions of the mesh it was built from).
    pub mesh: Mesh,
    offsets: Vec<u32>,
    sources: Vec<u32>,
    weights: Vec<f64>,
}

impl Subdivision {
    /// Subdivides `mesh` once.
    ///
    /// # Errors
    /// [`MeshError::Invalid`] when the refined mesh cannot be built (it can only fail on an
    /// invalid input mesh).
    pub fn new(mesh: &Mesh, scheme: SubdivisionScheme) -> Result<Self, MeshError> {
        let nv = mesh.vertex_count();
        let nf = mesh.face_count();
        let face = |f: usize| {
            let (a, b) = (
                mesh.face_offsets[f] as usize,
                mesh.face_offsets[f + 1] as usize,
            );
            &mesh.face_vertices[a..b]
        };
        // Edges, with the polygons on each side.
        let mut edge_index: HashMap<(u32, u32), u32> = HashMap::new();
        let mut edge_ends: Vec<(u32, u32)> = Vec::new();
        let mut edge_faces: Vec<Vec<u32>> = Vec::new();
        for f in 0..nf {
            let c = face(f);
            for i in 0..c.len() {
                let (a, b) = (c[i], c[(i + 1) % c.len()]);
                let key = (a.min(b), a.max(b));
                let e = *edge_index.entry(key).or_insert_with(|| {
                    edge_ends.push(key);
                    edge_faces.push(Vec::new());
                    (edge_ends.len() - 1) as u32
                });
                edge_faces[e as usize].push(f as u32);
            }
        }
        let ne = edge_ends.len();
        let crease = |e: usize| edge_faces[e].len() != 2;

        // Stencils: a list of (source vertex, weight) per new vertex.
        let mut stencils: Vec<Vec<(u32, f64)>> = Vec::with_capacity(nv + ne + nf);
        let face_stencil = |f: usize| -> Vec<(u32, f64)> {
            let c = face(f);
            let w = 1.0 / c.len() as f64;
            c.iter().map(|&v| (v, w)).collect()
        };
        let face_stencils: Vec<Vec<(u32, f64)>> = (0..nf).map(face_stencil).collect();

        // Original vertices.
        let mut vertex_edges: Vec<Vec<u32>> = vec![Vec::new(); nv];
        for (e, &(a, b)) in edge_ends.iter().enumerate() {
            vertex_edges[a as usize].push(e as u32);
            vertex_edges[b as usize].push(e as u32);
        }
        let mut vertex_faces: Vec<Vec<u32>> = vec![Vec::new(); nv];
        for f in 0..nf {
            for &v in face(f) {
                vertex_faces[v as usize].push(f as u32);
            }
        }
        for v in 0..nv {
            let mut s: Vec<(u32, f64)> = Vec::new();
            let edges = &vertex_edges[v];
            let other = |e: u32| {
                let (a, b) = edge_ends[e as usize];
                if a as usize == v { b } else { a }
            };
            match scheme {
                SubdivisionScheme::Linear => s.push((v as u32, 1.0)),
                SubdivisionScheme::CatmullClark => {
                    let creases: Vec<u32> = edges
                        .iter()
                        .copied()
                        .filter(|&e| crease(e as usize))
                        .collect();
                    if edges.is_empty() {
                        s.push((v as u32, 1.0));
                    } else if creases.len() == 2 {
                        s.push((v as u32, 0.75));
                        s.push((other(creases[0]), 0.125));
                        s.push((other(creases[1]), 0.125));
                    } else if !creases.is_empty() {
                        s.push((v as u32, 1.0));
                    } else {
                        let n = edges.len() as f64;
                        // Q/n: mean of adjacent face points.
                        let faces = &vertex_faces[v];
                        let qw = 1.0 / (faces.len() as f64 * n);
                        for &f in faces {
                            for &(u, w) in &face_stencils[f as usize] {
                                s.push((u, w * qw));
                            }
                        }
                        // 2R/n: R the mean of the incident edge midpoints.
                        let rw = 2.0 / (n * n);
                        for &e in edges {
                            s.push((v as u32, 0.5 * rw));
                            s.push((other(e), 0.5 * rw));
                        }
                        s.push((v as u32, (n - 3.0) / n));
                    }
                }
            }
            stencils.push(merge(s));
        }
        // Edge points.
        for (e, &(a, b)) in edge_ends.iter().enumerate() {
            let s = if scheme == SubdivisionScheme::Linear || crease(e) {
                vec![(a, 0.5), (b, 0.5)]
            } else {
                let mut s = vec![(a, 0.25), (b, 0.25)];
                for &f in &edge_faces[e] {
                    for &(u, w) in &face_stencils[f as usize] {
                        s.push((u, 0.25 * w));
                    }
                }
                s
            };
            stencils.push(merge(s));
        }
        // Face points.
        stencils.extend(face_stencils);

        // Refined polygons and UVs.
        let has_uvs = !mesh.uvs.is_empty() && mesh.face_uvs.len() == mesh.face_vertices.len();
        let mut uvs: Vec<Point2<f64>> = if has_uvs {
            mesh.uvs.clone()
        } else {
            Vec::new()
        };
        let mut uv_edge: HashMap<(u32, u32), u32> = HashMap::new();
        let mut polygons: Vec<Vec<u32>> = Vec::with_capacity(mesh.face_vertices.len());
        let mut polygon_uvs: Vec<Vec<u32>> = Vec::new();
        for f in 0..nf {
            let c = face(f);
            let n = c.len();
            let fp = (nv + ne + f) as u32;
            let edge_point = |i: usize| {
                let (a, b) = (c[i], c[(i + 1) % n]);
                nv as u32 + edge_index[&(a.min(b), a.max(b))]
            };
            let (cu, face_uv) = if has_uvs {
                let (a, b) = (
                    mesh.face_offsets[f] as usize,
                    mesh.face_offsets[f + 1] as usize,
                );
                let cu = &mesh.face_uvs[a..b];
                let centre = cu.iter().fold(nalgebra::Vector2::zeros(), |acc, &u| {
                    acc + mesh.uvs[u as usize].coords
                }) / n as f64;
                uvs.push(Point2::from(centre));
                (cu, (uvs.len() - 1) as u32)
            } else {
                (&[][..], 0)
            };
            let mut edge_uv = |i: usize, uvs: &mut Vec<Point2<f64>>| -> u32 {
                let (a, b) = (cu[i], cu[(i + 1) % n]);
                *uv_edge.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    uvs.push(Point2::from(
                        (mesh.uvs[a as usize].coords + mesh.uvs[b as usize].coords) * 0.5,
                    ));
                    (uvs.len() - 1) as u32
                })
            };
            for i in 0..n {
                let prev = (i + n - 1) % n;
                polygons.push(vec![c[i], edge_point(i), fp, edge_point(prev)]);
                if has_uvs {
                    let e_next = edge_uv(i, &mut uvs);
                    let e_prev = edge_uv(prev, &mut uvs);
                    polygon_uvs.push(vec![cu[i], e_next, face_uv, e_prev]);
                }
            }
        }
        let mut offsets = Vec::with_capacity(stencils.len() + 1);
        let mut sources = Vec::new();
        let mut weights = Vec::new();
        offsets.push(0u32);
        for s in &stencils {
            for &(u, w) in s {
                sources.push(u);
                weights.push(w);
            }
            offsets.push(sources.len() as u32);
        }
        let positions = apply_stencil(&offsets, &sources, &weights, &mesh.positions);
        let mut fine = Mesh::new(
            positions,
            &polygons,
            uvs,
            has_uvs.then_some(polygon_uvs.as_slice()),
        )?;
        fine.mtllib = mesh.mtllib.clone();
        Ok(Self {
            mesh: fine,
            offsets,
            sources,
            weights,
        })
    }

    /// Number of vertices of the refined mesh.
    pub fn vertex_count(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Refined positions of coarse `positions` (same vertex count as the coarse mesh).
    pub fn apply(&self, positions: &[Point3<f64>]) -> Vec<Point3<f64>> {
        apply_stencil(&self.offsets, &self.sources, &self.weights, positions)
    }
}

/// Σ weight·position over each new vertex's sources (missing sources count as zero).
fn apply_stencil(
    offsets: &[u32],
    sources: &[u32],
    weights: &[f64],
    positions: &[Point3<f64>],
) -> Vec<Point3<f64>> {
    offsets
        .windows(2)
        .map(|w| {
            let mut p = nalgebra::Vector3::zeros();
            for k in w[0] as usize..w[1] as usize {
                if let Some(q) = positions.get(sources[k] as usize) {
                    p += q.coords * weights[k];
                }
            }
            Point3::from(p)
        })
        .collect()
}

/// Sums the weights of repeated sources.
fn merge(mut s: Vec<(u32, f64)>) -> Vec<(u32, f64)> {
    s.sort_by_key(|&(u, _)| u);
    let mut out: Vec<(u32, f64)> = Vec::with_capacity(s.len());
    for (u, w) in s {
        match out.last_mut() {
            Some(last) if last.0 == u => last.1 += w,
            _ => out.push((u, w)),
        }
    }
    out
}

/// `levels` subdivisions of `mesh`, each applying to the previous level's positions.
///
/// # Errors
/// As [`Subdivision::new`].
pub fn subdivide_levels(
    mesh: &Mesh,
    levels: usize,
    scheme: SubdivisionScheme,
) -> Result<Vec<Subdivision>, MeshError> {
    let mut out: Vec<Subdivision> = Vec::with_capacity(levels);
    for _ in 0..levels {
        let next = Subdivision::new(out.last().map_or(mesh, |s| &s.mesh), scheme)?;
        out.push(next);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube of six quads.
    fn cube() -> Mesh {
        let p: Vec<Point3<f64>> = (0..8)
            .map(|i| {
                Point3::new(
                    f64::from(i & 1),
                    f64::from((i >> 1) & 1),
                    f64::from((i >> 2) & 1),
                )
            })
            .collect();
        let quads = vec![
            vec![0, 2, 3, 1],
            vec![4, 5, 7, 6],
            vec![0, 1, 5, 4],
            vec![2, 6, 7, 3],
            vec![0, 4, 6, 2],
            vec![1, 3, 7, 5],
        ];
        Mesh::new(p, &quads, Vec::new(), None).unwrap()
    }

    #[test]
    fn counts_and_stencils_sum_to_one() {
        let c = cube();
        let s = Subdivision::new(&c, SubdivisionScheme::CatmullClark).unwrap();
        // V + E + F = 8 + 12 + 6 new vertices; 24 quads.
        assert_eq!(s.vertex_count(), 26);
        assert_eq!(s.mesh.face_count(), 24);
        for i in 0..s.vertex_count() {
            let (a, b) = (s.offsets[i] as usize, s.offsets[i + 1] as usize);
            let sum: f64 = s.weights[a..b].iter().sum();
            assert!((sum - 1.0).abs() < 1e-12, "vertex {i}: {sum}");
        }
        // Catmull-Clark of a cube: the corner at the origin has n = 3, Q = (1/3, 1/3, 1/3)
        // (mean of its three face centres), R = (1/6, 1/6, 1/6) (mean of its edge
        // midpoints), so (Q + 2R + 0·P)/3 = (2/9, 2/9, 2/9).
        let p0 = s.mesh.positions[0];
        for k in 0..3 {
            assert!((p0[k] - 2.0 / 9.0).abs() < 1e-12, "{p0}");
        }
        // Face points are the face centres.
        let fp = s.mesh.positions[8 + 12];
        assert!((fp - Point3::new(0.5, 0.5, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn linear_subdivision_keeps_planar_grids_and_old_vertices() {
        // A 2×1 strip of quads in the plane z = 0, with UVs = xy.
        let p = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(1.0, 1.0, 0.0),
            Point3::new(2.0, 1.0, 0.0),
        ];
        let uvs: Vec<Point2<f64>> = p.iter().map(|q| Point2::new(q.x, q.y)).collect();
        let quads = vec![vec![0, 1, 4, 3], vec![1, 2, 5, 4]];
        let m = Mesh::new(p.clone(), &quads, uvs, Some(&quads)).unwrap();
        for scheme in [SubdivisionScheme::Linear, SubdivisionScheme::CatmullClark] {
            let levels = subdivide_levels(&m, 2, scheme).unwrap();
            let fine = &levels[1].mesh;
            // 3×5 → 5×9 vertices.
            assert_eq!(fine.vertex_count(), 45);
            assert_eq!(fine.face_count(), 32);
            assert!(fine.positions.iter().all(|q| q.z.abs() < 1e-12));
            // UVs follow positions on this planar strip (for the linear scheme exactly).
            if scheme == SubdivisionScheme::Linear {
                for (i, q) in p.iter().enumerate() {
                    assert!((fine.positions[i] - q).norm() < 1e-12);
                }
                for (k, &v) in fine.face_vertices.iter().enumerate() {
                    let uv = fine.uvs[fine.face_uvs[k] as usize];
                    let q = fine.positions[v as usize];
                    assert!((uv.x - q.x).abs() < 1e-12 && (uv.y - q.y).abs() < 1e-12);
                }
            }
            // Applying the stencils again to the coarse positions gives the same mesh.
            let again = levels[1].apply(&levels[0].apply(&m.positions));
            assert_eq!(again, fine.positions);
        }
    }
}
