//! Logging to the rerun viewer (<https://rerun.io>): a live view while the pipeline runs, or
//! an `.rrd` recording to open later with the `rerun` command.
//!
//! # What is logged
//! Per frame, on the `frame` timeline (frame index), the `timecode` timeline (timecode
//! seconds since midnight, when the frame has a timecode) and the `capture_time` timeline
//! (the capture timestamp):
//!
//! | entity | archetype | content |
//! |---|---|---|
//! | `cam0/image`, `cam1/image` | `Image` | the camera images (every [`RerunParams::image_every`]-th frame, downscaled by [`RerunParams::image_downscale`]) |
//! | `cam0/markers`, `cam1/markers` | `Points2D` | labeled 2D markers (class id = marker index, labels from the annotation context) |
//! | `world/bundles_in_cam0` | `Points3D` | triangulated bundles in cam0, grey |
//! | `world/head` | `Transform3D` | head pose: `cam0_from_head` |
//! | `world/head/bundles` | `Points3D` | stabilized bundles in the head frame, coloured by confidence (red 0 … green 1) |
//! | `world/head/mesh` | `Mesh3D` | dense mesh positions (topology and UVs are static), vertex colours = error heat map when ground truth exists |
//! | `timings/<stage>` | `Scalars` | per-stage time, ms |
//! | `accuracy/vertex_error_mean_mm`, `…_max_mm` | `Scalars` | mesh error against ground truth, mm |
//! | `timecode` | `TextDocument` | the timecode as text (`01:00:00;12.1@29.97df`) |
//!
//! Static, once per session: the annotation context with the marker names (so 2D and 3D
//! points show their labels), `world` in OpenCV axes (x right, y down, z forward), the
//! camera frustums `world/cam0`, `world/cam1` when the rig is known, and the mesh topology.
//!
//! Lengths are millimetres. Pixels are given in the OpenCV convention (centre of the
//! top-left pixel at (0, 0)); rerun puts that centre at (0.5, 0.5), so 0.5 is added.
//!
//! # Entity that has no data in a frame
//! A marker, pose or mesh missing in a frame is cleared at that frame, so the viewer never
//! shows a stale value as if it were current. Skipped images (see `image_every`) are not
//! cleared: the last logged image stays visible.
//!
//! # Without the viewer SDK
//! The SDK is the default cargo feature `rerun`. A build without it
//! (`cargo build --no-default-features`: about 300 fewer crates to compile, for headless
//! servers and benchmarks) keeps every option, and [`RerunSink::new`] answers
//! [`RerunSinkError::NotBuilt`].

use std::path::PathBuf;

use nalgebra::{Isometry3, Point2, Point3};

use crate::camera::StereoRig;
use crate::capture::GrayImage;
use crate::frame_index::FrameIndex;
use crate::timecode::Timecode;

#[cfg(feature = "rerun")]
mod sdk;
#[cfg(feature = "rerun")]
pub use sdk::{RerunSink, confidence_colour, heat_colour};
#[cfg(not(feature = "rerun"))]
mod unavailable;
#[cfg(not(feature = "rerun"))]
pub use unavailable::RerunSink;

/// Application id of every helmcap recording (groups them in the viewer).
pub const APPLICATION_ID: &str = "helmcap";

/// Default gRPC address of a running viewer (`rerun` listens there by default).
pub const DEFAULT_VIEWER_URL: &str = "rerun+http://127.0.0.1:9876/proxy";

/// Where the log goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RerunTarget {
    /// Write an `.rrd` recording. It is streamed to a hidden sibling file and renamed into
    /// place when the sink finishes (or is dropped), so the path never holds a half-written
    /// file.
    File(PathBuf),
    /// Start a viewer (the `rerun` executable on `PATH`, from `pip install rerun-sdk`) and
    /// stream to it; reuses a viewer already listening on the default port.
    Spawn,
    /// Stream to a running viewer: a gRPC URL (`rerun+http://HOST:PORT/proxy`) or just
    /// `HOST:PORT`.
    Connect(String),
}

impl RerunTarget {
    /// The URL of a [`RerunTarget::Connect`] address: `HOST:PORT` becomes
    /// `rerun+http://HOST:PORT/proxy`; a full URL is kept.
    pub fn connect_url(address: &str) -> String {
        if address.contains("://") {
            address.to_string()
        } else {
            format!("rerun+http://{address}/proxy")
        }
    }
}

