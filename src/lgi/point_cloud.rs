//! One marker's point cloud: the marker's position on every dataset shape (Cong et al.
//! 2019 §4), pruned as §4.1 describes.
//!
//! - **Shapes that do not move the marker** (displacement at the marker under
//!   `min_motion_mm`) add no point: they are the expressions "that do not involve" it. If
//!   they leave its patch as the neutral has it, they are dropped; if they deform the patch
//!   (a marker beside a moving region) they are kept as variants of the neutral point.
//! - **Coincident points** (closer than `merge_tolerance_mm`) are merged into one point.
//!   Its representative is the shape that deforms the marker's patch least
//!   (root-mean-square displacement over the vertices the marker blends into), with the
//!   neutral first: when nothing else tells shapes apart, the least surprising one is the
//!   safe choice. The other shapes stay as variants, chosen by the neighbour criterion.
//!   ICT-FaceKit's clouds are near-degenerate (most expressions leave a given marker where
//!   it is), and without merging every such shape would multiply the tetrahedra without
//!   adding any volume.

use nalgebra::{Point3, Vector3};

/// A marker's pruned point cloud.
///
/// Each point has one or more *variants*: shapes that put the marker at (nearly) the same
/// position but deform its patch differently. The first variant of a point is its
/// representative (the least deforming). Tetrahedra are built over the points; the
/// variants are told apart per frame by the neighbour criterion (§5.1), so merging
/// positions loses no local geometry.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PointCloud {
    /// Positions of the points, millimetres (unskinned when the index uses the jaw).
    pub points: Vec<Point3<f64>>,
    /// Variants of each point: `(shape, patch deformation in mm)`, `None` is the neutral.
    /// The neutral is always the first variant of point 0.
    pub variants: Vec<Vec<(Option<u32>, f64)>>,
    /// Shapes that do not move the marker and leave its patch as the neutral has it.
    pub still: usize,
    /// Shapes kept as a variant of a coincident point.
    pub merged: usize,
}

/// Builds the point cloud of the marker on `vertex` whose blending patch is `patch`.
///
/// `displacements[n][v]` is shape `n`'s displacement of vertex `v` from `neutral[v]`.
/// A shape moving the marker less than `min_motion_mm` is a variant of the neutral point
/// when its patch differs (RMS over the patch) from every variant by at least
/// `variant_tolerance_mm`, and is dropped otherwise; so is a shape within
/// `merge_tolerance_mm` of a kept point.
pub fn build_point_cloud(
    vertex: usize,
    patch: &[u32],
    neutral: &[Point3<f64>],
    displacements: &[Vec<Vector3<f64>>],
    min_motion_mm: f64,
    merge_tolerance_mm: f64,
    variant_tolerance_mm: f64,
) -> PointCloud {
    let x0 = neutral[vertex];
    let patch: Vec<u32> = if patch.is_empty() {
        vec![vertex as u32]
    } else {
        patch.to_vec()
    };
    let rms = |f: &dyn Fn(usize) -> Vector3<f64>| -> f64 {
        (patch
            .iter()
            .map(|&v| f(v as usize).norm_squared())
            .sum::<f64>()
            / patch.len() as f64)
            .sqrt()
    };
    let disp = |s: Option<u32>, v: usize| -> Vector3<f64> {
        s.map_or_else(Vector3::zeros, |s| displacements[s as usize][v])
    };
    // (shape, position, deformation, moves the marker), neutral first.
    let mut cands: Vec<(Option<u32>, Point3<f64>, f64)> = vec![(None, x0, 0.0)];
    for (n, d) in displacements.iter().enumerate() {
        let p = if d[vertex].norm() < min_motion_mm {
            x0
        } else {
            x0 + d[vertex]
        };
        cands.push((Some(n as u32), p, rms(&|v| d[v])));
    }
    // Least deforming first (neutral stays first at 0), ties by shape order.
    cands[1..].sort_by(|a, b| a.2.total_cmp(&b.2).then(a.0.cmp(&b.0)));
    let tol2 = merge_tolerance_mm * merge_tolerance_mm;
    let mut cloud = PointCloud {
        points: Vec::new(),
        variants: Vec::new(),
        still: 0,
        merged: 0,
    };
    for (s, p, d) in cands {
        if let Some(j) = cloud
            .points
            .iter()
            .position(|q| (q - p).norm_squared() <= tol2)
        {
            let distinct = cloud.variants[j]
                .iter()
                .all(|&(o, _)| rms(&|v| disp(s, v) - disp(o, v)) >= variant_tolerance_mm);
            if distinct {
                cloud.variants[j].push((s, d));
                cloud.merged += 1;
            } else {
                cloud.still += 1;
            }
            continue;
        }
        cloud.points.push(p);
        cloud.variants.push(vec![(s, d)]);
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
        let c = build_point_cloud(0, &[0, 1], &neutral, &shapes, 0.01, 0.01, 0.001);
        // Shape 0 leaves the marker still but deforms the patch: a variant of the neutral.
        // Shape 1 is coincident with shape 2 (less deforming): a variant of it.
        assert_eq!(c.points.len(), 3);
        assert_eq!(c.variants[0].len(), 2);
        assert!((c.variants[0][1].1 - 5.0 / 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(c.variants[1][0].0, Some(2));
        assert_eq!(c.variants[1][1].0, Some(1));
        assert_eq!(c.variants[2].len(), 1);
        assert_eq!(c.variants[2][0].0, Some(3));
        assert!((c.variants[2][0].1 - 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(c.merged, 2);
        assert_eq!(c.still, 0);
        // A shape moving nothing at all is dropped.
        let c = build_point_cloud(0, &[0, 1], &neutral, &[vec![z, z]], 0.01, 0.01, 0.001);
        assert_eq!((c.points.len(), c.still), (1, 1));
    }
}
