//! Take metrics: frame counts, throughput, latency per stage and end to end, labeling and
//! gap counts, the timecode range and accuracy against ground truth. Written as
//! `metrics.json` (DESIGN.md §4 "Pipeline outputs").
//!
//! Latencies go into fixed log-spaced histograms (2 % wide bins from 1 µs to 100 s), so a
//! take of any length costs the same memory; percentiles are exact to the bin width,
//! means and maxima are exact.

use std::collections::BTreeMap;

use super::frame::{BundleStatus, FrameResult, Stage};
use crate::align::PoseSource;
use crate::frame_index::FrameIndex;
use crate::timecode::Timecode;

/// Ratio between consecutive histogram bin edges.
const BIN_RATIO: f64 = 1.02;
/// Lower edge of the first bin, ms.
const BIN_MIN_MS: f64 = 1e-3;
/// Number of bins (1 µs · 1.02^n reaches 100 s at n ≈ 930).
const BIN_COUNT: usize = 940;

/// A latency distribution in constant memory (see the module docs). Saved (in a chunk's
/// `take.json`) as its non-empty bins.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(into = "HistogramFile", try_from = "HistogramFile")]
pub struct LatencyHistogram {
    bins: Vec<u64>,
    count: u64,
    sum_ms: f64,
    max_ms: f64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self {
            bins: vec![0; BIN_COUNT],
            count: 0,
            sum_ms: 0.0,
            max_ms: 0.0,
        }
    }
}

/// [`LatencyHistogram`] as saved: the non-empty bins as `[bin, count]` pairs.
#[derive(serde::Serialize, serde::Deserialize)]
struct HistogramFile {
    bins: Vec<(usize, u64)>,
    count: u64,
    sum_ms: f64,
    max_ms: f64,
}

impl From<LatencyHistogram> for HistogramFile {
    fn from(h: LatencyHistogram) -> Self {
        Self {
            bins: h
                .bins
                .iter()
                .enumerate()
                .filter(|(_, n)| **n > 0)
                .map(|(i, n)| (i, *n))
                .collect(),
            count: h.count,
            sum_ms: h.sum_ms,
            max_ms: h.max_ms,
        }
    }
}

impl TryFrom<HistogramFile> for LatencyHistogram {
    type Error = String;

    fn try_from(f: HistogramFile) -> Result<Self, String> {
        let mut h = Self::default();
        for (i, n) in f.bins {
            *h.bins
                .get_mut(i)
                .ok_or_else(|| format!("latency bin {i} is past the last ({BIN_COUNT})"))? += n;
        }
        if h.bins.iter().sum::<u64>() != f.count {
            return Err("latency bins do not add up to their count".into());
        }
        h.count = f.count;
        h.sum_ms = f.sum_ms;
        h.max_ms = f.max_ms;
        Ok(h)
    }
}

impl LatencyHistogram {
    /// Adds every sample of `other`.
    pub fn merge(&mut self, other: &LatencyHistogram) {
        for (a, b) in self.bins.iter_mut().zip(&other.bins) {
            *a += b;
        }
        self.count += other.count;
        self.sum_ms += other.sum_ms;
        self.max_ms = self.max_ms.max(other.max_ms);
    }

    /// Adds one sample, ms (non-finite or negative samples are ignored).
    pub fn add(&mut self, ms: f64) {
        if !(ms.is_finite() && ms >= 0.0) {
            return;
        }
        let bin = if ms <= BIN_MIN_MS {
            0
        } else {
            ((ms / BIN_MIN_MS).ln() / BIN_RATIO.ln()) as usize
        };
        self.bins[bin.min(BIN_COUNT - 1)] += 1;
        self.count += 1;
        self.sum_ms += ms;
        self.max_ms = self.max_ms.max(ms);
    }

