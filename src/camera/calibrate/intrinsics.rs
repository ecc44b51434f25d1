//! Step 2, per camera: OpenCV's intrinsic calibration (`calibrateCamera` or
//! `fisheye::calibrate`) on the usable views, with one round of outlier rejection.

use nalgebra::{IsometryMatrix3, Point3};
use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vector};

use super::super::Camera;
use super::cv::{CvError, camera_from_cv, isometry_from_cv, point2f, point3f};
use super::report::count_reasons;
use super::{
    CalibrateError, CalibrateParams, CameraModel, DropReason, TargetObservation, ViewUse,
    squared_residuals,
};

/// One camera's intrinsic calibration.
pub(super) struct Intrinsics {
    pub(super) camera: Camera,
    pub(super) rms_px: f64,
    /// Per input view: how it was used.
    pub(super) views: Vec<ViewUse>,
    /// Per input view: `cam_from_board` when used.
    pub(super) poses: Vec<Option<IsometryMatrix3<f64>>>,
}

/// Step 2 for camera `c`: calibrate on the usable views, drop outliers, calibrate again.
pub(super) fn calibrate_intrinsics(
    c: usize,
    observations: &[Result<&TargetObservation, DropReason>],
    points: &[Point3<f64>],
    size: (u32, u32),
    params: &CalibrateParams,
) -> Result<Intrinsics, CalibrateError> {
    let stage = format!("cam{c} intrinsics");
    let mut views: Vec<ViewUse> = observations
        .iter()
        .map(|o| match o {
            Ok(obs) => ViewUse::Used {
                points: obs.ids.len(),
                rms_px: f64::NAN,
            },
            Err(r) => ViewUse::Dropped(r.clone()),
        })
        .collect();
    let mut result = None;
    for round in 0..2 {
        let used: Vec<usize> = (0..views.len()).filter(|&v| views[v].is_used()).collect();
        if used.len() < params.min_pairs {
            return Err(CalibrateError::NotEnoughViews {
                stage,
                usable: used.len(),
                needed: params.min_pairs,
                dropped: count_reasons(views.iter()),
            });
        }
        let obs: Vec<&TargetObservation> = used
            .iter()
            .filter_map(|&v| observations[v].as_ref().ok().copied())
            .collect();
        let (camera, poses) = run_intrinsics(&obs, points, size, params.model, &stage)?;
        let per_view: Vec<(f64, usize)> = obs
            .iter()
            .zip(&poses)
            .map(|(o, pose)| {
                let board: Vec<Point3<f64>> = o.ids.iter().map(|&id| points[id]).collect();
                (
                    squared_residuals(&camera, pose, &board, &o.pixels),
                    o.ids.len(),
                )
            })
            .collect();
        let rms: Vec<f64> = per_view
            .iter()
            .map(|(s, n)| (s / *n as f64).sqrt())
            .collect();
        let mut sorted = rms.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
        let limit = (params.outlier_rms_factor * median).max(params.outlier_rms_floor_px);
        let mut dropped_any = false;
        for (k, &v) in used.iter().enumerate() {
            if round == 0 && rms[k] > limit {
                let reason = DropReason::Outlier {
                    rms_px: rms[k],
                    median_px: median,
                };
                tracing::warn!("cam{c} view {v}: {reason}");
                views[v] = ViewUse::Dropped(reason);
                dropped_any = true;
            } else {
                views[v] = ViewUse::Used {
                    points: per_view[k].1,
                    rms_px: rms[k],
                };
            }
        }
        if dropped_any {
            continue;
        }
        let (s, n) = per_view
            .iter()
            .fold((0.0, 0usize), |(s, n), (a, b)| (s + a, n + b));
        let mut pose_of = vec![None; views.len()];
        for (k, &v) in used.iter().enumerate() {
            pose_of[v] = Some(poses[k]);
        }
        result = Some(Intrinsics {
            camera,
            rms_px: (s / n.max(1) as f64).sqrt(),
            views: views.clone(),
            poses: pose_of,
        });
        break;
    }
    result.ok_or_else(|| CalibrateError::Failed {
        stage,
        message: "outlier rejection did not settle".into(),
    })
}

/// OpenCV's intrinsic calibration of one camera; returns the camera and the board pose
/// (`cam_from_board`) of each observation.
fn run_intrinsics(
    observations: &[&TargetObservation],
    points: &[Point3<f64>],
    (width, height): (u32, u32),
    model: CameraModel,
    stage: &str,
) -> Result<(Camera, Vec<IsometryMatrix3<f64>>), CalibrateError> {
    let cv = |e: opencv::Error| CalibrateError::OpenCv {
        stage: stage.to_string(),
        message: e.message,
    };
    let object: Vector<Vector<Point3f>> = observations
        .iter()
        .map(|o| o.ids.iter().map(|&id| point3f(&points[id])).collect())
        .collect();
    let image: Vector<Vector<Point2f>> = observations
        .iter()
        .map(|o| o.pixels.iter().map(point2f).collect())
        .collect();
    let size = Size::new(width as i32, height as i32);
    let mut k = Mat::default();
    let mut d = Mat::default();
    let mut rvecs = Vector::<Mat>::new();
    let mut tvecs = Vector::<Mat>::new();
    // Stop at a relative parameter change of 1e-10 (far below the noise), at most 100
    // iterations.
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        100,
        1e-10,
    )
    .map_err(cv)?;
    match model {
        CameraModel::Pinhole => {
            opencv::calib3d::calibrate_camera(
                &object, &image, size, &mut k, &mut d, &mut rvecs, &mut tvecs, 0, criteria,
            )
            .map_err(cv)?;
        }
        CameraModel::Fisheye => {
            let flags = opencv::calib3d::Fisheye_CALIB_RECOMPUTE_EXTRINSIC
                | opencv::calib3d::Fisheye_CALIB_FIX_SKEW;
            opencv::calib3d::calibrate(
                &object, &image, size, &mut k, &mut d, &mut rvecs, &mut tvecs, flags, criteria,
            )
            .map_err(cv)?;
        }
    }
    let camera =
        camera_from_cv(&k, &d, width, height, model).map_err(|e| CalibrateError::Failed {
            stage: stage.to_string(),
            message: e.to_string(),
        })?;
    let poses = rvecs
        .iter()
        .zip(tvecs.iter())
        .map(|(r, t)| isometry_from_cv(&r, &t))
        .collect::<Result<Vec<_>, CvError>>()
        .map_err(|e| CalibrateError::Failed {
            stage: stage.to_string(),
            message: e.to_string(),
        })?;
    if poses.len() != observations.len() {
        return Err(CalibrateError::Failed {
            stage: stage.to_string(),
            message: format!(
                "OpenCV returned {} poses for {} views",
                poses.len(),
                observations.len()
            ),
        });
    }
    Ok((camera, poses))
}
