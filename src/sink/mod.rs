//! Sinks: where finished frames go. The CSV outputs (`bundles.csv`, `head_pose.csv`,
//! `tracks.csv`), `metrics.json`, mesh sequences (OBJ, PLY), USD (`mesh.usda`) and C3D
//! (`bundles.c3d`); every file is published atomically, also when a take stops early.
//! [`rerun`] logs frames to the rerun viewer or an `.rrd` recording.
//! Each sink implements [`crate::pipeline::Sink`].
//!
//! Depends on [`crate::pipeline`] (frame and sink types), [`crate::mesh`],
//! [`crate::camera`], [`crate::capture`], [`crate::timecode`].

pub mod animation;
pub mod c3d;
pub mod csv;
pub mod mesh;
pub mod rerun;
pub mod staged_file;
pub mod take_dir;
pub mod usd;
pub mod usd_read;
pub mod usd_skel;

pub use animation::{AnimationOutputs, AnimationSink, AnimationSummary, AnimationWriter};
pub use c3d::{C3dPart, C3dSink, join_c3d};
pub use csv::{CsvSink, MetricsSink};
pub use mesh::{MeshFormat, MeshSequenceSink};
pub use rerun::{RerunParams, RerunSink, RerunSinkError, RerunTarget};
pub use staged_file::StagedFile;
pub use take_dir::{TakeDir, TakeDirError};
pub use usd::{UsdSink, join_layers};
pub use usd_read::{UsdMeshSequence, UsdReadError, read_usda_sequence};
