//! Head stabilization: the rigid motion of the head relative to the helmet cameras, from
//! the markers that move least with expression, and the bundles carried into the head
//! frame.
//!
//! Per frame, [`Stabilizer::process`] fits `cam0_from_head` by [`robust_horn`] between
//! the neutral positions of the observed markers (head frame) and their triangulated
//! positions (cam0 frame), each weighted by the layout's `stabilize_weight` times the
//! bundle's confidence (DESIGN.md §4: forehead, nose bridge and temples high, mouth and
//! jaw 0). Markers with weight 0 do not influence the pose. The bundles are then mapped by
//! `head_from_cam0 = cam0_from_head⁻¹`.
//!
//! # Fallback
//! When fewer than [`StabilizeParams::min_markers`] stabilizing markers are observed, or
//! the robust fit keeps fewer than that many inliers, or the inlier RMS exceeds
//! [`StabilizeParams::max_inlier_rms_mm`], the previous frame's pose is held (counted in
//! [`StabilizeCounts::held`]) for at most [`StabilizeParams::max_hold_frames`] frames;
//! before any pose is known, or after that, the frame has no pose (counted in
//! [`StabilizeCounts::missing`]) and no head-frame bundles.

use nalgebra::{Isometry3, Point3};

use super::robust::{RobustHornParams, robust_horn};
use crate::dataset::MarkerLayout;
use crate::param_error::ParamError;

/// Stabilization settings.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StabilizeParams {
    /// The robust Horn fit (Tukey IRLS, no scale by default).
    pub horn: RobustHornParams,
    /// Fewest observed stabilizing markers (weight > 0) and fewest inliers for a pose of
    /// this frame. Default 4 (three define a pose; one more lets an outlier show).
    pub min_markers: usize,
    /// Largest weighted RMS residual of the inliers, mm, for a pose of this frame.
    /// Default 2.0 (the synthetic rig's noise is ~0.1 mm; expressions move stabilizing
    /// markers under 1 mm).
    pub max_inlier_rms_mm: f64,
    /// Frames the last good pose is held when a frame has none. Default 30 (half a
    /// second at 60 fps: a helmet slips slowly).
    pub max_hold_frames: usize,
    /// An observed marker farther than this from its neutral position once in the head
    /// frame is dropped as mislabeled, mm. Default 30 (more than any expression moves a
    /// face point of the built-in actor or ICT).
    pub max_displacement_mm: f64,
}

impl Default for StabilizeParams {
    fn default() -> Self {
        Self {
            horn: RobustHornParams::default(),
            min_markers: 4,
            max_inlier_rms_mm: 2.0,
            max_hold_frames: 30,
            max_displacement_mm: 30.0,
        }
    }
}

impl StabilizeParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`ParamError`] naming the field.
    pub fn validate(&self) -> Result<(), ParamError> {
        self.horn.validate().map_err(|e| e.within("horn"))?;
        if self.min_markers < 3 {
            return Err(ParamError::new("min_markers", "must be at least 3"));
        }
        if self.max_inlier_rms_mm.is_nan() || self.max_inlier_rms_mm <= 0.0 {
            return Err(ParamError::new("max_inlier_rms_mm", "must be positive"));
        }
        if self.max_displacement_mm.is_nan() || self.max_displacement_mm <= 0.0 {
            return Err(ParamError::new("max_displacement_mm", "must be positive"));
        }
        Ok(())
    }
}

/// Errors building a [`Stabilizer`].
#[derive(Debug, thiserror::Error)]
pub enum StabilizeError {
    /// The layout and neutral positions disagree, or no marker stabilizes.
    #[error("stabilization: {0}")]
    Layout(String),
    /// A parameter is out of range.
    #[error("stabilization parameters: {0}")]
    Params(ParamError),
}

/// Where a frame's head pose came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseSource {
    /// Fitted to this frame's stabilizing markers.
    Estimated,
    /// Too few good stabilizing markers: the last estimated pose, held.
    Held,
    /// No pose (none known yet, or held too long).
    Missing,
}

/// The stabilization of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct StabilizedFrame {
    /// Head pose, head frame → cam0 (mm); None when [`PoseSource::Missing`].
    pub cam0_from_head: Option<Isometry3<f64>>,
    /// Where the pose came from.
    pub pose_source: PoseSource,
    /// Per layout marker: its bundle in the head frame (mm), None when not observed, when
    /// dropped, or without a pose.
    pub bundles_in_head: Vec<Option<Point3<f64>>>,
    /// Per layout marker: observed but dropped (too far from its neutral position).
    pub dropped: Vec<bool>,
    /// Stabilizing markers used by the fit (observed, weight > 0).
    pub stabilizing_observed: usize,
    /// Inliers of the robust fit (0 when not estimated).
    pub inliers: usize,
    /// Weighted RMS residual of the inliers, mm (NaN when not estimated).
    pub inlier_rms_mm: f64,
}