/// Options of the rerun sink. Every field has a documented default.
#[derive(Debug, Clone, PartialEq)]
pub struct RerunParams {
    /// Log the camera images of every Nth frame (1 = every frame, 0 = never). Markers,
    /// bundles and meshes are logged every frame regardless. Default 1.
    pub image_every: u32,
    /// Shrink the logged images by this integer factor (mean of `n × n` blocks; 1 = full
    /// resolution). The 2D markers are scaled to match. Default 1.
    pub image_downscale: u32,
    /// Mesh error (mm) at the top (red) of the heat map; 0 mm is blue. Default 2 mm.
    pub error_max_mm: f64,
    /// Log per-vertex normals with each mesh (smooth shading in the viewer). Default true.
    pub mesh_normals: bool,
    /// Radius of the 2D markers, pixels of the full-resolution image. Default 4 px.
    pub marker_radius_px: f32,
    /// Radius of the 3D bundles, mm. Default 1.5 mm.
    pub bundle_radius_mm: f32,
}

impl Default for RerunParams {
    fn default() -> Self {
        Self {
            image_every: 1,
            image_downscale: 1,
            error_max_mm: 2.0,
            mesh_normals: true,
            marker_radius_px: 4.0,
            bundle_radius_mm: 1.5,
        }
    }
}

impl RerunParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`RerunSinkError::Params`] naming the first bad field.
    pub fn validate(&self) -> Result<(), RerunSinkError> {
        let bad = |field: &str, why: &str| Err(RerunSinkError::Params(format!("{field}: {why}")));
        if self.image_downscale == 0 {
            return bad("image_downscale", "must be at least 1");
        }
        if !(self.error_max_mm.is_finite() && self.error_max_mm > 0.0) {
            return bad("error_max_mm", "must be a positive number of millimetres");
        }
        if !(self.marker_radius_px.is_finite() && self.marker_radius_px > 0.0) {
            return bad("marker_radius_px", "must be positive");
        }
        if !(self.bundle_radius_mm.is_finite() && self.bundle_radius_mm > 0.0) {
            return bad("bundle_radius_mm", "must be positive");
        }
        Ok(())
    }
}

/// An error of the rerun SDK, boxed so the error type exists in builds without it.
pub type SdkError = Box<dyn std::error::Error + Send + Sync>;

/// Errors of the rerun sink.
#[derive(Debug, thiserror::Error)]
pub enum RerunSinkError {
    /// A parameter is out of range.
    #[error("rerun sink parameters: {0}")]
    Params(String),
    /// The recording could not be started (file not creatable, viewer not found or not
    /// reachable).
    #[error("starting the rerun recording ({target}): {source}")]
    Start {
        /// What was being opened.
        target: String,
        /// The SDK's error.
        #[source]
        source: SdkError,
    },
    /// Data could not be serialized for logging.
    #[error("logging {entity} of frame {frame} to rerun: {source}")]
    Log {
        /// Frame index.
        frame: FrameIndex,
        /// Entity path.
        entity: String,
        /// The SDK's error.
        #[source]
        source: SdkError,
    },
    /// A frame's data does not fit the session (mesh size, marker index).
    #[error("rerun sink, frame {frame}: {message}")]
    Frame {
        /// Frame index.
        frame: FrameIndex,
        /// What is wrong.
        message: String,
    },
    /// This helmcap was built without the viewer SDK (cargo feature `rerun`).
    #[error(
        "rerun support is not built into this helmcap (it was compiled without the `rerun` \
         feature; rebuild with default features)"
    )]
    NotBuilt,
    /// Flushing or finalizing the recording failed.
    #[error("finishing the rerun recording: {0}")]
    Finish(String),
}

/// Triangle topology and texture coordinates of the dense mesh, logged once.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshTopology {
    /// Number of vertices every frame's positions must have.
    pub vertex_count: usize,
    /// Vertex indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex texture coordinates, when the mesh has UVs.
    pub vertex_uvs: Option<Vec<Point2<f64>>>,
}

impl MeshTopology {
    /// The triangulated topology and per-vertex UVs of `mesh`.
    pub fn of_mesh(mesh: &crate::mesh::Mesh) -> Self {
        Self {
            vertex_count: mesh.vertex_count(),
            triangles: mesh.triangles.clone(),
            vertex_uvs: mesh.vertex_uvs(),
        }
    }
}

