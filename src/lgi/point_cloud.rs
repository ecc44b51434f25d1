//! One marker's point cloud: the marker's position on every dataset shape (Cong et al.
//! 2019 §4), pruned as §4.1 describes.
//!
//! - **Shapes that do not move the marker** (displacement at the marker under
//!   `min_motion_mm`) are left out: they are the expressions "that do not involve" it. The
//!   neutral stands for all of them.
//! - **Coincident points** (closer than `merge_tolerance_mm`) are merged into one point. The
//!   survivor is the shape that deforms the marker's patch least (root-mean-square
//!   displacement over the vertices the marker blends into), with the neutral first: when
//!   the marker alone cannot tell shapes apart, the least surprising one is the safe choice.
//!   ICT-FaceKit's clouds are near-degenerate (most expressions leave a given marker where
//!   it is), and without merging every such shape would multiply the tetrahedra without
//!   adding any volume.

use nalgebra::{Point3, Vector3};

/// A marker's pruned point cloud.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PointCloud {
    /// Positions of the points, millimetres (unskinned when the index uses the jaw).
    pub points: Vec<Point3<f64>>,
    /// Dataset shape of each point; `None` is the neutral. The neutral is always point 0.
    pub shapes: Vec<Option<u32>>,
    /// Root-mean-square displacement of each point's shape over the marker's patch, mm.
    pub deformation_mm: Vec<f64>,
    /// Shapes left out because they do not move the marker.
    pub still: usize,
    /// Shapes merged into a coincident point.
    pub merged: usize,
}

/// Builds the point cloud of the marker on `vertex` whose blending patch is `patch`.
///
/// `displacements[n][v]` is shape `n`'s displacement of vertex `v` from `neutral[v]`.
pub fn build_point_cloud(
    vertex: usize,
    patch: &[u32],
    neutral: &[Point3<f64>],
    displacements: &[Vec<Vector3<f64>>],
    min_motion_mm: f64,
    merge_tolerance_mm: f64,
) -> PointCloud {
    let x0 = neutral[vertex];
    let rms = |d: &[Vector3<f64>]| -> f64 {
        if patch.is_empty() {
            return d[vertex].norm();
        }
        (patch
            .iter()
            .map(|&v| d[v as usize].norm_squared())
            .sum::<f64>()
            / patch.len() as f64)
            .sqrt()
    };
    let mut still = 0;
    // (shape, position, deformation), neutral first.
    let mut cands: Vec<(Option<u32>, Point3<f64>, f64)> = vec![(None, x0, 0.0)];
    for (n, d) in displacements.iter().enumerate() {
        if d[vertex].norm() < min_motion_mm {
            still += 1;
            continue;
        }
        cands.push((Some(n as u32), x0 + d[vertex], rms(d)));
    }
    // Least deforming first (neutral stays first at 0), ties by shape order.
    cands[1..].sort_by(|a, b| a.2.total_cmp(&b.2).then(a.0.cmp(&b.0)));
    let tol2 = merge_tolerance_mm * merge_tolerance_mm;
    let mut cloud = PointCloud {
        points: Vec::new(),
        shapes: Vec::new(),
        deformation_mm: Vec::new(),
        still,
        merged: 0,
    };
    for (s, p, d) in cands {
        if cloud.points.iter().any(|q| (q - p).norm_squared() < tol2) {
            cloud.merged += 1;
            continue;
        }
        cloud.points.push(p);
        cloud.shapes.push(s);
        cloud.deformation_mm.push(d);
    }
    cloud
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prunes_still_shapes_and_merges_toward_least_deforming() {
        let neutral = vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)];
        let z = Vector3::zeros();
        let shapes = vec![
            vec![z, Vector3::new(0.0, 5.0, 0.0)], // moves only the other vertex
            vec![Vector3::new(1.0, 0.0, 0.0), Vector3::new(0.0, 3.0, 0.0)],
            vec![Vector3::new(1.0, 0.0, 0.001), Vector3::new(0.0, 1.0, 0.0)], // coincident, less deforming
            vec![Vector3::new(0.0, 2.0, 0.0), z],
        ];
        let c = build_point_cloud(0, &[0, 1], &neutral, &shapes, 0.01, 0.01);
        assert_eq!(c.still, 1);
        assert_eq!(c.merged, 1);
        assert_eq!(c.shapes, vec![None, Some(2), Some(3)]);
        assert_eq!(c.points[0], Point3::origin());
    }
}
