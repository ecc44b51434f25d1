//! Marker tracking and labeling: which painted dot is which layout marker, frame after
//! frame, from the two cameras' unlabeled detections.
//!
//! # Acquisition
//! While no head pose is known, the detections are paired under the epipolar constraint
//! ([`pair_detections`], ambiguous pairs dropped) and triangulated; the unlabeled 3D points
//! are registered to the layout's neutral positions with no prior beyond "the face is in
//! front of the cameras". RANSAC over point triples with distance-invariant matching:
//! three well-spread triangulated points give three distances, and every triple of
//! neutral markers with the same three pairwise distances (within a tolerance) is a
//! hypothesis, solved by Horn's closed form ([`horn_alignment`]) and scored by the
//! truncated quadratic (MSAC) count of neutral markers landing on a triangulated point.
//! The best hypothesis is refined by iterated closest points and accepted only when it is
//! unambiguous (no distinct hypothesis scores close to it) and most points match within a
//! tight gate.
//!
//! # Tracking
//! Each marker keeps its position in the head frame `hᵢ` (the neutral position until seen,
//! then its last triangulated position carried back by the head pose) and its velocity in
//! the head frame. Per frame:
//! 1. The rigid head pose is predicted at constant velocity and every marker is predicted
//!    at `T·(hᵢ + vᵢ)` and projected into both cameras.
//! 2. Per camera, markers are assigned to detections within a gate around their
//!    prediction by the Hungarian method ([`hungarian`], per connected component of the
//!    gated bipartite graph). An assignment with a rival (another detection near the
//!    prediction, or another prediction near the detection) is in doubt.
//! 3. Left/right pairing under the epipolar constraint: a marker's two detections must
//!    triangulate within the epipolar gate ([`super::gate`]: `k` robust standard
//!    deviations of the residuals of confidently labeled markers, at least
//!    [`LabelParams::max_reprojection_px`]) and land near the 3D
//!    prediction. A marker in doubt in one camera is kept only when exactly one of its
//!    candidate pairs passes both tests; otherwise it is dropped for the frame (a wrong
//!    label is worse than a missing one).
//! 4. The head pose of the frame is estimated by weighted Horn (stabilizing weights of
//!    the layout, with outlier rejection) from these labels, all markers are predicted
//!    again with it, and steps 2-3 run a second time with the tight gate: this absorbs
//!    fast head motion that the constant-velocity prediction misses.
//!
//! Markers that come back after an occlusion are re-identified at their last seen
//! head-frame position carried by the current pose, with a gate that grows with the gap.
//! Spurious blobs match no prediction, or fail the epipolar and 3D gates. When too few
//! markers are labeled for a few frames, or the head pose does not fit the labels, the
//! tracks are dropped and the next frame is acquired again.

use nalgebra::{Isometry3, Point2, Point3, Vector3};

use super::Detection;
use super::gate::{EpipolarGate, EpipolarGateParams};
use crate::align::horn_alignment;
use crate::camera::StereoRig;
use crate::dataset::MarkerLayout;
use crate::stereo::{
    Bundle, PairParams, TriangulateParams, hungarian, pair_detections, triangulate,
};

/// Labeling settings.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct LabelParams {
    /// Pairing and triangulation for acquisition (epipolar gate, depth range, ambiguity).
    /// Default [`PairParams::default`].
    pub pair: PairParams,
    /// Acquisition: absolute tolerance when matching a distance between two triangulated
    /// points with a distance between two neutral markers, mm. Default 1.5.
    pub acquire_distance_tolerance_mm: f64,
    /// Acquisition: tolerance relative to the distance, added to the absolute one.
    /// Default 0.02.
    pub acquire_distance_tolerance_rel: f64,
    /// Acquisition: smallest distance between the points of a sampled triple, mm.
    /// Default 25.
    pub acquire_min_spread_mm: f64,
    /// Acquisition: number of sampled triples. Default 300.
    pub acquire_iterations: usize,
    /// Acquisition: a neutral marker matches a triangulated point within this, mm.
    /// Default 3.
    pub acquire_gate_mm: f64,
    /// Acquisition: smallest share of the triangulated points that must match a marker.
    /// Default 0.6.
    pub acquire_min_inlier_fraction: f64,
    /// Acquisition: fewest matched markers. Default 8.
    pub acquire_min_markers: usize,
    /// Acquisition: the best distinct rival hypothesis must score below this share of the
    /// best. Default 0.5.
    pub acquire_ambiguity_ratio: f64,
    /// Search radius around a marker's predicted pixel when it was labeled in the previous
    /// frame, pixels. Default 6.
    pub gate_px: f64,
    /// Added to the search radius per frame of a gap (a marker coming back after an
    /// occlusion), pixels. Default 1.
    pub gate_growth_px_per_frame: f64,
    /// Largest search radius for a marker coming back after a gap, pixels. Default 10.
    pub max_gap_gate_px: f64,
    /// Added to the search radius per pixel of predicted expression motion. Default 0.5.
    pub velocity_gate_factor: f64,
    /// Extra search radius of the first pass, which only estimates the head pose,
    /// pixels. Default 10.
    pub pose_pass_extra_gate_px: f64,
    /// An assignment at distance `e` is in doubt when a rival lies within
    /// `ambiguity_ratio · e + ambiguity_margin_px`. Default 2.
    pub ambiguity_ratio: f64,
    /// See [`LabelParams::ambiguity_ratio`], pixels. Default 2.
    pub ambiguity_margin_px: f64,
    /// Largest RMS reprojection error of a labeled marker's two detections (the epipolar
    /// gate) before the centroid noise is measured, and its floor afterwards, pixels.
    /// Default 0.6.
    pub max_reprojection_px: f64,
    /// Scaling of the epipolar gate with the measured centroid noise (its `floor_px` is
    /// replaced by [`LabelParams::max_reprojection_px`]). Default
    /// [`EpipolarGateParams::default`].
    pub epipolar_gate: EpipolarGateParams,
    /// The 3D gate around the prediction, as a multiple of the pixel gate's size at the
    /// marker's depth. Default 1.5.
    pub gate_3d_factor: f64,
    /// Share of the last frame-to-frame expression motion carried into the prediction.
    /// Default 0.8.
    pub velocity_damping: f64,
    /// Tracking is lost when fewer markers than this are labeled ... Default 6.
    pub lost_min_markers: usize,
    /// ... for this many frames in a row. Default 3.
    pub lost_frames: usize,
    /// A frame's labels are dropped when the stabilizing markers fit the rigid head pose
    /// worse than this RMS, mm. Default 2.5.
    pub max_pose_rms_mm: f64,
    /// A jump of more than this many frames (or a frame number that does not increase)
    /// drops the tracks. Default 5.
    pub max_frame_gap: usize,
    /// Margin added around the predicted markers for the detector's region of interest,
    /// pixels. Default 40.
    pub roi_margin_px: f64,
}

impl Default for LabelParams {
    fn default() -> Self {
        Self {
            pair: PairParams::default(),
            acquire_distance_tolerance_mm: 1.5,
            acquire_distance_tolerance_rel: 0.02,
            acquire_min_spread_mm: 25.0,
            acquire_iterations: 300,
            acquire_gate_mm: 3.0,
            acquire_min_inlier_fraction: 0.6,
            acquire_min_markers: 8,
            acquire_ambiguity_ratio: 0.5,
            gate_px: 6.0,
            gate_growth_px_per_frame: 1.0,
            max_gap_gate_px: 10.0,
            velocity_gate_factor: 0.5,
            pose_pass_extra_gate_px: 10.0,
            ambiguity_ratio: 2.0,
            ambiguity_margin_px: 2.0,
            max_reprojection_px: 0.6,
            epipolar_gate: EpipolarGateParams::default(),
            gate_3d_factor: 1.5,
            velocity_damping: 0.8,
            lost_min_markers: 6,
            lost_frames: 3,
            max_pose_rms_mm: 2.5,
            max_frame_gap: 5,
            roi_margin_px: 40.0,
        }
    }
}

