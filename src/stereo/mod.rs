//! Stereo: pairing of cam0 and cam1 detections under the epipolar constraint (optimal
//! assignment, ambiguous pairs dropped) and triangulation into bundles in the cam0 frame.
//!
//! Depends on [`crate::camera`].

pub mod assignment;
pub mod triangulate;

pub use assignment::{assign_sparse, hungarian};
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
    /// Triangulation and its gates (the reprojection gate is the epipolar tolerance). In a
    /// settings file, keys this table leaves out keep the pairing defaults (depth range
    /// 100 to 450 mm, gate 1 px), not those of [`TriangulateParams::default`].
    #[serde(deserialize_with = "triangulate_over_pair_defaults")]
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

/// Deserializes a `triangulate` table over [`PairParams::default`]'s: a file that sets one
/// key keeps the pairing defaults of the others.
fn triangulate_over_pair_defaults<'de, D>(d: D) -> Result<TriangulateParams, D::Error>
where
    D: serde::Deserializer<'de>,
{
    use serde::Deserialize as _;
    use serde::de::Error as _;
    let given = toml::Table::deserialize(d)?;
    let has_range = given.contains_key("depth_range_mm");
    let defaults = PairParams::default().triangulate;
    let mut merged = toml::Table::try_from(defaults.clone()).map_err(D::Error::custom)?;
    merged.extend(given);
    let mut t: TriangulateParams = toml::Value::Table(merged)
        .try_into()
        .map_err(D::Error::custom)?;
    // The depth range is not serialized (a capture profile derives it): keep the
    // pairing default unless the table sets it.
    if !has_range {
        t.depth_range_mm = defaults.depth_range_mm;
    }
    Ok(t)
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
    pair_detections_where(rig, pixels0, pixels1, params, |_, _, _| true)
}

/// [`pair_detections`] among the pairs `(i, j, bundle)` that `keep` accepts: the others
/// are neither paired nor anyone's competitor (blobs that could not be one dot seen from
/// both cameras, such as a freckle on the epipolar line of a painted dot, do not make its
/// pairing ambiguous).
pub fn pair_detections_where(
    rig: &StereoRig,
    pixels0: &[Point2<f64>],
    pixels1: &[Point2<f64>],
    params: &PairParams,
    keep: impl Fn(usize, usize, &Bundle) -> bool,
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
    // Sparse candidate lists: a cam0 detection meets few cam1 rays within the gate, so a
    // few hundred blobs per image (skin clutter) cost little more than their candidates.
    let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n0];
    let mut bundles: Vec<Vec<Bundle>> = vec![Vec::new(); n0];
    let mut col_costs: Vec<Vec<f64>> = vec![Vec::new(); n1];
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
            if let Ok(b) = triangulate(rig, &pixels0[i], &pixels1[j], &params.triangulate)
                && keep(i, j, &b)
            {
                rows[i].push((j, b.reprojection_px));
                bundles[i].push(b);
                col_costs[j].push(b.reprojection_px);
            }
        }
    }
    let margin = params.ambiguity_margin_px;
    let mut out = Vec::new();
    for (i, j) in assign_sparse(&rows, n1) {
        let Some(k) = rows[i].iter().position(|&(jj, _)| jj == j) else {
            continue;
        };
        let c = rows[i][k].1;
        // A rival: another candidate of the same row, or of the same column, that costs
        // less than `margin` more (the pair's own cost appears once in each list).
        let row_rival = rows[i]
            .iter()
            .enumerate()
            .any(|(kk, &(_, ck))| kk != k && ck < c + margin);
        let own = usize::from(c < c + margin);
        let col_rival = col_costs[j].iter().filter(|&&ck| ck < c + margin).count() > own;
        if row_rival || col_rival {
            continue;
        }
        out.push(StereoMatch {
            index0: i,
            index1: j,
            bundle: bundles[i][k],
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_a_cloud_and_drops_ambiguity() {
        let rig = crate::camera::default_helmet_rig().unwrap();
        // Jittered points on a curved surface 230-280 mm away.
        let mut pts = Vec::new();
        let mut rng = crate::numeric::SplitMix64::new(99);
        let mut jitter = || rng.uniform(-4.0, 4.0);
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

    #[test]
    fn blobs_left_out_of_pairing_make_no_pair_ambiguous() {
        // Dots on a surface, and in cam1 beside each dot a freckle on its epipolar line
        // (the dot's ray 4 mm deeper): every dot has a rival as cheap as itself. Told that
        // a freckle cannot pair (it is not the size of a dot at that depth), the pairing
        // keeps every dot; without that, the rivals drop them.
        let rig = crate::camera::default_helmet_rig().unwrap();
        let mut pts = Vec::new();
        for a in -3..=3 {
            for b in -3..=3 {
                // Sheared, so that no two dots share a (vertical) epipolar line.
                let (x, y) = (
                    f64::from(a) * 15.0 + f64::from(b) * 2.1,
                    35.0 + f64::from(b) * 15.0,
                );
                pts.push(Point3::new(x, y, 230.0 + 0.004 * (x * x + y * y)));
            }
        }
        let n = pts.len();
        let to_cam1 = |p: &Point3<f64>| rig.cam1.project(&(rig.cam1_from_cam0 * p).coords);
        let px0: Vec<_> = pts
            .iter()
            .map(|p| rig.cam0.project(&p.coords).unwrap())
            .collect();
        let mut px1: Vec<_> = pts.iter().map(|p| to_cam1(p).unwrap()).collect();
        let params = PairParams::default();
        let alone = pair_detections(&rig, &px0, &px1, &params);
        assert!(alone.len() >= n - 3, "{} of {n}", alone.len());
        px1.extend(
            pts.iter()
                .map(|p| to_cam1(&(p * (1.0 + 4.0 / p.coords.norm()))).unwrap()),
        );
        let all = pair_detections(&rig, &px0, &px1, &params);
        assert!(
            all.len() < n / 2,
            "{} of {n} kept beside their rivals",
            all.len()
        );
        let dots = pair_detections_where(&rig, &px0, &px1, &params, |_, j, _| j < n);
        let pairs = |m: &[StereoMatch]| m.iter().map(|s| (s.index0, s.index1)).collect::<Vec<_>>();
        assert_eq!(pairs(&dots), pairs(&alone));
        assert!(dots.iter().all(|s| s.index0 == s.index1));
    }
}
