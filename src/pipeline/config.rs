//! [`PipelineConfig`]: everything a take needs besides its source and sinks, one part per
//! stage ([`TrackConfig`], the stabilizer's parameters, [`SolveConfig`], the enhancer, the
//! rig solver), the channels ([`ChannelConfig`]) and what the sinks are told of the take
//! ([`TakeInfo`]).

use std::sync::Arc;

use nalgebra::{Point3, Vector3};

use super::truth::GroundTruth;
use crate::align::StabilizeParams;
use crate::animation::RigSolver;
use crate::camera::StereoRig;
use crate::dataset::MarkerLayout;
use crate::enhance::Enhancer;
use crate::frame_index::FrameIndex;
use crate::mesh::Mesh;
use crate::solve::Solver;
use crate::timecode::TimecodeRate;
use crate::track::{DetectParams, LabelParams};

/// Everything a take needs besides its source and sinks.
pub struct PipelineConfig {
    /// The marker layout ([`super::FrameResult::markers`] is in its order).
    pub layout: Arc<MarkerLayout>,
    /// Each layout marker's neutral position, head frame, mm.
    pub neutral_markers_head: Arc<Vec<Point3<f64>>>,
    /// The stereo rig (the source's calibration, or one given on the command line).
    pub rig: StereoRig,
    /// The track stage: detection and labeling.
    pub track: TrackConfig,
    /// The stabilize stage: head pose by robust Horn.
    pub stabilize: StabilizeParams,
    /// The solve stage: dense reconstruction and gap filling.
    pub solve: SolveConfig,
    /// The enhance stage: detail enhancement of the solved mesh; None: off.
    pub enhancer: Option<Arc<Enhancer>>,
    /// The rig stage: rig weights of every solved (and enhanced) mesh
    /// ([`super::FrameResult::rig_fit`], which the animation sinks write); None: off.
    pub rig_solver: Option<RigSolver>,
    /// Ground truth, for accuracy figures.
    pub ground_truth: Option<Arc<GroundTruth>>,
    /// The channels between the stages.
    pub channels: ChannelConfig,
    /// What the sinks are told of the take, and which frames they get.
    pub take: TakeInfo,
}

impl PipelineConfig {
    /// A configuration with default parameters, bundles only (no solve, no enhance).
    pub fn new(
        layout: Arc<MarkerLayout>,
        neutral_markers_head: Arc<Vec<Point3<f64>>>,
        rig: StereoRig,
    ) -> Self {
        Self {
            layout,
            neutral_markers_head,
            rig,
            track: TrackConfig::default(),
            stabilize: StabilizeParams::default(),
            solve: SolveConfig::default(),
            enhancer: None,
            rig_solver: None,
            ground_truth: None,
            channels: ChannelConfig::default(),
            take: TakeInfo::default(),
        }
    }
}

/// The track stage's settings.
#[derive(Debug, Clone, Default)]
pub struct TrackConfig {
    /// Marker detection. Default [`DetectParams::default`].
    pub detect: DetectParams,
    /// Labeling. Default [`LabelParams::default`].
    pub label: LabelParams,
    /// Expressions labeling may find the face in when it starts from nothing: marker
    /// positions (head frame, layout order) per expression, e.g. from
    /// [`MarkerLayout::expression_templates`]. Default none (the neutral only).
    pub expression_templates: Arc<Vec<Vec<Point3<f64>>>>,
    /// The skin's normal at each marker on the neutral face (head frame, layout order),
    /// e.g. from [`MarkerLayout::neutral_normals`]: labeling then refuses blobs much
    /// thinner than a marker's dot can look ([`LabelParams::min_roundness_ratio`]).
    /// Default none (no roundness check).
    pub marker_normals: Arc<Vec<Vector3<f64>>>,
    /// Frames on which labeling starts again from nothing (a fresh labeler, as at the
    /// start of the take); None: never. Default None.
    ///
    /// A farm chunk starts labeling from nothing at its warm-up's first frame, and the
    /// labeler's state (which markers it tracks) depends on every frame before: the
    /// restarts of a chunked take, done in one pass too, make that pass write exactly
    /// what the merged chunks write (see `farm job`).
    pub label_restarts: Option<LabelRestarts>,
}

/// The frames on which labeling starts again from nothing
/// ([`TrackConfig::label_restarts`]): every frame `f` with `f % every == at`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LabelRestarts {
    /// Period, frames (at least 1).
    pub every: u64,
    /// Phase, frames (below `every`).
    pub at: u64,
}

impl LabelRestarts {
    /// The restarts of a take chunked from frame `first` into chunks of `chunk` frames,
    /// each warmed up by `warm_up` frames: the frames `first + k·chunk − warm_up`, where
    /// the chunks' warm-ups start. `None` for a chunk size of 0.
    pub fn of_chunks(first: FrameIndex, chunk: u64, warm_up: u64) -> Option<Self> {
        (chunk > 0).then(|| Self {
            every: chunk,
            at: (first.get() % chunk + chunk - warm_up % chunk) % chunk,
        })
    }

    /// Whether labeling restarts on frame `index`.
    pub fn restarts_at(&self, index: FrameIndex) -> bool {
        self.every > 0 && index.get() % self.every == self.at
    }
}

