//! USD export: one `mesh.usda` (USD's text format) holding the face as one `Mesh` prim
//! with the neutral's topology (`faceVertexCounts`, `faceVertexIndices`), its UVs
//! (`primvars:st`, face-varying, indexed) and the solved positions as time samples of
//! `points`, one per frame at time code = frame index. Stage metadata: `metersPerUnit =
//! 0.001` (millimetres), `upAxis = "Y"` (the head frame's up), `timeCodesPerSecond` = the
//! camera rate, `startTimeCode`/`endTimeCode` = the first and last frame written, and the
//! timecode of the first and last frame (with rate) in `customLayerData`.
//!
//! The head pose moves the whole face: `/Face` is an `Xform` with a time-sampled
//! `xformOp:transform`, the head's pose relative to the first frame that has one
//! (`first_from_head`, identity on that frame; the mesh points are in the head frame), so
//! that a DCC tool plays the stabilized face with the head's motion put back. Frames
//! without a pose (labels lost) have no sample: USD holds the neighbouring ones.
//!
//! Streaming, in place: [`Sink::begin`] writes the file's start (a fixed-size room for
//! the layer metadata, topology, UVs, rest points) and its end; each frame's points are
//! written before the end, so the temporary file (beside `mesh.usda`) is a complete layer
//! after every frame. [`Sink::finish`] writes the metadata into its room and publishes the
//! file atomically. No mesh is kept in memory, and no step needs more disk space than the
//! frames themselves: when a write fails (disk full), the file goes back to the last
//! complete frame and is published with the frames before it. The head-pose samples (a
//! few hundred bytes a frame) are kept in memory and written at the end of the take,
//! after the mesh; a layer cut short by a crash has the meshes without them (the poses
//! are in `head_pose.csv` too).

use std::fmt::Write as _;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::staged_file::StagedFile;
use crate::mesh::Mesh;
use crate::pipeline::{FrameResult, Metrics, SessionMeta, Sink, SinkError};
use crate::timecode::Timecode;
use nalgebra::Isometry3;

/// Writes `mesh.usda` (see the module docs).
#[derive(Debug)]
pub struct UsdSink {
    path: PathBuf,
    fps: f64,
    neutral: Option<Arc<Mesh>>,
    file: Option<StagedFile>,
    first: Option<(usize, Option<Timecode>)>,
    last: Option<(usize, Option<Timecode>)>,
    frames: usize,
    /// The inverse of the first head pose (`head → cam0`) of the take.
    head_origin: Option<Isometry3<f64>>,
    /// Per written frame with a head pose: (frame index, `first_from_head`).
    head_poses: Vec<(usize, Isometry3<f64>)>,
}

/// Bytes reserved at the start of the file for the layer metadata (written at the end of
/// the take, padded with blanks).
const META_BYTES: usize = 2048;

/// The end of the file after the last time sample: [`MESH_END`], then the end of `/Face`.
const TAIL: &str = "\n        }\n        uniform token subdivisionScheme = \"none\"\n    }\n}\n";

/// The end of the mesh prim after the last time sample (the start of [`TAIL`]).
const MESH_END: &str = "\n        }\n        uniform token subdivisionScheme = \"none\"\n    }\n";

/// Longest `stopped` reason quoted in the metadata, characters.
const MAX_STOPPED_CHARS: usize = 600;

impl UsdSink {
    /// A sink writing `path` (e.g. `<out>/mesh.usda`).
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            fps: 0.0,
            neutral: None,
            file: None,
            first: None,
            last: None,
            frames: 0,
            head_origin: None,
            head_poses: Vec::new(),
        }
    }
}

/// A float in USD text: shortest round-trip form of the `f32` (USD `point3f` is 32-bit).
fn f(x: f64) -> String {
    let v = x as f32;
    if v == v.trunc() && v.abs() < 1e9 {
        format!("{v:.1}")
    } else {
        format!("{v}")
    }
}

fn write_points(out: &mut String, points: &[nalgebra::Point3<f64>]) {
    out.push('[');
    for (i, p) in points.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        let _ = write!(out, "({}, {}, {})", f(p.x), f(p.y), f(p.z));
    }
    out.push(']');
}

/// A string literal for USD (quotes and backslashes escaped).
fn quoted(s: &str) -> String {
    format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""))
}

impl Sink for UsdSink {
    fn name(&self) -> &str {
        "usd"
    }