/// What stays fixed over a session: logged once, as static data.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RerunSession {
    /// Recording name shown in the viewer (e.g. the session folder's name).
    pub name: String,
    /// Marker names in layout order; a marker's index is its class id.
    pub marker_names: Vec<String>,
    /// The stereo calibration, for the camera frustums.
    pub rig: Option<StereoRig>,
    /// Topology of the dense mesh, when meshes will be logged.
    pub mesh: Option<MeshTopology>,
}

/// A labeled 2D marker: index in the layout, pixel position (OpenCV convention).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerPixel {
    /// Marker index in the layout.
    pub marker: usize,
    /// Pixel position, OpenCV convention.
    pub pixel: Point2<f64>,
}

/// A labeled 3D bundle with its confidence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BundlePoint {
    /// Marker index in the layout.
    pub marker: usize,
    /// Position, mm (frame given by where the bundle is passed).
    pub position_mm: Point3<f64>,
    /// Confidence 0..1 (1 = certain).
    pub confidence: f64,
}

/// One frame's content, borrowed from the pipeline's frame result.
#[derive(Debug, Clone, Copy, Default)]
pub struct RerunFrame<'a> {
    /// Frame index.
    pub frame: FrameIndex,
    /// Capture timestamp, ns.
    pub timestamp_ns: u64,
    /// Timecode, when the source has one.
    pub timecode: Option<&'a Timecode>,
    /// The camera images (cam0, cam1), when available.
    pub images: [Option<&'a GrayImage>; 2],
    /// Labeled 2D markers per camera.
    pub markers: [&'a [MarkerPixel]; 2],
    /// Triangulated bundles in cam0, mm.
    pub bundles_in_cam0: &'a [BundlePoint],
    /// Stabilized bundles in the head frame, mm.
    pub bundles_in_head: &'a [BundlePoint],
    /// Head pose: maps head-frame points into cam0 (mm).
    pub cam0_from_head: Option<Isometry3<f64>>,
    /// Dense mesh vertex positions, head frame, mm.
    pub mesh_in_head: Option<&'a [Point3<f64>]>,
    /// Per-vertex distance to ground truth, mm (parallel to `mesh_in_head`; NaN where a
    /// vertex has none).
    pub vertex_error_mm: Option<&'a [f32]>,
    /// RMS distance of the observed bundles to ground truth, mm.
    pub bundle_error_rms_mm: Option<f64>,
    /// Time spent per stage, ms, by stage name.
    pub stage_ms: &'a [(&'a str, f64)],
}

/// Counts of what the sink logged.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RerunStats {
    /// Frames logged.
    pub frames: usize,
    /// Frames whose images were logged.
    pub image_frames: usize,
    /// Frames with a mesh.
    pub mesh_frames: usize,
}

/// Timeline of frame indices.
pub const TIMELINE_FRAME: &str = "frame";
/// Timeline of timecode seconds (since midnight).
pub const TIMELINE_TIMECODE: &str = "timecode";
/// Timeline of capture timestamps.
pub const TIMELINE_CAPTURE: &str = "capture_time";

/// The image shrunk by `factor` (mean of `factor × factor` blocks; a partial last row or
/// column of blocks is dropped), as `(width, height, pixels)`.
pub fn downscale(image: &GrayImage, factor: u32) -> (u32, u32, Vec<u8>) {
    if factor <= 1 {
        return (image.width, image.height, image.data.clone());
    }
    let (w, h) = (image.width / factor, image.height / factor);
    let f = factor as usize;
    let src_w = image.width as usize;
    let mut out = vec![0u8; w as usize * h as usize];
    let mut sums = vec![0u32; w as usize];
    let area = (f * f) as u32;
    for (y, out_row) in out.chunks_exact_mut(w as usize).enumerate() {
        sums.iter_mut().for_each(|s| *s = 0);
        let block_rows = image.data.get(y * f * src_w..).unwrap_or_default();
        for row in block_rows.chunks_exact(src_w).take(f) {
            for (s, block) in sums.iter_mut().zip(row.chunks_exact(f)) {
                *s += block.iter().map(|&v| u32::from(v)).sum::<u32>();
            }
        }
        for (o, &s) in out_row.iter_mut().zip(&sums) {
            *o = ((s + area / 2) / area) as u8;
        }
    }
    (w, h, out)
}
