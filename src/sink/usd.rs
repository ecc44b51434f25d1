//! USD export: one `mesh.usda` (USD's text format) holding the face as one `Mesh` prim
//! with the neutral's topology (`faceVertexCounts`, `faceVertexIndices`), its UVs
//! (`primvars:st`, face-varying, indexed) and the solved positions as time samples of
//! `points`, one per frame at time code = frame index. Stage metadata: `metersPerUnit =
//! 0.001` (millimetres), `upAxis = "Y"` (the head frame's up), `timeCodesPerSecond` = the
//! camera rate, `framesPerSecond` = the camera rate too (readers assume 24 without it),
//! `startTimeCode`/`endTimeCode` = the first and last frame written, and the timecode of
//! the first and last frame (with rate) in `customLayerData`.
//!
//! Head pose: the `/Face` Xform carries a time-sampled `xformOp:transform`, the head's
//! motion relative to the helmet cameras since the first frame with a pose,
//! `first_from_head(t) = cam0_from_head(t₀)⁻¹ · cam0_from_head(t)` (identity at the first
//! posed frame, so the face stays upright in the head frame's Y-up axes; the mesh points
//! stay in the head frame). Frames without a pose get no sample (USD interpolates). The
//! helmet moves with the head, so this is the helmet's slip on the head, not the head's
//! motion in the room.
//!
//! Streaming: each frame's points are appended to a temporary file as the frame arrives
//! (no mesh is kept in memory); [`Sink::finish`] writes the header and topology, copies
//! the samples, and publishes the file atomically.

use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::staged_file::StagedFile;
use nalgebra::Isometry3;

use crate::mesh::Mesh;
use crate::pipeline::{FrameResult, Metrics, SessionMeta, Sink, SinkError};
use crate::timecode::Timecode;

/// Writes `mesh.usda` (see the module docs).
#[derive(Debug)]
pub struct UsdSink {
    path: PathBuf,
    fps: f64,
    neutral: Option<Arc<Mesh>>,
    samples: Option<StagedFile>,
    first: Option<(usize, Option<Timecode>)>,
    last: Option<(usize, Option<Timecode>)>,
    frames: usize,
    /// The first posed frame's `head_from_cam0` and the per-frame relative poses.
    pose_origin: Option<Isometry3<f64>>,
    poses: Vec<(usize, Isometry3<f64>)>,
}

impl UsdSink {
    /// A sink writing `path` (e.g. `<out>/mesh.usda`).
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            fps: 0.0,
            neutral: None,
            samples: None,
            first: None,
            last: None,
            frames: 0,
            pose_origin: None,
            poses: Vec::new(),
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
        let mut samples_path = self.path.clone().into_os_string();
        samples_path.push(".samples");
        self.samples = Some(StagedFile::create(Path::new(&samples_path))?);
        self.neutral = Some(neutral);
        self.fps = session.fps;
        Ok(())
    }

    fn write(&mut self, fr: &FrameResult) -> Result<(), SinkError> {
        let (Some(mesh), Some(samples)) = (&fr.mesh, &mut self.samples) else {
            return Ok(());
        };
        let mut line = String::with_capacity(mesh.len() * 32 + 16);
        if self.frames > 0 {
            line.push_str(",\n");
        }
        let _ = write!(line, "            {}: ", fr.index);
        write_points(&mut line, mesh);
        samples.write_with(|w| w.write_all(line.as_bytes()))?;
        self.first.get_or_insert((fr.index, fr.timecode));
        self.last = Some((fr.index, fr.timecode));
        self.frames += 1;
        if let Some(cam0_from_head) = fr.cam0_from_head {
            let first_from_cam0 = *self
                .pose_origin
                .get_or_insert_with(|| cam0_from_head.inverse());
            self.poses
                .push((fr.index, first_from_cam0 * cam0_from_head));
        }
        Ok(())
    }

    fn finish(&mut self, metrics: &Metrics) -> Result<(), SinkError> {
        let (Some(samples), Some(neutral)) = (self.samples.take(), self.neutral.clone()) else {
            return Ok(());
        };
        let samples_path = samples.close_temp()?;
        let result = self.assemble(&neutral, &samples_path, metrics);
        let _ = std::fs::remove_file(&samples_path);
        result
    }
}

impl UsdSink {
    fn assemble(
        &self,
        neutral: &Mesh,
        samples_path: &Path,
        metrics: &Metrics,
    ) -> Result<(), SinkError> {
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
        if let Some(reason) = &metrics.stopped {
            let _ = writeln!(head, "        string stopped = {}", quoted(reason));
        }
        let _ = writeln!(head, "    }}");
        let _ = writeln!(head, "    defaultPrim = \"Face\"");
        let _ = writeln!(head, "    endTimeCode = {end}");
        let _ = writeln!(head, "    framesPerSecond = {}", f(self.fps));
        let _ = writeln!(head, "    metersPerUnit = 0.001");
        let _ = writeln!(head, "    startTimeCode = {start}");
        let _ = writeln!(head, "    timeCodesPerSecond = {}", f(self.fps));
        let _ = writeln!(head, "    upAxis = \"Y\"");
        let _ = writeln!(head, ")\n");
        let _ = writeln!(
            head,
            "def Xform \"Face\" (\n    kind = \"component\"\n)\n{{"
        );
        if !self.poses.is_empty() {
            let _ = writeln!(head, "    matrix4d xformOp:transform.timeSamples = {{");
            for (i, (frame, pose)) in self.poses.iter().enumerate() {
                let sep = if i + 1 < self.poses.len() { "," } else { "" };
                let _ = writeln!(head, "        {frame}: {}{sep}", usd_matrix(pose));
            }
            let _ = writeln!(head, "    }}");
            let _ = writeln!(
                head,
                "    uniform token[] xformOpOrder = [\"xformOp:transform\"]"
            );
        }
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
        let _ = writeln!(head, "        point3f[] points.timeSamples = {{");
        let mut tail = String::from("\n        }\n");
        if neutral.has_uvs() {
            let uvs: Vec<String> = neutral
                .uvs
                .iter()
                .map(|t| format!("({}, {})", f(t.x), f(t.y)))
                .collect();
            let _ = writeln!(
                tail,
                "        texCoord2f[] primvars:st = [{}] (\n            interpolation = \"faceVarying\"\n        )",
                uvs.join(", ")
            );
            let uv_indices: Vec<String> = neutral.face_uvs.iter().map(u32::to_string).collect();
            let _ = writeln!(
                tail,
                "        int[] primvars:st:indices = [{}]",
                uv_indices.join(", ")
            );
        }
        let _ = writeln!(tail, "        uniform token subdivisionScheme = \"none\"");
        let _ = writeln!(tail, "    }}\n}}");
        let mut out = StagedFile::create(&self.path)?;
        let samples =
            std::fs::File::open(samples_path).map_err(|e| SinkError::io(samples_path, e))?;
        out.write_with(|w| {
            w.write_all(head.as_bytes())?;
            let mut reader = BufReader::with_capacity(1 << 16, samples);
            loop {
                let buf = reader.fill_buf()?;
                if buf.is_empty() {
                    break;
                }
                w.write_all(buf)?;
                let n = buf.len();
                reader.consume(n);
            }
            w.write_all(tail.as_bytes())
        })?;
        out.commit()
    }
}