    fn begin(&mut self, session: &SessionMeta) -> Result<(), SinkError> {
        let neutral = session.neutral.clone().ok_or_else(|| {
            SinkError::Other("USD export needs a dataset to solve meshes with".into())
        })?;
        if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| SinkError::io(dir, e))?;
        }
        self.fps = session.fps;
        let mut file = StagedFile::create(&self.path)?;
        let meta = self.metadata(None)?;
        let body = mesh_body(&neutral);
        file.write_with(|w| {
            w.write_all(meta.as_bytes())?;
            w.write_all(body.as_bytes())?;
            w.write_all(TAIL.as_bytes())
        })?;
        file.mark_complete()?;
        back_over_tail(&mut file)?;
        self.file = Some(file);
        self.neutral = Some(neutral);
        Ok(())
    }

    fn write(&mut self, fr: &FrameResult) -> Result<(), SinkError> {
        let (Some(mesh), Some(file)) = (&fr.mesh, &mut self.file) else {
            return Ok(());
        };
        let mut line = String::with_capacity(mesh.len() * 32 + 16 + TAIL.len());
        if self.frames > 0 {
            line.push_str(",\n");
        }
        let _ = write!(line, "            {}: ", fr.index);
        write_points(&mut line, mesh);
        line.push_str(TAIL);
        let result = file
            .write_with(|w| w.write_all(line.as_bytes()))
            .and_then(|()| file.mark_complete());
        if let Err(e) = result {
            if let Err(r) = roll_back(file) {
                tracing::error!(
                    "{}: cannot go back to the last frame: {r}",
                    self.path.display()
                );
                // Unpublishable: dropping the staged file removes it.
                self.file = None;
            }
            return Err(e);
        }
        back_over_tail(file)?;
        if let Some(pose) = &fr.cam0_from_head {
            let origin = *self.head_origin.get_or_insert_with(|| pose.inverse());
            self.head_poses.push((fr.index, origin * pose));
        }
        self.first.get_or_insert((fr.index, fr.timecode));
        self.last = Some((fr.index, fr.timecode));
        self.frames += 1;
        Ok(())
    }

    fn finish(&mut self, metrics: &Metrics) -> Result<(), SinkError> {
        let Some(mut file) = self.file.take() else {
            return Ok(());
        };
        let meta = self.metadata(metrics.stopped.as_deref())?;
        if !self.head_poses.is_empty() {
            // The head pose replaces the end: the file grows by the samples. Without room
            // for them the take keeps its meshes (the poses are in head_pose.csv).
            let end = head_pose_tail(&self.head_poses);
            let written = file
                .write_with(|w| w.write_all(end.as_bytes()))
                .and_then(|()| file.mark_complete());
            if let Err(e) = written {
                tracing::warn!(
                    "{}: head pose not written ({e}); the meshes are kept",
                    self.path.display()
                );
                roll_back(&mut file)?;
            }
        }
        // The metadata goes into its room at the start: no new space is needed.
        file.write_with(|w| {
            w.seek(SeekFrom::Start(0))?;
            w.write_all(meta.as_bytes())
        })?;
        file.commit()
    }
}

/// The end of the file with the head pose: the mesh closed as [`TAIL`] closes it, then
/// the `/Face` prim's transform samples.
fn head_pose_tail(poses: &[(usize, Isometry3<f64>)]) -> String {
    let mut end = String::with_capacity(poses.len() * 160 + 256);
    end.push_str(MESH_END);
    end.push_str("    matrix4d xformOp:transform.timeSamples = {\n");
    for (index, pose) in poses {
        let _ = writeln!(end, "        {index}: {},", usd_matrix(pose));
    }
    end.push_str("    }\n    uniform token[] xformOpOrder = [\"xformOp:transform\"]\n}\n");
    end
}

/// Back to the last complete frame after a failed write: the file is cut there and its end
/// ([`TAIL`], whose bytes are on disk already: no new space) written again.
fn roll_back(file: &mut StagedFile) -> Result<(), SinkError> {
    file.roll_back()?;
    let end = file.complete_len().unwrap_or(0);
    file.write_with(|w| {
        w.seek(SeekFrom::Start(end.saturating_sub(TAIL.len() as u64)))?;
        w.write_all(TAIL.as_bytes())?;
        w.flush()
    })?;
    back_over_tail(file)
}

/// Puts the writer back before [`TAIL`] (the next frame overwrites it).
fn back_over_tail(file: &mut StagedFile) -> Result<(), SinkError> {
    let end = file.complete_len().unwrap_or(0);
    file.write_with(|w| {
        w.seek(SeekFrom::Start(end.saturating_sub(TAIL.len() as u64)))
            .map(drop)
    })
}