    /// Number of samples.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The `q` quantile (0..1), ms: the geometric centre of the bin holding it.
    pub fn quantile(&self, q: f64) -> f64 {
        if self.count == 0 {
            return f64::NAN;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (i, &n) in self.bins.iter().enumerate() {
            seen += n;
            if seen >= rank {
                let centre = BIN_MIN_MS * BIN_RATIO.powf(i as f64 + 0.5);
                return centre.min(self.max_ms);
            }
        }
        self.max_ms
    }

    /// Mean, p50, p99 and max.
    pub fn stats(&self) -> LatencyStats {
        LatencyStats {
            mean: if self.count == 0 {
                f64::NAN
            } else {
                self.sum_ms / self.count as f64
            },
            p50: self.quantile(0.5),
            p99: self.quantile(0.99),
            max: if self.count == 0 {
                f64::NAN
            } else {
                self.max_ms
            },
            count: self.count,
        }
    }
}

/// Summary of one latency distribution, ms.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LatencyStats {
    /// Mean.
    pub mean: f64,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
    /// Samples.
    pub count: u64,
}

/// Marker labeling over the take.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct LabelingMetrics {
    /// Markers in the layout.
    pub markers: usize,
    /// Marker-frames observed (labeled and triangulated).
    pub observed: u64,
    /// Marker-frames filled from the dense solve.
    pub gap_filled: u64,
    /// Marker-frames dropped (implausible, or no head pose).
    pub dropped: u64,
    /// Marker-frames with nothing.
    pub missing: u64,
    /// observed / (frames × markers).
    pub labeled_fraction: f64,
    /// Markers labeled again after a gap.
    pub reacquired: u64,
    /// Candidate labels the labeler rejected.
    pub rejected: u64,
    /// Frames the labeler spent (re)acquiring the face.
    pub acquiring_frames: u64,
}

/// Frames with something missing.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct GapMetrics {
    /// Frames the source skipped (unreadable frames of a replay, lost camera frames).
    pub source: usize,
    /// Frames that held the previous head pose (too few stabilizing markers).
    pub pose_held: u64,
    /// Frames without a head pose.
    pub pose_missing: u64,
    /// Frames without a dense mesh although the pipeline solves meshes.
    pub mesh_missing: u64,
}

/// First and last timecode of the take.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TimecodeRange {
    /// Rate (`30`, `29.97df`, ...).
    pub rate: String,
    /// First frame's timecode with its rate (`01:00:00:00.0@30`).
    pub first: String,
    /// Last frame's timecode with its rate.
    pub last: String,
}

/// Accuracy against the session's ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct AccuracyMetrics {
    /// Frames with ground-truth bundles compared.
    pub bundle_frames: u64,
    /// RMS over all observed bundles of the distance to the true marker position in the
    /// head frame, mm.
    pub bundle_rms_mm: f64,
    /// Frames with a ground-truth mesh compared.
    pub mesh_frames: u64,
    /// RMS over frames and face vertices of the distance to the true surface vertex, mm.
    pub mesh_rms_mm: f64,
    /// Mean of the same distances, mm.
    pub mesh_mean_mm: f64,
    /// Largest face-vertex distance in any frame, mm.
    pub mesh_max_mm: f64,
}

/// Plausibility warnings of a take: things that are not errors but usually mean a wrong
/// setup, counted (and logged once each) rather than stopping the take.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct PlausibilityWarnings {
    /// Marker-frames whose bundle lies farther than [`MAX_FACE_EXTENT_MM`] from the head
    /// frame's origin (wrong calibration units, a bad triangulation).
    pub bundles_far_outside_face: u64,
    /// Frames whose solved mesh has a vertex farther than [`MAX_FACE_EXTENT_MM`] from the
    /// origin.
    pub meshes_far_outside_face: u64,
    /// The take's first [`NO_LABEL_WARNING_SECS`] seconds labeled no marker at all: the
    /// cameras are probably swapped, the same camera twice, or not the calibration's.
    pub nothing_labeled_at_start: bool,
    /// Frames whose timecode equals the previous frame's (sync lines not locked to the
    /// cameras' trigger).
    pub timecode_repeats: u64,
    /// Frames whose timecode runs more frames ahead of the previous frame's than the frame
    /// indices do, or runs backwards.
    pub timecode_jumps: u64,
}

/// A face in the head frame fits well inside a sphere of this radius, mm: farther
/// bundles or mesh vertices are counted as implausible.
pub const MAX_FACE_EXTENT_MM: f64 = 1_000.0;

