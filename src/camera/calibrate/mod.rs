//! Stereo calibration from image pairs of a planar target: target detection, per-camera
//! intrinsics, then stereo extrinsics, with a report of what was used and what was dropped.
//!
//! # Method
//! 1. **Detection**, per image: a chessboard's inner corners by OpenCV's
//!    `findChessboardCorners` refined by `cornerSubPix`, put in a canonical order (board
//!    axes right-handed in the image, the black square at the board origin first) so both
//!    cameras label a view alike; an AprilTag grid's tag corners by the AprilTag 3 library
//!    (tag36h11, at most [`CalibrateParams::max_tag_hamming`] corrected bits), each corner
//!    then refined by fitting the two tag edges that meet there near the corner only (see
//!    [`refine_tag_corners`]). A view is dropped, with its reason, when the target is not
//!    found, has fewer than [`CalibrateParams::min_points_per_view`] points, or is
//!    degenerate (points nearly collinear on the board, or covering too little of the
//!    image).
//! 2. **Intrinsics**, per camera, from every view usable in that camera: OpenCV
//!    `calibrateCamera` (pinhole: `fx, fy, cx, cy`, `k1, k2, p1, p2, k3`) or
//!    `fisheye::calibrate` (`fx, fy, cx, cy`, `k1..k4`, skew fixed at 0, extrinsics
//!    recomputed each iteration). Views whose RMS exceeds
//!    `max(outlier_rms_factor × median, outlier_rms_floor_px)` are dropped and the camera
//!    calibrated again once.
//! 3. **Extrinsics** with both cameras' intrinsics fixed, from the pairs usable in both
//!    cameras, on the points seen in both: the objective of OpenCV's `stereoCalibrate` with
//!    `CALIB_FIX_INTRINSIC`, minimized here by Levenberg-Marquardt over the rig and every
//!    view's board pose (see `calibrate_extrinsics` for why not OpenCV's fisheye solver).
//!    Keeping the intrinsics fixed keeps each camera's RMS meaningful and the stereo step
//!    well conditioned.
//! 4. **RMS** figures are computed with helmcap's own camera models
//!    ([`Camera::project`]), as OpenCV's `calibrateCamera` defines them:
//!    `sqrt(Σ‖x̂ − x‖² / N)` over all N image points. Per camera: with the per-view board
//!    poses of step 2. For the pair: over both images of every stereo pair, with the rig and
//!    board poses of step 3.
//!
//! At least [`CalibrateParams::min_pairs`] pairs must survive to the stereo step (and as
//! many views per camera to the intrinsics), else [`CalibrateError::NotEnoughViews`] says
//! why the others were dropped.
//!
//! The steps live apart: detection and the view checks in `detect`, intrinsics in
//! `intrinsics`, extrinsics in `extrinsics`, the OpenCV conversions in `cv`, and what
//! became of each view in `report`; this module holds the parameters, the errors and the
//! entry point [`calibrate_stereo`].

mod cv;
mod detect;
mod extrinsics;
mod intrinsics;
mod report;

use std::fmt;
use std::path::{Path, PathBuf};

use nalgebra::{IsometryMatrix3, Point2, Point3};
use rayon::prelude::*;

use super::target::CalibrationTarget;
use super::{Camera, StereoRig};
use crate::gray_image::GrayImage;

pub use detect::{TargetObservation, detect_target, refine_tag_corners};
pub use report::{CalibrationReport, DropReason, ViewReport, ViewUse};

use extrinsics::{StereoView, calibrate_extrinsics, common_points};
use intrinsics::{Intrinsics, calibrate_intrinsics};
use report::count_reasons;

/// The lens model to calibrate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraModel {
    /// OpenCV radial-tangential, 5 coefficients.
    Pinhole,
    /// OpenCV fisheye (Kannala-Brandt), 4 coefficients.
    Fisheye,
}

impl std::str::FromStr for CameraModel {
    type Err = CalibrateError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "pinhole" => Ok(Self::Pinhole),
            "fisheye" => Ok(Self::Fisheye),
            other => Err(CalibrateError::Params(format!(
                "unknown camera model {other:?} (expected pinhole or fisheye)"
            ))),
        }
    }
}

impl fmt::Display for CameraModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Pinhole => "pinhole",
            Self::Fisheye => "fisheye",
        })
    }
}

