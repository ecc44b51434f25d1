//! Animation exports of a take: the rig weights of every frame (`rig_weights.csv`) and
//! Unreal's Live Link Face CSV (`livelink.csv`), from the solved meshes through a
//! [`RigSolver`].
//!
//! - `rig_weights.csv`: `frame,timecode,<shape>...,residual_mm`: one row per frame with a
//!   mesh, the rig's shapes in rig order (weights in [0, 1]), the timecode with its rate
//!   (`01:00:00:12.1@30`, empty without one), and the fit's RMS residual over the face
//!   vertices, mm.
//! - `livelink.csv` (on request): the layout of [`crate::animation::livelink`]; the
//!   curves through a [`NameMap`] to Apple's ARKit names (unmapped shapes are reported
//!   once at the start), head yaw/pitch/roll of `first_from_head` (the head's rotation
//!   relative to the helmet cameras since the first posed frame, as in `mesh.usda`), eye
//!   angles 0 (helmcap does not track gaze). Frames without a timecode get one counted
//!   from `00:00:00:00` at the camera rate.
//!
//! - `face_skel.usda` (on request): the weights as a UsdSkel blend-shape animation (see
//!   [`super::usd_skel`]); the weights are kept in memory until the end of the take
//!   (4 bytes per shape and frame: 50 shapes for an hour at 60 fps is 43 MB).
//!
//! The writer works frame by frame. In the pipeline (`replay/live --rig`) the rig stage
//! solves the weights ([`crate::pipeline::PipelineConfig::rig_solver`]) and the
//! [`AnimationSink`] writes them; `helmcap animate` solves and writes finished takes
//! with [`AnimationWriter::frame`].

use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3};

use super::staged_file::StagedFile;
use crate::animation::ResolvedMap;
use crate::animation::livelink::{csv_header, csv_row, csv_timecode, yaw_pitch_roll};
use crate::animation::{ARKIT_NAMES, NameMap, RigFit, RigSolver};
use crate::pipeline::{FrameResult, Metrics, SessionMeta, Sink, SinkError};
use crate::timecode::{Timecode, TimecodeRate};

/// What the animation writer writes.
#[derive(Debug, Clone)]
pub struct AnimationOutputs {
    /// Folder of the outputs.
    pub dir: PathBuf,
    /// Also write `livelink.csv`, with this map from the rig's names to ARKit's.
    pub livelink: Option<NameMap>,
    /// Also write `face_skel.usda` (UsdSkel blend-shape animation) with this mesh as the
    /// rig's neutral (topology and UVs; the rig's vertex count).
    pub usd_skel: Option<std::sync::Arc<crate::mesh::Mesh>>,
    /// Also stream every frame to Unreal's Live Link in the Live Link Face UDP format
    /// (`HOST:PORT`), with this name map to ARKit's names.
    pub livelink_udp: Option<(String, NameMap)>,
}

/// Figures of a finished animation export.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AnimationSummary {
    /// Frames written.
    pub frames: usize,
    /// Mean of the per-frame fit residuals, mm.
    pub mean_residual_mm: f64,
    /// Largest per-frame fit residual, mm.
    pub max_residual_mm: f64,
    /// Frames without a mesh (no row written).
    pub frames_without_mesh: usize,
    /// Rig shapes the name map does not map (their curves are not in `livelink.csv`).
    pub unmapped_shapes: Vec<String>,
    /// Live Link packets that could not be sent.
    pub udp_send_failures: usize,
}

/// Solves and writes frame by frame (see the module docs).
#[derive(Debug)]
pub struct AnimationWriter {
    solver: RigSolver,
    weights: StagedFile,
    livelink: Option<(StagedFile, ResolvedMap)>,
    fps: f64,
    head_origin: Option<Isometry3<f64>>,
    summary: AnimationSummary,
    sum_residual: f64,
    /// `face_skel.usda`: its path, the rig's neutral mesh and the frames so far (frame,
    /// weights, `first_from_head`), written at the end.
    skel: Option<SkelFrames>,
    udp: Option<LiveLinkStream>,
}