/// Seconds at the start of a take after which "no marker labeled yet" is warned about.
pub const NO_LABEL_WARNING_SECS: f64 = 2.0;

/// Everything `metrics.json` holds.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Metrics {
    /// Frames taken from the source (including those dropped at the source).
    pub frames_in: u64,
    /// Frames that went through every stage to the sinks.
    pub frames_out: u64,
    /// Frames a live source dropped because the pipeline was full.
    pub frames_dropped: u64,
    /// frames_out / wall time, frames per second.
    pub throughput_fps: f64,
    /// Wall time of the take, seconds.
    pub wall_secs: f64,
    /// The source's frame rate, for comparison with the throughput.
    pub source_fps: f64,
    /// Per stage (by name) and `end_to_end`: mean, p50, p99, max, count (ms).
    pub latency_ms: BTreeMap<String, LatencyStats>,
    /// Labeling counts.
    pub labeling: LabelingMetrics,
    /// Gap counts.
    pub gaps: GapMetrics,
    /// Timecode of the first and last frame out, when the source has timecode.
    pub timecode: Option<TimecodeRange>,
    /// First and last frame index out.
    pub frame_range: Option<(FrameIndex, FrameIndex)>,
    /// Accuracy against ground truth, when the session has it.
    pub accuracy: Option<AccuracyMetrics>,
    /// Why the take stopped early (a stage error or an interruption), if it did.
    pub stopped: Option<String>,
    /// Plausibility warnings (see [`PlausibilityWarnings`]).
    #[serde(default)]
    pub warnings: PlausibilityWarnings,
    /// Frames run before the take's range only to warm the stages up (a chunk of a long
    /// take, `replay --warm-up`); counted in no other figure.
    #[serde(default)]
    pub warm_up_frames: u64,
    /// The collector these figures came from, for joining the chunks of a take
    /// ([`MetricsCollector::merge`]); not part of `metrics.json`.
    #[serde(skip)]
    pub collector: Option<Box<MetricsCollector>>,
}

/// Accumulates [`Metrics`] frame by frame (in the sink thread). It is saved whole (a
/// chunk's `take.json`), and the collectors of consecutive chunks of a take merge into
/// the one a single pass would have ([`MetricsCollector::merge`]): counts and sums add,
/// latency histograms add bin by bin, so the percentiles are those of all frames, not an
/// average of the chunks' percentiles.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MetricsCollector {
    #[serde(with = "stage_map")]
    stages: BTreeMap<Stage, LatencyHistogram>,
    end_to_end: LatencyHistogram,
    metrics: Metrics,
    #[serde(with = "timecode_file")]
    first_tc: Option<Timecode>,
    /// Index of the first frame out with a timecode (where a merge checks the step from
    /// the previous chunk's last timecode).
    #[serde(default)]
    first_tc_index: Option<FrameIndex>,
    #[serde(with = "timecode_file")]
    last_tc: Option<Timecode>,
    bundle_sq_sum: f64,
    bundle_count: u64,
    mesh_sq_sum: f64,
    mesh_sum: f64,
    mesh_count: u64,
    solves_meshes: bool,
    /// Index and timecode of the previous frame out.
    #[serde(with = "indexed_timecode_file")]
    previous_tc: Option<(FrameIndex, Timecode)>,
    /// Frames out so far without any observed marker, while none had one.
    unlabeled_start_frames: u64,
    any_labeled: bool,
}

impl MetricsCollector {
    /// A collector for a take of `markers` layout markers; `solves_meshes` says whether a
    /// frame without a mesh is a gap.
    pub fn new(markers: usize, source_fps: f64, solves_meshes: bool) -> Self {
        let mut c = Self {
            solves_meshes,
            ..Self::default()
        };
        c.metrics.labeling.markers = markers;
        c.metrics.source_fps = source_fps;
        c
    }

    /// Counts one frame as taken from the source.
    pub fn frame_in(&mut self) {
        self.metrics.frames_in += 1;
    }

    /// Sets the source counts (frames taken, dropped, skipped).
    pub fn set_source_counts(&mut self, frames_in: u64, dropped: u64, gaps: usize) {
        self.metrics.frames_in = frames_in;
        self.metrics.frames_dropped = dropped;
        self.metrics.gaps.source = gaps;
    }

