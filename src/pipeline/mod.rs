//! The streaming pipeline: stage threads joined by bounded channels, from a frame source
//! to the sinks (DESIGN.md §1).
//!
//! ```text
//! source ─> track (detect cam0 ∥ cam1, label, triangulate) ─> stabilize (robust Horn)
//!        ─> solve (LGI) ─> [enhance] ─> [rig weights]
//!        ─> sinks (CSV, meshes, C3D, rig weights, viewer, metrics)
//! ```
//!
//! Each stage runs on its own named thread (`helmcap:<stage>`) and passes one envelope,
//! [`FrameResult`], through bounded crossbeam channels; each stage fills its part and
//! records its time; every stage between the source and the sinks runs the same loop
//! (receive, time the work, record a failure as the take's error, send on). Detection of the two cameras runs in parallel (`rayon::join`) inside
//! the track stage, which also feeds the labeler's predicted regions of interest back to
//! the detector for the next frame (same thread: no race, no stale region). In a replay
//! the other stages run at lower priorities than the track stage, the one that sets the
//! pace, so that they fill the cores it leaves idle ([`priority`]).
//!
//! # Ordering and backpressure
//! Frames stay in source order (every stage is one thread, every channel FIFO). A replay
//! ([`crate::capture::FrameSource::is_live`] false) blocks on a full channel and never
//! drops a frame. A live source must not be blocked: when the first channel is full the
//! frame is dropped at the source and counted ([`Metrics::frames_dropped`]).
//!
//! # Shutdown
//! At the end of input the source thread returns, its channel disconnects, and each stage
//! drains its input and returns in turn; the sink thread then calls [`Sink::finish`] on
//! every sink. Setting the stop flag (Ctrl-C) makes the source stop at the next frame, and
//! the same orderly shutdown follows. A stage error stops that stage; the stages before it
//! see their output disconnect and stop, the stages after it drain what they already
//! have, and the sinks are finished, so every file written so far stays valid; [`run`]
//! then returns the error naming the stage and frame.
//!
//! Depends on every stage module ([`crate::capture`], [`crate::track`],
//! [`crate::stereo`], [`crate::align`], [`crate::solve`], [`crate::enhance`],
//! [`crate::animation`]).

mod config;
pub mod frame;
pub mod metrics;
mod priority;
mod run;
pub mod sink;
pub mod sources;
pub mod truth;

use crate::frame_index::FrameIndex;

pub use config::{
    ChannelConfig, GAP_FILL_MEMORY_HALF_LIVES, LabelRestarts, PipelineConfig, SolveConfig,
    TakeInfo, TrackConfig,
};
pub use frame::{BundleStatus, FrameResult, LabelCounts, MarkerResult, Stage, StageTimings};
pub use metrics::{
    AccuracyMetrics, GapMetrics, LabelingMetrics, LatencyHistogram, LatencyStats, Metrics,
    MetricsCollector, TimecodeRange,
};
pub use run::run;
pub use sink::{SessionMeta, Sink, SinkError};
pub use truth::GroundTruth;

/// Errors of a pipeline run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PipelineError {
    /// A stage failed on a frame.
    #[error("stage {stage} failed{}: {message}", frame.map(|f| format!(" at frame {f}")).unwrap_or_default())]
    Stage {
        /// The stage.
        stage: Stage,
        /// The frame, when the failure concerns one.
        frame: Option<FrameIndex>,
        /// What went wrong.
        message: String,
    },
    /// A sink failed on a frame (or at begin/finish).
    #[error("sink {sink} failed{}: {message}", frame.map(|f| format!(" at frame {f}")).unwrap_or_default())]
    Sink {
        /// The sink's name.
        sink: String,
        /// The frame, when the failure concerns one.
        frame: Option<FrameIndex>,
        /// What went wrong.
        message: String,
    },
    /// The configuration cannot run.
    #[error("pipeline configuration: {0}")]
    Config(String),
    /// A stage thread could not start or ended abnormally.
    #[error("pipeline thread {0}")]
    Thread(String),
}