/// The Live Link Face UDP stream of a take.
#[derive(Debug)]
struct LiveLinkStream {
    socket: std::net::UdpSocket,
    map: ResolvedMap,
    subject_id: String,
    subject_name: String,
    /// When the first frame was sent, and its index: later frames wait for their time.
    start: Option<(std::time::Instant, usize)>,
    sent: usize,
}

/// What `face_skel.usda` needs, gathered frame by frame.
#[derive(Debug)]
struct SkelFrames {
    path: PathBuf,
    neutral: std::sync::Arc<crate::mesh::Mesh>,
    frames: Vec<super::usd_skel::SkelFrame>,
}

impl AnimationWriter {
    /// Creates the staged files and writes their headers.
    ///
    /// # Errors
    /// [`SinkError::Io`] when the folder or files cannot be created.
    pub fn new(solver: RigSolver, outputs: &AnimationOutputs, fps: f64) -> Result<Self, SinkError> {
        std::fs::create_dir_all(&outputs.dir).map_err(|e| SinkError::io(&outputs.dir, e))?;
        let mut weights = StagedFile::create(&outputs.dir.join("rig_weights.csv"))?;
        let header = format!("frame,timecode,{},residual_mm", solver.names().join(","));
        weights.write_with(|w| writeln!(w, "{header}"))?;
        let mut summary = AnimationSummary::default();
        let livelink = match &outputs.livelink {
            Some(map) => {
                let resolved = map.resolve(solver.names(), &ARKIT_NAMES);
                if !resolved.unmapped_shapes.is_empty() {
                    tracing::warn!(
                        "livelink.csv: {} rig shape(s) have no ARKit name in the name map \
                         and are left out: {}",
                        resolved.unmapped_shapes.len(),
                        resolved.unmapped_shapes.join(", ")
                    );
                }
                summary.unmapped_shapes = resolved.unmapped_shapes.clone();
                let mut f = StagedFile::create(&outputs.dir.join("livelink.csv"))?;
                f.write_with(|w| writeln!(w, "{}", csv_header()))?;
                Some((f, resolved))
            }
            None => None,
        };
        let skel = match &outputs.usd_skel {
            Some(mesh) if mesh.vertex_count() != solver.vertex_count() => {
                return Err(SinkError::Other(format!(
                    "face_skel.usda: the mesh has {} vertices, the rig {}",
                    mesh.vertex_count(),
                    solver.vertex_count()
                )));
            }
            Some(mesh) => Some(SkelFrames {
                path: outputs.dir.join("face_skel.usda"),
                neutral: mesh.clone(),
                frames: Vec::new(),
            }),
            None => None,
        };
        let udp = match &outputs.livelink_udp {
            Some((target, map)) => {
                let socket = std::net::UdpSocket::bind("0.0.0.0:0")
                    .and_then(|s| s.connect(target.as_str()).map(|()| s))
                    .map_err(|e| SinkError::Other(format!("--livelink {target}: {e}")))?;
                Some(LiveLinkStream {
                    socket,
                    map: map.resolve(solver.names(), &ARKIT_NAMES),
                    subject_id: format!("{:036x}", std::process::id()),
                    subject_name: "helmcap".into(),
                    start: None,
                    sent: 0,
                })
            }
            None => None,
        };
        Ok(Self {
            solver,
            weights,
            livelink,
            fps,
            head_origin: None,
            summary,
            sum_residual: 0.0,
            skel,
            udp,
        })
    }

    /// Solves one frame's mesh and writes its rows.
    ///
    /// # Errors
    /// [`SinkError::Other`] when the mesh does not fit the rig; [`SinkError::Io`].
    pub fn frame(
        &mut self,
        index: usize,
        timecode: Option<&Timecode>,
        mesh: &[Point3<f64>],
        cam0_from_head: Option<&Isometry3<f64>>,
    ) -> Result<(), SinkError> {
        let fit = self
            .solver
            .solve(mesh)
            .map_err(|e| SinkError::Other(format!("rig solve, frame {index}: {e}")))?;
        self.write_fit(index, timecode, &fit, cam0_from_head)
    }