    /// Adds a finished frame; `end_to_end_ms` from the source to the end of the sinks.
    /// `face_vertices` selects the vertices the mesh error statistics cover.
    pub fn frame_out(
        &mut self,
        frame: &FrameResult,
        end_to_end_ms: f64,
        face_vertices: Option<&std::ops::RangeInclusive<u32>>,
    ) {
        let m = &mut self.metrics;
        m.frames_out += 1;
        for s in Stage::ALL {
            let ms = frame.timings.get(s);
            if ms.is_finite() {
                self.stages.entry(s).or_default().add(ms);
            }
        }
        self.end_to_end.add(end_to_end_ms);
        for r in &frame.markers {
            match r.status {
                BundleStatus::Observed => m.labeling.observed += 1,
                BundleStatus::GapFilled => m.labeling.gap_filled += 1,
                BundleStatus::Dropped => m.labeling.dropped += 1,
                BundleStatus::Missing => m.labeling.missing += 1,
            }
        }
        m.labeling.reacquired += frame.label_counts.reacquired as u64;
        m.labeling.rejected += frame.label_counts.rejected as u64;
        m.labeling.acquiring_frames += u64::from(frame.label_counts.acquiring);
        match frame.pose_source {
            PoseSource::Estimated => {}
            PoseSource::Held => m.gaps.pose_held += 1,
            PoseSource::Missing => m.gaps.pose_missing += 1,
        }
        if self.solves_meshes && frame.mesh.is_none() {
            m.gaps.mesh_missing += 1;
        }
        if let Some(tc) = frame.timecode {
            if self.first_tc.is_none() {
                self.first_tc = Some(tc);
                self.first_tc_index = Some(frame.index);
            }
            self.last_tc = Some(tc);
        }
        m.frame_range = Some(match m.frame_range {
            None => (frame.index, frame.index),
            Some((a, _)) => (a, frame.index),
        });
        if let Some(rms) = frame.bundle_error_rms_mm {
            let observed = frame.count(BundleStatus::Observed) as u64;
            self.bundle_sq_sum += rms * rms * observed as f64;
            self.bundle_count += observed;
            m.accuracy
                .get_or_insert_with(Default::default)
                .bundle_frames += 1;
        }
        if let Some(err) = &frame.mesh_error_mm {
            let acc = m.accuracy.get_or_insert_with(Default::default);
            acc.mesh_frames += 1;
            for (v, &e) in err.iter().enumerate() {
                if face_vertices.is_none_or(|r| r.contains(&(v as u32))) {
                    let e = f64::from(e);
                    self.mesh_sq_sum += e * e;
                    self.mesh_sum += e;
                    self.mesh_count += 1;
                    acc.mesh_max_mm = acc.mesh_max_mm.max(e);
                }
            }
        }
        self.check_plausibility(frame);
    }

    /// Counts the plausibility warnings of one frame (see [`PlausibilityWarnings`]).
    fn check_plausibility(&mut self, frame: &FrameResult) {
        let w = &mut self.metrics.warnings;
        // NaN counts as far too.
        let far = |p: &nalgebra::Point3<f64>| {
            let norm = p.coords.norm();
            norm.is_nan() || norm > MAX_FACE_EXTENT_MM
        };
        let far_bundles = frame
            .markers
            .iter()
            .filter(|r| {
                r.status == BundleStatus::Observed && r.point_in_head.is_some_and(|p| far(&p))
            })
            .count() as u64;
        if far_bundles > 0 && w.bundles_far_outside_face == 0 {
            tracing::warn!(
                "frame {}: {far_bundles} bundles farther than {MAX_FACE_EXTENT_MM} mm from the head \
                 frame's origin (calibration units?); counted in metrics.json",
                frame.index
            );
        }
        w.bundles_far_outside_face += far_bundles;
        if let Some(mesh) = &frame.mesh
            && mesh.iter().any(far)
        {
            if w.meshes_far_outside_face == 0 {
                tracing::warn!(
                    "frame {}: the solved mesh reaches farther than {MAX_FACE_EXTENT_MM} mm; \
                     counted in metrics.json",
                    frame.index
                );
            }
            w.meshes_far_outside_face += 1;
        }
        if !self.any_labeled {
            if frame.count(BundleStatus::Observed) > 0 {
                self.any_labeled = true;
            } else {
                self.unlabeled_start_frames += 1;
                let fps = self.metrics.source_fps;
                if !w.nothing_labeled_at_start
                    && fps > 0.0
                    && self.unlabeled_start_frames as f64 >= NO_LABEL_WARNING_SECS * fps
                {
                    w.nothing_labeled_at_start = true;
                    tracing::warn!(
                        "no marker labeled in the first {NO_LABEL_WARNING_SECS} s: are the \
                         cameras swapped, the same camera twice, or not the calibration's, or \
                         the marker layout or the capture profile not the footage's?"
                    );
                }
            }
        }
        if let Some(tc) = frame.timecode {
            self.check_timecode_step(frame.index, tc);
        }
    }