/// The prims: topology, rest points, UVs, and the opening of `points.timeSamples`.
fn mesh_body(neutral: &Mesh) -> String {
    let mut head = String::new();
    let _ = writeln!(
        head,
        "def Xform \"Face\" (\n    kind = \"component\"\n)\n{{"
    );
    let _ = writeln!(head, "    def Mesh \"face\"\n    {{");
    let counts: Vec<String> = neutral.faces().map(|p| p.len().to_string()).collect();
    let _ = writeln!(
        head,
        "        int[] faceVertexCounts = [{}]",
        counts.join(", ")
    );
    let indices: Vec<String> = neutral.face_vertices.iter().map(u32::to_string).collect();
    let _ = writeln!(
        head,
        "        int[] faceVertexIndices = [{}]",
        indices.join(", ")
    );
    let _ = writeln!(head, "        uniform token orientation = \"rightHanded\"");
    if let Some((lo, hi)) = neutral.bounding_box() {
        let _ = writeln!(
            head,
            "        float3[] extent = [({}, {}, {}), ({}, {}, {})]",
            f(lo.x),
            f(lo.y),
            f(lo.z),
            f(hi.x),
            f(hi.y),
            f(hi.z)
        );
    }
    let mut rest = String::new();
    write_points(&mut rest, &neutral.positions);
    let _ = writeln!(head, "        point3f[] points = {rest}");
    if neutral.has_uvs() {
        let uvs: Vec<String> = neutral
            .uvs
            .iter()
            .map(|t| format!("({}, {})", f(t.x), f(t.y)))
            .collect();
        let _ = writeln!(
            head,
            "        texCoord2f[] primvars:st = [{}] (\n            interpolation = \"faceVarying\"\n        )",
            uvs.join(", ")
        );
        let uv_indices: Vec<String> = neutral.face_uvs.iter().map(u32::to_string).collect();
        let _ = writeln!(
            head,
            "        int[] primvars:st:indices = [{}]",
            uv_indices.join(", ")
        );
    }
    let _ = writeln!(head, "        point3f[] points.timeSamples = {{");
    head
}

/// A rigid transform as a USD `matrix4d` literal: row-vector convention (a point is
/// `p' = p · M`), so the rotation is transposed and the translation is the last row.
pub(crate) fn usd_matrix(pose: &Isometry3<f64>) -> String {
    let m = pose.to_homogeneous();
    let mut out = String::from("(");
    for row in 0..4 {
        if row > 0 {
            out.push_str(", ");
        }
        let _ = write!(
            out,
            "({}, {}, {}, {})",
            m[(0, row)],
            m[(1, row)],
            m[(2, row)],
            m[(3, row)]
        );
    }
    out.push(')');
    out
}

impl UsdSink {
    /// Test aid: what a failing write leaves (part of a frame in the file), then the
    /// roll-back the sink does on a failure.
    #[cfg(test)]
    pub(crate) fn simulate_failed_write(&mut self) {
        if let Some(file) = self.file.as_mut() {
            let junk = vec![b'7'; 5000];
            file.write_with(|w| w.write_all(&junk)).ok();
            roll_back(file).ok();
        }
    }

    /// The layer header and metadata, padded with blanks to exactly [`META_BYTES`].
    fn metadata(&self, stopped: Option<&str>) -> Result<String, SinkError> {
        let (start, end) = match (self.first, self.last) {
            (Some((a, _)), Some((b, _))) => (a, b),
            _ => (0, 0),
        };
        let mut head = String::new();
        let _ = writeln!(head, "#usda 1.0\n(");
        let _ = writeln!(head, "    customLayerData = {{");
        let _ = writeln!(
            head,
            "        string creator = \"helmcap {}\"",
            env!("CARGO_PKG_VERSION")
        );
        let _ = writeln!(head, "        int frames = {}", self.frames);
        if let (Some((_, Some(a))), Some((_, Some(b)))) = (self.first, self.last) {
            let _ = writeln!(
                head,
                "        string timecodeRate = {}",
                quoted(&a.rate.to_string())
            );
            let _ = writeln!(
                head,
                "        string timecodeStart = {}",
                quoted(&a.to_string_with_rate())
            );
            let _ = writeln!(
                head,
                "        string timecodeEnd = {}",
                quoted(&b.to_string_with_rate())
            );
        }
        if let Some(reason) = stopped {
            let short: String = reason
                .chars()
                .take(MAX_STOPPED_CHARS)
                .map(|c| if c.is_control() { ' ' } else { c })
                .collect();
            let _ = writeln!(head, "        string stopped = {}", quoted(&short));
        }
        let _ = writeln!(head, "    }}");
        let _ = writeln!(head, "    defaultPrim = \"Face\"");
        let _ = writeln!(head, "    endTimeCode = {end}");
        let _ = writeln!(head, "    metersPerUnit = 0.001");
        let _ = writeln!(head, "    startTimeCode = {start}");
        let _ = writeln!(head, "    timeCodesPerSecond = {}", f(self.fps));
        let _ = writeln!(head, "    framesPerSecond = {}", f(self.fps));
        let _ = writeln!(head, "    upAxis = \"Y\"");
        let close = ")\n\n";
        if head.len() + close.len() > META_BYTES {
            return Err(SinkError::Other(format!(
                "{}: the layer metadata takes {} bytes, {META_BYTES} are reserved",
                self.path.display(),
                head.len()
            )));
        }
        // Blanks inside the metadata's parentheses are white space to USD.
        let pad = META_BYTES - head.len() - close.len();
        head.extend(std::iter::repeat_n(' ', pad.saturating_sub(1)));
        if pad > 0 {
            head.push('\n');
        }
        head.push_str(close);
        Ok(head)
    }
}
