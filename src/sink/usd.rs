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
            self.head_poses.push((fr.index.as_usize(), origin * pose));
        }
        // USD time codes are the frame numbers.
        self.first.get_or_insert((fr.index.as_usize(), fr.timecode));
        self.last = Some((fr.index.as_usize(), fr.timecode));
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
        let timecodes = match (self.first, self.last) {
            (Some((_, Some(a))), Some((_, Some(b)))) => Some([
                a.rate.to_string(),
                a.to_string_with_rate(),
                b.to_string_with_rate(),
            ]),
            _ => None,
        };
        layer_metadata(
            &LayerMeta {
                frames: self.frames,
                start,
                end,
                fps: self.fps,
                timecodes,
            },
            stopped,
        )
        .map_err(|len| {
            SinkError::Other(format!(
                "{}: the layer metadata takes {len} bytes, {META_BYTES} are reserved",
                self.path.display()
            ))
        })
    }
}

/// What the layer metadata says.
#[derive(Debug, Clone, PartialEq)]
struct LayerMeta {
    /// Frames with a mesh.
    frames: usize,
    /// First and last frame with a mesh (`startTimeCode`, `endTimeCode`).
    start: usize,
    end: usize,
    /// Camera rate (`timeCodesPerSecond`, `framesPerSecond`).
    fps: f64,
    /// Timecode rate, first and last frame's timecode (with rate), when the take has them.
    timecodes: Option<[String; 3]>,
}

