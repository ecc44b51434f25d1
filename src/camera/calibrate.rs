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

use std::fmt;
use std::path::{Path, PathBuf};

use nalgebra::{
    IsometryMatrix3, Matrix2, Matrix3, Point2, Point3, Rotation3, Translation3, Vector2, Vector3,
};
use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use rayon::prelude::*;

use super::target::{Aprilgrid, CalibrationTarget, Chessboard};
use super::{Camera, Distortion, StereoRig};

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

/// Why a view was not used.
#[derive(Debug, Clone, PartialEq)]
pub enum DropReason {
    /// The detector did not find the target.
    TargetNotFound,
    /// Too few target points were found.
    TooFewPoints {
        /// Points found.
        found: usize,
        /// Points needed.
        needed: usize,
    },
    /// The points cannot constrain a calibration (nearly collinear, too small, ...).
    Degenerate(String),
    /// The view's reprojection RMS is far above the camera's other views.
    Outlier {
        /// The view's RMS, pixels.
        rms_px: f64,
        /// The camera's median view RMS, pixels.
        median_px: f64,
    },
    /// (Stereo step) the pair's images are not both usable: `cameras` names the cameras
    /// whose image was dropped, e.g. `cam1` or `cam0 and cam1`.
    UnusableImage {
        /// The cameras whose image was dropped.
        cameras: String,
    },
}

impl fmt::Display for DropReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::TargetNotFound => f.write_str("target not found"),
            Self::TooFewPoints { found, needed } => {
                write!(f, "too few points ({found}, need {needed})")
            }
            Self::Degenerate(why) => write!(f, "degenerate: {why}"),
            Self::Outlier { rms_px, median_px } => write!(
                f,
                "reprojection outlier (RMS {rms_px:.2} px, median {median_px:.2} px)"
            ),
            Self::UnusableImage { cameras } => write!(f, "{cameras} image unusable"),
        }
    }
}

impl DropReason {
    /// A short name for counting reasons.
    fn kind(&self) -> &'static str {
        match self {
            Self::TargetNotFound => "target not found",
            Self::TooFewPoints { .. } => "too few points",
            Self::Degenerate(_) => "degenerate",
            Self::Outlier { .. } => "reprojection outlier",
            Self::UnusableImage { .. } => "an image of the pair unusable",
        }
    }
}

/// How one image (or, for the stereo step, one pair) was used.
#[derive(Debug, Clone, PartialEq)]
pub enum ViewUse {
    /// Used, with its number of points and its reprojection RMS (pixels).
    Used {
        /// Target points used.
        points: usize,
        /// Reprojection RMS of the view, pixels.
        rms_px: f64,
    },
    /// Not used, and why.
    Dropped(DropReason),
}

impl ViewUse {
    fn is_used(&self) -> bool {
        matches!(self, Self::Used { .. })
    }
}

impl fmt::Display for ViewUse {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Used { points, rms_px } => write!(f, "{points} points, RMS {rms_px:.3} px"),
            Self::Dropped(r) => write!(f, "dropped: {r}"),
        }
    }
}

/// One image pair: the files of cam0 and cam1.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ImagePair {
    /// cam0's image.
    pub cam0: PathBuf,
    /// cam1's image.
    pub cam1: PathBuf,
}

/// An 8-bit grayscale image, row-major, as a loader hands it over.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TargetImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `width × height` values, row by row.
    pub pixels: Vec<u8>,
}

/// What happened to one image pair.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewReport {
    /// The pair.
    pub pair: ImagePair,
    /// cam0's image in cam0's intrinsic calibration.
    pub cam0: ViewUse,
    /// cam1's image in cam1's intrinsic calibration.
    pub cam1: ViewUse,
    /// The pair in the stereo step (RMS over both images with the final rig).
    pub stereo: ViewUse,
}

/// The result of [`calibrate_stereo`].
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationReport {
    /// The calibrated rig; its `rms_px` is [`Self::rms_stereo_px`].
    pub rig: StereoRig,
    /// RMS reprojection error of cam0's intrinsic calibration, pixels.
    pub rms_cam0_px: f64,
    /// RMS reprojection error of cam1's intrinsic calibration, pixels.
    pub rms_cam1_px: f64,
    /// RMS reprojection error of the rig over both images of the stereo pairs, pixels.
    pub rms_stereo_px: f64,
    /// One entry per input pair, in input order.
    pub views: Vec<ViewReport>,
}

