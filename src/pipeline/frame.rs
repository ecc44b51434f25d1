//! The per-frame envelope that travels through every stage and reaches the sinks.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Isometry3, Point2, Point3};

use crate::align::PoseSource;
use crate::animation::RigFit;
use crate::capture::GrayImage;
use crate::frame_index::FrameIndex;
use crate::timecode::Timecode;
use crate::track::Detection;

/// The stages of the pipeline, in order (names as in `metrics.json`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stage {
    /// Reading (decoding) frames from the source.
    Source,
    /// Marker detection in both images, labeling and triangulation.
    Track,
    /// Head stabilization (robust Horn) into the head frame.
    Stabilize,
    /// Dense reconstruction (LGI or a baseline).
    Solve,
    /// Detail enhancement.
    Enhance,
    /// Rig weights from the dense mesh (`--rig`, the animation exports).
    Rig,
    /// The sinks (files, viewer).
    Sinks,
}

impl Stage {
    /// Every stage, in pipeline order.
    pub const ALL: [Stage; 7] = [
        Stage::Source,
        Stage::Track,
        Stage::Stabilize,
        Stage::Solve,
        Stage::Enhance,
        Stage::Rig,
        Stage::Sinks,
    ];

    /// Short name (`source`, `track`, ...), also the stage thread's name after
    /// `helmcap:`.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Source => "source",
            Stage::Track => "track",
            Stage::Stabilize => "stabilize",
            Stage::Solve => "solve",
            Stage::Enhance => "enhance",
            Stage::Rig => "rig",
            Stage::Sinks => "sinks",
        }
    }

    /// Position in [`Stage::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Time spent in each stage on one frame, milliseconds (NaN: the stage did not run).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageTimings {
    /// Indexed by [`Stage::index`].
    pub ms: [f64; Stage::ALL.len()],
}

impl Default for StageTimings {
    fn default() -> Self {
        Self {
            ms: [f64::NAN; Stage::ALL.len()],
        }
    }
}

impl StageTimings {
    /// The time of `stage`, ms (NaN when it did not run).
    pub fn get(&self, stage: Stage) -> f64 {
        self.ms[stage.index()]
    }

    /// Records the time of `stage`, ms.
    pub fn set(&mut self, stage: Stage, ms: f64) {
        self.ms[stage.index()] = ms;
    }
}

/// What happened to one layout marker in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BundleStatus {
    /// Labeled in both cameras and triangulated this frame.
    Observed,
    /// Not observed this frame; its position is the reconstructed surface's at the
    /// marker's vertex (the dense solve fills the gap from the neighbouring markers).
    GapFilled,
    /// Labeled, but rejected (too far from where the face can put it, or no head pose
    /// to stabilize it): written with non-finite coordinates so readers count it missing.
    Dropped,
    /// Not observed and not filled: no row in the bundles CSV.
    Missing,
}

impl BundleStatus {
    /// The name written in CSV files (`observed`, `gap-filled`, `dropped`, `missing`).
    pub fn name(self) -> &'static str {
        match self {
            BundleStatus::Observed => "observed",
            BundleStatus::GapFilled => "gap-filled",
            BundleStatus::Dropped => "dropped",
            BundleStatus::Missing => "missing",
        }
    }
}

/// One layout marker in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerResult {
    /// What happened to it.
    pub status: BundleStatus,
    /// Triangulated position in cam0, mm (observed and dropped markers).
    pub point_in_cam0: Option<Point3<f64>>,
    /// Position in the head frame, mm (observed and gap-filled markers).
    pub point_in_head: Option<Point3<f64>>,
    /// Labeled detections, cam0 and cam1, pixels (observed and dropped markers).
    pub pixels: Option<[Point2<f64>; 2]>,
    /// Confidence 0..1: the triangulation's for observed markers, decaying with the
    /// gap length for gap-filled ones, 0 otherwise.
    pub confidence: f64,
    /// RMS reprojection error of the triangulation, pixels (NaN when not triangulated).
    pub reprojection_px: f64,
    /// Labeled again after a gap this frame.
    pub reacquired: bool,
}