/// The layer header and metadata padded with blanks to exactly [`META_BYTES`]; `Err` with
/// the length needed when they do not fit.
fn layer_metadata(meta: &LayerMeta, stopped: Option<&str>) -> Result<String, usize> {
    let LayerMeta {
        frames,
        start,
        end,
        fps,
        ..
    } = *meta;
    let mut head = String::new();
    let _ = writeln!(head, "#usda 1.0\n(");
    let _ = writeln!(head, "    customLayerData = {{");
    let _ = writeln!(
        head,
        "        string creator = \"helmcap {}\"",
        env!("CARGO_PKG_VERSION")
    );
    let _ = writeln!(head, "        int frames = {frames}");
    if let Some([rate, first, last]) = &meta.timecodes {
        let _ = writeln!(head, "        string timecodeRate = {}", quoted(rate));
        let _ = writeln!(head, "        string timecodeStart = {}", quoted(first));
        let _ = writeln!(head, "        string timecodeEnd = {}", quoted(last));
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
    let _ = writeln!(head, "    timeCodesPerSecond = {}", f(fps));
    let _ = writeln!(head, "    framesPerSecond = {}", f(fps));
    let _ = writeln!(head, "    upAxis = \"Y\"");
    let close = ")\n\n";
    if head.len() + close.len() > META_BYTES {
        return Err(head.len() + close.len());
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

/// The line that opens the `points` samples (the end of [`mesh_body`]).
const SAMPLES_OPEN: &str = "        point3f[] points.timeSamples = {\n";

/// One chunk's layer, cut into its parts.
struct LayerParts {
    meta: LayerMeta,
    /// From the end of the metadata room to the end of [`SAMPLES_OPEN`].
    body: String,
    /// The samples as written (`            N: [...]`, separated by `,\n`); empty when the
    /// chunk has no mesh.
    samples: String,
    /// Frames of the samples, in order.
    sample_frames: Vec<usize>,
}

/// Reads a layer [`UsdSink`] wrote.
fn read_layer(path: &Path) -> Result<LayerParts, SinkError> {
    let bad = |m: &str| SinkError::Other(format!("{}: {m}", path.display()));
    let text = std::fs::read_to_string(path).map_err(|e| SinkError::io(path, e))?;
    if !text.starts_with("#usda 1.0")
        || text.len() < META_BYTES
        || !text.is_char_boundary(META_BYTES)
    {
        return Err(bad("not a mesh layer helmcap wrote"));
    }
    let (head, rest) = text.split_at(META_BYTES);
    let open = rest
        .find(SAMPLES_OPEN)
        .ok_or_else(|| bad("no points.timeSamples"))?
        + SAMPLES_OPEN.len();
    let close = rest[open..]
        .find(MESH_END)
        .ok_or_else(|| bad("the points samples do not end"))?
        + open;
    let samples = rest[open..close].to_string();
    let mut sample_frames = Vec::new();
    for line in samples.split(",\n").filter(|l| !l.trim().is_empty()) {
        let frame = line
            .trim_start()
            .split_once(':')
            .and_then(|(n, _)| n.parse::<usize>().ok())
            .ok_or_else(|| bad("a points sample without a frame number"))?;
        sample_frames.push(frame);
    }
    let value = |key: &str| -> Option<&str> {
        head.lines()
            .map(str::trim)
            .find_map(|l| l.strip_prefix(key)?.trim_start().strip_prefix('='))
            .map(str::trim)
    };
    let number = |key: &str| -> Result<f64, SinkError> {
        value(key)
            .and_then(|v| v.parse::<f64>().ok())
            .ok_or_else(|| bad(&format!("no {key} in the layer metadata")))
    };
    let string = |key: &str| value(key).map(|v| v.trim_matches('"').to_string());
    if value("string stopped").is_some() {
        return Err(bad("the run that wrote it stopped early"));
    }
    let timecodes = match (
        string("string timecodeRate"),
        string("string timecodeStart"),
        string("string timecodeEnd"),
    ) {
        (Some(r), Some(a), Some(b)) => Some([r, a, b]),
        _ => None,
    };
    Ok(LayerParts {
        meta: LayerMeta {
            frames: number("int frames")? as usize,
            start: number("startTimeCode")? as usize,
            end: number("endTimeCode")? as usize,
            fps: number("timeCodesPerSecond")?,
            timecodes,
        },
        body: rest[..open].to_string(),
        samples,
        sample_frames,
    })
}

/// Joins the `mesh.usda` layers of consecutive chunks of a take (in frame order) into one
/// layer at `out`, written atomically: what one [`UsdSink`] over all their frames writes.
/// The mesh samples are copied as they are; the head-pose samples are made again from
/// `head_poses` (each frame's `cam0_from_head`, from the take's `head_pose.csv`) relative to
/// the first frame that has a mesh and a pose, as the sink does.
///
/// # Errors
/// A layer that is not one helmcap wrote, layers of other meshes or rates, frames out of
/// order, a file that cannot be read or written.
pub fn join_layers(
    out: &Path,
    parts: &[PathBuf],
    head_poses: &[(usize, Isometry3<f64>)],
) -> Result<(), SinkError> {
    let layers = parts
        .iter()
        .map(|p| read_layer(p))
        .collect::<Result<Vec<_>, _>>()?;
    let Some(first) = layers.first() else {
        return Err(SinkError::Other("no layers to join".into()));
    };
    let mut samples = String::new();
    let mut frames = 0;
    let mut range: Option<(usize, usize)> = None;
    let mut timecodes: (Option<String>, Option<String>) = (None, None);
    let mut with_mesh = std::collections::BTreeSet::new();
    for (layer, path) in layers.iter().zip(parts) {
        let bad = |m: String| SinkError::Other(format!("{}: {m}", path.display()));
        if layer.body != first.body {
            return Err(bad(
                "another mesh (topology, UVs or rest points) than the first layer's".into(),
            ));
        }
        if layer.meta.fps != first.meta.fps {
            return Err(bad(format!(
                "{} frames per second, the first layer has {}",
                layer.meta.fps, first.meta.fps
            )));
        }
        let Some((&a, &b)) = layer.sample_frames.first().zip(layer.sample_frames.last()) else {
            continue;
        };
        if let Some((_, end)) = range
            && a <= end
        {
            return Err(bad(format!(
                "frame {a} comes after frame {end} of the layers before"
            )));
        }
        range = Some((range.map_or(a, |r| r.0), b));
        if !samples.is_empty() {
            samples.push_str(",\n");
        }
        samples.push_str(&layer.samples);
        frames += layer.meta.frames;
        with_mesh.extend(layer.sample_frames.iter().copied());
        if let Some([_, start, end]) = &layer.meta.timecodes {
            timecodes.0.get_or_insert_with(|| start.clone());
            timecodes.1 = Some(end.clone());
        }
    }
    let (start, end) = range.unwrap_or((0, 0));
    let rate = first
        .meta
        .timecodes
        .as_ref()
        .or_else(|| layers.iter().find_map(|l| l.meta.timecodes.as_ref()))
        .map(|t| t[0].clone());
    let meta = LayerMeta {
        frames,
        start,
        end,
        fps: first.meta.fps,
        timecodes: match (rate, timecodes.0, timecodes.1) {
            (Some(r), Some(a), Some(b)) => Some([r, a, b]),
            _ => None,
        },
    };
    let head = layer_metadata(&meta, None).map_err(|len| {
        SinkError::Other(format!(
            "{}: the layer metadata takes {len} bytes, {META_BYTES} are reserved",
            out.display()
        ))
    })?;
    let mut origin: Option<Isometry3<f64>> = None;
    let poses: Vec<(usize, Isometry3<f64>)> = head_poses
        .iter()
        .filter(|(frame, _)| with_mesh.contains(frame))
        .map(|(frame, pose)| {
            let o = *origin.get_or_insert_with(|| pose.inverse());
            (*frame, o * pose)
        })
        .collect();
    let end = if poses.is_empty() {
        TAIL.to_string()
    } else {
        head_pose_tail(&poses)
    };
    crate::atomic_file::write_atomically(out, |w| {
        w.write_all(head.as_bytes())?;
        w.write_all(first.body.as_bytes())?;
        w.write_all(samples.as_bytes())?;
        w.write_all(end.as_bytes())
    })
    .map_err(|e| SinkError::io(out, e))
}