impl CalibrationReport {
    /// Number of pairs used in the stereo step.
    pub fn stereo_pairs_used(&self) -> usize {
        self.views.iter().filter(|v| v.stereo.is_used()).count()
    }
}

/// Target points found in one image: point ids (see [`crate::camera::target`]) and pixels
/// (OpenCV convention: pixel centres at integer coordinates).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TargetObservation {
    /// Point id of each detection.
    pub ids: Vec<usize>,
    /// Pixel of each detection.
    pub pixels: Vec<Point2<f64>>,
}

/// Finds the target in one image. An `Err(DropReason)` says why the image cannot be used.
///
/// # Errors
/// [`CalibrateError::OpenCv`] or [`CalibrateError::Failed`] when a detector fails to run
/// (not when it finds nothing).
pub fn detect_target(
    image: &TargetImage,
    target: &CalibrationTarget,
    params: &CalibrateParams,
) -> Result<Result<TargetObservation, DropReason>, CalibrateError> {
    let found = match target {
        CalibrationTarget::Chessboard(b) => detect_chessboard(image, b, params)?,
        CalibrationTarget::Aprilgrid(g) => detect_aprilgrid(image, g, params)?,
    };
    Ok(found.and_then(|obs| check_view(&obs, image, target, params).map(|()| obs)))
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
    load: &(dyn Fn(&Path) -> Result<TargetImage, String> + Sync),
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
                    || image.pixels.len() != image.width as usize * image.height as usize
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

/// One camera's intrinsic calibration.
struct Intrinsics {
    camera: Camera,
    rms_px: f64,
    /// Per input view: how it was used.
    views: Vec<ViewUse>,
    /// Per input view: `cam_from_board` when used.
    poses: Vec<Option<IsometryMatrix3<f64>>>,
}

/// Step 2 for camera `c`: calibrate on the usable views, drop outliers, calibrate again.
fn calibrate_intrinsics(
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
        camera_from_cv(&k, &d, width, height, model).map_err(|message| CalibrateError::Failed {
            stage: stage.to_string(),
            message,
        })?;
    let poses = rvecs
        .iter()
        .zip(tvecs.iter())
        .map(|(r, t)| isometry_from_cv(&r, &t))
        .collect::<Result<Vec<_>, String>>()
        .map_err(|message| CalibrateError::Failed {
            stage: stage.to_string(),
            message,
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

/// The points of a pair seen in both images: (id, cam0 pixel, cam1 pixel), by id.
fn common_points(
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
struct StereoView {
    board: Vec<Point3<f64>>,
    px0: Vec<Point2<f64>>,
    px1: Vec<Point2<f64>>,
}

/// Result of the extrinsic step.
struct Extrinsics {
    cam1_from_cam0: IsometryMatrix3<f64>,
    /// Per stereo view: the sum of squared residuals over both images, px².
    view_sq: Vec<f64>,
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
fn calibrate_extrinsics(
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

/// Counts of drop reasons, e.g. `3 target not found, 1 degenerate`.
fn count_reasons<'a>(uses: impl Iterator<Item = &'a ViewUse>) -> String {
    let mut counts: Vec<(&'static str, usize)> = Vec::new();
    for u in uses {
        if let ViewUse::Dropped(r) = u {
            match counts.iter_mut().find(|(k, _)| *k == r.kind()) {
                Some((_, n)) => *n += 1,
                None => counts.push((r.kind(), 1)),
            }
        }
    }
    if counts.is_empty() {
        return "none".into();
    }
    counts
        .iter()
        .map(|(k, n)| format!("{n} {k}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Rejects views with too few points, nearly collinear board points, or a footprint too
/// small in the image.
fn check_view(
    obs: &TargetObservation,
    image: &TargetImage,
    target: &CalibrationTarget,
    params: &CalibrateParams,
) -> Result<(), DropReason> {
    let n = obs.ids.len();
    if n < params.min_points_per_view {
        return Err(DropReason::TooFewPoints {
            found: n,
            needed: params.min_points_per_view,
        });
    }
    let points = target.points();
    // Spread of the board points: the smaller principal axis against the larger.
    let board: Vec<Vector2<f64>> = obs
        .ids
        .iter()
        .filter_map(|&id| points.get(id).map(|p| Vector2::new(p.x, p.y)))
        .collect();
    let mean = board.iter().sum::<Vector2<f64>>() / board.len().max(1) as f64;
    let cov = board.iter().fold(Matrix2::zeros(), |a, p| {
        a + (p - mean) * (p - mean).transpose()
    });
    let eig = cov.symmetric_eigenvalues();
    let (lo, hi) = (eig.min(), eig.max());
    if hi.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || lo / hi < 1e-2 {
        return Err(DropReason::Degenerate(
            "target points nearly collinear".into(),
        ));
    }
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in &obs.pixels {
        x0 = x0.min(p.x);
        y0 = y0.min(p.y);
        x1 = x1.max(p.x);
        y1 = y1.max(p.y);
    }
    let coverage = (x1 - x0) * (y1 - y0) / (f64::from(image.width) * f64::from(image.height));
    if coverage < params.min_image_coverage {
        return Err(DropReason::Degenerate(format!(
            "target covers {:.2} % of the image (need {:.2} %)",
            100.0 * coverage,
            100.0 * params.min_image_coverage
        )));
    }
    Ok(())
}

/// Chessboard corners by OpenCV, refined to subpixel and put in canonical order.
fn detect_chessboard(
    image: &TargetImage,
    board: &Chessboard,
    params: &CalibrateParams,
) -> Result<Result<TargetObservation, DropReason>, CalibrateError> {
    let cv = |e: opencv::Error| CalibrateError::OpenCv {
        stage: "chessboard detection".into(),
        message: e.message,
    };
    let mat = Mat::new_rows_cols_with_data(image.height as i32, image.width as i32, &image.pixels)
        .map_err(cv)?;
    let pattern = Size::new(board.cols as i32, board.rows as i32);
    let mut corners = Vector::<Point2f>::new();
    let found = opencv::calib3d::find_chessboard_corners(
        &mat,
        pattern,
        &mut corners,
        opencv::calib3d::CALIB_CB_ADAPTIVE_THRESH
            | opencv::calib3d::CALIB_CB_NORMALIZE_IMAGE
            | opencv::calib3d::CALIB_CB_FAST_CHECK,
    )
    .map_err(cv)?;
    let n = (board.cols * board.rows) as usize;
    if !found || corners.len() != n {
        return Ok(Err(DropReason::TargetNotFound));
    }
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        100,
        1e-4,
    )
    .map_err(cv)?;
    let half = params.subpix_half_window_px;
    opencv::imgproc::corner_sub_pix(
        &mat,
        &mut corners,
        Size::new(half, half),
        Size::new(-1, -1),
        criteria,
    )
    .map_err(cv)?;
    let pixels: Vec<Point2<f64>> = corners
        .iter()
        .map(|p| Point2::new(f64::from(p.x), f64::from(p.y)))
        .collect();
    Ok(
        canonical_chessboard_order(image, board, pixels).map(|pixels| TargetObservation {
            ids: (0..n).collect(),
            pixels,
        }),
    )
}

/// Puts OpenCV's corner list (row by row) in the board's order: board x and y axes
/// right-handed in the image (as seen from the printed side; mirrored otherwise), and
/// the black square at the board origin before corner 0 (rotated by a half turn
/// otherwise).
fn canonical_chessboard_order(
    image: &TargetImage,
    board: &Chessboard,
    mut px: Vec<Point2<f64>>,
) -> Result<Vec<Point2<f64>>, DropReason> {
    let (cols, rows) = (board.cols as usize, board.rows as usize);
    let at = |px: &[Point2<f64>], c: usize, r: usize| px[r * cols + c];
    let ex = at(&px, cols - 1, 0) - at(&px, 0, 0);
    let ey = at(&px, 0, rows - 1) - at(&px, 0, 0);
    if ex.x * ey.y - ex.y * ey.x < 0.0 {
        for row in px.chunks_mut(cols) {
            row.reverse();
        }
    }
    let origin_square = at(&px, 0, 0) + (at(&px, 0, 0) - at(&px, 1, 1)) * 0.5;
    let far_square = at(&px, cols - 1, rows - 1)
        + (at(&px, cols - 1, rows - 1) - at(&px, cols - 2, rows - 2)) * 0.5;
    let (Some(a), Some(b)) = (
        mean_around(image, origin_square),
        mean_around(image, far_square),
    ) else {
        return Err(DropReason::Degenerate(
            "the board's corner squares are outside the image".into(),
        ));
    };
    if a > b {
        px.reverse();
    }
    Ok(px)
}

/// Mean intensity in a 5×5 window around a pixel, `None` when it leaves the image.
fn mean_around(image: &TargetImage, p: Point2<f64>) -> Option<f64> {
    let (x, y) = (p.x.round() as i64, p.y.round() as i64);
    let (w, h) = (i64::from(image.width), i64::from(image.height));
    if x < 2 || y < 2 || x + 2 >= w || y + 2 >= h {
        return None;
    }
    let mut sum = 0.0;
    for yy in y - 2..=y + 2 {
        for xx in x - 2..=x + 2 {
            sum += f64::from(*image.pixels.get((yy * w + xx) as usize)?);
        }
    }
    Some(sum / 25.0)
}

/// AprilTag grid corners: tag36h11 detections with ids on the grid, each corner refined.
fn detect_aprilgrid(
    image: &TargetImage,
    grid: &Aprilgrid,
    params: &CalibrateParams,
) -> Result<Result<TargetObservation, DropReason>, CalibrateError> {
    let fail = |e: apriltag::Error| CalibrateError::Failed {
        stage: "AprilTag detection".into(),
        message: e.to_string(),
    };
    let (w, h) = (image.width as usize, image.height as usize);
    let mut at_image = apriltag::Image::zeros_with_stride(w, h, w).map_err(fail)?;
    let stride = at_image.stride();
    for (dst, src) in at_image
        .as_slice_mut()
        .chunks_mut(stride)
        .zip(image.pixels.chunks(w))
    {
        dst[..w].copy_from_slice(src);
    }
    let mut detector = apriltag::Detector::builder()
        .add_family_bits(apriltag::Family::tag_36h11(), params.max_tag_hamming)
        .build()
        .map_err(fail)?;
    detector.set_decimation(1.0);
    detector.set_refine_edges(true);
    let detections = detector.detect(&at_image);
    let mut tags: Vec<(usize, [Point2<f64>; 4])> = Vec::new();
    let mut duplicated = Vec::new();
    for d in &detections {
        let id = d.id();
        if id >= grid.tag_count() || d.hamming() > params.max_tag_hamming {
            continue;
        }
        if tags.iter().any(|(t, _)| *t == id) {
            duplicated.push(id);
            continue;
        }
        // The library puts pixel centres at +0.5; OpenCV and helmcap at integers.
        let c = d.corners();
        tags.push((id, c.map(|[x, y]| Point2::new(x - 0.5, y - 0.5))));
    }
    tags.retain(|(id, _)| !duplicated.contains(id));
    if tags.is_empty() {
        return Ok(Err(DropReason::TargetNotFound));
    }
    tags.sort_by_key(|t| t.0);
    let mut obs = TargetObservation::default();
    for (id, corners) in &tags {
        let refined = if params.refine_tag_corners {
            refine_tag_corners(image, corners)
        } else {
            *corners
        };
        for (k, p) in refined.iter().enumerate() {
            obs.ids.push(4 * id + k);
            obs.pixels.push(*p);
        }
    }
    Ok(Ok(obs))
}

/// Refines the four corners of a detected tag. The library intersects straight lines
/// fitted along whole tag edges, which lens distortion bends; here each corner is the
/// intersection of two lines fitted to the edge points found on the two edges that meet at
/// it, sampled only over the third of each edge nearest to the corner. An edge point is the
/// gradient-weighted centroid of the intensity profile across the edge. A corner whose
/// fit fails (too few edge samples) keeps the library's position.
pub fn refine_tag_corners(image: &TargetImage, corners: &[Point2<f64>; 4]) -> [Point2<f64>; 4] {
    let mut out = *corners;
    for k in 0..4 {
        let p = corners[k];
        let next = corners[(k + 1) % 4];
        let prev = corners[(k + 3) % 4];
        let (Some(la), Some(lb)) = (fit_edge_near(image, p, next), fit_edge_near(image, p, prev))
        else {
            continue;
        };
        if let Some(x) = intersect(&la, &lb)
            && (x - p).norm() < 3.0
        {
            out[k] = x;
        }
    }
    out
}

/// A line `n·x = c` with unit normal `n`.
struct Line {
    n: Vector2<f64>,
    c: f64,
}

/// Fits a line to the edge from corner `a` toward corner `b`, using edge points found
/// between 8 % and 35 % of the way (away from the corner's blur, near enough to be nearly
/// straight).
fn fit_edge_near(image: &TargetImage, a: Point2<f64>, b: Point2<f64>) -> Option<Line> {
    let d = b - a;
    let len = d.norm();
    if len < 12.0 {
        return None;
    }
    let t = d / len;
    let normal = Vector2::new(-t.y, t.x);
    let samples = ((0.27 * len) as usize).clamp(4, 40);
    // Stay within the tag's black border and its white ring (one cell, len / 8, each).
    let half_width = (0.4 * len / 8.0).clamp(1.0, 3.0);
    let steps = (4.0 * half_width).round() as i32;
    let mut pts: Vec<Point2<f64>> = Vec::with_capacity(samples);
    for s in 0..samples {
        let f = 0.08 + 0.27 * (s as f64 + 0.5) / samples as f64;
        let centre = a + d * f;
        // Gradient magnitude across the edge in quarter-pixel steps; its centroid is the
        // edge.
        let mut prev: Option<f64> = None;
        let (mut wsum, mut osum) = (0.0, 0.0);
        for j in -steps..=steps {
            let o = f64::from(j) * 0.25;
            let v = bilinear(image, centre + normal * o)?;
            if let Some(pv) = prev {
                let g = (v - pv).abs();
                wsum += g;
                osum += g * (o - 0.125);
            }
            prev = Some(v);
        }
        if wsum > 20.0 {
            pts.push(centre + normal * (osum / wsum));
        }
    }
    if pts.len() < 4 {
        return None;
    }
    // Total least squares line through the points.
    let mean = pts.iter().map(|p| p.coords).sum::<Vector2<f64>>() / pts.len() as f64;
    let cov = pts.iter().fold(Matrix2::zeros(), |acc, p| {
        let q = p.coords - mean;
        acc + q * q.transpose()
    });
    let eig = cov.symmetric_eigen();
    let i = if eig.eigenvalues[0] < eig.eigenvalues[1] {
        0
    } else {
        1
    };
    let n: Vector2<f64> = eig.eigenvectors.column(i).into_owned();
    Some(Line { n, c: n.dot(&mean) })
}

/// Intersection of two lines, `None` when nearly parallel.
fn intersect(a: &Line, b: &Line) -> Option<Point2<f64>> {
    let m = Matrix2::new(a.n.x, a.n.y, b.n.x, b.n.y);
    if m.determinant().abs() < 0.1 {
        return None;
    }
    m.try_inverse()
        .map(|inv| Point2::from(inv * Vector2::new(a.c, b.c)))
}

/// Bilinear intensity at a point (pixel centres at integers), `None` outside.
fn bilinear(image: &TargetImage, p: Point2<f64>) -> Option<f64> {
    let (x0, y0) = (p.x.floor(), p.y.floor());
    if x0 < 0.0
        || y0 < 0.0
        || x0 + 1.0 >= f64::from(image.width)
        || y0 + 1.0 >= f64::from(image.height)
    {
        return None;
    }
    let (fx, fy) = (p.x - x0, p.y - y0);
    let w = image.width as usize;
    let i = y0 as usize * w + x0 as usize;
    let g = |j: usize| image.pixels.get(j).map(|&v| f64::from(v));
    Some(
        g(i)? * (1.0 - fx) * (1.0 - fy)
            + g(i + 1)? * fx * (1.0 - fy)
            + g(i + w)? * (1.0 - fx) * fy
            + g(i + w + 1)? * fx * fy,
    )
}

fn point3f(p: &Point3<f64>) -> Point3f {
    Point3f::new(p.x as f32, p.y as f32, p.z as f32)
}

fn point2f(p: &Point2<f64>) -> Point2f {
    Point2f::new(p.x as f32, p.y as f32)
}

/// The values of a continuous `f64` matrix, row by row.
fn mat_values(m: &Mat) -> Result<Vec<f64>, String> {
    let m64 = if m.depth() == opencv::core::CV_64F {
        m.try_clone().map_err(|e| e.message)?
    } else {
        let mut out = Mat::default();
        m.convert_to(&mut out, opencv::core::CV_64F, 1.0, 0.0)
            .map_err(|e| e.message)?;
        out
    };
    let m64 = if m64.is_continuous() {
        m64
    } else {
        m64.try_clone().map_err(|e| e.message)?
    };
    let n = m64.total() * m64.channels() as usize;
    let data = m64.data_bytes().map_err(|e| e.message)?;
    if data.len() != 8 * n {
        return Err(format!("matrix holds {} bytes for {n} values", data.len()));
    }
    Ok(data
        .chunks_exact(8)
        .map(|b| f64::from_ne_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
        .collect())
}

fn mat3_from_cv(m: &Mat) -> Result<Matrix3<f64>, String> {
    let v = mat_values(m)?;
    if v.len() != 9 {
        return Err(format!("expected a 3×3 matrix, got {} values", v.len()));
    }
    Ok(Matrix3::from_row_slice(&v))
}

fn vec3_from_cv(m: &Mat) -> Result<Vector3<f64>, String> {
    let v = mat_values(m)?;
    if v.len() != 3 {
        return Err(format!("expected 3 values, got {}", v.len()));
    }
    Ok(Vector3::new(v[0], v[1], v[2]))
}

fn isometry_from_cv(r: &Mat, t: &Mat) -> Result<IsometryMatrix3<f64>, String> {
    let rv = vec3_from_cv(r)?;
    let tv = vec3_from_cv(t)?;
    Ok(IsometryMatrix3::from_parts(
        Translation3::from(tv),
        Rotation3::from_scaled_axis(rv),
    ))
}

fn camera_from_cv(
    k: &Mat,
    d: &Mat,
    width: u32,
    height: u32,
    model: CameraModel,
) -> Result<Camera, String> {
    let k = mat3_from_cv(k)?;
    let d = mat_values(d)?;
    let distortion = match model {
        CameraModel::Pinhole => {
            let d5: Vec<f64> = d
                .iter()
                .copied()
                .chain(std::iter::repeat(0.0))
                .take(5)
                .collect();
            Distortion::from_coefficients("pinhole", &d5)
        }
        CameraModel::Fisheye => Distortion::from_coefficients("fisheye", &d),
    }
    .map_err(|e| e.to_string())?;
    let camera = Camera {
        width_px: width,
        height_px: height,
        k,
        distortion,
    };
    camera.validate().map_err(|e| e.to_string())?;
    Ok(camera)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::parse_rig;

    fn rig() -> StereoRig {
        parse_rig(
            Path::new("calib/helmet-fisheye.yaml"),
            include_str!("../../calib/helmet-fisheye.yaml"),
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

    #[test]
    fn views_with_collinear_or_tiny_targets_are_degenerate() {
        let target = CalibrationTarget::parse("aprilgrid:6x6:30:0.3").unwrap();
        let image = TargetImage {
            width: 1000,
            height: 1000,
            pixels: vec![0; 1_000_000],
        };
        let params = CalibrateParams::default();
        // One row of tags: 24 collinear-ish corners (two rows of points, 30 mm apart over
        // 225 mm: spread ratio ≈ 0.02²) — use only the tags' top corners: collinear.
        let ids: Vec<usize> = (0..6).flat_map(|t| [4 * t + 2, 4 * t + 3]).collect();
        let ids: Vec<usize> = ids.iter().chain(ids.iter()).copied().take(16).collect();
        let pixels = (0..ids.len())
            .map(|i| Point2::new(100.0 + 40.0 * i as f64, 300.0 + 20.0 * i as f64))
            .collect();
        let obs = TargetObservation { ids, pixels };
        assert!(matches!(
            check_view(&obs, &image, &target, &params),
            Err(DropReason::Degenerate(_))
        ));
        // Four whole tags but only 20 px across in the image.
        let ids: Vec<usize> = (0..16).collect();
        let pixels = (0..16)
            .map(|i| {
                Point2::new(
                    500.0 + f64::from(i % 4) * 5.0,
                    500.0 + f64::from(i / 4) * 5.0,
                )
            })
            .collect();
        let obs = TargetObservation { ids, pixels };
        let r = check_view(&obs, &image, &target, &params);
        assert!(matches!(r, Err(DropReason::Degenerate(ref m)) if m.contains("% of the image")));
        // Too few points.
        let obs = TargetObservation {
            ids: vec![0, 1, 2, 3],
            pixels: vec![Point2::origin(); 4],
        };
        assert_eq!(
            check_view(&obs, &image, &target, &params),
            Err(DropReason::TooFewPoints {
                found: 4,
                needed: 16
            })
        );
    }

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