    /// Counts a repeat or jump from the previous frame's timecode to frame `index`'s.
    fn check_timecode_step(&mut self, index: FrameIndex, tc: Timecode) {
        let w = &mut self.metrics.warnings;
        if let Some((prev_index, prev)) = self.previous_tc
            && prev.rate == tc.rate
        {
            let k = i64::from(tc.subframes.max(1));
            let at = |t: &Timecode| t.frame_count as i64 * k + i64::from(t.subframe);
            let step = at(&tc) - at(&prev);
            let frames = (index.get() as i64 - prev_index.get() as i64).max(1);
            // A whole day of timecode wraps at midnight.
            let day = tc.rate.frames_per_day() as i64 * k;
            let step = if step < -day / 2 { step + day } else { step };
            // Every camera frame has its own label with sub-frames, or when the camera
            // runs at the timecode rate; else (60 fps on 24 fps code) labels repeat.
            let fps = self.metrics.source_fps;
            let unique = tc.subframes > 1 || (fps - tc.rate.fps()).abs() <= 0.01 * fps;
            if unique && step == 0 && tc.subframes == prev.subframes {
                if w.timecode_repeats == 0 {
                    tracing::warn!(
                        "frame {}: timecode {} repeats the previous frame's (sync not \
                     locked to the cameras?); counted in metrics.json",
                        index,
                        tc.to_string_with_rate()
                    );
                }
                w.timecode_repeats += 1;
            } else if unique && (step < 0 || step > frames) {
                if w.timecode_jumps == 0 {
                    tracing::warn!(
                        "frame {}: timecode jumps from {} to {}; counted in metrics.json",
                        index,
                        prev.to_string_with_rate(),
                        tc.to_string_with_rate()
                    );
                }
                w.timecode_jumps += 1;
            }
        }
        self.previous_tc = Some((index, tc));
    }

    /// The first frame out that has a timecode, and its timecode.
    pub fn first_timecode(&self) -> Option<(FrameIndex, Timecode)> {
        self.first_tc_index.zip(self.first_tc)
    }

    /// First and last frame index out.
    pub fn frame_range(&self) -> Option<(FrameIndex, FrameIndex)> {
        self.metrics.frame_range
    }

    /// Sets the count of warm-up frames (run but not written).
    pub fn set_warm_up_frames(&mut self, frames: u64) {
        self.metrics.warm_up_frames = frames;
    }