impl LabelParams {
    /// Checks every field.
    ///
    /// # Errors
    /// A message naming the field.
    pub fn validate(&self) -> Result<(), String> {
        let positive = |v: f64, name: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{name} must be positive and finite"))
            }
        };
        let non_negative = |v: f64, name: &str| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(format!("{name} must be non-negative and finite"))
            }
        };
        let tp = &self.pair.triangulate;
        positive(
            tp.max_reprojection_px,
            "pair.triangulate.max_reprojection_px",
        )?;
        positive(tp.sigma_px, "pair.triangulate.sigma_px")?;
        let (z0, z1) = tp.depth_range_mm;
        if !(z0.is_finite() && z1.is_finite() && 0.0 < z0 && z0 < z1) {
            return Err("pair.triangulate.depth_range_mm must be 0 < near < far".into());
        }
        non_negative(self.pair.ambiguity_margin_px, "pair.ambiguity_margin_px")?;
        non_negative(
            self.acquire_distance_tolerance_mm,
            "acquire_distance_tolerance_mm",
        )?;
        non_negative(
            self.acquire_distance_tolerance_rel,
            "acquire_distance_tolerance_rel",
        )?;
        if self.acquire_distance_tolerance_mm + self.acquire_distance_tolerance_rel <= 0.0 {
            return Err("acquire distance tolerances cannot both be 0".into());
        }
        non_negative(self.acquire_min_spread_mm, "acquire_min_spread_mm")?;
        if self.acquire_iterations == 0 {
            return Err("acquire_iterations must be at least 1".into());
        }
        positive(self.acquire_gate_mm, "acquire_gate_mm")?;
        if !(0.0..=1.0).contains(&self.acquire_min_inlier_fraction) {
            return Err("acquire_min_inlier_fraction must be in [0, 1]".into());
        }
        if self.acquire_min_markers < 3 {
            return Err("acquire_min_markers must be at least 3".into());
        }
        if !(self.acquire_ambiguity_ratio > 0.0 && self.acquire_ambiguity_ratio <= 1.0) {
            return Err("acquire_ambiguity_ratio must be in (0, 1]".into());
        }
        positive(self.gate_px, "gate_px")?;
        non_negative(self.gate_growth_px_per_frame, "gate_growth_px_per_frame")?;
        positive(self.max_gap_gate_px, "max_gap_gate_px")?;
        non_negative(self.velocity_gate_factor, "velocity_gate_factor")?;
        non_negative(self.pose_pass_extra_gate_px, "pose_pass_extra_gate_px")?;
        if !(self.ambiguity_ratio.is_finite() && self.ambiguity_ratio >= 1.0) {
            return Err("ambiguity_ratio must be at least 1".into());
        }
        non_negative(self.ambiguity_margin_px, "ambiguity_margin_px")?;
        positive(self.max_reprojection_px, "max_reprojection_px")?;
        EpipolarGateParams {
            floor_px: self.max_reprojection_px,
            ceiling_px: self.epipolar_gate.ceiling_px.max(self.max_reprojection_px),
            ..self.epipolar_gate.clone()
        }
        .validate()?;
        positive(self.gate_3d_factor, "gate_3d_factor")?;
        if !(0.0..=1.0).contains(&self.velocity_damping) {
            return Err("velocity_damping must be in [0, 1]".into());
        }
        if self.lost_min_markers < 3 {
            return Err("lost_min_markers must be at least 3".into());
        }
        if self.lost_frames == 0 {
            return Err("lost_frames must be at least 1".into());
        }
        positive(self.max_pose_rms_mm, "max_pose_rms_mm")?;
        if self.max_frame_gap == 0 {
            return Err("max_frame_gap must be at least 1".into());
        }
        non_negative(self.roi_margin_px, "roi_margin_px")?;
        Ok(())
    }
}

/// Why a [`Labeler`] cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LabelError {
    /// The layout or the neutral positions are unusable.
    #[error("marker layout: {0}")]
    Layout(String),
    /// The stereo rig is invalid.
    #[error("stereo rig: {0}")]
    Rig(String),
    /// A parameter is out of range.
    #[error("label parameters: {0}")]
    Params(String),
}

/// One labeled marker of a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct LabeledMarker {
    /// The triangulated position (cam0 frame, mm) with reprojection error and confidence.
    pub bundle: Bundle,
    /// The detections used, cam0 and cam1, pixels.
    pub pixels: [Point2<f64>; 2],
    /// Their indices in the input slices.
    pub detections: [usize; 2],
    /// True on the first frame the marker is labeled again after a gap.
    pub reacquired: bool,
}

/// Counts of one frame.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct LabelStats {
    /// Detections given, cam0 and cam1.
    pub detections: [usize; 2],
    /// Stereo pairs formed: unambiguous epipolar pairs while acquiring, markers with a
    /// candidate detection in both cameras while tracking.
    pub paired: usize,
    /// Markers labeled.
    pub labeled: usize,
    /// Markers labeled again after a gap.
    pub reacquired: usize,
    /// Markers with candidates that were dropped: in doubt, or failing the epipolar or
    /// 3D gate (and all labels of a frame whose head pose does not fit).
    pub rejected: usize,
    /// True when the frame was (or failed to be) labeled by acquisition.
    pub acquiring: bool,
}

/// The labels of one stereo frame.
#[derive(Debug, Clone, PartialEq)]
pub struct LabeledFrame {
    /// One entry per layout marker, in layout order: None when not labeled this frame.
    pub markers: Vec<Option<LabeledMarker>>,
    /// Counts.
    pub stats: LabelStats,
}

/// What the labeler remembers of one marker.
#[derive(Debug, Clone, PartialEq)]
struct Track {
    /// Position in the head frame, mm (the neutral position until seen).
    head: Point3<f64>,
    /// Motion in the head frame over the last frame, mm per frame.
    velocity: Vector3<f64>,
    /// Frames since the marker was last labeled (0: labeled in the last frame); None
    /// when never labeled since the last acquisition.
    frames_since_seen: Option<usize>,
}

/// Tracks and labels markers frame by frame (see the module docs).
#[derive(Debug, Clone)]
pub struct Labeler {
    rig: StereoRig,
    neutral: Vec<Point3<f64>>,
    stabilize: Vec<f64>,
    params: LabelParams,
    /// Neutral distance matrix, `m × m`.
    distances: Vec<f64>,
    /// Ordered neutral marker pairs `(distance, i, j)`, sorted by distance.
    pair_table: Vec<(f64, u32, u32)>,
    /// The markers in a fixed shuffled order (hypothesis scoring looks at a spread-out
    /// subset first).
    score_order: Vec<usize>,
    /// Per marker: up to 6 nearest other markers on the neutral within 35 mm, with their
    /// distances.
    neighbours: Vec<Vec<(usize, f64)>>,
    tracks: Vec<Track>,
    /// Head pose (head → cam0) of the last labeled frame and the one before.
    pose: Option<Isometry3<f64>>,
    prev_pose: Option<Isometry3<f64>>,
    last_frame: Option<usize>,
    lost_count: usize,
    rois: [Option<(u32, u32, u32, u32)>; 2],
    /// The epipolar gate, scaled with the measured residuals (kept across re-acquisition:
    /// the noise belongs to the cameras, not the tracks).
    gate: EpipolarGate,
}

/// A marker's prediction for one labeling pass.
#[derive(Debug, Clone, Copy)]
struct Prediction {
    point: Point3<f64>,
    pixels: [Option<Point2<f64>>; 2],
    gate_px: f64,
    gate_mm: f64,
}

/// A labeled marker before it becomes output.
#[derive(Debug, Clone, Copy)]
struct Label {
    marker: usize,
    det: [usize; 2],
    bundle: Bundle,
    /// Assigned without a rival in either camera (its residual feeds the gate estimate).
    confident: bool,
}

/// Result of one labeling pass.
struct PassResult {
    labels: Vec<Label>,
    paired: usize,
    rejected: usize,
}

