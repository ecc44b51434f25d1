//! Stereo: pairing of cam0 and cam1 detections under the epipolar constraint (optimal
//! assignment, ambiguous pairs dropped) and triangulation into bundles in the cam0 frame.
//!
//! Depends on [`crate::camera`].

pub mod assignment;
pub mod triangulate;

pub use assignment::hungarian;
pub use triangulate::{Bundle, TriangulateParams, ray_midpoint, triangulate};

use nalgebra::{Point2, Point3, Vector3};

use crate::camera::StereoRig;

/// Errors of the stereo stage.
#[derive(Debug, thiserror::Error)]
pub enum StereoError {
    /// A point cannot be triangulated (reason given).
    #[error("triangulation: {0}")]
    Triangulation(String),
}

/// Pairing settings.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct PairParams {
    /// Triangulation and its gates (the reprojection gate is the epipolar tolerance).
    pub triangulate: TriangulateParams,
    /// A pair is dropped as ambiguous when another candidate of its cam0 or cam1 detection
    /// costs less than this much more (pixels of RMS reprojection error). Default 0.5.
    pub ambiguity_margin_px: f64,
}

impl Default for PairParams {
    fn default() -> Self {
        Self {
            triangulate: TriangulateParams {
                depth_range_mm: (100.0, 450.0),
                max_reprojection_px: 1.0,
                ..TriangulateParams::default()
            },
            ambiguity_margin_px: 0.5,
        }
    }
}

/// One paired and triangulated observation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoMatch {
    /// Index of the cam0 detection.
    pub index0: usize,
    /// Index of the cam1 detection.
    pub index1: usize,
    /// The triangulated bundle.
    pub bundle: Bundle,
}

/// Pairs detections of cam0 (`pixels0`) and cam1 (`pixels1`): every pair whose rays meet
/// within the depth range is triangulated; the cost is its RMS reprojection error (the
/// epipolar distance, in effect); the Hungarian method picks the cheapest one-to-one
/// pairing; a pair with a competitor within [`PairParams::ambiguity_margin_px`] in its row
/// or column is dropped (a wrong pair is worse than a missing one).
pub fn pair_detections(
    rig: &StereoRig,
    pixels0: &[Point2<f64>],
    pixels1: &[Point2<f64>],
    params: &PairParams,
) -> Vec<StereoMatch> {
    let (n0, n1) = (pixels0.len(), pixels1.len());
    if n0 == 0 || n1 == 0 {
        return Vec::new();
    }
    let cam0_from_cam1 = rig.cam1_from_cam0.inverse();
    let o1 = cam0_from_cam1 * Point3::origin();
    let rays0: Vec<Option<Vector3<f64>>> = pixels0
        .iter()
        .map(|p| rig.cam0.unproject(p).ok().map(|r| r.into_inner()))
        .collect();
    let rays1: Vec<Option<Vector3<f64>>> = pixels1
        .iter()
        .map(|p| {
            rig.cam1
                .unproject(p)
                .ok()
                .map(|r| cam0_from_cam1.rotation * r.into_inner())
        })
        .collect();
    let f = rig.cam0.fx().min(rig.cam1.fx());
    let gate = params.triangulate.max_reprojection_px;
    let (zmin, zmax) = params.triangulate.depth_range_mm;
    let mut cost = vec![f64::INFINITY; n0 * n1];
    let mut bundles: Vec<Option<Bundle>> = vec![None; n0 * n1];
    for (i, r0) in rays0.iter().enumerate() {
        let Some(r0) = r0 else { continue };
        for (j, r1) in rays1.iter().enumerate() {
            let Some(r1) = r1 else { continue };
            let Some((m, d)) = ray_midpoint(&Point3::origin(), r0, &o1, r1) else {
                continue;
            };
            // Cheap pre-gate: ray gap in pixels, with a factor 3 of slack for the lens.
            if m.z < zmin || m.z > zmax || d * f / m.z > 3.0 * gate {
                continue;
            }
            if let Ok(b) = triangulate(rig, &pixels0[i], &pixels1[j], &params.triangulate) {
                cost[i * n1 + j] = b.reprojection_px;
                bundles[i * n1 + j] = Some(b);
            }
        }
    }
    let assignment = hungarian(&cost, n0, n1);
    let margin = params.ambiguity_margin_px;
    let mut out = Vec::new();
    for (i, a) in assignment.iter().enumerate() {
        let Some(j) = *a else { continue };
        let c = cost[i * n1 + j];
        let row_rival = (0..n1).any(|k| k != j && cost[i * n1 + k] < c + margin);
        let col_rival = (0..n0).any(|k| k != i && cost[k * n1 + j] < c + margin);
        if row_rival || col_rival {
            continue;
        }
        if let Some(bundle) = bundles[i * n1 + j] {
            out.push(StereoMatch {
                index0: i,
                index1: j,
                bundle,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_a_cloud_and_drops_ambiguity() {
        let rig = crate::synth::default_rig().unwrap();
        // Jittered points on a curved surface 230-280 mm away.
        let mut pts = Vec::new();
        let mut s = 99u64;
        let mut jitter = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 33) as f64 / (1u64 << 31) as f64 * 8.0 - 4.0
        };
        for a in -4..=4 {
            for b in -4..=4 {
                let (x, y) = (
                    f64::from(a) * 14.0 + jitter(),
                    35.0 + f64::from(b) * 14.0 + jitter(),
                );
                pts.push(Point3::new(x, y, 230.0 + 0.004 * (x * x + y * y)));
            }
        }
        let px0: Vec<_> = pts
            .iter()
            .map(|p| rig.cam0.project(&p.coords).unwrap())
            .collect();
        let mut px1: Vec<_> = pts
            .iter()
            .map(|p| rig.cam1.project(&(rig.cam1_from_cam0 * p).coords).unwrap())
            .collect();
        px1.reverse();
        let m = pair_detections(&rig, &px0, &px1, &PairParams::default());
        // Points whose x differs by a fraction of a millimetre are near-ambiguous along the
        // vertical epipolar lines: some are dropped, none may be wrong.
        assert!(m.len() >= pts.len() / 2, "{} of {}", m.len(), pts.len());
        for s in &m {
            assert_eq!(s.index1, pts.len() - 1 - s.index0, "wrong pair");
            assert!((s.bundle.point_in_cam0 - pts[s.index0]).norm() < 1e-6);
        }
    }
}