/// Calibration parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrateParams {
    /// Lens model of both cameras. Default fisheye.
    pub model: CameraModel,
    /// Fewest image pairs usable in both cameras (and views per camera) to calibrate.
    /// Default 6.
    pub min_pairs: usize,
    /// Fewest target points in a view (in both images, for the stereo step). Default 16
    /// (four tags of an AprilTag grid; a chessboard is found whole or not at all).
    pub min_points_per_view: usize,
    /// Smallest part of the image the bounding box of a view's points must cover, as a
    /// fraction of the image area. Default 0.01.
    pub min_image_coverage: f64,
    /// A view is an outlier when its RMS exceeds this many times the camera's median view
    /// RMS (and [`Self::outlier_rms_floor_px`]). Default 3.
    pub outlier_rms_factor: f64,
    /// Views with an RMS below this are never outliers, pixels. Default 1.
    pub outlier_rms_floor_px: f64,
    /// Half side of the `cornerSubPix` search window for chessboard corners, pixels.
    /// Default 5.
    pub subpix_half_window_px: i32,
    /// Most corrected bits accepted in a tag detection. Default 1.
    pub max_tag_hamming: usize,
    /// Refine AprilTag corners on the tag edges near each corner ([`refine_tag_corners`]);
    /// off keeps the AprilTag library's corners. Default on.
    pub refine_tag_corners: bool,
}

impl Default for CalibrateParams {
    fn default() -> Self {
        Self {
            model: CameraModel::Fisheye,
            min_pairs: 6,
            min_points_per_view: 16,
            min_image_coverage: 0.01,
            outlier_rms_factor: 3.0,
            outlier_rms_floor_px: 1.0,
            subpix_half_window_px: 5,
            max_tag_hamming: 1,
            refine_tag_corners: true,
        }
    }
}

impl CalibrateParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`CalibrateError::Params`] naming the field.
    pub fn validate(&self) -> Result<(), CalibrateError> {
        let check = |ok: bool, field: &str| {
            if ok {
                Ok(())
            } else {
                Err(CalibrateError::Params(format!("{field} out of range")))
            }
        };
        check(self.min_pairs >= 3, "min_pairs (at least 3)")?;
        check(
            self.min_points_per_view >= 6,
            "min_points_per_view (at least 6)",
        )?;
        check(
            (0.0..1.0).contains(&self.min_image_coverage),
            "min_image_coverage",
        )?;
        check(self.outlier_rms_factor > 1.0, "outlier_rms_factor")?;
        check(self.outlier_rms_floor_px >= 0.0, "outlier_rms_floor_px")?;
        check(
            (1..=50).contains(&self.subpix_half_window_px),
            "subpix_half_window_px",
        )?;
        check(self.max_tag_hamming <= 3, "max_tag_hamming")
    }
}

/// Errors of the calibration.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    /// A parameter or the target is unusable.
    #[error("invalid calibration parameter: {0}")]
    Params(String),
    /// No image pairs were given.
    #[error("no image pairs to calibrate from")]
    NoImages,
    /// An image could not be read or decoded.
    #[error("{path}: {message}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// An image differs in size from the first one.
    #[error(
        "{path}: image is {width}×{height}, the first image is {expected_width}×{expected_height}"
    )]
    ImageSize {
        /// The file.
        path: PathBuf,
        /// Its width, pixels.
        width: u32,
        /// Its height, pixels.
        height: u32,
        /// The first image's width.
        expected_width: u32,
        /// The first image's height.
        expected_height: u32,
    },
    /// Too few views survived detection and filtering.
    #[error("{stage}: {usable} usable views, need at least {needed}; dropped: {dropped}")]
    NotEnoughViews {
        /// Which step ran short (`cam0 intrinsics`, `cam1 intrinsics`, `stereo`).
        stage: String,
        /// Views left.
        usable: usize,
        /// Views needed ([`CalibrateParams::min_pairs`]).
        needed: usize,
        /// Counts of the reasons views were dropped.
        dropped: String,
    },
    /// OpenCV failed (for example a calibration that did not converge).
    #[error("{stage}: OpenCV: {message}")]
    OpenCv {
        /// Which step failed.
        stage: String,
        /// OpenCV's message.
        message: String,
    },
    /// The calibration produced an unusable camera or rig.
    #[error("{stage}: {message}")]
    Failed {
        /// Which step failed.
        stage: String,
        /// What is wrong.
        message: String,
    },
}