impl Labeler {
    /// `neutral_markers_head`: each layout marker's position on the neutral mesh (head
    /// frame, mm), in layout order.
    ///
    /// # Errors
    /// [`LabelError::Layout`] for an empty layout, a count mismatch or non-finite
    /// positions; [`LabelError::Rig`] for an invalid rig; [`LabelError::Params`].
    pub fn new(
        rig: StereoRig,
        layout: &MarkerLayout,
        neutral_markers_head: Vec<Point3<f64>>,
        params: LabelParams,
    ) -> Result<Self, LabelError> {
        params.validate().map_err(LabelError::Params)?;
        rig.validate().map_err(|e| LabelError::Rig(e.to_string()))?;
        if layout.len() < 3 {
            return Err(LabelError::Layout(format!(
                "{} markers; labeling needs at least 3",
                layout.len()
            )));
        }
        if neutral_markers_head.len() != layout.len() {
            return Err(LabelError::Layout(format!(
                "{} neutral positions for {} markers",
                neutral_markers_head.len(),
                layout.len()
            )));
        }
        if let Some(i) = neutral_markers_head
            .iter()
            .position(|p| !p.coords.iter().all(|v| v.is_finite()))
        {
            return Err(LabelError::Layout(format!(
                "neutral position of marker {} is not finite",
                layout.markers[i].name
            )));
        }
        let m = layout.len();
        let mut distances = vec![0.0; m * m];
        let mut pair_table = Vec::with_capacity(m * (m - 1));
        for i in 0..m {
            for j in 0..m {
                let d = (neutral_markers_head[i] - neutral_markers_head[j]).norm();
                distances[i * m + j] = d;
                if i != j {
                    pair_table.push((d, i as u32, j as u32));
                }
            }
        }
        pair_table.sort_by(|a, b| a.0.total_cmp(&b.0));
        let stabilize = layout
            .markers
            .iter()
            .map(|mk| {
                if mk.stabilize_weight.is_finite() {
                    mk.stabilize_weight.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        let tracks = fresh_tracks(&neutral_markers_head);
        let mut score_order: Vec<usize> = (0..m).collect();
        let mut rng = SplitMix64(0x5c0e);
        for k in (1..m).rev() {
            score_order.swap(k, rng.below(k + 1));
        }
        let neighbours = (0..m)
            .map(|i| {
                let mut near: Vec<(usize, f64)> = (0..m)
                    .filter(|&j| j != i && distances[i * m + j] <= 35.0)
                    .map(|j| (j, distances[i * m + j]))
                    .collect();
                near.sort_by(|a, b| a.1.total_cmp(&b.1));
                near.truncate(6);
                near
            })
            .collect();
        Ok(Self {
            rig,
            neutral: neutral_markers_head,
            stabilize,
            distances,
            pair_table,
            score_order,
            neighbours,
            tracks,
            pose: None,
            prev_pose: None,
            last_frame: None,
            lost_count: 0,
            rois: [None, None],
            gate: EpipolarGate::new(EpipolarGateParams {
                floor_px: params.max_reprojection_px,
                ceiling_px: params
                    .epipolar_gate
                    .ceiling_px
                    .max(params.max_reprojection_px),
                ..params.epipolar_gate.clone()
            }),
            params,
        })
    }

    /// The settings.
    pub fn params(&self) -> &LabelParams {
        &self.params
    }

    /// The current epipolar gate (largest RMS reprojection error of a labeled marker),
    /// pixels, and the measured robust scale of the residuals it comes from (None until
    /// enough markers were labeled).
    pub fn epipolar_gate(&self) -> (f64, Option<f64>) {
        (self.gate.gate_px(), self.gate.sigma_px())
    }

    /// The head pose (head → cam0) of the last labeled frame; None while acquiring.
    pub fn head_pose(&self) -> Option<Isometry3<f64>> {
        self.pose
    }

    /// Forget all tracks (next frame re-acquires by registration).
    pub fn reset(&mut self) {
        self.tracks = fresh_tracks(&self.neutral);
        self.pose = None;
        self.prev_pose = None;
        self.last_frame = None;
        self.lost_count = 0;
        self.rois = [None, None];
    }

    /// Regions of interest (x0, y0, x1, y1, end exclusive) per camera around where markers
    /// are expected next frame, None while acquiring. (For the detector's
    /// `DetectParams::roi`.)
    pub fn predicted_rois(&self) -> [Option<(u32, u32, u32, u32)>; 2] {
        self.rois
    }

    /// Labels one stereo frame's detections (cam0, cam1). Never panics on any input.
    pub fn process(&mut self, frame: usize, detections: [&[Detection]; 2]) -> LabeledFrame {
        let m = self.neutral.len();
        let mut stats = LabelStats {
            detections: [detections[0].len(), detections[1].len()],
            ..LabelStats::default()
        };
        // Detections with non-finite centres are never used.
        let pixels: [Vec<Option<Point2<f64>>>; 2] = [0, 1].map(|c| {
            detections[c]
                .iter()
                .map(|d| {
                    let p = d.centre_px;
                    (p.x.is_finite() && p.y.is_finite()).then_some(p)
                })
                .collect()
        });
        let steps = match self.last_frame {
            Some(last) if frame > last && frame - last <= self.params.max_frame_gap => frame - last,
            Some(_) => {
                tracing::debug!(frame, "frame gap or out of order: re-acquiring");
                self.reset();
                1
            }
            None => 1,
        };
        let mut result = None;
        if self.pose.is_some() {
            result = self.track(&pixels, steps);
        }
        if result.is_none() {
            // Acquisition (also right after tracking was lost).
            self.reset();
            stats.acquiring = true;
            result = self.acquire(&pixels, &mut stats);
        }
        let mut out = vec![None; m];
        let Some((pose, pass)) = result else {
            self.last_frame = None;
            return LabeledFrame {
                markers: out,
                stats,
            };
        };
        stats.paired = stats.paired.max(pass.paired);
        stats.rejected += pass.rejected;
        self.gate.update(
            pass.labels
                .iter()
                .filter(|l| l.confident)
                .map(|l| l.bundle.reprojection_px),
        );
        let mut seen = vec![false; m];
        let inverse = pose.inverse();
        for l in &pass.labels {
            let track = &mut self.tracks[l.marker];
            let reacquired = matches!(track.frames_since_seen, Some(n) if n > 0);
            let head = inverse * l.bundle.point_in_cam0;
            track.velocity = if track.frames_since_seen == Some(0) {
                (head - track.head) / steps as f64
            } else {
                Vector3::zeros()
            };
            track.head = head;
            seen[l.marker] = true;
            stats.labeled += 1;
            stats.reacquired += usize::from(reacquired);
            let px = |c: usize| pixels[c][l.det[c]].unwrap_or_else(Point2::origin);
            out[l.marker] = Some(LabeledMarker {
                bundle: l.bundle,
                pixels: [px(0), px(1)],
                detections: l.det,
                reacquired,
            });
        }
        for (track, &s) in self.tracks.iter_mut().zip(&seen) {
            if !s {
                track.velocity = Vector3::zeros();
                track.frames_since_seen = track.frames_since_seen.map(|n| n + steps);
            } else {
                track.frames_since_seen = Some(0);
            }
        }
        if stats.labeled < self.params.lost_min_markers {
            self.lost_count += 1;
        } else {
            self.lost_count = 0;
        }
        if self.lost_count >= self.params.lost_frames {
            tracing::debug!(frame, "tracking lost: re-acquiring next frame");
            self.reset();
        } else {
            self.prev_pose = if steps == 1 { self.pose } else { None };
            self.pose = Some(pose);
            self.last_frame = Some(frame);
            self.rois = self.compute_rois();
        }
        LabeledFrame {
            markers: out,
            stats,
        }
    }

    /// Constant-velocity prediction of the head pose `steps` frames after the last one.
    fn predicted_pose(&self, steps: usize) -> Option<Isometry3<f64>> {
        let pose = self.pose?;
        let Some(prev) = self.prev_pose else {
            return Some(pose);
        };
        let delta = pose * prev.inverse();
        let mut p = pose;
        for _ in 0..steps {
            p = delta * p;
        }
        Some(p)
    }

    /// Predictions of all markers under `pose`, with the gates of the final pass plus
    /// `extra_gate_px`; `steps` frames of expression motion are carried.
    fn predictions(
        &self,
        pose: &Isometry3<f64>,
        steps: usize,
        extra_gate_px: f64,
    ) -> Vec<Prediction> {
        let p = &self.params;
        let f = self.rig.cam0.fx().min(self.rig.cam1.fx()).max(1e-9);
        self.tracks
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let motion = t.velocity * (p.velocity_damping * steps as f64);
                let head = if t.frames_since_seen == Some(0) {
                    t.head
                } else {
                    self.head_from_neighbours(i).unwrap_or(t.head)
                };
                let point = pose * (head + motion);
                let pixels = self.project_both(&point);
                let depth = point.coords.norm().max(1.0);
                let motion_px = motion.norm() * f / depth;
                let gap_gate = match t.frames_since_seen {
                    Some(0) => p.gate_px,
                    Some(n) => (p.gate_px + p.gate_growth_px_per_frame * n as f64)
                        .min(p.max_gap_gate_px.max(p.gate_px)),
                    None => p.max_gap_gate_px.max(p.gate_px),
                };
                let gate_px = gap_gate + p.velocity_gate_factor * motion_px + extra_gate_px;
                let gate_mm = p.gate_3d_factor * gate_px * depth / f;
                Prediction {
                    point,
                    pixels,
                    gate_px,
                    gate_mm,
                }
            })
            .collect()
    }

    /// Head-frame position of a marker not labeled in the last frame: its neutral
    /// position moved like its neighbours that were (inverse-distance weights); None
    /// with fewer than two such neighbours.
    fn head_from_neighbours(&self, i: usize) -> Option<Point3<f64>> {
        let (mut sum, mut wsum, mut count) = (Vector3::zeros(), 0.0, 0);
        for &(j, d) in &self.neighbours[i] {
            let t = &self.tracks[j];
            if t.frames_since_seen == Some(0) {
                let w = 1.0 / (d + 5.0);
                sum += (t.head - self.neutral[j]) * w;
                wsum += w;
                count += 1;
            }
        }
        (count >= 2).then(|| self.neutral[i] + sum / wsum)
    }

    /// Pixels of a cam0 point in both cameras (None behind a camera or outside its image).
    fn project_both(&self, point: &Point3<f64>) -> [Option<Point2<f64>>; 2] {
        let p0 = self
            .rig
            .cam0
            .project(&point.coords)
            .filter(|q| self.rig.cam0.contains(q));
        let p1 = self
            .rig
            .cam1
            .project(&(self.rig.cam1_from_cam0 * point).coords)
            .filter(|q| self.rig.cam1.contains(q));
        [p0, p1]
    }

    /// Tracking from the last frame's state: the two passes of the module docs. None when
    /// the frame cannot be labeled from the tracks (re-acquire).
    fn track(
        &mut self,
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        steps: usize,
    ) -> Option<(Isometry3<f64>, PassResult)> {
        let predicted = self.predicted_pose(steps)?;
        // Pass 1: wide gates, labels used only to estimate the head pose of this frame.
        let wide = self.predictions(&predicted, steps, self.params.pose_pass_extra_gate_px);
        let first = self.label_pass(&wide, pixels);
        let pose = self
            .estimate_pose(&first.labels)
            .map_or(predicted, |(pose, _)| pose);
        // Pass 2: tight gates around predictions under the estimated pose.
        let tight = self.predictions(&pose, steps, 0.0);
        let mut second = self.label_pass(&tight, pixels);
        let final_pose = match self.estimate_pose(&second.labels) {
            Some((pose, rms)) if rms <= self.params.max_pose_rms_mm => pose,
            Some((_, rms)) => {
                tracing::debug!(rms, "head pose does not fit the labels: frame dropped");
                second.rejected += second.labels.len();
                second.labels.clear();
                pose
            }
            None => pose,
        };
        Some((final_pose, second))
    }

    /// Weighted robust Horn fit of the head pose to labels: sources are the neutral
    /// positions weighted by the layout's stabilizing weights (drift-free); with too
    /// little stabilizing weight labeled, the tracks' head positions with unit weights.
    /// Returns the pose and the weighted RMS residual of the inliers, mm.
    fn estimate_pose(&self, labels: &[Label]) -> Option<(Isometry3<f64>, f64)> {
        if labels.len() < 3 {
            return None;
        }
        let stab: f64 = labels.iter().map(|l| self.stabilize[l.marker]).sum();
        let use_neutral = stab >= 3.0;
        let src: Vec<Point3<f64>> = labels
            .iter()
            .map(|l| {
                if use_neutral {
                    self.neutral[l.marker]
                } else {
                    self.tracks[l.marker].head
                }
            })
            .collect();
        let dst: Vec<Point3<f64>> = labels.iter().map(|l| l.bundle.point_in_cam0).collect();
        let base: Vec<f64> = labels
            .iter()
            .map(|l| {
                if use_neutral {
                    self.stabilize[l.marker]
                } else {
                    1.0
                }
            })
            .collect();
        robust_horn(&src, &dst, &base)
    }

    /// One labeling pass: per-camera gated optimal assignment, then left/right pairing
    /// under the epipolar constraint and the 3D gate (steps 2-3 of the module docs).
    fn label_pass(
        &self,
        preds: &[Prediction],
        pixels: &[Vec<Option<Point2<f64>>>; 2],
    ) -> PassResult {
        let p = &self.params;
        let m = preds.len();
        // Per camera: candidates (within the gate) of every marker, and the assignment.
        let mut candidates: [Vec<Vec<(usize, f64)>>; 2] =
            [vec![Vec::new(); m], vec![Vec::new(); m]];
        let mut assigned: [Vec<Option<(usize, bool)>>; 2] = [vec![None; m], vec![None; m]];
        for c in 0..2 {
            let dets = &pixels[c];
            for (i, pr) in preds.iter().enumerate() {
                let Some(q) = pr.pixels[c] else { continue };
                for (a, d) in dets.iter().enumerate() {
                    let Some(d) = d else { continue };
                    let e = (d - q).norm();
                    if e <= pr.gate_px {
                        candidates[c][i].push((a, e));
                    }
                }
                candidates[c][i].sort_by(|x, y| x.1.total_cmp(&y.1));
            }
            // Markers per detection (for column rivals).
            let mut by_det: Vec<Vec<(usize, f64)>> = vec![Vec::new(); dets.len()];
            for (i, cands) in candidates[c].iter().enumerate() {
                for &(a, e) in cands {
                    by_det[a].push((i, e));
                }
            }
            for (i, a) in assign_components(&candidates[c], dets.len()) {
                let e = candidates[c][i]
                    .iter()
                    .find(|x| x.0 == a)
                    .map_or(f64::INFINITY, |x| x.1);
                let limit = p.ambiguity_ratio * e + p.ambiguity_margin_px;
                let row_rival = candidates[c][i].iter().any(|&(b, eb)| b != a && eb < limit);
                let col_rival = by_det[a].iter().any(|&(j, ej)| j != i && ej < limit);
                assigned[c][i] = Some((a, row_rival || col_rival));
            }
        }
        let tri = TriangulateParams {
            max_reprojection_px: self.gate.gate_px(),
            ..p.pair.triangulate.clone()
        };
        let check = |i: usize, a: usize, b: usize| -> Option<Bundle> {
            let (Some(x0), Some(x1)) = (pixels[0][a], pixels[1][b]) else {
                return None;
            };
            let bundle = triangulate(&self.rig, &x0, &x1, &tri).ok()?;
            ((bundle.point_in_cam0 - preds[i].point).norm() <= preds[i].gate_mm).then_some(bundle)
        };
        let mut labels = Vec::new();
        let mut used: [Vec<bool>; 2] = [vec![false; pixels[0].len()], vec![false; pixels[1].len()]];
        let mut paired = 0;
        let mut rejected = 0;
        let mut in_doubt = Vec::new();
        for i in 0..m {
            if candidates[0][i].is_empty() || candidates[1][i].is_empty() {
                continue;
            }
            paired += 1;
            match (assigned[0][i], assigned[1][i]) {
                (Some((a, false)), Some((b, false))) => match check(i, a, b) {
                    Some(bundle) => {
                        used[0][a] = true;
                        used[1][b] = true;
                        labels.push(Label {
                            marker: i,
                            det: [a, b],
                            bundle,
                            confident: true,
                        });
                    }
                    None => rejected += 1,
                },
                _ => in_doubt.push(i),
            }
        }
        // Markers in doubt in a camera: exactly one candidate pair among free detections
        // must pass the epipolar and 3D gates.
        let mut tentative: Vec<Label> = Vec::new();
        for &i in &in_doubt {
            let mut found: Option<Label> = None;
            let mut count = 0;
            for &(a, _) in candidates[0][i].iter().take(4) {
                if used[0][a] {
                    continue;
                }
                for &(b, _) in candidates[1][i].iter().take(4) {
                    if used[1][b] {
                        continue;
                    }
                    if let Some(bundle) = check(i, a, b) {
                        count += 1;
                        found = Some(Label {
                            marker: i,
                            det: [a, b],
                            bundle,
                            confident: false,
                        });
                    }
                }
            }
            match (count, found) {
                (1, Some(l)) => tentative.push(l),
                _ => rejected += 1,
            }
        }
        // A detection claimed by two markers in doubt labels neither.
        let mut claims: [Vec<u32>; 2] = [vec![0; pixels[0].len()], vec![0; pixels[1].len()]];
        for l in &tentative {
            claims[0][l.det[0]] += 1;
            claims[1][l.det[1]] += 1;
        }
        for l in tentative {
            if claims[0][l.det[0]] == 1 && claims[1][l.det[1]] == 1 {
                labels.push(l);
            } else {
                rejected += 1;
            }
        }
        PassResult {
            labels,
            paired,
            rejected,
        }
    }

    /// Acquisition by registration (module docs). Returns the pose and the labels of a
    /// tracking pass under it, or None when the registration is ambiguous or too weak.
    fn acquire(
        &mut self,
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        stats: &mut LabelStats,
    ) -> Option<(Isometry3<f64>, PassResult)> {
        let p = &self.params;
        // Pair only finite detections, remembering their original indices.
        let finite: [Vec<usize>; 2] = [0, 1].map(|c| {
            (0..pixels[c].len())
                .filter(|&a| pixels[c][a].is_some())
                .collect()
        });
        let px: [Vec<Point2<f64>>; 2] = [0, 1].map(|c| {
            finite[c]
                .iter()
                .filter_map(|&a| pixels[c][a])
                .collect::<Vec<_>>()
        });
        let matches = pair_detections(&self.rig, &px[0], &px[1], &p.pair);
        stats.paired = matches.len();
        let points: Vec<Point3<f64>> = matches.iter().map(|s| s.bundle.point_in_cam0).collect();
        if points.len() < p.acquire_min_markers {
            return None;
        }
        let pose = self.register(&points)?;
        // Label with the tracking pass around the registered neutral.
        let preds = self.predictions(&pose, 1, 0.0);
        let pass = self.label_pass(&preds, pixels);
        let (pose, rms) = self.estimate_pose(&pass.labels)?;
        if rms > p.max_pose_rms_mm || pass.labels.len() < p.acquire_min_markers {
            return None;
        }
        // Second pass under the refined pose.
        let preds = self.predictions(&pose, 1, 0.0);
        let pass = self.label_pass(&preds, pixels);
        if pass.labels.len() < p.acquire_min_markers {
            return None;
        }
        Some((pose, pass))
    }

    /// RANSAC registration of unlabeled triangulated points to the neutral markers:
    /// returns `cam0_from_head`, or None when no hypothesis is both strong and unambiguous.
    fn register(&self, points: &[Point3<f64>]) -> Option<Isometry3<f64>> {
        let p = &self.params;
        let m = self.neutral.len();
        let n = points.len();
        let grid = PointGrid::new(points, p.acquire_gate_mm);
        let tol = |d: f64| p.acquire_distance_tolerance_mm + p.acquire_distance_tolerance_rel * d;
        let mut rng = SplitMix64(0x6c61_6265_6c00 ^ n as u64);
        let mut top: Vec<(f64, Isometry3<f64>)> = Vec::new();
        let (z0, z1) = p.pair.triangulate.depth_range_mm;
        let spread = p.acquire_min_spread_mm;
        let strong = 0.7 * n.min(m) as f64;
        for iteration in 0..p.acquire_iterations {
            // Enough evidence: a strong hypothesis and a good number of samples after it.
            if iteration >= 60 && top.first().is_some_and(|x| x.0 >= strong) {
                break;
            }
            // A well-spread triple of observed points.
            let mut triple = None;
            for _ in 0..30 {
                let a = rng.below(n);
                let b = rng.below(n);
                let c = rng.below(n);
                if a == b || b == c || a == c {
                    continue;
                }
                let (dab, dac, dbc) = (
                    (points[a] - points[b]).norm(),
                    (points[a] - points[c]).norm(),
                    (points[b] - points[c]).norm(),
                );
                if dab >= spread && dac >= spread && dbc >= spread {
                    triple = Some((a, b, c, dab, dac, dbc));
                    break;
                }
            }
            let Some((a, b, c, dab, dac, dbc)) = triple else {
                continue;
            };
            let lo = self.pair_table.partition_point(|e| e.0 < dab - tol(dab));
            let hi = self.pair_table.partition_point(|e| e.0 <= dab + tol(dab));
            let (tac, tbc) = (tol(dac), tol(dbc));
            for &(_, i, j) in &self.pair_table[lo..hi] {
                let (i, j) = (i as usize, j as usize);
                for k in 0..m {
                    if k == i
                        || k == j
                        || (self.distances[i * m + k] - dac).abs() > tac
                        || (self.distances[j * m + k] - dbc).abs() > tbc
                    {
                        continue;
                    }
                    let Ok(t) = horn_alignment(
                        &[self.neutral[i], self.neutral[j], self.neutral[k]],
                        &[points[a], points[b], points[c]],
                        &[],
                    ) else {
                        continue;
                    };
                    // Prior: the face is in front of the cameras.
                    let centre = t * self.centroid();
                    if !(z0..=z1).contains(&centre.z) {
                        continue;
                    }
                    let score = self.score(&t, &grid, points);
                    self.keep_top(&mut top, score, t);
                }
            }
        }
        // Refine the leading distinct hypotheses by ICP, then compare.
        let mut refined: Vec<(f64, usize, Isometry3<f64>)> = top
            .iter()
            .take(4)
            .map(|&(_, t)| {
                let t = self.icp(t, &grid, points);
                let (score, inliers) = self.score_with_inliers(&t, &grid, points);
                (score, inliers, t)
            })
            .collect();
        refined.sort_by(|x, y| y.0.total_cmp(&x.0));
        let &(best_score, inliers, best) = refined.first()?;
        let rival = refined
            .iter()
            .skip(1)
            .filter(|(_, _, t)| !self.same_hypothesis(t, &best))
            .map(|x| x.0)
            .fold(0.0, f64::max);
        let needed = (p.acquire_min_inlier_fraction * n as f64)
            .ceil()
            .max(p.acquire_min_markers as f64) as usize;
        tracing::debug!(best_score, rival, inliers, n, "registration");
        if inliers < needed || rival >= p.acquire_ambiguity_ratio * best_score {
            return None;
        }
        Some(best)
    }

    fn centroid(&self) -> Point3<f64> {
        let s = self
            .neutral
            .iter()
            .fold(Vector3::zeros(), |a, q| a + q.coords);
        Point3::from(s / self.neutral.len() as f64)
    }

    /// MSAC score: Σ over neutral markers of `1 − (d/gate)²` for the nearest observed
    /// point within the gate.
    /// Gives up early (returning the partial score) when fewer than a fifth of the first
    /// 20 markers match: most hypotheses are wrong, and this keeps acquisition fast.
    fn score(&self, t: &Isometry3<f64>, grid: &PointGrid, points: &[Point3<f64>]) -> f64 {
        let g = self.params.acquire_gate_mm;
        let mut score = 0.0;
        let mut hits = 0;
        for (k, &i) in self.score_order.iter().enumerate() {
            if k == 20 && hits < 4 {
                break;
            }
            if let Some((_, d)) = grid.nearest(&(t * self.neutral[i]), points) {
                score += 1.0 - (d / g).powi(2);
                hits += 1;
            }
        }
        score
    }

    fn score_with_inliers(
        &self,
        t: &Isometry3<f64>,
        grid: &PointGrid,
        points: &[Point3<f64>],
    ) -> (f64, usize) {
        let g = self.params.acquire_gate_mm;
        let mut score = 0.0;
        let mut inliers = 0;
        for q in &self.neutral {
            if let Some((_, d)) = grid.nearest(&(t * q), points) {
                score += 1.0 - (d / g).powi(2);
                inliers += 1;
            }
        }
        (score, inliers)
    }

    /// Keeps up to 6 distinct hypotheses with the highest scores.
    fn keep_top(&self, top: &mut Vec<(f64, Isometry3<f64>)>, score: f64, t: Isometry3<f64>) {
        if top.len() >= 6 && top.last().is_some_and(|x| x.0 >= score) {
            return;
        }
        if let Some(k) = top.iter().position(|(_, u)| self.same_hypothesis(u, &t)) {
            if top[k].0 >= score {
                return;
            }
            top.remove(k);
        }
        let at = top.partition_point(|x| x.0 >= score);
        top.insert(at, (score, t));
        top.truncate(6);
    }

    /// Two poses label the same way when no neutral marker moves by more than the gate.
    fn same_hypothesis(&self, a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        let g = self.params.acquire_gate_mm;
        self.neutral.iter().all(|q| (a * q - b * q).norm() < g)
    }

    /// Iterated closest points: mutual nearest neighbours within the gate, Horn.
    fn icp(
        &self,
        mut t: Isometry3<f64>,
        grid: &PointGrid,
        points: &[Point3<f64>],
    ) -> Isometry3<f64> {
        for _ in 0..6 {
            let mut src = Vec::new();
            let mut dst = Vec::new();
            for q in &self.neutral {
                if let Some((k, _)) = grid.nearest(&(t * q), points) {
                    src.push(*q);
                    dst.push(points[k]);
                }
            }
            if src.len() < 3 {
                break;
            }
            match horn_alignment(&src, &dst, &[]) {
                Ok(u) => t = u,
                Err(_) => break,
            }
        }
        t
    }

    /// Bounding boxes of the next frame's predicted marker pixels, grown by the margin.
    fn compute_rois(&self) -> [Option<(u32, u32, u32, u32)>; 2] {
        let Some(pose) = self.predicted_pose(1) else {
            return [None, None];
        };
        let preds = self.predictions(&pose, 1, self.params.pose_pass_extra_gate_px);
        [0, 1].map(|c| {
            let cam = if c == 0 {
                &self.rig.cam0
            } else {
                &self.rig.cam1
            };
            let mut bb: Option<(f64, f64, f64, f64)> = None;
            for pr in &preds {
                let Some(q) = pr.pixels[c] else { continue };
                let g = pr.gate_px + self.params.roi_margin_px;
                let b = (q.x - g, q.y - g, q.x + g, q.y + g);
                bb = Some(match bb {
                    None => b,
                    Some(a) => (a.0.min(b.0), a.1.min(b.1), a.2.max(b.2), a.3.max(b.3)),
                });
            }
            let (x0, y0, x1, y1) = bb?;
            let (w, h) = (f64::from(cam.width_px), f64::from(cam.height_px));
            let x0 = x0.floor().clamp(0.0, w) as u32;
            let y0 = y0.floor().clamp(0.0, h) as u32;
            let x1 = (x1.ceil() + 1.0).clamp(0.0, w) as u32;
            let y1 = (y1.ceil() + 1.0).clamp(0.0, h) as u32;
            (x0 < x1 && y0 < y1).then_some((x0, y0, x1, y1))
        })
    }
}

fn fresh_tracks(neutral: &[Point3<f64>]) -> Vec<Track> {
    neutral
        .iter()
        .map(|q| Track {
            head: *q,
            velocity: Vector3::zeros(),
            frames_since_seen: None,
        })
        .collect()
}

/// Weighted Horn with outlier rejection: residuals above `max(3·median, 1 mm)` are
/// dropped, twice. Returns the pose and the weighted RMS residual of the kept points.
fn robust_horn(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    base: &[f64],
) -> Option<(Isometry3<f64>, f64)> {
    let mut w = base.to_vec();
    let mut t = horn_alignment(src, dst, &w).ok()?;
    for _ in 0..2 {
        let res: Vec<f64> = src
            .iter()
            .zip(dst)
            .map(|(s, d)| (t * s - d).norm())
            .collect();
        let mut kept: Vec<f64> = res
            .iter()
            .zip(base)
            .filter(|(_, b)| **b > 0.0)
            .map(|(r, _)| *r)
            .collect();
        if kept.len() < 3 {
            break;
        }
        let mid = kept.len() / 2;
        let median = *kept.select_nth_unstable_by(mid, f64::total_cmp).1;
        let limit = (3.0 * median).max(1.0);
        w = base
            .iter()
            .zip(&res)
            .map(|(b, r)| if *r <= limit { *b } else { 0.0 })
            .collect();
        if w.iter().filter(|x| **x > 0.0).count() < 3 {
            return None;
        }
        t = horn_alignment(src, dst, &w).ok()?;
    }
    let (mut num, mut den) = (0.0, 0.0);
    for ((s, d), wi) in src.iter().zip(dst).zip(&w) {
        num += wi * (t * s - d).norm_squared();
        den += wi;
    }
    (den > 0.0).then(|| (t, (num / den).sqrt()))
}

/// Optimal assignment of markers to detections, per connected component of the gated
/// candidate graph. Returns (marker, detection) pairs.
fn assign_components(candidates: &[Vec<(usize, f64)>], dets: usize) -> Vec<(usize, usize)> {
    let m = candidates.len();
    // Union-find over markers 0..m and detections m..m+dets.
    let mut parent: Vec<usize> = (0..m + dets).collect();
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    for (i, cands) in candidates.iter().enumerate() {
        for &(a, _) in cands {
            let (r1, r2) = (find(&mut parent, i), find(&mut parent, m + a));
            if r1 != r2 {
                parent[r1] = r2;
            }
        }
    }
    let mut groups: std::collections::HashMap<usize, (Vec<usize>, Vec<usize>)> =
        std::collections::HashMap::new();
    for (i, cands) in candidates.iter().enumerate() {
        if cands.is_empty() {
            continue;
        }
        let r = find(&mut parent, i);
        groups.entry(r).or_default().0.push(i);
    }
    for a in 0..dets {
        let r = find(&mut parent, m + a);
        if let Some(g) = groups.get_mut(&r) {
            g.1.push(a);
        }
    }
    let mut out = Vec::new();
    let mut keys: Vec<usize> = groups.keys().copied().collect();
    keys.sort_unstable();
    for key in keys {
        let Some((rows, cols)) = groups.get(&key) else {
            continue;
        };
        if rows.len() == 1 && cols.len() == 1 {
            out.push((rows[0], cols[0]));
            continue;
        }
        let mut cost = vec![f64::INFINITY; rows.len() * cols.len()];
        for (r, &i) in rows.iter().enumerate() {
            for &(a, e) in &candidates[i] {
                if let Some(c) = cols.iter().position(|&x| x == a) {
                    cost[r * cols.len() + c] = e * e;
                }
            }
        }
        for (r, c) in hungarian(&cost, rows.len(), cols.len()).iter().enumerate() {
            if let Some(c) = c {
                out.push((rows[r], cols[*c]));
            }
        }
    }
    out
}

/// A uniform grid of 3D points (cell size = the query radius, cells stored densely over
/// the points' bounding box) for nearest-neighbour queries within the radius.
struct PointGrid {
    radius: f64,
    cell: f64,
    origin: Vector3<f64>,
    dims: [usize; 3],
    /// Start of each cell's run in `order` (CSR layout), `cells + 1` entries.
    starts: Vec<u32>,
    order: Vec<u32>,
}

impl PointGrid {
    fn new(points: &[Point3<f64>], radius: f64) -> Self {
        let cell = radius.max(1e-6);
        let finite = points
            .iter()
            .filter(|p| p.coords.iter().all(|v| v.is_finite()));
        let (mut lo, mut hi) = (Vector3::repeat(f64::MAX), Vector3::repeat(f64::MIN));
        for p in finite {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        if lo.x > hi.x {
            return Self {
                radius: cell,
                cell,
                origin: Vector3::zeros(),
                dims: [0; 3],
                starts: vec![0],
                order: Vec::new(),
            };
        }
        // At most 256 cells per axis (coarser cells for huge spreads stay correct).
        let cell = ((hi - lo).max() / 255.0).max(cell);
        let dims = [0, 1, 2].map(|k| ((hi[k] - lo[k]) / cell).floor() as usize + 1);
        let count = dims[0] * dims[1] * dims[2];
        let key = |p: &Point3<f64>| -> Option<usize> {
            let mut idx = [0usize; 3];
            for k in 0..3 {
                let v = ((p[k] - lo[k]) / cell).floor();
                if !(v >= 0.0 && (v as usize) < dims[k]) {
                    return None;
                }
                idx[k] = v as usize;
            }
            Some((idx[2] * dims[1] + idx[1]) * dims[0] + idx[0])
        };
        let mut starts = vec![0u32; count + 1];
        let keys: Vec<Option<usize>> = points.iter().map(key).collect();
        for k in keys.iter().flatten() {
            starts[k + 1] += 1;
        }
        for c in 0..count {
            starts[c + 1] += starts[c];
        }
        let mut fill = starts.clone();
        let mut order = vec![0u32; starts[count] as usize];
        for (i, k) in keys.iter().enumerate() {
            if let Some(k) = k {
                order[fill[*k] as usize] = i as u32;
                fill[*k] += 1;
            }
        }
        Self {
            radius: radius.max(1e-6),
            cell,
            origin: lo,
            dims,
            starts,
            order,
        }
    }

    /// Index and distance of the nearest point within the radius.
    fn nearest(&self, q: &Point3<f64>, points: &[Point3<f64>]) -> Option<(usize, f64)> {
        let mut c = [0i64; 3];
        for k in 0..3 {
            let v = ((q[k] - self.origin[k]) / self.cell).floor();
            if !(v >= -1.0 && v <= self.dims[k] as f64) {
                return None;
            }
            c[k] = v as i64;
        }
        let mut best: Option<(usize, f64)> = None;
        let r2 = self.radius * self.radius;
        for z in (c[2] - 1).max(0)..=(c[2] + 1).min(self.dims[2] as i64 - 1) {
            for y in (c[1] - 1).max(0)..=(c[1] + 1).min(self.dims[1] as i64 - 1) {
                let row = (z as usize * self.dims[1] + y as usize) * self.dims[0];
                let x0 = (c[0] - 1).max(0) as usize;
                let x1 = (c[0] + 1).min(self.dims[0] as i64 - 1);
                if x1 < x0 as i64 {
                    continue;
                }
                let (a, b) = (
                    self.starts[row + x0] as usize,
                    self.starts[row + x1 as usize + 1] as usize,
                );
                for &k in &self.order[a..b] {
                    let d2 = (points[k as usize] - q).norm_squared();
                    if d2 < r2 && best.is_none_or(|bb| d2 < bb.1) {
                        best = Some((k as usize, d2));
                    }
                }
            }
        }
        best.map(|(k, d2)| (k, d2.sqrt()))
    }
}

/// A small deterministic generator for RANSAC sampling (SplitMix64).
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::Marker;
    use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion};

