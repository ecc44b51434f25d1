//! Step 3: the rig's extrinsics with both cameras' intrinsics fixed, by
//! Levenberg-Marquardt over the rig and every view's board pose.

use nalgebra::{
    IsometryMatrix3, Matrix3, Point2, Point3, Rotation3, Translation3, Vector2, Vector3,
};

use super::super::Camera;
use super::{CalibrateError, TargetObservation, squared_residuals};

/// The points of a pair seen in both images: (id, cam0 pixel, cam1 pixel), by id.
pub(super) fn common_points(
    a: &TargetObservation,
    b: &TargetObservation,
) -> Vec<(usize, Point2<f64>, Point2<f64>)> {
    let mut out: Vec<(usize, Point2<f64>, Point2<f64>)> = a
        .ids
        .iter()
        .zip(&a.pixels)
        .filter_map(|(id, pa)| {
            b.ids
                .iter()
                .position(|x| x == id)
                .and_then(|j| b.pixels.get(j))
                .map(|pb| (*id, *pa, *pb))
        })
        .collect();
    out.sort_by_key(|x| x.0);
    out
}

/// One stereo view for the extrinsic step: board points and their pixels in both images.
pub(super) struct StereoView {
    pub(super) board: Vec<Point3<f64>>,
    pub(super) px0: Vec<Point2<f64>>,
    pub(super) px1: Vec<Point2<f64>>,
}

/// Result of the extrinsic step.
pub(super) struct Extrinsics {
    pub(super) cam1_from_cam0: IsometryMatrix3<f64>,
    /// Per stereo view: the sum of squared residuals over both images, px².
    pub(super) view_sq: Vec<f64>,
}