    /// Adds the frames of `later`, the collector of the next chunk of the same take (its
    /// frames all after this one's): afterwards this collector holds what one collector
    /// over both chunks' frames would. The step from this chunk's last timecode to
    /// `later`'s first is checked as any other frame's.
    ///
    /// # Errors
    /// The collectors are not of the same take (marker counts, rates or solving differ)
    /// or not in order.
    pub fn merge(&mut self, later: &MetricsCollector) -> Result<(), String> {
        let (a, b) = (&self.metrics, &later.metrics);
        if a.labeling.markers != b.labeling.markers {
            return Err(format!(
                "{} markers against {}",
                a.labeling.markers, b.labeling.markers
            ));
        }
        if a.source_fps != b.source_fps || self.solves_meshes != later.solves_meshes {
            return Err("the chunks ran at other frame rates or with other stages".into());
        }
        if let (Some((_, end)), Some((start, _))) = (a.frame_range, b.frame_range)
            && start <= end
        {
            return Err(format!(
                "frames {start}.. come after frame {end}: the chunks overlap or are out of order"
            ));
        }
        for (stage, h) in &later.stages {
            self.stages.entry(*stage).or_default().merge(h);
        }
        self.end_to_end.merge(&later.end_to_end);
        // Plausibility: the start-of-take check goes on while nothing was labeled.
        if !self.any_labeled {
            self.unlabeled_start_frames += later.unlabeled_start_frames;
            self.any_labeled = later.any_labeled;
            let fps = self.metrics.source_fps;
            if fps > 0.0 && self.unlabeled_start_frames as f64 >= NO_LABEL_WARNING_SECS * fps {
                self.metrics.warnings.nothing_labeled_at_start = true;
            }
        }
        if let (Some(index), Some(tc)) = (later.first_tc_index, later.first_tc) {
            self.check_timecode_step(index, tc);
        }
        let m = &mut self.metrics;
        let b = &later.metrics;
        m.frames_in += b.frames_in;
        m.frames_out += b.frames_out;
        m.frames_dropped += b.frames_dropped;
        m.warm_up_frames += b.warm_up_frames;
        let l = &mut m.labeling;
        l.observed += b.labeling.observed;
        l.gap_filled += b.labeling.gap_filled;
        l.dropped += b.labeling.dropped;
        l.missing += b.labeling.missing;
        l.reacquired += b.labeling.reacquired;
        l.rejected += b.labeling.rejected;
        l.acquiring_frames += b.labeling.acquiring_frames;
        let g = &mut m.gaps;
        g.source += b.gaps.source;
        g.pose_held += b.gaps.pose_held;
        g.pose_missing += b.gaps.pose_missing;
        g.mesh_missing += b.gaps.mesh_missing;
        let w = &mut m.warnings;
        w.bundles_far_outside_face += b.warnings.bundles_far_outside_face;
        w.meshes_far_outside_face += b.warnings.meshes_far_outside_face;
        w.timecode_repeats += b.warnings.timecode_repeats;
        w.timecode_jumps += b.warnings.timecode_jumps;
        m.frame_range = match (m.frame_range, b.frame_range) {
            (Some((first, _)), Some((_, last))) => Some((first, last)),
            (x, y) => x.or(y),
        };
        if let Some(acc) = &b.accuracy {
            let mine = m.accuracy.get_or_insert_with(Default::default);
            mine.bundle_frames += acc.bundle_frames;
            mine.mesh_frames += acc.mesh_frames;
            mine.mesh_max_mm = mine.mesh_max_mm.max(acc.mesh_max_mm);
        }
        if m.stopped.is_none() {
            m.stopped.clone_from(&b.stopped);
        }
        self.bundle_sq_sum += later.bundle_sq_sum;
        self.bundle_count += later.bundle_count;
        self.mesh_sq_sum += later.mesh_sq_sum;
        self.mesh_sum += later.mesh_sum;
        self.mesh_count += later.mesh_count;
        if self.first_tc.is_none() {
            self.first_tc = later.first_tc;
            self.first_tc_index = later.first_tc_index;
        }
        if later.last_tc.is_some() {
            self.last_tc = later.last_tc;
        }
        Ok(())
    }

    /// Marks the take as stopped early, with the reason.
    pub fn stopped(&mut self, reason: String) {
        self.metrics.stopped = Some(reason);
    }