    /// Deterministic uniform numbers in [0, 1).
    struct Rng(SplitMix64);
    impl Rng {
        fn new(seed: u64) -> Self {
            Self(SplitMix64(seed))
        }
        fn uniform(&mut self) -> f64 {
            (self.0.next() >> 11) as f64 / (1u64 << 53) as f64
        }
        fn range(&mut self, a: f64, b: f64) -> f64 {
            a + (b - a) * self.uniform()
        }
        fn normal(&mut self) -> f64 {
            let u1 = self.uniform().max(1e-12);
            let u2 = self.uniform();
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        }
    }

    /// A face-like cap of markers (head frame, +z out of the face, +y up), at least 9 mm
    /// apart; stabilizing weights high on the upper part.
    fn face(seed: u64) -> (MarkerLayout, Vec<Point3<f64>>) {
        let mut rng = Rng::new(seed);
        let mut pts: Vec<Point3<f64>> = Vec::new();
        for _ in 0..20000 {
            if pts.len() >= 100 {
                break;
            }
            let x = rng.range(-65.0, 65.0);
            let y = rng.range(-85.0, 75.0);
            if (x / 65.0).powi(2) + (y / 85.0).powi(2) > 1.0 {
                continue;
            }
            let p = Point3::new(x, y, 60.0 - x * x / 140.0 - y * y / 260.0);
            if pts.iter().all(|q| (q - p).norm() >= 9.0) {
                pts.push(p);
            }
        }
        let layout = MarkerLayout {
            markers: pts
                .iter()
                .enumerate()
                .map(|(k, p)| Marker {
                    name: format!("M{k:03}"),
                    vertex: k as u32,
                    stabilize_weight: if p.y > 20.0 { 0.95 } else { 0.1 },
                })
                .collect(),
        };
        (layout, pts)
    }