/// Step 3: the rig's extrinsics with both cameras' intrinsics fixed, by Levenberg-Marquardt
/// on `Σ_v Σ_i ‖π0(T_v·P_i) − x0_vi‖² + ‖π1(E·T_v·P_i) − x1_vi‖²` over `E = cam1_from_cam0`
/// and every view's board pose `T_v = cam0_from_board` (the objective of OpenCV's
/// `stereoCalibrate` with `CALIB_FIX_INTRINSIC`). `E` starts at the chordal mean of the
/// per-view `T1_v·T0_v⁻¹` from the two intrinsic calibrations, `T_v` at cam0's poses.
/// Updates are left-multiplied: `R ← exp([δω]×)·R`, `t ← t + δt`.
///
/// # Deviations
/// OpenCV's `fisheye::stereoCalibrate` (4.6) assumes every view has as many points as the
/// first, which a partly seen AprilTag grid breaks, and inverts a dense normal matrix built
/// from a dense Jacobian each iteration; this solver takes any number of points per view
/// and both lens models alike through [`Camera::project_with_jacobian`].
pub(super) fn calibrate_extrinsics(
    cam0: &Camera,
    cam1: &Camera,
    views: &[StereoView],
    initial_poses: &[(IsometryMatrix3<f64>, IsometryMatrix3<f64>)],
) -> Result<Extrinsics, CalibrateError> {
    let fail = |message: String| CalibrateError::Failed {
        stage: "stereo".into(),
        message,
    };
    if views.is_empty() || views.len() != initial_poses.len() {
        return Err(fail("no views".into()));
    }
    // Initial E: chordal mean rotation and mean translation of the per-view estimates.
    let mut rsum = Matrix3::zeros();
    let mut tsum = Vector3::zeros();
    for (t0, t1) in initial_poses {
        let e = t1 * t0.inverse();
        rsum += e.rotation.into_inner();
        tsum += e.translation.vector;
    }
    let svd = rsum.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(fail("rotation average failed".into()));
    };
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        return Err(fail("per-view rig rotations disagree".into()));
    }
    r = Rotation3::from_matrix(&r).into_inner();
    let mut rig = IsometryMatrix3::from_parts(
        Translation3::from(tsum / initial_poses.len() as f64),
        Rotation3::from_matrix_unchecked(r),
    );
    let mut poses: Vec<IsometryMatrix3<f64>> = initial_poses.iter().map(|p| p.0).collect();
    let cost_of = |rig: &IsometryMatrix3<f64>, poses: &[IsometryMatrix3<f64>]| -> Vec<f64> {
        views
            .iter()
            .zip(poses)
            .map(|(v, t)| {
                squared_residuals(cam0, t, &v.board, &v.px0)
                    + squared_residuals(cam1, &(rig * t), &v.board, &v.px1)
            })
            .collect()
    };
    let n = 6 + 6 * views.len();
    let mut cost: f64 = cost_of(&rig, &poses).iter().sum();
    let mut lambda = 1e-3;
    for _ in 0..100 {
        let mut h = nalgebra::DMatrix::<f64>::zeros(n, n);
        let mut g = nalgebra::DVector::<f64>::zeros(n);
        let re = rig.rotation.into_inner();
        for (k, (v, t)) in views.iter().zip(&poses).enumerate() {
            let o = 6 + 6 * k;
            for ((p, x0), x1) in v.board.iter().zip(&v.px0).zip(&v.px1) {
                let rp = t.rotation * p.coords;
                let p0 = rp + t.translation.vector;
                let p1 = re * p0 + rig.translation.vector;
                let mut d0 = nalgebra::Matrix3x6::<f64>::zeros();
                d0.fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&(-rp.cross_matrix()));
                d0.fixed_view_mut::<3, 3>(0, 3)
                    .copy_from(&Matrix3::identity());
                let mut de = nalgebra::Matrix3x6::<f64>::zeros();
                de.fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&(-(re * p0).cross_matrix()));
                de.fixed_view_mut::<3, 3>(0, 3)
                    .copy_from(&Matrix3::identity());
                if let Some((q, j)) = cam0.project_with_jacobian(&p0) {
                    let res: Vector2<f64> = q - x0;
                    let jt = j * d0;
                    let mut hb = h.view_mut((o, o), (6, 6));
                    hb += jt.transpose() * jt;
                    let mut gb = g.rows_mut(o, 6);
                    gb += jt.transpose() * res;
                }
                if let Some((q, j)) = cam1.project_with_jacobian(&p1) {
                    let res: Vector2<f64> = q - x1;
                    let jt = j * re * d0;
                    let je = j * de;
                    let mut b = h.view_mut((o, o), (6, 6));
                    b += jt.transpose() * jt;
                    let mut b = h.view_mut((0, 0), (6, 6));
                    b += je.transpose() * je;
                    let cross = je.transpose() * jt;
                    let mut b = h.view_mut((0, o), (6, 6));
                    b += cross;
                    let mut b = h.view_mut((o, 0), (6, 6));
                    b += cross.transpose();
                    let mut gb = g.rows_mut(o, 6);
                    gb += jt.transpose() * res;
                    let mut gb = g.rows_mut(0, 6);
                    gb += je.transpose() * res;
                }
            }
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = h.clone();
            for i in 0..n {
                damped[(i, i)] += lambda * h[(i, i)].max(1e-9);
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let step = chol.solve(&-&g);
            let apply = |iso: &IsometryMatrix3<f64>, s: &[f64]| {
                IsometryMatrix3::from_parts(
                    Translation3::from(iso.translation.vector + Vector3::new(s[3], s[4], s[5])),
                    Rotation3::from_scaled_axis(Vector3::new(s[0], s[1], s[2])) * iso.rotation,
                )
            };
            let new_rig = apply(&rig, &step.as_slice()[0..6]);
            let new_poses: Vec<IsometryMatrix3<f64>> = poses
                .iter()
                .enumerate()
                .map(|(k, t)| apply(t, &step.as_slice()[6 + 6 * k..12 + 6 * k]))
                .collect();
            let new_cost: f64 = cost_of(&new_rig, &new_poses).iter().sum();
            if new_cost.is_finite() && new_cost < cost {
                let rel = (cost - new_cost) / cost.max(1e-300);
                rig = new_rig;
                poses = new_poses;
                cost = new_cost;
                lambda = (lambda * 0.1).max(1e-12);
                improved = rel > 1e-12;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    if !cost.is_finite() {
        return Err(fail("the optimization diverged".into()));
    }
    Ok(Extrinsics {
        cam1_from_cam0: rig,
        view_sq: cost_of(&rig, &poses),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{StereoRig, parse_rig};
    use std::path::Path;

    fn rig() -> StereoRig {
        parse_rig(
            Path::new("calib/helmet-fisheye.yaml"),
            include_str!("../../../calib/helmet-fisheye.yaml"),
        )
        .unwrap()
    }

    /// Exact projections of a grid seen from several poses, the board poses in cam0, and a
    /// per-view slightly wrong starting pose for each camera.
    #[allow(clippy::type_complexity)]
    fn synthetic_views(
        rig: &StereoRig,
        n: usize,
    ) -> (
        Vec<StereoView>,
        Vec<(IsometryMatrix3<f64>, IsometryMatrix3<f64>)>,
    ) {
        let grid: Vec<Point3<f64>> = (0..48)
            .map(|i| Point3::new(f64::from(i % 8) * 20.0, f64::from(i / 8) * 20.0, 0.0))
            .collect();
        let mut views = Vec::new();
        let mut initial = Vec::new();
        for v in 0..n {
            let a = v as f64;
            let pose = IsometryMatrix3::from_parts(
                Translation3::new(-70.0 + 6.0 * a, -20.0 + 3.0 * a, 230.0 + 5.0 * a),
                Rotation3::from_euler_angles(0.3 * (a * 1.3).sin(), 0.3 * (a * 0.7).cos(), 0.1 * a),
            );
            let px0 = grid
                .iter()
                .map(|p| rig.cam0.project(&(pose * p).coords).unwrap())
                .collect();
            let px1 = grid
                .iter()
                .map(|p| {
                    rig.cam1
                        .project(&(rig.cam1_from_cam0 * pose * p).coords)
                        .unwrap()
                })
                .collect();
            // Perturb: 1° and 2 mm off for cam0, a different error for cam1.
            let nudge = |iso: IsometryMatrix3<f64>, s: f64| {
                IsometryMatrix3::from_parts(
                    Translation3::from(iso.translation.vector + Vector3::new(2.0, -1.0, 1.5) * s),
                    Rotation3::from_scaled_axis(Vector3::new(0.01, -0.012, 0.008) * s)
                        * iso.rotation,
                )
            };
            initial.push((
                nudge(pose, (a * 0.9).sin()),
                nudge(rig.cam1_from_cam0 * pose, (a * 1.7).cos()),
            ));
            views.push(StereoView {
                board: grid.clone(),
                px0,
                px1,
            });
        }
        (views, initial)
    }

    #[test]
    fn extrinsics_are_recovered_exactly_from_exact_projections() {
        let rig = rig();
        let (views, initial) = synthetic_views(&rig, 6);
        let e = calibrate_extrinsics(&rig.cam0, &rig.cam1, &views, &initial).unwrap();
        let dt =
            (e.cam1_from_cam0.translation.vector - rig.cam1_from_cam0.translation.vector).norm();
        // (The file's R is orthonormal to ~1e-12 only: compare matrices, not angles.)
        let dr = (e.cam1_from_cam0.rotation.matrix() - rig.cam1_from_cam0.rotation.matrix()).norm();
        assert!(dt < 1e-6 && dr < 1e-9, "{dt} mm, {dr}");
        assert!(e.view_sq.iter().sum::<f64>() < 1e-12);
    }

    #[test]
    fn extrinsics_take_views_with_different_point_counts() {
        let rig = rig();
        let (mut views, initial) = synthetic_views(&rig, 6);
        for (k, v) in views.iter_mut().enumerate() {
            let keep = 20 + 4 * k;
            v.board.truncate(keep);
            v.px0.truncate(keep);
            v.px1.truncate(keep);
        }
        let e = calibrate_extrinsics(&rig.cam0, &rig.cam1, &views, &initial).unwrap();
        let dt =
            (e.cam1_from_cam0.translation.vector - rig.cam1_from_cam0.translation.vector).norm();
        assert!(dt < 1e-6, "{dt} mm");
    }
}
