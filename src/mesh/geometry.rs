//! Per-triangle and per-vertex geometric quantities: normals and areas.

use nalgebra::{Point3, Vector3};

use super::Mesh;

/// Unit normal of each triangle of the triangulated view (#T), right-handed
/// (counter-clockwise corners face the viewer). Degenerate triangles get a zero vector.
pub fn triangle_normals(mesh: &Mesh) -> Vec<Vector3<f64>> {
    mesh.triangles
        .iter()
        .map(|t| {
            let n = triangle_cross(&mesh.positions, t);
            n.try_normalize(0.0).unwrap_or_else(Vector3::zeros)
        })
        .collect()
}

/// Area of each triangle of the triangulated view (#T), in squared mesh units.
pub fn triangle_areas(mesh: &Mesh) -> Vec<f64> {
    triangle_areas_of(mesh, &mesh.positions)
}

/// [`triangle_areas`] of `mesh`'s triangles placed at other `positions` (#V), e.g. a
/// dataset shape that shares the neutral's topology.
///
/// # Panics
/// If `positions` has fewer entries than a triangle index needs (a caller bug).
pub fn triangle_areas_of(mesh: &Mesh, positions: &[Point3<f64>]) -> Vec<f64> {
    mesh.triangles
        .iter()
        .map(|t| 0.5 * triangle_cross(positions, t).norm())
        .collect()
}

/// Area-weighted unit vertex normals (#V): the normalized sum of the incident triangles'
/// cross products. Vertices used by no triangle, or only by degenerate ones, get a zero
/// vector.
pub fn vertex_normals(mesh: &Mesh) -> Vec<Vector3<f64>> {
    vertex_normals_of(mesh, &mesh.positions)
}

/// [`vertex_normals`] of `mesh`'s triangles placed at other `positions` (#V), e.g. a
/// dataset shape that shares the neutral's topology.
///
/// # Panics
/// If `positions` has fewer entries than a triangle index needs (a caller bug).
pub fn vertex_normals_of(mesh: &Mesh, positions: &[Point3<f64>]) -> Vec<Vector3<f64>> {
    vertex_normals_of_triangles(&mesh.triangles, positions)
}

/// [`vertex_normals`] of a bare triangle list over `positions` (#V), for callers that hold
/// a topology without a [`Mesh`].
///
/// # Panics
/// If `positions` has fewer entries than a triangle index needs (a caller bug).
pub fn vertex_normals_of_triangles(
    triangles: &[[u32; 3]],
    positions: &[Point3<f64>],
) -> Vec<Vector3<f64>> {
    let mut normals = vec![Vector3::zeros(); positions.len()];
    for t in triangles {
        let n = triangle_cross(positions, t);
        for &v in t {
            normals[v as usize] += n;
        }
    }
    for n in &mut normals {
        *n = n.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
    }
    normals
}

/// Barycentric (one third of the incident triangles' area) area of each vertex (#V).
pub fn vertex_areas(mesh: &Mesh) -> Vec<f64> {
    let mut areas = vec![0.0; mesh.vertex_count()];
    for (t, a) in mesh.triangles.iter().zip(triangle_areas(mesh)) {
        for &v in t {
            areas[v as usize] += a / 3.0;
        }
    }
    areas
}

/// Cross product (p1 − p0) × (p2 − p0) of a triangle: twice its area times its normal.
fn triangle_cross(positions: &[Point3<f64>], t: &[u32; 3]) -> Vector3<f64> {
    let p0 = positions[t[0] as usize];
    let p1 = positions[t[1] as usize];
    let p2 = positions[t[2] as usize];
    (p1 - p0).cross(&(p2 - p0))
}

#[cfg(test)]
mod tests {
    use super::super::test_meshes::{grid, tetrahedron};
    use super::*;

    #[test]
    fn grid_normals_point_up_and_areas_sum() {
        let g = grid(3, 2.0);
        for n in vertex_normals(&g) {
            assert!((n - Vector3::z()).norm() < 1e-12);
        }
        let total: f64 = triangle_areas(&g).iter().sum();
        assert!((total - 36.0).abs() < 1e-12);
        let vtotal: f64 = vertex_areas(&g).iter().sum();
        assert!((vtotal - 36.0).abs() < 1e-12);
    }

    #[test]
    fn closed_mesh_normals_point_outward() {
        let t = tetrahedron();
        let centroid = Point3::new(0.25, 0.25, 0.25);
        for (tri, n) in t.triangles.iter().zip(triangle_normals(&t)) {
            let p = t.positions[tri[0] as usize];
            assert!((p - centroid).dot(&n) > 0.0);
        }
    }
}