impl MarkerResult {
    /// A marker with no data this frame.
    pub const MISSING: MarkerResult = MarkerResult {
        status: BundleStatus::Missing,
        point_in_cam0: None,
        point_in_head: None,
        pixels: None,
        confidence: 0.0,
        reprojection_px: f64::NAN,
        reacquired: false,
    };
}

/// Labeling counts of one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LabelCounts {
    /// Detections in cam0 and cam1.
    pub detections: [usize; 2],
    /// Markers labeled.
    pub labeled: usize,
    /// Markers labeled again after a gap.
    pub reacquired: usize,
    /// Candidate labels rejected by the labeler.
    pub rejected: usize,
    /// The labeler was (re)acquiring the face this frame.
    pub acquiring: bool,
}

/// One frame as it leaves the pipeline: every stage fills its part. Sinks receive it by
/// reference.
#[derive(Debug, Clone)]
pub struct FrameResult {
    /// Frame index (as the source numbers it).
    pub index: FrameIndex,
    /// Capture timestamp, ns.
    pub timestamp_ns: u64,
    /// Timecode, when the source has one.
    pub timecode: Option<Timecode>,
    /// When the source delivered the frame (start of the end-to-end latency).
    pub received_at: Instant,
    /// The two images (cam0, cam1).
    pub images: Arc<[GrayImage; 2]>,
    /// The detections per camera, labeled or not: every one while acquiring or searching
    /// the region of interest; in search windows, those that could be a marker's (see
    /// [`crate::track::StereoTracker`]).
    pub detections: [Vec<Detection>; 2],
    /// Per layout marker, in layout order.
    pub markers: Vec<MarkerResult>,
    /// Labeling counts.
    pub label_counts: LabelCounts,
    /// Head pose, head frame → cam0 (mm); None when the frame has none.
    pub cam0_from_head: Option<Isometry3<f64>>,
    /// Where the head pose came from.
    pub pose_source: PoseSource,
    /// Dense mesh, every vertex of the dataset's neutral topology, head frame, mm (None
    /// when no solve ran or the frame could not be solved).
    pub mesh: Option<Arc<Vec<Point3<f64>>>>,
    /// The mesh was detail-enhanced.
    pub enhanced: bool,
    /// The rig's weights that best reproduce `mesh`, and the fit's residual (None when the
    /// take solves no rig, or the frame has no mesh).
    pub rig_fit: Option<Arc<RigFit>>,
    /// Per-vertex distance to the ground-truth mesh, mm, when the session has one.
    pub mesh_error_mm: Option<Arc<Vec<f32>>>,
    /// RMS distance of the observed bundles to the ground truth (head frame), mm, when
    /// the session has it.
    pub bundle_error_rms_mm: Option<f64>,
    /// Time per stage, ms (the sinks' own time is filled after they ran).
    pub timings: StageTimings,
}

impl FrameResult {
    /// A frame fresh from the source, with `marker_count` markers not yet seen.
    pub fn new(
        index: FrameIndex,
        timestamp_ns: u64,
        timecode: Option<Timecode>,
        images: [GrayImage; 2],
        marker_count: usize,
    ) -> Self {
        Self {
            index,
            timestamp_ns,
            timecode,
            received_at: Instant::now(),
            images: Arc::new(images),
            detections: [Vec::new(), Vec::new()],
            markers: vec![MarkerResult::MISSING; marker_count],
            label_counts: LabelCounts::default(),
            cam0_from_head: None,
            pose_source: PoseSource::Missing,
            mesh: None,
            enhanced: false,
            rig_fit: None,
            mesh_error_mm: None,
            bundle_error_rms_mm: None,
            timings: StageTimings::default(),
        }
    }

    /// Labeled 2D positions of camera `camera` (0 or 1): `(marker index, pixel)`.
    pub fn tracks(&self, camera: usize) -> impl Iterator<Item = (usize, Point2<f64>)> + '_ {
        self.markers
            .iter()
            .enumerate()
            .filter_map(move |(m, r)| r.pixels.and_then(|p| p.get(camera).map(|px| (m, *px))))
    }

    /// Count of markers with `status`.
    pub fn count(&self, status: BundleStatus) -> usize {
        self.markers.iter().filter(|m| m.status == status).count()
    }
}