    /// Writes the rows of one frame whose weights are solved already (by the pipeline's
    /// rig stage, with a solver of the same rig).
    ///
    /// # Errors
    /// [`SinkError::Other`] when the fit has another number of weights than the rig has
    /// shapes; [`SinkError::Io`].
    pub fn write_fit(
        &mut self,
        index: usize,
        timecode: Option<&Timecode>,
        fit: &RigFit,
        cam0_from_head: Option<&Isometry3<f64>>,
    ) -> Result<(), SinkError> {
        if fit.weights.len() != self.solver.names().len() {
            return Err(SinkError::Other(format!(
                "frame {index}: {} rig weights for a rig of {} shapes",
                fit.weights.len(),
                self.solver.names().len()
            )));
        }
        let mut row = format!(
            "{index},{}",
            timecode
                .map(Timecode::to_string_with_rate)
                .unwrap_or_default()
        );
        for w in &fit.weights {
            row.push_str(&format!(",{w:.6}"));
        }
        row.push_str(&format!(",{:.4}", fit.residual_mm));
        self.weights.write_with(|w| writeln!(w, "{row}"))?;
        let first_from_head = cam0_from_head.map(|pose| {
            let origin = *self.head_origin.get_or_insert_with(|| pose.inverse());
            origin * pose
        });
        if let Some(skel) = &mut self.skel {
            skel.frames
                .push((index, fit.weights.clone(), first_from_head));
        }
        if let Some((file, map)) = &mut self.livelink {
            let values = map.apply(&fit.weights);
            let mut curves = [0.0; 52];
            for (c, v) in curves.iter_mut().zip(&values) {
                *c = *v;
            }
            let mut angles = [0.0; 9];
            if let Some(first_from_head) = first_from_head {
                let [y, p, r] = yaw_pitch_roll(&first_from_head.rotation.to_rotation_matrix());
                angles[..3].copy_from_slice(&[y, p, r]);
            }
            let tc = match timecode {
                Some(tc) => csv_timecode(tc),
                None => csv_timecode(&fallback_timecode(index, self.fps)),
            };
            let line = csv_row(&tc, &curves, &angles);
            file.write_with(|w| writeln!(w, "{line}"))?;
        }
        if let Some(udp) = &mut self.udp {
            let curves = udp.map.apply(&fit.weights);
            let mut values = [0.0f32; crate::animation::livelink::VALUE_COUNT];
            for (v, c) in values.iter_mut().zip(&curves) {
                *v = *c as f32;
            }
            if let Some(first_from_head) = first_from_head {
                let a = yaw_pitch_roll(&first_from_head.rotation.to_rotation_matrix());
                for (v, a) in values[52..55].iter_mut().zip(a) {
                    *v = a as f32;
                }
            }
            // Paced at camera rate: frame i leaves (i − first) / fps after the first.
            let (t0, first) = *udp.start.get_or_insert((std::time::Instant::now(), index));
            if self.fps > 0.0 {
                let due = t0
                    + std::time::Duration::from_secs_f64(
                        index.saturating_sub(first) as f64 / self.fps,
                    );
                let now = std::time::Instant::now();
                if due > now {
                    std::thread::sleep(due - now);
                }
            }
            let (frame, sub) = match timecode {
                Some(tc) if tc.subframes > 1 => (
                    tc.frame_count as i32,
                    tc.subframe as f32 / tc.subframes as f32,
                ),
                Some(tc) => (tc.frame_count as i32, 0.0),
                None => (index as i32, 0.0),
            };
            let rate = timecode.map_or(self.fps.round() as i32, |tc| tc.rate.nominal as i32);
            let packet = crate::animation::livelink::udp_packet(
                &udp.subject_id,
                &udp.subject_name,
                frame,
                sub,
                rate,
                1,
                &values,
            );
            // A lost datagram is not an error of the take (UDP, a viewer may be absent):
            // count it.
            if udp.socket.send(&packet).is_ok() {
                udp.sent += 1;
            } else {
                self.summary.udp_send_failures += 1;
            }
        }
        self.summary.frames += 1;
        self.sum_residual += fit.residual_mm;
        self.summary.max_residual_mm = self.summary.max_residual_mm.max(fit.residual_mm);
        Ok(())
    }

