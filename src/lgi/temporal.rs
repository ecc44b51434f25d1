//! Temporal smoothing of the per-marker barycentric weights (Cong et al. 2019 §7: "taking
//! a central moving average of the barycentric weights associated with each bundle relative
//! to the jaw skinned neutral mesh in order to avoid smoothing the jaw animation").
//!
//! A window of `past_frames` before and `future_frames` after each frame: centred
//! (`past = future`) for offline replay, and for live use a small `future_frames` bounds
//! the lag: frame `t` comes out when frame `t + future_frames` has gone in. The jaw pose is
//! never smoothed, and the reconstruction still passes through each frame's own bundles
//! (the residual to the bundle is recomputed after smoothing; see
//! [`super::LgiParams::snap_to_bundles`]).
//!
//! # Deviations
//! The paper's moving average has a box kernel; ours defaults to a triangular (Bartlett)
//! kernel of the same support, whose output has no jumps in velocity when a marker switches
//! shapes, so the acceleration (the jitter a viewer sees) stays lower. The box is
//! available as [`Kernel::Box`].

use std::collections::VecDeque;

use super::FrameWeights;

/// Weighting of the frames in the window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Kernel {
    /// Equal weights (the paper's moving average).
    Box,
    /// Weights falling linearly to zero one frame past each end of the window.
    Triangle,
}

/// Temporal smoothing settings.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TemporalParams {
    /// Frames before the current one in the window. Default 0 (no smoothing).
    pub past_frames: usize,
    /// Frames after the current one (the output lag, in frames). Default 0.
    pub future_frames: usize,
    /// Weighting of the window. Default triangle.
    pub kernel: Kernel,
}

impl Default for TemporalParams {
    fn default() -> Self {
        Self {
            past_frames: 0,
            future_frames: 0,
            kernel: Kernel::Triangle,
        }
    }
}

impl TemporalParams {
    /// Centred window of `half` frames each side, for offline replay.
    pub fn centered(half: usize) -> Self {
        Self {
            past_frames: half,
            future_frames: half,
            kernel: Kernel::Triangle,
        }
    }

    /// Whether smoothing does anything.
    pub fn is_enabled(&self) -> bool {
        self.past_frames + self.future_frames > 0
    }

    fn weight(&self, offset: isize) -> f64 {
        match self.kernel {
            Kernel::Box => 1.0,
            Kernel::Triangle => {
                let half = if offset < 0 {
                    self.past_frames
                } else {
                    self.future_frames
                } as f64;
                1.0 - offset.unsigned_abs() as f64 / (half + 1.0)
            }
        }
    }
}

/// Streaming smoother of [`FrameWeights`]: push frames in order, take smoothed frames out
/// with a lag of `future_frames`; [`WeightSmoother::finish`] flushes the rest.
#[derive(Debug)]
pub struct WeightSmoother {
    params: TemporalParams,
    window: VecDeque<FrameWeights>,
    /// Index in `window` of the next frame to emit.
    next: usize,
}

impl WeightSmoother {
    /// A smoother with `params`.
    pub fn new(params: TemporalParams) -> Self {
        Self {
            params,
            window: VecDeque::new(),
            next: 0,
        }
    }

    /// Adds the next frame; returns the frames that are now complete (at most one).
    pub fn push(&mut self, frame: FrameWeights) -> Vec<FrameWeights> {
        self.window.push_back(frame);
        let mut out = Vec::new();
        while self.next + self.params.future_frames < self.window.len() {
            out.push(self.emit());
        }
        out
    }

    /// Emits every frame still waiting for its future frames (the window is truncated at
    /// the end of the take).
    pub fn finish(&mut self) -> Vec<FrameWeights> {
        let mut out = Vec::new();
        while self.next < self.window.len() {
            out.push(self.emit());
        }
        out
    }

    fn emit(&mut self) -> FrameWeights {
        let t = self.next;
        let lo = t.saturating_sub(self.params.past_frames);
        let hi = (t + self.params.future_frames).min(self.window.len() - 1);
        let current = &self.window[t];
        let mut out = current.clone();
        for (m, mw) in out.markers.iter_mut().enumerate() {
            if !mw.present {
                continue;
            }
            let mut acc: Vec<(u16, f64)> = Vec::new();
            let mut total = 0.0;
            for (s, f) in self.window.iter().enumerate().take(hi + 1).skip(lo) {
                let other = &f.markers[m];
                if !other.present {
                    continue;
                }
                let k = self.params.weight(s as isize - t as isize);
                total += k;
                for &(j, w) in &other.points {
                    match acc.iter_mut().find(|e| e.0 == j) {
                        Some(e) => e.1 += k * w,
                        None => acc.push((j, k * w)),
                    }
                }
            }
            if total > 0.0 {
                for e in &mut acc {
                    e.1 /= total;
                }
                acc.retain(|e| e.1 > 0.0);
                acc.sort_by_key(|e| e.0);
                mw.points = acc;
            }
        }
        self.next += 1;
        // Drop frames no longer needed by any future window.
        while self.next > self.params.past_frames {
            self.window.pop_front();
            self.next -= 1;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::super::MarkerWeights;
    use super::*;
    use crate::frame_index::FrameIndex;

    fn frame(f: u64, j: u16) -> FrameWeights {
        FrameWeights {
            frame: FrameIndex::new(f),
            markers: vec![MarkerWeights {
                present: true,
                inside: true,
                points: vec![(j, 1.0)],
            }],
            jaw: None,
        }
    }

    #[test]
    fn centered_window_smooths_a_switch_and_keeps_order() {
        let mut s = WeightSmoother::new(TemporalParams {
            past_frames: 1,
            future_frames: 1,
            kernel: Kernel::Box,
        });
        let mut out = Vec::new();
        for f in 0..6 {
            out.extend(s.push(frame(f, if f < 3 { 0 } else { 1 })));
            assert!(out.len() as u64 <= f, "lag of one frame");
        }
        out.extend(s.finish());
        assert_eq!(
            out.iter().map(|f| f.frame.get()).collect::<Vec<_>>(),
            (0..6).collect::<Vec<_>>()
        );
        let w = |f: &FrameWeights, j: u16| {
            f.markers[0]
                .points
                .iter()
                .find(|e| e.0 == j)
                .map_or(0.0, |e| e.1)
        };
        assert_eq!(w(&out[0], 0), 1.0);
        assert!((w(&out[2], 1) - 1.0 / 3.0).abs() < 1e-12);
        assert!((w(&out[3], 1) - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(w(&out[5], 1), 1.0);
        for f in &out {
            let total: f64 = f.markers[0].points.iter().map(|e| e.1).sum();
            assert!((total - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn disabled_smoothing_is_identity() {
        let mut s = WeightSmoother::new(TemporalParams::default());
        let a = s.push(frame(0, 3));
        assert_eq!(a, vec![frame(0, 3)]);
        assert!(s.finish().is_empty());
    }
}
