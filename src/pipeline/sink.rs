//! The sink interface: where finished frames go (files, a viewer).

use std::path::PathBuf;
use std::sync::Arc;

use super::frame::FrameResult;
use super::metrics::Metrics;
use crate::camera::StereoRig;
use crate::dataset::MarkerLayout;
use crate::frame_index::FrameIndex;
use crate::mesh::Mesh;
use crate::timecode::TimecodeRate;

/// What every sink may want to know about the take before the first frame.
#[derive(Debug, Clone)]
pub struct SessionMeta {
    /// Name of the take (the session folder's name for a replay).
    pub name: String,
    /// Camera frames per second.
    pub fps: f64,
    /// Timecode rate, when the source stamps frames with timecode.
    pub timecode_rate: Option<TimecodeRate>,
    /// Index of the first frame the source will deliver.
    pub first_frame: FrameIndex,
    /// Frames the source will deliver, when known (a replay).
    pub frame_count: Option<usize>,
    /// The marker layout: [`FrameResult::markers`] is in this order.
    pub layout: Arc<MarkerLayout>,
    /// Each layout marker's neutral position, head frame, mm.
    pub neutral_markers_head: Arc<Vec<nalgebra::Point3<f64>>>,
    /// The dataset's neutral mesh (topology and UVs of [`FrameResult::mesh`]), when the
    /// pipeline solves meshes.
    pub neutral: Option<Arc<Mesh>>,
    /// Face vertices of the neutral (the rest are eyes, teeth, ...).
    pub face_vertices: Option<std::ops::RangeInclusive<u32>>,
    /// The stereo rig.
    pub rig: Option<StereoRig>,
    /// Image size, pixels (width, height).
    pub image_size: Option<(u32, u32)>,
}

/// Errors of a sink; the pipeline stops at the first one and names the sink and frame.
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
    /// A file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// Anything else (a viewer connection, invalid data for the format).
    #[error("{0}")]
    Other(String),
}

impl SinkError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SinkError::Io {
            path: path.into(),
            source,
        }
    }
}

/// A consumer of finished frames. The pipeline calls [`Sink::begin`] once before the first
/// frame, [`Sink::write`] once per frame in frame order, and [`Sink::finish`] once at the
/// end of the take, also when the take stopped early on an error or Ctrl-C: a sink must
/// leave valid files for the frames it was given. All calls come from the pipeline's
/// sink thread (`helmcap:sinks`).
pub trait Sink: Send {
    /// Short name for messages (`bundles.csv`, `usd`, `rerun`).
    fn name(&self) -> &str;
    /// Called before the first frame.
    ///
    /// # Errors
    /// [`SinkError`] stops the take before it starts.
    fn begin(&mut self, session: &SessionMeta) -> Result<(), SinkError>;
    /// Called for each frame, in order.
    ///
    /// # Errors
    /// [`SinkError`] stops the take (the message names the sink and frame).
    fn write(&mut self, frame: &FrameResult) -> Result<(), SinkError>;
    /// Called once at the end with the take's metrics: flush and close.
    ///
    /// # Errors
    /// [`SinkError`] is reported after the take.
    fn finish(&mut self, metrics: &Metrics) -> Result<(), SinkError>;
}