/// Counts over a take.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct StabilizeCounts {
    /// Frames with an estimated pose.
    pub estimated: usize,
    /// Frames that held the previous pose.
    pub held: usize,
    /// Frames without a pose.
    pub missing: usize,
    /// Marker observations dropped as too far from neutral.
    pub dropped_markers: usize,
}

/// Stabilizes frame after frame (see the module docs). One per take: it remembers the
/// last pose for the fallback.
#[derive(Debug, Clone)]
pub struct Stabilizer {
    neutral: Vec<Point3<f64>>,
    weights: Vec<f64>,
    params: StabilizeParams,
    last_pose: Option<Isometry3<f64>>,
    held_for: usize,
    counts: StabilizeCounts,
}

impl Stabilizer {
    /// `neutral_markers_head`: each layout marker's neutral position (head frame, mm), in
    /// layout order; the weights are the layout's `stabilize_weight`s.
    ///
    /// # Errors
    /// [`StabilizeError::Layout`] when the counts differ, a position is not finite, or
    /// fewer than `min_markers` markers have a positive weight; [`StabilizeError::Params`].
    pub fn new(
        layout: &MarkerLayout,
        neutral_markers_head: Vec<Point3<f64>>,
        params: StabilizeParams,
    ) -> Result<Self, StabilizeError> {
        params.validate().map_err(StabilizeError::Params)?;
        if neutral_markers_head.len() != layout.len() {
            return Err(StabilizeError::Layout(format!(
                "{} neutral positions for {} markers",
                neutral_markers_head.len(),
                layout.len()
            )));
        }
        if neutral_markers_head
            .iter()
            .any(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(StabilizeError::Layout(
                "a neutral marker position is not finite".into(),
            ));
        }
        let weights: Vec<f64> = layout
            .markers
            .iter()
            .map(|m| {
                if m.stabilize_weight.is_finite() {
                    m.stabilize_weight.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        let stabilizing = weights.iter().filter(|&&w| w > 0.0).count();
        if stabilizing < params.min_markers {
            return Err(StabilizeError::Layout(format!(
                "{stabilizing} markers have a positive stabilize_weight; at least {} are needed",
                params.min_markers
            )));
        }
        Ok(Self {
            neutral: neutral_markers_head,
            weights,
            params,
            last_pose: None,
            held_for: 0,
            counts: StabilizeCounts::default(),
        })
    }

    /// Counts so far.
    pub fn counts(&self) -> StabilizeCounts {
        self.counts
    }

    /// Forgets the last pose (a new take).
    pub fn reset(&mut self) {
        self.last_pose = None;
        self.held_for = 0;
    }

    /// Stabilizes one frame. `observed`: per layout marker, its bundle in cam0 (mm) and
    /// confidence (0..1), or None.
    pub fn process(&mut self, observed: &[Option<(Point3<f64>, f64)>]) -> StabilizedFrame {
        let m = self.neutral.len();
        let mut source = Vec::new();
        let mut target = Vec::new();
        let mut weights = Vec::new();
        for (i, o) in observed.iter().enumerate().take(m) {
            if let Some((p, conf)) = o {
                let w = self.weights[i] * conf.clamp(0.0, 1.0);
                if w > 0.0 && p.coords.iter().all(|c| c.is_finite()) {
                    source.push(self.neutral[i]);
                    target.push(*p);
                    weights.push(w);
                }
            }
        }
        let stabilizing_observed = source.len();
        let mut inliers = 0;
        let mut inlier_rms_mm = f64::NAN;
        let mut estimated = None;
        if stabilizing_observed >= self.params.min_markers
            && let Ok(fit) = robust_horn(&source, &target, &weights, &self.params.horn)
        {
            inliers = fit.inlier_count;
            inlier_rms_mm = fit.inlier_rms;
            if inliers >= self.params.min_markers && fit.inlier_rms <= self.params.max_inlier_rms_mm
            {
                estimated = Some(fit.target_from_source);
            }
        }
        let (pose, pose_source) = match estimated {
            Some(p) => {
                self.last_pose = Some(p);
                self.held_for = 0;
                self.counts.estimated += 1;
                (Some(p), PoseSource::Estimated)
            }
            None => match self.last_pose {
                Some(p) if self.held_for < self.params.max_hold_frames => {
                    self.held_for += 1;
                    self.counts.held += 1;
                    (Some(p), PoseSource::Held)
                }
                _ => {
                    self.counts.missing += 1;
                    (None, PoseSource::Missing)
                }
            },
        };
        let mut bundles_in_head = vec![None; m];
        let mut dropped = vec![false; m];
        if let Some(cam0_from_head) = pose {
            let head_from_cam0 = cam0_from_head.inverse();
            for (i, o) in observed.iter().enumerate().take(m) {
                if let Some((p, _)) = o {
                    let h = head_from_cam0 * p;
                    if (h - self.neutral[i]).norm() > self.params.max_displacement_mm
                        || !h.coords.iter().all(|c| c.is_finite())
                    {
                        dropped[i] = true;
                        self.counts.dropped_markers += 1;
                    } else {
                        bundles_in_head[i] = Some(h);
                    }
                }
            }
        }
        StabilizedFrame {
            cam0_from_head: pose,
            pose_source,
            bundles_in_head,
            dropped,
            stabilizing_observed,
            inliers,
            inlier_rms_mm,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::Marker;
    use nalgebra::Vector3;

    fn setup(n: usize) -> (MarkerLayout, Vec<Point3<f64>>) {
        let layout = MarkerLayout {
            markers: (0..n)
                .map(|i| Marker {
                    name: format!("m{i}"),
                    vertex: i as u32,
                    // Every other marker stabilizes.
                    stabilize_weight: if i % 2 == 0 { 1.0 } else { 0.0 },
                })
                .collect(),
        };
        let neutral = (0..n)
            .map(|i| {
                let f = i as f64;
                Point3::new(
                    (f * 1.7).sin() * 50.0,
                    (f * 0.9).cos() * 60.0,
                    (f * 0.4).sin() * 20.0,
                )
            })
            .collect();
        (layout, neutral)
    }

    fn pose() -> Isometry3<f64> {
        Isometry3::new(Vector3::new(3.0, 20.0, 225.0), Vector3::new(0.1, 3.0, 0.05))
    }

    #[test]
    fn recovers_pose_and_head_frame_bundles() {
        let (layout, neutral) = setup(20);
        let mut s = Stabilizer::new(&layout, neutral.clone(), StabilizeParams::default()).unwrap();
        let t = pose();
        // Non-stabilizing markers move (expression) by up to 8 mm; the pose ignores them.
        let moved: Vec<Point3<f64>> = neutral
            .iter()
            .enumerate()
            .map(|(i, p)| {
                if i % 2 == 1 {
                    p + Vector3::new(0.0, -8.0, 3.0)
                } else {
                    *p
                }
            })
            .collect();
        let obs: Vec<_> = moved.iter().map(|p| Some((t * p, 1.0))).collect();
        let f = s.process(&obs);
        assert_eq!(f.pose_source, PoseSource::Estimated);
        let est = f.cam0_from_head.unwrap();
        assert!((est.translation.vector - t.translation.vector).norm() < 1e-9);
        for (b, m) in f.bundles_in_head.iter().zip(&moved) {
            assert!((b.unwrap() - m).norm() < 1e-9);
        }
    }

    #[test]
    fn holds_then_loses_the_pose() {
        let (layout, neutral) = setup(12);
        let params = StabilizeParams {
            max_hold_frames: 2,
            ..StabilizeParams::default()
        };
        let mut s = Stabilizer::new(&layout, neutral.clone(), params).unwrap();
        let none: Vec<Option<(Point3<f64>, f64)>> = vec![None; 12];
        assert_eq!(s.process(&none).pose_source, PoseSource::Missing);
        let t = pose();
        let obs: Vec<_> = neutral.iter().map(|p| Some((t * p, 1.0))).collect();
        assert_eq!(s.process(&obs).pose_source, PoseSource::Estimated);
        // Only three stabilizing markers seen: too few, the pose is held.
        let few: Vec<_> = obs
            .iter()
            .enumerate()
            .map(|(i, o)| if i < 6 || i % 2 == 1 { *o } else { None })
            .collect();
        let f = s.process(&few);
        assert_eq!(f.pose_source, PoseSource::Held);
        assert!(f.bundles_in_head[1].is_some());
        assert_eq!(s.process(&few).pose_source, PoseSource::Held);
        assert_eq!(s.process(&few).pose_source, PoseSource::Missing);
        let c = s.counts();
        assert_eq!((c.estimated, c.held, c.missing), (1, 2, 2));
    }

    #[test]
    fn drops_a_mislabeled_marker() {
        let (layout, neutral) = setup(12);
        let mut s = Stabilizer::new(&layout, neutral.clone(), StabilizeParams::default()).unwrap();
        let t = pose();
        let mut obs: Vec<_> = neutral.iter().map(|p| Some((t * p, 1.0))).collect();
        obs[3] = Some((t * (neutral[3] + Vector3::new(40.0, 0.0, 0.0)), 1.0));
        let f = s.process(&obs);
        assert!(f.dropped[3] && f.bundles_in_head[3].is_none());
        assert_eq!(f.dropped.iter().filter(|&&d| d).count(), 1);
    }

    #[test]
    fn rejects_layouts_without_stabilizing_markers() {
        let (mut layout, neutral) = setup(6);
        for m in &mut layout.markers {
            m.stabilize_weight = 0.0;
        }
        assert!(Stabilizer::new(&layout, neutral, StabilizeParams::default()).is_err());
    }
}