    /// Counts a frame that had no mesh (no row).
    pub fn skip(&mut self) {
        self.summary.frames_without_mesh += 1;
    }

    /// Publishes the files.
    ///
    /// # Errors
    /// [`SinkError::Io`] naming the file that could not be published.
    pub fn finish(self) -> Result<AnimationSummary, SinkError> {
        self.weights.commit()?;
        if let Some((f, _)) = self.livelink {
            f.commit()?;
        }
        if let Some(skel) = &self.skel
            && !skel.frames.is_empty()
        {
            super::usd_skel::write_face_skel(
                &skel.path,
                &skel.neutral,
                self.solver.names(),
                |s| self.solver.offsets(s),
                &skel.frames,
                self.fps,
            )?;
        }
        let mut s = self.summary;
        if s.frames > 0 {
            s.mean_residual_mm = self.sum_residual / s.frames as f64;
        }
        Ok(s)
    }
}

/// A timecode for frame `index` counted from `00:00:00:00` at the nearest standard rate
/// to `fps` (30 fps code with sub-frames for 60 fps cameras).
fn fallback_timecode(index: usize, fps: f64) -> Timecode {
    let rate = TimecodeRate::from_fps(fps).unwrap_or(TimecodeRate::FPS_30);
    let clock = crate::timecode::TimecodeClock::new(Timecode::from_frame_count(rate, 0), fps);
    clock.stamp(index as u64)
}

/// The pipeline sink of `replay/live --rig`: an [`AnimationWriter`] fed with each
/// frame's rig weights ([`FrameResult::rig_fit`], from the pipeline's rig stage) and head
/// pose. `solver` is a solver of the same rig as the stage's: the sink takes the shape
/// names and targets from it (it solves nothing).
#[derive(Debug)]
pub struct AnimationSink {
    solver: Option<RigSolver>,
    outputs: AnimationOutputs,
    writer: Option<AnimationWriter>,
}

impl AnimationSink {
    /// A sink writing the weights of `solver`'s rig into `outputs`.
    pub fn new(solver: RigSolver, outputs: AnimationOutputs) -> Self {
        Self {
            solver: Some(solver),
            outputs,
            writer: None,
        }
    }

    /// The folder the sink writes into.
    pub fn dir(&self) -> &Path {
        &self.outputs.dir
    }
}

impl Sink for AnimationSink {
    fn name(&self) -> &str {
        "rig_weights.csv"
    }

    fn begin(&mut self, session: &SessionMeta) -> Result<(), SinkError> {
        let solver = self
            .solver
            .take()
            .ok_or_else(|| SinkError::Other("animation sink started twice".into()))?;
        if let Some(n) = &session.neutral
            && n.vertex_count() != solver.vertex_count()
        {
            return Err(SinkError::Other(format!(
                "--rig has {} vertices but the take's dataset {}: give the dataset the take \
                 is solved with (or a rig built from it)",
                solver.vertex_count(),
                n.vertex_count()
            )));
        }
        self.writer = Some(AnimationWriter::new(solver, &self.outputs, session.fps)?);
        Ok(())
    }

    fn write(&mut self, fr: &FrameResult) -> Result<(), SinkError> {
        let Some(w) = &mut self.writer else {
            return Ok(());
        };
        match (&fr.rig_fit, &fr.mesh) {
            (Some(fit), _) => w.write_fit(
                fr.index.as_usize(),
                fr.timecode.as_ref(),
                fit,
                fr.cam0_from_head.as_ref(),
            ),
            (None, Some(_)) => Err(SinkError::Other(format!(
                "frame {} has a mesh but no rig weights: the pipeline's rig stage is off \
                 (PipelineConfig::rig_solver)",
                fr.index
            ))),
            (None, None) => {
                w.skip();
                Ok(())
            }
        }
    }

    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        if let Some(w) = self.writer.take() {
            let s = w.finish()?;
            tracing::info!(
                "rig weights: {} frames, fit residual mean {:.3} mm, max {:.3} mm",
                s.frames,
                s.mean_residual_mm,
                s.max_residual_mm
            );
        }
        Ok(())
    }
}