    /// The metrics so far, with `wall_secs` of running time.
    pub fn snapshot(&self, wall_secs: f64) -> Metrics {
        let mut m = self.metrics.clone();
        m.collector = Some(Box::new(self.clone()));
        m.wall_secs = wall_secs;
        m.throughput_fps = if wall_secs > 0.0 {
            m.frames_out as f64 / wall_secs
        } else {
            0.0
        };
        m.latency_ms = self
            .stages
            .iter()
            .map(|(s, h)| (s.name().to_string(), h.stats()))
            .collect();
        m.latency_ms
            .insert("end_to_end".into(), self.end_to_end.stats());
        let total = m.frames_out * m.labeling.markers as u64;
        m.labeling.labeled_fraction = if total > 0 {
            m.labeling.observed as f64 / total as f64
        } else {
            0.0
        };
        if let (Some(a), Some(b)) = (self.first_tc, self.last_tc) {
            m.timecode = Some(TimecodeRange {
                rate: a.rate.to_string(),
                first: a.to_string_with_rate(),
                last: b.to_string_with_rate(),
            });
        }
        if let Some(acc) = &mut m.accuracy {
            acc.bundle_rms_mm = if self.bundle_count > 0 {
                (self.bundle_sq_sum / self.bundle_count as f64).sqrt()
            } else {
                f64::NAN
            };
            if self.mesh_count > 0 {
                acc.mesh_rms_mm = (self.mesh_sq_sum / self.mesh_count as f64).sqrt();
                acc.mesh_mean_mm = self.mesh_sum / self.mesh_count as f64;
            } else {
                acc.mesh_rms_mm = f64::NAN;
                acc.mesh_mean_mm = f64::NAN;
            }
        }
        m
    }
}

/// Stage-keyed maps saved with the stages' names as keys.
mod stage_map {
    use std::collections::BTreeMap;

    use super::{LatencyHistogram, Stage};

    pub fn serialize<S: serde::Serializer>(
        map: &BTreeMap<Stage, LatencyHistogram>,
        s: S,
    ) -> Result<S::Ok, S::Error> {
        use serde::Serialize;
        map.iter()
            .map(|(k, v)| (k.name(), v))
            .collect::<BTreeMap<_, _>>()
            .serialize(s)
    }

    pub fn deserialize<'de, D: serde::Deserializer<'de>>(
        d: D,
    ) -> Result<BTreeMap<Stage, LatencyHistogram>, D::Error> {
        use serde::Deserialize;
        let named = BTreeMap::<String, LatencyHistogram>::deserialize(d)?;
        named
            .into_iter()
            .map(|(k, v)| {
                Stage::ALL
                    .into_iter()
                    .find(|s| s.name() == k)
                    .map(|s| (s, v))
                    .ok_or_else(|| serde::de::Error::custom(format!("unknown stage {k:?}")))
            })
            .collect()
    }
}

/// A timecode saved as its label with rate and its sub-frames per frame (the label alone
/// does not say how many sub-frames a frame has).
#[derive(serde::Serialize, serde::Deserialize)]
struct TimecodeFile {
    timecode: String,
    subframes: u32,
}

impl TimecodeFile {
    fn new(tc: &Timecode) -> Self {
        Self {
            timecode: tc.to_string_with_rate(),
            subframes: tc.subframes,
        }
    }

    fn timecode<E: serde::de::Error>(&self) -> Result<Timecode, E> {
        let mut tc: Timecode = self.timecode.parse().map_err(E::custom)?;
        tc.subframes = self.subframes.max(1);
        Ok(tc)
    }
}

mod timecode_file {
    use super::{Timecode, TimecodeFile};

    pub fn serialize<S: serde::Serializer>(tc: &Option<Timecode>, s: S) -> Result<S::Ok, S::Error> {
        use serde::Serialize;
        tc.as_ref().map(TimecodeFile::new).serialize(s)
    }

    pub fn deserialize<'de, D: serde::Deserializer<'de>>(
        d: D,
    ) -> Result<Option<Timecode>, D::Error> {
        use serde::Deserialize;
        Option::<TimecodeFile>::deserialize(d)?
            .map(|f| f.timecode())
            .transpose()
    }
}

mod indexed_timecode_file {
    use super::{FrameIndex, Timecode, TimecodeFile};

    pub fn serialize<S: serde::Serializer>(
        tc: &Option<(FrameIndex, Timecode)>,
        s: S,
    ) -> Result<S::Ok, S::Error> {
        use serde::Serialize;
        tc.as_ref()
            .map(|(i, t)| (*i, TimecodeFile::new(t)))
            .serialize(s)
    }