/// One image pair: the files of cam0 and cam1.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ImagePair {
    /// cam0's image.
    pub cam0: PathBuf,
    /// cam1's image.
    pub cam1: PathBuf,
}

/// Calibrates a stereo rig from image pairs of `target` (see the module docs).
/// `load` reads an image (the CLI decodes PNGs); `progress` is called once per pair
/// detected.
///
/// # Errors
/// [`CalibrateError`]: bad parameters, an unreadable image or one of another size, too few
/// usable views, or a failed optimization.
pub fn calibrate_stereo(
    pairs: &[ImagePair],
    target: &CalibrationTarget,
    params: &CalibrateParams,
    load: &(dyn Fn(&Path) -> Result<GrayImage, String> + Sync),
    progress: &(dyn Fn() + Sync),
) -> Result<CalibrationReport, CalibrateError> {
    params.validate()?;
    if let CalibrationTarget::Chessboard(b) = target
        && b.is_half_turn_symmetric()
    {
        return Err(CalibrateError::Params(format!(
            "chessboard {}x{} looks the same after a half turn, so the two cameras may number \
             its corners differently: use one odd and one even corner count (e.g. 9x6)",
            b.cols, b.rows
        )));
    }
    if pairs.is_empty() {
        return Err(CalibrateError::NoImages);
    }
    // 1. Detection, in parallel over pairs.
    let clock = std::time::Instant::now();
    let size = load(&pairs[0].cam0)
        .map(|im| (im.width, im.height))
        .map_err(|message| CalibrateError::Image {
            path: pairs[0].cam0.clone(),
            message,
        })?;
    let detections: Vec<[Result<TargetObservation, DropReason>; 2]> = pairs
        .par_iter()
        .map(|pair| {
            let mut out = [
                Err(DropReason::TargetNotFound),
                Err(DropReason::TargetNotFound),
            ];
            for (slot, path) in out.iter_mut().zip([&pair.cam0, &pair.cam1]) {
                let image = load(path).map_err(|message| CalibrateError::Image {
                    path: path.clone(),
                    message,
                })?;
                if (image.width, image.height) != size
                    || image.data.len() != image.width as usize * image.height as usize
                {
                    return Err(CalibrateError::ImageSize {
                        path: path.clone(),
                        width: image.width,
                        height: image.height,
                        expected_width: size.0,
                        expected_height: size.1,
                    });
                }
                *slot = detect_target(&image, target, params)?;
            }
            progress();
            Ok(out)
        })
        .collect::<Result<_, CalibrateError>>()?;
    for (pair, det) in pairs.iter().zip(&detections) {
        for (path, d) in [&pair.cam0, &pair.cam1].into_iter().zip(det) {
            if let Err(reason) = d {
                tracing::warn!("{}: {reason}", path.display());
            }
        }
    }
    tracing::debug!("detection: {:.2} s", clock.elapsed().as_secs_f64());
    let clock = std::time::Instant::now();
    let points = target.points();
    // 2. Intrinsics per camera.
    let mut cams = Vec::with_capacity(2);
    for c in 0..2 {
        let obs: Vec<Result<&TargetObservation, DropReason>> = detections
            .iter()
            .map(|d| d[c].as_ref().map_err(Clone::clone))
            .collect();
        cams.push(calibrate_intrinsics(c, &obs, &points, size, params)?);
    }
    let [cam0, cam1]: [Intrinsics; 2] = cams.try_into().map_err(|_| CalibrateError::Failed {
        stage: "intrinsics".into(),
        message: "expected two cameras".into(),
    })?;
    // 3. Extrinsics from the pairs usable in both cameras.
    let mut stereo_use: Vec<ViewUse> = Vec::with_capacity(pairs.len());
    let mut stereo_views = Vec::new();
    for (v, det) in detections.iter().enumerate() {
        let (ok0, ok1) = (cam0.views[v].is_used(), cam1.views[v].is_used());
        if !(ok0 && ok1) {
            let cameras = match (ok0, ok1) {
                (true, _) => "cam1",
                (_, true) => "cam0",
                _ => "cam0 and cam1",
            };
            stereo_use.push(ViewUse::Dropped(DropReason::UnusableImage {
                cameras: cameras.into(),
            }));
            if ok0 || ok1 {
                tracing::warn!(
                    "pair {v}: used for one camera's intrinsics only (the other image is unusable)"
                );
            }
            continue;
        }
        let (Ok(a), Ok(b)) = (&det[0], &det[1]) else {
            return Err(CalibrateError::Failed {
                stage: "stereo".into(),
                message: format!("pair {v} is used by both cameras but has no detection"),
            });
        };
        let common = common_points(a, b);
        if common.len() < params.min_points_per_view {
            let reason = DropReason::TooFewPoints {
                found: common.len(),
                needed: params.min_points_per_view,
            };
            tracing::warn!("pair {v}: stereo: {reason} seen by both cameras");
            stereo_use.push(ViewUse::Dropped(reason));
            continue;
        }
        stereo_use.push(ViewUse::Used {
            points: common.len(),
            rms_px: f64::NAN,
        });
        stereo_views.push((v, common));
    }
    if stereo_views.len() < params.min_pairs {
        return Err(CalibrateError::NotEnoughViews {
            stage: "stereo".into(),
            usable: stereo_views.len(),
            needed: params.min_pairs,
            dropped: count_reasons(stereo_use.iter()),
        });
    }
    tracing::debug!("intrinsics: {:.2} s", clock.elapsed().as_secs_f64());
    let clock = std::time::Instant::now();
    let mut views3 = Vec::with_capacity(stereo_views.len());
    let mut initial = Vec::with_capacity(stereo_views.len());
    for (v, common) in &stereo_views {
        let (Some(t0), Some(t1)) = (cam0.poses[*v], cam1.poses[*v]) else {
            return Err(CalibrateError::Failed {
                stage: "stereo".into(),
                message: format!("pair {v} has no board pose"),
            });
        };
        initial.push((t0, t1));
        views3.push(StereoView {
            board: common.iter().map(|(id, _, _)| points[*id]).collect(),
            px0: common.iter().map(|(_, p, _)| *p).collect(),
            px1: common.iter().map(|(_, _, p)| *p).collect(),
        });
    }
    let extrinsics = calibrate_extrinsics(&cam0.camera, &cam1.camera, &views3, &initial)?;
    tracing::debug!("extrinsics: {:.2} s", clock.elapsed().as_secs_f64());
    let cam1_from_cam0 = extrinsics.cam1_from_cam0;
    let mut sum_sq = 0.0;
    let mut count = 0usize;
    for ((v, common), sq) in stereo_views.iter().zip(&extrinsics.view_sq) {
        let n = 2 * common.len();
        stereo_use[*v] = ViewUse::Used {
            points: common.len(),
            rms_px: (sq / n as f64).sqrt(),
        };
        sum_sq += sq;
        count += n;
    }
    let rms_stereo_px = (sum_sq / count.max(1) as f64).sqrt();
    let rig = StereoRig {
        cam0: cam0.camera,
        cam1: cam1.camera,
        cam1_from_cam0,
        rms_px: rms_stereo_px,
    };
    rig.validate().map_err(|e| CalibrateError::Failed {
        stage: "result".into(),
        message: e.to_string(),
    })?;
    let views = pairs
        .iter()
        .enumerate()
        .map(|(v, pair)| ViewReport {
            pair: pair.clone(),
            cam0: cam0.views[v].clone(),
            cam1: cam1.views[v].clone(),
            stereo: stereo_use[v].clone(),
        })
        .collect();
    Ok(CalibrationReport {
        rig,
        rms_cam0_px: cam0.rms_px,
        rms_cam1_px: cam1.rms_px,
        rms_stereo_px,
        views,
    })
}
/// `Σ‖project(cam_from_board·P) − x‖²` over a view (points behind the camera count as
/// 1e6 px² each, so a wrong pose cannot hide).
fn squared_residuals(
    camera: &Camera,
    cam_from_board: &IsometryMatrix3<f64>,
    board: &[Point3<f64>],
    pixels: &[Point2<f64>],
) -> f64 {
    board
        .iter()
        .zip(pixels)
        .map(|(p, x)| {
            camera
                .project(&(cam_from_board * p).coords)
                .map_or(1e6, |q| (q - x).norm_squared())
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_are_checked() {
        assert!(CalibrateParams::default().validate().is_ok());
        let p = CalibrateParams {
            min_pairs: 1,
            ..Default::default()
        };
        assert!(p.validate().is_err());
        assert!("kb".parse::<CameraModel>().is_err());
        assert_eq!(
            "pinhole".parse::<CameraModel>().unwrap(),
            CameraModel::Pinhole
        );
    }
}
