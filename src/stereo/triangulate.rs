//! Two-view triangulation: midpoint of the undistorted rays, refined by Gauss-Newton on the
//! reprojection error in both images (Hartley and Zisserman 2004 §12.4, the "gold standard"
//! cost `Σ_c ‖π_c(X) − x_c‖²`, minimized over `X` only since the rig is calibrated).

use nalgebra::{Matrix3, Point2, Point3, Vector3};

use super::StereoError;
use crate::camera::StereoRig;

/// Triangulation settings.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct TriangulateParams {
    /// Reject a bundle whose RMS reprojection error exceeds this, pixels. Default 1.5.
    pub max_reprojection_px: f64,
    /// Expected detection noise σ, pixels: confidence is `exp(−e²/(2σ²))` of the RMS
    /// reprojection error `e`. Default 0.5.
    pub sigma_px: f64,
    /// Gauss-Newton iterations at most. Default 10.
    pub max_iterations: usize,
    /// Accepted depth range in cam0, mm. Default 50 to 1000.
    #[serde(skip_serializing)]
    pub depth_range_mm: (f64, f64),
}

impl Default for TriangulateParams {
    fn default() -> Self {
        Self {
            max_reprojection_px: 1.5,
            sigma_px: 0.5,
            max_iterations: 10,
            depth_range_mm: (50.0, 1000.0),
        }
    }
}

/// A triangulated marker position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bundle {
    /// Position in the cam0 frame, mm.
    pub point_in_cam0: Point3<f64>,
    /// RMS reprojection error over both images, pixels.
    pub reprojection_px: f64,
    /// Confidence 0..1 from the reprojection error (see [`TriangulateParams::sigma_px`]).
    pub confidence: f64,
}

/// Midpoint of the closest points of two rays `o0 + s·d0` and `o1 + t·d1` and the distance
/// between them; `None` for (nearly) parallel rays or a point behind either origin.
pub fn ray_midpoint(
    o0: &Point3<f64>,
    d0: &Vector3<f64>,
    o1: &Point3<f64>,
    d1: &Vector3<f64>,
) -> Option<(Point3<f64>, f64)> {
    let w = o0 - o1;
    let (a, b, c) = (d0.dot(d0), d0.dot(d1), d1.dot(d1));
    let (d, e) = (d0.dot(&w), d1.dot(&w));
    let den = a * c - b * b;
    if den.abs() < 1e-12 * a * c {
        return None;
    }
    let s = (b * e - c * d) / den;
    let t = (a * e - b * d) / den;
    if s <= 0.0 || t <= 0.0 {
        return None;
    }
    let p0 = o0 + d0 * s;
    let p1 = o1 + d1 * t;
    Some((
        Point3::from((p0.coords + p1.coords) * 0.5),
        (p0 - p1).norm(),
    ))
}