    fn normal_at(p: &Point3<f64>) -> Vector3<f64> {
        Vector3::new(p.x / 70.0, p.y / 130.0, 1.0).normalize()
    }

    /// The head pose that puts the face centre `distance` mm in front of the rig, facing
    /// it, then turned by `angles` (radians, about the face centre) and shifted.
    fn pose_facing(
        rig: &StereoRig,
        distance: f64,
        angles: Vector3<f64>,
        shift: Vector3<f64>,
    ) -> Isometry3<f64> {
        let c1 = rig.cam1_centre_in_cam0();
        let mid = Point3::from(c1.coords * 0.5);
        let axis1 = rig.cam1_from_cam0.rotation.inverse() * Vector3::z();
        let axis = (Vector3::z() + axis1).normalize();
        let z_h = -axis;
        let y_h = (-Vector3::y() - z_h * z_h.dot(&-Vector3::y())).normalize();
        let x_h = y_h.cross(&z_h);
        let base = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x_h, y_h, z_h]));
        let turn = Rotation3::from_euler_angles(angles.x, angles.y, angles.z);
        let rotation = base * turn;
        let centre_head = Vector3::new(0.0, 0.0, 40.0);
        let target = mid + axis * distance + shift;
        let t = target.coords - rotation * centre_head;
        Isometry3::from_parts(
            Translation3::from(t),
            UnitQuaternion::from_rotation_matrix(&rotation),
        )
    }

    /// Detections of both cameras with the true marker of each (None: a spurious blob),
    /// shuffled. `hidden` markers are not drawn.
    fn observe(
        rig: &StereoRig,
        pose: &Isometry3<f64>,
        pts: &[Point3<f64>],
        hidden: &[usize],
        noise_px: f64,
        spurious: usize,
        rng: &mut Rng,
    ) -> [(Vec<Detection>, Vec<Option<usize>>); 2] {
        [0, 1].map(|c| {
            let mut items: Vec<(Point2<f64>, Option<usize>)> = Vec::new();
            let cam = if c == 0 { &rig.cam0 } else { &rig.cam1 };
            let cam_from_head: Isometry3<f64> = if c == 0 {
                *pose
            } else {
                let r = UnitQuaternion::from_rotation_matrix(&rig.cam1_from_cam0.rotation);
                Isometry3::from_parts(rig.cam1_from_cam0.translation, r) * pose
            };
            for (k, p) in pts.iter().enumerate() {
                if hidden.contains(&k) {
                    continue;
                }
                let pc = cam_from_head * p;
                let n = cam_from_head.rotation * normal_at(p);
                if n.dot(&(-pc.coords.normalize())) < 0.26 {
                    continue;
                }
                let Some(px) = cam.project(&pc.coords) else {
                    continue;
                };
                let px = Point2::new(
                    px.x + noise_px * rng.normal(),
                    px.y + noise_px * rng.normal(),
                );
                if cam.contains(&px) {
                    items.push((px, Some(k)));
                }
            }
            for _ in 0..spurious {
                let px = Point2::new(rng.range(0.0, 1279.0), rng.range(0.0, 1023.0));
                items.push((px, None));
            }
            // Shuffle.
            for k in (1..items.len()).rev() {
                let j = (rng.uniform() * (k + 1) as f64) as usize;
                items.swap(k, j.min(k));
            }
            let dets = items
                .iter()
                .map(|(px, _)| Detection {
                    centre_px: *px,
                    area_px: 12,
                    roundness: 0.9,
                    contrast_dn: 60.0,
                    quality: 0.5,
                })
                .collect();
            (dets, items.iter().map(|x| x.1).collect())
        })
    }

    /// (correct, wrong) labels of a frame; panics on nothing.
    fn count(frame: &LabeledFrame, truth: &[Vec<Option<usize>>; 2]) -> (usize, usize) {
        let (mut ok, mut wrong) = (0, 0);
        for (i, m) in frame.markers.iter().enumerate() {
            if let Some(m) = m {
                if truth[0][m.detections[0]] == Some(i) && truth[1][m.detections[1]] == Some(i) {
                    ok += 1;
                } else {
                    wrong += 1;
                }
            }
        }
        (ok, wrong)
    }

    fn visible_both(truth: &[Vec<Option<usize>>; 2]) -> usize {
        truth[0]
            .iter()
            .flatten()
            .filter(|k| truth[1].contains(&Some(**k)))
            .count()
    }

    fn labeler(layout: &MarkerLayout, pts: &[Point3<f64>]) -> Labeler {
        let rig = crate::synth::default_rig().unwrap();
        Labeler::new(rig, layout, pts.to_vec(), LabelParams::default()).unwrap()
    }

    #[test]
    fn acquires_under_arbitrary_head_poses() {
        let rig = crate::synth::default_rig().unwrap();
        let (layout, pts) = face(3);
        assert!(pts.len() >= 90, "{}", pts.len());
        let mut rng = Rng::new(11);
        for trial in 0..8 {
            let angles = Vector3::new(
                rng.range(-0.45, 0.45),
                rng.range(-0.5, 0.5),
                rng.range(-0.6, 0.6),
            );
            let shift = Vector3::new(
                rng.range(-20.0, 20.0),
                rng.range(-20.0, 20.0),
                rng.range(-25.0, 25.0),
            );
            let pose = pose_facing(&rig, 230.0, angles, shift);
            let obs = observe(&rig, &pose, &pts, &[], 0.15, 5, &mut rng);
            let truth = [obs[0].1.clone(), obs[1].1.clone()];
            let mut lab = labeler(&layout, &pts);
            assert_eq!(lab.predicted_rois(), [None, None]);
            let out = lab.process(0, [&obs[0].0, &obs[1].0]);
            let (ok, wrong) = count(&out, &truth);
            let vis = visible_both(&truth);
            assert_eq!(wrong, 0, "trial {trial}: {wrong} wrong labels");
            assert!(
                ok as f64 >= 0.95 * vis as f64,
                "trial {trial}: {ok} of {vis} labeled ({:?})",
                out.stats
            );
            assert!(out.stats.acquiring && out.stats.labeled == ok);
            let est = lab.head_pose().unwrap();
            assert!((est.translation.vector - pose.translation.vector).norm() < 1.0);
            assert!(lab.predicted_rois().iter().all(Option::is_some));
        }
    }

    #[test]
    fn no_acquisition_without_a_face() {
        let (layout, pts) = face(3);
        let mut lab = labeler(&layout, &pts);
        let mut rng = Rng::new(5);
        let rig = crate::synth::default_rig().unwrap();
        // Random points in front of the cameras: pairs exist but nothing registers.
        let cloud: Vec<Point3<f64>> = (0..90)
            .map(|_| {
                Point3::new(
                    rng.range(-70.0, 70.0),
                    rng.range(-40.0, 110.0),
                    rng.range(180.0, 260.0),
                )
            })
            .collect();
        let px0: Vec<Detection> = cloud
            .iter()
            .filter_map(|p| rig.cam0.project(&p.coords))
            .map(|c| Detection {
                centre_px: c,
                area_px: 10,
                roundness: 1.0,
                contrast_dn: 50.0,
                quality: 0.5,
            })
            .collect();
        let px1: Vec<Detection> = cloud
            .iter()
            .filter_map(|p| rig.cam1.project(&(rig.cam1_from_cam0 * p).coords))
            .map(|c| Detection {
                centre_px: c,
                area_px: 10,
                roundness: 1.0,
                contrast_dn: 50.0,
                quality: 0.5,
            })
            .collect();
        let out = lab.process(0, [&px0, &px1]);
        assert_eq!(out.stats.labeled, 0, "{:?}", out.stats);
        assert!(out.stats.acquiring && out.markers.iter().all(Option::is_none));
    }

    /// A head moving fast with random accelerations, a changing expression, an
    /// occlusion of ten markers, spurious blobs: everything labeled is right.
    fn run_sequence(
        frames: usize,
        rot_acc: f64,
        trans_acc: f64,
        spurious: usize,
        hide: Option<(std::ops::Range<usize>, Vec<usize>)>,
        seed: u64,
    ) -> (usize, usize, usize, usize) {
        let rig = crate::synth::default_rig().unwrap();
        let (layout, pts) = face(seed);
        let mut lab = labeler(&layout, &pts);
        let mut rng = Rng::new(seed + 100);
        let (mut angles, mut shift) = (Vector3::zeros(), Vector3::zeros());
        let (mut w, mut v) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
        let (mut ok_total, mut wrong_total, mut vis_total, mut reacq) = (0, 0, 0, 0);
        for f in 0..frames {
            if f >= 5 {
                w += Vector3::new(rng.normal(), rng.normal(), rng.normal()) * rot_acc;
                v += Vector3::new(rng.normal(), rng.normal(), rng.normal()) * trans_acc;
                // Keep the head in a plausible range: pull back toward the centre.
                w -= angles * 0.05 + w * 0.05;
                v -= shift * 0.05 + v * 0.05;
            }
            angles += w;
            shift += v;
            let pose = pose_facing(&rig, 230.0, angles, shift);
            // Expression: smooth motion of up to 3 mm of the lower markers.
            let t = f as f64 / 60.0;
            let moved: Vec<Point3<f64>> = pts
                .iter()
                .map(|p| {
                    let a = 0.3 + 2.7 * ((20.0 - p.y) / 40.0).clamp(0.0, 1.0);
                    p + Vector3::new(
                        0.3 * a * (3.0 * t + p.y / 40.0).cos(),
                        a * (2.0 * t + p.x / 30.0).sin(),
                        0.3 * a * (3.0 * t).cos(),
                    )
                })
                .collect();
            let hidden: Vec<usize> = match &hide {
                Some((range, set)) if range.contains(&f) => set.clone(),
                _ => Vec::new(),
            };
            let obs = observe(&rig, &pose, &moved, &hidden, 0.15, spurious, &mut rng);
            let truth = [obs[0].1.clone(), obs[1].1.clone()];
            let out = lab.process(f, [&obs[0].0, &obs[1].0]);
            let (ok, wrong) = count(&out, &truth);
            if (ok as f64) < 0.9 * visible_both(&truth) as f64 {
                eprintln!(
                    "frame {f}: {ok} of {} {:?}",
                    visible_both(&truth),
                    out.stats
                );
            }
            assert_eq!(wrong, 0, "frame {f}: {wrong} wrong labels, {:?}", out.stats);
            if let Some((range, set)) = &hide
                && f == range.end + 2
            {
                for &k in set {
                    assert!(out.markers[k].is_some(), "marker {k} not back at frame {f}");
                }
            }
            reacq += out.stats.reacquired;
            ok_total += ok;
            wrong_total += wrong;
            vis_total += visible_both(&truth);
        }
        (ok_total, wrong_total, vis_total, reacq)
    }

    #[test]
    fn tracks_through_fast_motion() {
        // Rotation speeds reach several degrees per frame, translations several mm per
        // frame, with random changes of direction.
        let (ok, wrong, vis, _) = run_sequence(150, 0.006, 0.8, 0, None, 3);
        assert_eq!(wrong, 0);
        let rate = ok as f64 / vis as f64;
        assert!(rate > 0.97, "{ok} of {vis}");
    }

    #[test]
    fn occluded_markers_return_with_their_labels() {
        let hide = (30..50, vec![2, 5, 17, 23, 41, 42, 60, 77, 80, 91]);
        let (ok, wrong, vis, reacq) = run_sequence(80, 0.002, 0.3, 0, Some(hide), 4);
        assert_eq!(wrong, 0);
        assert!(reacq >= 10, "{reacq} reacquired");
        assert!(ok as f64 > 0.97 * vis as f64, "{ok} of {vis}");
    }

    #[test]
    fn spurious_blobs_are_rejected() {
        let (ok, wrong, vis, _) = run_sequence(60, 0.002, 0.3, 60, None, 5);
        assert_eq!(wrong, 0);
        assert!(ok as f64 > 0.95 * vis as f64, "{ok} of {vis}");
    }

    #[test]
    fn markers_in_contact_are_dropped_not_swapped() {
        // Two markers slide toward each other until they nearly touch (lips pressing),
        // then apart again.
        let rig = crate::synth::default_rig().unwrap();
        let (layout, pts) = face(6);
        let mut lab = labeler(&layout, &pts);
        let mut rng = Rng::new(66);
        // The closest pair of lower-face markers.
        let mut pair = (0, 1, f64::MAX);
        for i in 0..pts.len() {
            for j in i + 1..pts.len() {
                let d = (pts[i] - pts[j]).norm();
                if pts[i].y < 0.0 && d < pair.2 {
                    pair = (i, j, d);
                }
            }
        }
        let (a, b, _) = pair;
        let pose = pose_facing(
            &rig,
            230.0,
            Vector3::new(0.05, -0.1, 0.02),
            Vector3::zeros(),
        );
        let mut dropped = 0;
        for f in 0..120 {
            // Closure 0 → 1 → 0 over frames 20..100.
            let s = ((f as f64 - 20.0) / 80.0).clamp(0.0, 1.0);
            let closure = (std::f64::consts::PI * s).sin();
            let mid = Point3::from((pts[a].coords + pts[b].coords) * 0.5);
            let mut moved = pts.clone();
            // Down to 1 mm apart.
            let keep = 1.0 - closure * (1.0 - 1.0 / (pts[a] - pts[b]).norm());
            moved[a] = mid + (pts[a] - mid) * keep;
            moved[b] = mid + (pts[b] - mid) * keep;
            let obs = observe(&rig, &pose, &moved, &[], 0.2, 0, &mut rng);
            // Nearly touching dots merge into one blob in the image: detections closer
            // than 4 px become one at their mean, which belongs to neither marker.
            let mut merged = [obs[0].clone(), obs[1].clone()];
            for (dets, truth) in &mut merged {
                let ia = truth.iter().position(|t| *t == Some(a));
                let ib = truth.iter().position(|t| *t == Some(b));
                if let (Some(ia), Some(ib)) = (ia, ib)
                    && (dets[ia].centre_px - dets[ib].centre_px).norm() < 4.0
                {
                    let c = nalgebra::center(&dets[ia].centre_px, &dets[ib].centre_px);
                    dets[ia].centre_px = c;
                    truth[ia] = None;
                    dets.remove(ib);
                    truth.remove(ib);
                }
            }
            let truth = [merged[0].1.clone(), merged[1].1.clone()];
            let out = lab.process(f, [&merged[0].0, &merged[1].0]);
            let (_, wrong) = count(&out, &truth);
            assert_eq!(wrong, 0, "frame {f}");
            if out.markers[a].is_none() || out.markers[b].is_none() {
                dropped += 1;
            }
        }
        // Labeled again after separating.
        assert!(dropped < 100, "{dropped}");
    }

    #[test]
    fn never_panics_on_garbage_and_recovers() {
        let rig = crate::synth::default_rig().unwrap();
        let (layout, pts) = face(3);
        let mut lab = labeler(&layout, &pts);
        let bad = |x: f64, y: f64| Detection {
            centre_px: Point2::new(x, y),
            area_px: 0,
            roundness: f64::NAN,
            contrast_dn: -1.0,
            quality: f64::INFINITY,
        };
        let garbage = vec![
            bad(f64::NAN, 3.0),
            bad(f64::INFINITY, f64::NEG_INFINITY),
            bad(-1e300, 1e300),
            bad(640.0, 512.0),
            bad(640.0, 512.0),
        ];
        for f in [0, 1, 1, 0, 7, 1000, usize::MAX] {
            let out = lab.process(f, [&garbage, &[]]);
            assert_eq!(out.markers.len(), layout.len());
            let out = lab.process(f, [&garbage, &garbage]);
            assert_eq!(out.stats.labeled, 0);
        }
        // Then a real face: acquired.
        let mut rng = Rng::new(1);
        let pose = pose_facing(&rig, 230.0, Vector3::zeros(), Vector3::zeros());
        let obs = observe(&rig, &pose, &pts, &[], 0.1, 0, &mut rng);
        let out = lab.process(3, [&obs[0].0, &obs[1].0]);
        assert!(out.stats.labeled > 50, "{:?}", out.stats);
        // A frame of nothing, a few times: lost, then re-acquired.
        for f in 4..8 {
            let out = lab.process(f, [&[], &[]]);
            assert_eq!(out.stats.labeled, 0);
        }
        let truth = [obs[0].1.clone(), obs[1].1.clone()];
        let out = lab.process(8, [&obs[0].0, &obs[1].0]);
        assert!(out.stats.acquiring && out.stats.labeled > 50);
        assert_eq!(count(&out, &truth).1, 0);
    }

    #[test]
    fn rejects_bad_construction() {
        let rig = crate::synth::default_rig().unwrap();
        let (layout, pts) = face(3);
        let short = pts[..5].to_vec();
        assert!(matches!(
            Labeler::new(rig.clone(), &layout, short, LabelParams::default()),
            Err(LabelError::Layout(_))
        ));
        let mut nan = pts.clone();
        nan[3].x = f64::NAN;
        assert!(matches!(
            Labeler::new(rig.clone(), &layout, nan, LabelParams::default()),
            Err(LabelError::Layout(_))
        ));
        let p = LabelParams {
            gate_px: -1.0,
            ..Default::default()
        };
        assert!(matches!(
            Labeler::new(rig.clone(), &layout, pts.clone(), p),
            Err(LabelError::Params(_))
        ));
        let mut bad_rig = rig;
        bad_rig.cam1.width_px = 10;
        assert!(matches!(
            Labeler::new(bad_rig, &layout, pts, LabelParams::default()),
            Err(LabelError::Rig(_))
        ));
    }
}
