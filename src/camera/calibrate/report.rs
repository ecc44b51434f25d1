//! What became of each view: the reasons a view was dropped, how each image and pair was
//! used, and the report of a calibration.

use std::fmt;

use super::{ImagePair, StereoRig};

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
    pub(super) fn is_used(&self) -> bool {
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

/// The result of [`calibrate_stereo`](super::calibrate_stereo).
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
/// Counts of drop reasons, e.g. `3 target not found, 1 degenerate`.
pub(super) fn count_reasons<'a>(uses: impl Iterator<Item = &'a ViewUse>) -> String {
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