/// Triangulates one marker seen at `px0` in cam0 and `px1` in cam1.
///
/// # Errors
/// [`StereoError::Triangulation`] when a pixel cannot be unprojected, the rays are parallel
/// or meet behind a camera, the depth is out of range, or the reprojection error is above
/// the gate.
pub fn triangulate(
    rig: &StereoRig,
    px0: &Point2<f64>,
    px1: &Point2<f64>,
    params: &TriangulateParams,
) -> Result<Bundle, StereoError> {
    let fail = |m: &str| StereoError::Triangulation(m.to_string());
    let d0 = rig.cam0.unproject(px0).map_err(|e| fail(&e.to_string()))?;
    let d1 = rig.cam1.unproject(px1).map_err(|e| fail(&e.to_string()))?;
    let cam0_from_cam1 = rig.cam1_from_cam0.inverse();
    let (mut x, _) = ray_midpoint(
        &Point3::origin(),
        &d0,
        &(cam0_from_cam1 * Point3::origin()),
        &(cam0_from_cam1.rotation * d1.into_inner()),
    )
    .ok_or_else(|| fail("rays do not meet in front of both cameras"))?;
    let residuals =
        |x: &Point3<f64>| -> Option<(nalgebra::Vector4<f64>, nalgebra::Matrix4x3<f64>)> {
            let (p0, j0) = rig.cam0.project_with_jacobian(&x.coords)?;
            let x1 = rig.cam1_from_cam0 * x;
            let (p1, j1) = rig.cam1.project_with_jacobian(&x1.coords)?;
            let j1 = j1 * rig.cam1_from_cam0.rotation.matrix();
            let r = nalgebra::Vector4::new(p0.x - px0.x, p0.y - px0.y, p1.x - px1.x, p1.y - px1.y);
            let mut j = nalgebra::Matrix4x3::zeros();
            j.fixed_view_mut::<2, 3>(0, 0).copy_from(&j0);
            j.fixed_view_mut::<2, 3>(2, 0).copy_from(&j1);
            Some((r, j))
        };
    let (mut r, mut j) = residuals(&x).ok_or_else(|| fail("point behind a camera"))?;
    for _ in 0..params.max_iterations {
        let jt = j.transpose();
        let h: Matrix3<f64> = jt * j;
        let Some(step) = h.try_inverse().map(|hi| hi * (jt * r)) else {
            break;
        };
        let candidate = x - step;
        match residuals(&candidate) {
            Some((rn, jn)) if rn.norm_squared() <= r.norm_squared() => {
                x = candidate;
                r = rn;
                j = jn;
                if step.norm() < 1e-9 {
                    break;
                }
            }
            _ => break,
        }
    }
    if !(params.depth_range_mm.0..=params.depth_range_mm.1).contains(&x.z) {
        return Err(fail(&format!("depth {:.1} mm out of range", x.z)));
    }
    let rms = (r.norm_squared() / 2.0).sqrt();
    if rms > params.max_reprojection_px {
        return Err(fail(&format!(
            "reprojection error {rms:.2} px above the gate"
        )));
    }
    Ok(Bundle {
        point_in_cam0: x,
        reprojection_px: rms,
        confidence: (-rms * rms / (2.0 * params.sigma_px * params.sigma_px)).exp(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_points_exactly_and_gates_noise() {
        let rig = crate::camera::default_helmet_rig().unwrap();
        let p = TriangulateParams::default();
        for truth in [
            Point3::new(0.0, 35.0, 225.0),
            Point3::new(-60.0, 10.0, 200.0),
            Point3::new(40.0, 90.0, 240.0),
        ] {
            let px0 = rig.cam0.project(&truth.coords).unwrap();
            let px1 = rig
                .cam1
                .project(&(rig.cam1_from_cam0 * truth).coords)
                .unwrap();
            let b = triangulate(&rig, &px0, &px1, &p).unwrap();
            assert!(
                (b.point_in_cam0 - truth).norm() < 1e-7,
                "{}",
                b.point_in_cam0
            );
            assert!(b.reprojection_px < 1e-6 && b.confidence > 0.999);
            // Shift cam1's pixel across the epipolar line: rejected.
            let off = Point2::new(px1.x + 6.0, px1.y);
            assert!(triangulate(&rig, &px0, &off, &p).is_err());
        }
    }

    #[test]
    fn midpoint_of_crossing_rays() {
        let (m, d) = ray_midpoint(
            &Point3::origin(),
            &Vector3::new(0.0, 0.0, 1.0),
            &Point3::new(10.0, 0.0, 0.0),
            &Vector3::new(-1.0, 0.0, 1.0),
        )
        .unwrap();
        assert!((m - Point3::new(0.0, 0.0, 10.0)).norm() < 1e-12 && d < 1e-12);
        assert!(
            ray_midpoint(
                &Point3::origin(),
                &Vector3::z(),
                &Point3::new(1.0, 0.0, 0.0),
                &Vector3::z()
            )
            .is_none()
        );
    }
}