/// The solve stage's settings.
pub struct SolveConfig {
    /// Dense reconstruction; None: bundles only (the stage passes frames on).
    pub solver: Option<Solver>,
    /// The dataset's neutral mesh (topology and UVs for the mesh sinks). Default None.
    pub neutral: Option<Arc<Mesh>>,
    /// Face vertices of the neutral (for accuracy figures). Default None.
    pub face_vertices: Option<std::ops::RangeInclusive<u32>>,
    /// The solve forgets the previous frame's choices (LGI's temporal preference, §5.1)
    /// on every frame whose index is a multiple of this; 0: never. Default 30.
    ///
    /// The preference makes each frame's solve depend on every frame before it, so a
    /// chunk of a take started anywhere else than frame 0 could settle a near-tie
    /// differently from a single pass. Forgetting at fixed frame numbers bounds that
    /// memory: a chunk warmed up past such a frame solves exactly as the single pass
    /// does. Half a second at 60 fps keeps the preference's purpose (no flicker between
    /// near-equal candidates from frame to frame).
    pub keyframe_interval: usize,
    /// Gap-filled bundles: confidence halves every this many frames since the marker was
    /// last observed, and is 0 after [`GAP_FILL_MEMORY_HALF_LIVES`] half-lives. Default 15.
    pub gap_fill_half_life_frames: f64,
}

impl Default for SolveConfig {
    fn default() -> Self {
        Self {
            solver: None,
            neutral: None,
            face_vertices: None,
            keyframe_interval: 30,
            gap_fill_half_life_frames: 15.0,
        }
    }
}

/// Half-lives after which a gap-filled bundle's confidence drops to 0 (1/16 before).
pub const GAP_FILL_MEMORY_HALF_LIVES: f64 = 4.0;

/// The channels between the stages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelConfig {
    /// Frames each channel holds. Default 4: enough to absorb jitter between stages,
    /// small enough to keep latency and memory (two images per frame) bounded.
    pub capacity: usize,
    /// Frames a live source may have waiting at the pipeline's entrance. Default 1: when
    /// the first stage is still busy with an earlier frame (the face acquisition at the
    /// start, a slow frame), a newer frame than the one waiting is dropped at the source
    /// and counted, so the pipeline does not work through a backlog of stale frames and
    /// its latency recovers within a frame. Replays ignore it (they never drop).
    pub live_entry_capacity: usize,
    /// Frames a replay's source may have decoded ahead of the track stage. Default 16
    /// (two images each: 42 MB at 1280×1024): the source decodes at a lower priority
    /// than the track stage (see the pipeline's thread priorities) and catches up while
    /// the track stage leaves a core idle, so a deeper queue lets it ride out the frames
    /// where it gets less of the cores. On the 480-frame cluttered take, 112-115 frames/s
    /// at the default channel capacity of 4 and 116-118 at 16 (four alternated pairs).
    /// Never below `capacity` (`helmcap replay` sets four times `--queue`).
    pub replay_entry_capacity: usize,
}

impl Default for ChannelConfig {
    fn default() -> Self {
        Self {
            capacity: 4,
            live_entry_capacity: 1,
            replay_entry_capacity: 16,
        }
    }
}

/// What the sinks are told of the take, and which frames they get.
#[derive(Debug, Clone, PartialEq)]
pub struct TakeInfo {
    /// Name of the take. Default `take`.
    pub name: String,
    /// Timecode rate of the source, when known. Default None.
    pub timecode_rate: Option<TimecodeRate>,
    /// Index of the first frame the sinks get. Default 0.
    pub first_frame: FrameIndex,
    /// Frames the sinks will get, when known (for sinks and progress). Default None.
    pub frame_count: Option<usize>,
    /// Frames before this index are warm-up: they go through every stage (the labeler,
    /// the stabilizer's held pose and the solver's temporal preference learn from them)
    /// but reach no sink and count in no metric but `warm_up_frames`. A chunk of a long
    /// take uses it to start where a single pass would be. Default 0 (none).
    pub write_from: FrameIndex,
}

impl Default for TakeInfo {
    fn default() -> Self {
        Self {
            name: "take".into(),
            timecode_rate: None,
            first_frame: FrameIndex::new(0),
            frame_count: None,
            write_from: FrameIndex::new(0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn label_restarts_fall_where_chunks_start_their_warm_up() {
        // Chunks of 600 from frame 0, 60 of warm-up: warm-ups start at 540, 1140, ...
        let r = LabelRestarts::of_chunks(FrameIndex::new(0), 600, 60).unwrap();
        let hits: Vec<u64> = (0..2000)
            .filter(|&f| r.restarts_at(FrameIndex::new(f)))
            .collect();
        assert_eq!(hits, [540, 1140, 1740]);
        // A take starting at frame 1000, chunks of 80, warm-up 60: 1020, 1100, ...
        let r = LabelRestarts::of_chunks(FrameIndex::new(1000), 80, 60).unwrap();
        let hits: Vec<u64> = (1000..1200)
            .filter(|&f| r.restarts_at(FrameIndex::new(f)))
            .collect();
        assert_eq!(hits, [1020, 1100, 1180]);
        // A warm-up longer than a chunk: the same residue.
        let r = LabelRestarts::of_chunks(FrameIndex::new(0), 50, 120).unwrap();
        let at = |f: u64| r.restarts_at(FrameIndex::new(f));
        assert!(at(30) && at(80) && !at(0));
        assert_eq!(LabelRestarts::of_chunks(FrameIndex::new(0), 0, 60), None);
    }
}