    pub fn deserialize<'de, D: serde::Deserializer<'de>>(
        d: D,
    ) -> Result<Option<(FrameIndex, Timecode)>, D::Error> {
        use serde::Deserialize;
        Option::<(FrameIndex, TimecodeFile)>::deserialize(d)?
            .map(|(i, f)| f.timecode().map(|t| (i, t)))
            .transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frame `i` of a synthetic take: every third marker observed, the rest missing,
    /// latencies varying over three orders of magnitude, timecode with one jump.
    fn frame(i: usize) -> FrameResult {
        let image = crate::capture::GrayImage {
            width: 1,
            height: 1,
            data: vec![0],
        };
        let rate = crate::timecode::TimecodeRate::FPS_30;
        // A jump of 5 timecode frames at frame 40 (the first of the second chunk below).
        let tc = Timecode::from_frame_count(rate, 108_000 + i as u64 + if i >= 40 { 5 } else { 0 });
        let mut f = FrameResult::new(i.into(), 0, Some(tc), [image.clone(), image], 6);
        for (k, m) in f.markers.iter_mut().enumerate() {
            if (k + i).is_multiple_of(3) {
                m.status = BundleStatus::Observed;
            }
        }
        f.timings.set(Stage::Track, 0.05 * (1 + i % 50) as f64);
        f.timings.set(Stage::Solve, 2.0 + (i % 7) as f64);
        f
    }

    #[test]
    fn collectors_of_chunks_merge_into_the_single_pass_collector() {
        let latency = |i: usize| 0.1 + (i * 37 % 101) as f64;
        let mut single = MetricsCollector::new(6, 30.0, false);
        let mut chunks = [
            MetricsCollector::new(6, 30.0, false),
            MetricsCollector::new(6, 30.0, false),
        ];
        for i in 0..100 {
            let f = frame(i);
            single.frame_out(&f, latency(i), None);
            chunks[usize::from(i >= 40)].frame_out(&f, latency(i), None);
        }
        single.set_source_counts(100, 0, 0);
        chunks[0].set_source_counts(40, 0, 0);
        chunks[1].set_source_counts(60, 0, 0);
        // Through a file, as a chunk's take.json carries it.
        let saved: Vec<MetricsCollector> = chunks
            .iter()
            .map(|c| serde_json::from_str(&serde_json::to_string(c).unwrap()).unwrap())
            .collect();
        // (JSON keeps the sums to the last bit or two: means compare to 1e-12.)
        assert_eq!(saved[0].stages.keys().count(), chunks[0].stages.len());
        let mut merged = saved[0].clone();
        merged.merge(&saved[1]).unwrap();
        let (a, b) = (single.snapshot(1.0), merged.snapshot(1.0));
        assert_eq!(a.latency_ms.len(), 3);
        for (stage, x) in &a.latency_ms {
            let y = &b.latency_ms[stage];
            assert_eq!(
                (x.p50, x.p99, x.max, x.count),
                (y.p50, y.p99, y.max, y.count)
            );
            assert!((x.mean - y.mean).abs() <= 1e-12 * x.mean, "{stage}");
        }
        assert_eq!(a.labeling, b.labeling);
        assert_eq!(a.frames_in, b.frames_in);
        assert_eq!(a.frame_range, b.frame_range);
        assert_eq!(a.timecode, b.timecode);
        // The jump sits at the chunk boundary: the merge counts it as the single pass does.
        assert_eq!(a.warnings.timecode_jumps, 1);
        assert_eq!(a.warnings, b.warnings);
        // Out of order or overlapping chunks are refused.
        let mut wrong = saved[1].clone();
        assert!(wrong.merge(&saved[0]).is_err());
    }

    #[test]
    fn histogram_quantiles_within_a_bin() {
        let mut h = LatencyHistogram::default();
        for i in 1..=1000 {
            h.add(f64::from(i) * 0.01); // 0.01 .. 10 ms
        }
        let s = h.stats();
        assert!((s.mean - 5.005).abs() < 1e-9);
        assert!((s.p50 / 5.0 - 1.0).abs() < 0.02, "{}", s.p50);
        assert!((s.p99 / 9.9 - 1.0).abs() < 0.02, "{}", s.p99);
        assert_eq!(s.max, 10.0);
        assert_eq!(s.count, 1000);
        let empty = LatencyHistogram::default().stats();
        assert!(empty.p50.is_nan());
    }
}
