//! The rerun SDK side of the sink (cargo feature `rerun`): the recording stream and what
//! is logged per frame; the module docs of [`super`] list the entities.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use ::rerun as rr;
use nalgebra::{Isometry3, Point3, UnitQuaternion};
use rr::{EntityPath, RecordingStream, RecordingStreamBuilder};

use super::{
    APPLICATION_ID, BundlePoint, MarkerPixel, MeshTopology, RerunFrame, RerunParams, RerunSession,
    RerunSinkError, RerunStats, RerunTarget, TIMELINE_CAPTURE, TIMELINE_FRAME, TIMELINE_TIMECODE,
    downscale,
};
use crate::frame_index::FrameIndex;
use crate::pipeline::{BundleStatus, FrameResult, Metrics, SessionMeta, Sink, SinkError, Stage};

/// Which per-frame entities held data in the previous frame (to clear them when a frame
/// has none).
#[derive(Debug, Clone, Copy, Default)]
struct Present {
    markers: [bool; 2],
    bundles_in_cam0: bool,
    bundles_in_head: bool,
    head_pose: bool,
    mesh: bool,
    error_colours: bool,
    timecode: bool,
}

/// Logs the pipeline's frames to rerun: a spawned or running viewer, or an `.rrd` file.
///
/// # Usage
/// [`RerunSink::new`] opens the recording, [`RerunSink::begin_session`] logs the static
/// data, [`RerunSink::log_frame`] each frame, [`RerunSink::finish`] flushes and closes it.
///
/// # Threads
/// The SDK batches and encodes on its own threads; `log_frame` only serializes the frame's
/// data. The time of each frame is set for the calling thread, so one frame is logged from
/// one thread.
pub struct RerunSink {
    name: String,
    rec: Option<RecordingStream>,
    params: RerunParams,
    target: RerunTarget,
    /// Hidden file being written and the path it is renamed to at the end.
    rename: Option<(PathBuf, PathBuf)>,
    mesh_vertex_count: Option<usize>,
    mesh_triangles: Vec<[u32; 3]>,
    timing_paths: HashMap<String, EntityPath>,
    present: Present,
    stats: RerunStats,
}

impl std::fmt::Debug for RerunSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RerunSink")
            .field("target", &self.target)
            .field("params", &self.params)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

/// Hidden sibling of `path` the recording is streamed to: `.NAME.PID.partial`.
fn partial_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "recording.rrd".to_string());
    path.with_file_name(format!(".{name}.{}.partial", std::process::id()))
}

impl RerunSink {
    /// Opens the recording: creates the file, or spawns / connects to a viewer.
    ///
    /// # Errors
    /// [`RerunSinkError::Params`] for bad parameters, [`RerunSinkError::Start`] when the
    /// file cannot be created or the viewer cannot be started or reached.
    pub fn new(target: RerunTarget, params: RerunParams) -> Result<Self, RerunSinkError> {
        params.validate()?;
        let builder = RecordingStreamBuilder::new(APPLICATION_ID);
        let start_error = |source: rr::RecordingStreamError| RerunSinkError::Start {
            target: describe_target(&target),
            source: Box::new(source),
        };
        let mut rename = None;
        let rec = match &target {
            RerunTarget::File(path) => {
                if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                    // A failure shows as the SDK's error creating the file, naming it.
                    let _ = std::fs::create_dir_all(dir);
                }
                let partial = partial_path(path);
                let rec = builder.save(&partial).map_err(start_error)?;
                rename = Some((partial, path.clone()));
                rec
            }
            RerunTarget::Spawn => builder.spawn().map_err(start_error)?,
            RerunTarget::Connect(address) => builder
                .connect_grpc_opts(RerunTarget::connect_url(address))
                .map_err(start_error)?,
        };
        Ok(Self {
            name: format!("rerun ({})", describe_target(&target)),
            rec: Some(rec),
            params,
            target,
            rename,
            mesh_vertex_count: None,
            mesh_triangles: Vec::new(),
            timing_paths: HashMap::new(),
            present: Present::default(),
            stats: RerunStats::default(),
        })
    }

    /// Where this sink logs to.
    pub fn target(&self) -> &RerunTarget {
        &self.target
    }

    /// What was logged so far.
    pub fn stats(&self) -> RerunStats {
        self.stats
    }

    fn rec(&self) -> Result<&RecordingStream, RerunSinkError> {
        self.rec
            .as_ref()
            .ok_or_else(|| RerunSinkError::Finish("the recording was already finished".into()))
    }

    /// Logs the session's static data: marker names, axes, camera frustums, mesh topology.
    ///
    /// # Errors
    /// [`RerunSinkError::Log`] when the SDK rejects the data (should not happen), or
    /// [`RerunSinkError::Frame`] for more than 65 536 markers (rerun class ids are 16 bit).
    pub fn begin_session(&mut self, session: &RerunSession) -> Result<(), RerunSinkError> {
        let rec = self.rec()?;
        let log_err = |entity: &str| {
            let entity = entity.to_string();
            move |source: rr::RecordingStreamError| RerunSinkError::Log {
                frame: FrameIndex::new(0),
                entity,
                source: Box::new(source),
            }
        };
        if !session.name.is_empty() {
            rec.send_recording_name(session.name.clone())
                .map_err(log_err("recording name"))?;
        }
        if session.marker_names.len() > usize::from(u16::MAX) + 1 {
            return Err(RerunSinkError::Frame {
                frame: FrameIndex::new(0),
                message: format!(
                    "{} markers: rerun labels at most 65536",
                    session.marker_names.len()
                ),
            });
        }
        let classes: Vec<rr::datatypes::ClassDescriptionMapElem> = session
            .marker_names
            .iter()
            .enumerate()
            .map(|(i, name)| (class_id(i), name.as_str()).into())
            .collect();
        rec.log_static("/", &rr::AnnotationContext::new(classes))
            .map_err(log_err("/"))?;
        rec.log_static("world", &rr::ViewCoordinates::RDF())
            .map_err(log_err("world"))?;
        if let Some(rig) = &session.rig {
            let cam0_from_cam1 = rig.cam1_from_cam0.inverse();
            let rotation = UnitQuaternion::from_rotation_matrix(&cam0_from_cam1.rotation);
            let poses = [
                ("world/cam0", &rig.cam0, Isometry3::identity()),
                (
                    "world/cam1",
                    &rig.cam1,
                    Isometry3::from_parts(cam0_from_cam1.translation, rotation),
                ),
            ];
            for (entity, camera, pose) in poses {
                rec.log_static(entity, &transform_of(&pose))
                    .map_err(log_err(entity))?;
                let k = &camera.k;
                // Columns of K (rerun is column-major); principal point shifted by half a
                // pixel to rerun's pixel-edge convention.
                let image_from_camera = [
                    [k[(0, 0)] as f32, 0.0, 0.0],
                    [k[(0, 1)] as f32, k[(1, 1)] as f32, 0.0],
                    [(k[(0, 2)] + 0.5) as f32, (k[(1, 2)] + 0.5) as f32, 1.0],
                ];
                let pinhole = rr::Pinhole::new(image_from_camera)
                    .with_resolution([camera.width_px as f32, camera.height_px as f32])
                    .with_image_plane_distance(FRUSTUM_DEPTH_MM);
                rec.log_static(entity, &pinhole).map_err(log_err(entity))?;
            }
        }
        if let Some(mesh) = &session.mesh {
            let mut topology = rr::Mesh3D::update_fields()
                .with_triangle_indices(mesh.triangles.iter().map(|t| rr::datatypes::UVec3D(*t)));
            if let Some(uvs) = &mesh.vertex_uvs {
                topology =
                    topology.with_vertex_texcoords(uvs.iter().map(|uv| [uv.x as f32, uv.y as f32]));
            }
            rec.log_static(MESH, &topology).map_err(log_err(MESH))?;
            self.mesh_vertex_count = Some(mesh.vertex_count);
            // Only for the normals: a triangle with an index outside the topology adds
            // nothing to them.
            self.mesh_triangles = mesh
                .triangles
                .iter()
                .filter(|t| t.iter().all(|&i| (i as usize) < mesh.vertex_count))
                .copied()
                .collect();
        }
        Ok(())
    }

    /// Logs one frame.
    ///
    /// # Errors
    /// [`RerunSinkError::Frame`] when the mesh does not match the session's topology, the
    /// error array does not match the mesh, or a marker index does not fit a class id;
    /// [`RerunSinkError::Log`] when the SDK rejects the data.
    pub fn log_frame(&mut self, f: &RerunFrame<'_>) -> Result<(), RerunSinkError> {
        self.check_frame(f)?;
        let frame = f.frame;
        let params = self.params.clone();
        let rec = self.rec()?.clone();
        let log_err = |entity: &str| {
            let entity = entity.to_string();
            move |source: rr::RecordingStreamError| RerunSinkError::Log {
                frame,
                entity,
                source: Box::new(source),
            }
        };
        rec.reset_time();
        rec.set_time_sequence(
            TIMELINE_FRAME,
            i64::try_from(frame.get()).unwrap_or(i64::MAX),
        );
        rec.set_time(
            TIMELINE_CAPTURE,
            rr::TimeCell::from_duration_nanos(i64::try_from(f.timestamp_ns).unwrap_or(i64::MAX)),
        );
        if let Some(tc) = f.timecode {
            rec.set_duration_secs(TIMELINE_TIMECODE, tc.seconds());
            rec.log(TIMECODE, &rr::TextDocument::new(tc.to_string_with_rate()))
                .map_err(log_err(TIMECODE))?;
            self.present.timecode = true;
        } else if std::mem::take(&mut self.present.timecode) {
            rec.log(TIMECODE, &rr::Clear::flat())
                .map_err(log_err(TIMECODE))?;
        }

        // Camera images and labeled 2D markers.
        let log_images =
            params.image_every > 0 && frame.get().is_multiple_of(u64::from(params.image_every));
        let scale = params.image_downscale;
        for cam in 0..2 {
            if log_images && let Some(image) = f.images[cam] {
                let entity = IMAGES[cam];
                let (w, h, pixels) = downscale(image, scale);
                rec.log(entity, &rr::Image::from_l8(pixels, [w, h]))
                    .map_err(log_err(entity))?;
                if cam == 0 {
                    self.stats.image_frames += 1;
                }
            }
            let entity = MARKERS[cam];
            let markers = f.markers[cam];
            if !markers.is_empty() {
                let s = 1.0 / f64::from(scale);
                let points = rr::Points2D::new(markers.iter().map(|m| {
                    [
                        ((m.pixel.x + 0.5) * s) as f32,
                        ((m.pixel.y + 0.5) * s) as f32,
                    ]
                }))
                .with_class_ids(markers.iter().map(|m| class_id(m.marker)))
                .with_radii([rr::Radius::new_scene_units(
                    params.marker_radius_px / scale as f32,
                )]);
                rec.log(entity, &points).map_err(log_err(entity))?;
                self.present.markers[cam] = true;
            } else if std::mem::take(&mut self.present.markers[cam]) {
                rec.log(entity, &rr::Clear::flat())
                    .map_err(log_err(entity))?;
            }
        }

        // Bundles and head pose.
        let grey = rr::Color::from_rgb(150, 150, 150);
        log_or_clear(
            &rec,
            BUNDLES_CAM0,
            &mut self.present.bundles_in_cam0,
            (!f.bundles_in_cam0.is_empty()).then(|| {
                bundle_points(f.bundles_in_cam0, params.bundle_radius_mm * 0.6).with_colors([grey])
            }),
        )
        .map_err(log_err(BUNDLES_CAM0))?;
        log_or_clear(
            &rec,
            HEAD,
            &mut self.present.head_pose,
            f.cam0_from_head.as_ref().map(transform_of),
        )
        .map_err(log_err(HEAD))?;
        log_or_clear(
            &rec,
            BUNDLES_HEAD,
            &mut self.present.bundles_in_head,
            (!f.bundles_in_head.is_empty()).then(|| {
                bundle_points(f.bundles_in_head, params.bundle_radius_mm).with_colors(
                    f.bundles_in_head
                        .iter()
                        .map(|b| confidence_colour(b.confidence)),
                )
            }),
        )
        .map_err(log_err(BUNDLES_HEAD))?;

        // Dense mesh, with the error heat map when ground truth exists.
        if let Some(positions) = f.mesh_in_head {
            let mut mesh = rr::Mesh3D::update_fields().with_vertex_positions(
                positions
                    .iter()
                    .map(|p| [p.x as f32, p.y as f32, p.z as f32]),
            );
            if params.mesh_normals {
                let normals = vertex_normals(positions, &self.mesh_triangles);
                mesh = mesh.with_vertex_normals(normals);
            }
            if let Some(errors) = f.vertex_error_mm {
                mesh = mesh.with_vertex_colors(
                    errors
                        .iter()
                        .map(|&e| heat_colour(f64::from(e) / params.error_max_mm)),
                );
                self.present.error_colours = true;
                let (mean, max) = mean_and_max(errors);
                rec.log(ERROR_MEAN, &rr::Scalars::single(mean))
                    .map_err(log_err(ERROR_MEAN))?;
                rec.log(ERROR_MAX, &rr::Scalars::single(max))
                    .map_err(log_err(ERROR_MAX))?;
            } else if std::mem::take(&mut self.present.error_colours) {
                mesh = mesh.with_vertex_colors(std::iter::empty::<rr::Color>());
            }
            rec.log(MESH, &mesh).map_err(log_err(MESH))?;
            self.present.mesh = true;
            self.stats.mesh_frames += 1;
        } else if std::mem::take(&mut self.present.mesh) {
            rec.log(
                MESH,
                &rr::Mesh3D::update_fields().with_vertex_positions(std::iter::empty::<[f32; 3]>()),
            )
            .map_err(log_err(MESH))?;
        }

        if let Some(rms) = f.bundle_error_rms_mm {
            rec.log(BUNDLE_ERROR, &rr::Scalars::single(rms))
                .map_err(log_err(BUNDLE_ERROR))?;
        }

        // Per-stage timings.
        for (stage, ms) in f.stage_ms {
            let path = self
                .timing_paths
                .entry((*stage).to_string())
                .or_insert_with(|| {
                    EntityPath::new(vec![
                        rr::EntityPathPart::new("timings"),
                        rr::EntityPathPart::new(*stage),
                    ])
                });
            rec.log(path.clone(), &rr::Scalars::single(*ms))
                .map_err(log_err(&format!("timings/{stage}")))?;
        }
        self.stats.frames += 1;
        Ok(())
    }

    /// Validates a frame against the session before anything of it is logged.
    fn check_frame(&self, f: &RerunFrame<'_>) -> Result<(), RerunSinkError> {
        let bad = |message: String| {
            Err(RerunSinkError::Frame {
                frame: f.frame,
                message,
            })
        };
        if let Some(positions) = f.mesh_in_head {
            match self.mesh_vertex_count {
                None => {
                    return bad("a mesh was given but the session has no mesh topology".into());
                }
                Some(n) if n != positions.len() => {
                    return bad(format!(
                        "mesh has {} vertices, the session's topology {n}",
                        positions.len()
                    ));
                }
                Some(_) => {}
            }
            if let Some(errors) = f.vertex_error_mm
                && errors.len() != positions.len()
            {
                return bad(format!(
                    "{} vertex errors for {} vertices",
                    errors.len(),
                    positions.len()
                ));
            }
        } else if f.vertex_error_mm.is_some() {
            return bad("vertex errors without a mesh".into());
        }
        let too_big = f
            .markers
            .iter()
            .flat_map(|m| m.iter().map(|m| m.marker))
            .chain(f.bundles_in_cam0.iter().map(|b| b.marker))
            .chain(f.bundles_in_head.iter().map(|b| b.marker))
            .find(|&m| m > usize::from(u16::MAX));
        if let Some(m) = too_big {
            return bad(format!("marker index {m} does not fit a rerun class id"));
        }
        Ok(())
    }

    /// Flushes everything to the file or viewer and closes the recording; a file is renamed
    /// into place.
    ///
    /// # Errors
    /// [`RerunSinkError::Finish`] when the data could not be flushed or the file not
    /// renamed.
    pub fn finish(&mut self) -> Result<RerunStats, RerunSinkError> {
        self.close()?;
        Ok(self.stats)
    }

    fn close(&mut self) -> Result<(), RerunSinkError> {
        let Some(rec) = self.rec.take() else {
            return Ok(());
        };
        let flushed = rec
            .flush_blocking()
            .map_err(|e| RerunSinkError::Finish(e.to_string()));
        // Dropping the last handle joins the SDK's threads; the file sink writes its footer.
        drop(rec);
        flushed?;
        if let Some((partial, path)) = self.rename.take() {
            std::fs::rename(&partial, &path).map_err(|e| {
                RerunSinkError::Finish(format!(
                    "renaming {} to {}: {e}",
                    partial.display(),
                    path.display()
                ))
            })?;
        }
        Ok(())
    }
}

impl Drop for RerunSink {
    /// A sink dropped without [`RerunSink::finish`] (a stopped pipeline) still closes its
    /// recording, so what was logged stays readable.
    fn drop(&mut self) {
        if let Err(e) = self.close() {
            tracing::warn!("{e}");
        }
    }
}

impl Sink for RerunSink {
    fn name(&self) -> &str {
        &self.name
    }

    fn begin(&mut self, session: &SessionMeta) -> Result<(), SinkError> {
        let session = RerunSession {
            name: session.name.clone(),
            marker_names: session
                .layout
                .markers
                .iter()
                .map(|m| m.name.clone())
                .collect(),
            rig: session.rig.clone(),
            mesh: session.neutral.as_deref().map(MeshTopology::of_mesh),
        };
        self.begin_session(&session)
            .map_err(|e| SinkError::Other(e.to_string()))
    }

    fn write(&mut self, fr: &FrameResult) -> Result<(), SinkError> {
        let tracks: [Vec<MarkerPixel>; 2] = [0, 1].map(|camera| {
            fr.tracks(camera)
                .map(|(marker, pixel)| MarkerPixel { marker, pixel })
                .collect()
        });
        let mut bundles_in_cam0 = Vec::new();
        let mut bundles_in_head = Vec::new();
        for (marker, m) in fr.markers.iter().enumerate() {
            if let (BundleStatus::Observed, Some(p)) = (m.status, m.point_in_cam0) {
                bundles_in_cam0.push(BundlePoint {
                    marker,
                    position_mm: p,
                    confidence: m.confidence,
                });
            }
            if let (BundleStatus::Observed | BundleStatus::GapFilled, Some(p)) =
                (m.status, m.point_in_head)
            {
                bundles_in_head.push(BundlePoint {
                    marker,
                    position_mm: p,
                    confidence: m.confidence,
                });
            }
        }
        // Stages that ran on this frame, and the latency from the source so far.
        let mut stage_ms: Vec<(&str, f64)> = Stage::ALL
            .iter()
            .map(|&stage| (stage.name(), fr.timings.get(stage)))
            .filter(|(_, ms)| ms.is_finite())
            .collect();
        stage_ms.push(("end_to_end", fr.received_at.elapsed().as_secs_f64() * 1e3));
        let frame = RerunFrame {
            frame: fr.index,
            timestamp_ns: fr.timestamp_ns,
            timecode: fr.timecode.as_ref(),
            images: [Some(&fr.images[0]), Some(&fr.images[1])],
            markers: [&tracks[0], &tracks[1]],
            bundles_in_cam0: &bundles_in_cam0,
            bundles_in_head: &bundles_in_head,
            cam0_from_head: fr.cam0_from_head,
            mesh_in_head: fr.mesh.as_deref().map(Vec::as_slice),
            vertex_error_mm: fr.mesh_error_mm.as_deref().map(Vec::as_slice),
            bundle_error_rms_mm: fr.bundle_error_rms_mm,
            stage_ms: &stage_ms,
        };
        self.log_frame(&frame)
            .map_err(|e| SinkError::Other(e.to_string()))
    }

    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        RerunSink::finish(self)
            .map(|_| ())
            .map_err(|e| SinkError::Other(e.to_string()))
    }
}

const IMAGES: [&str; 2] = ["cam0/image", "cam1/image"];
const MARKERS: [&str; 2] = ["cam0/markers", "cam1/markers"];
const BUNDLES_CAM0: &str = "world/bundles_in_cam0";
const HEAD: &str = "world/head";
const BUNDLES_HEAD: &str = "world/head/bundles";
const MESH: &str = "world/head/mesh";
const TIMECODE: &str = "timecode";
const ERROR_MEAN: &str = "accuracy/vertex_error_mean_mm";
const ERROR_MAX: &str = "accuracy/vertex_error_max_mm";
const BUNDLE_ERROR: &str = "accuracy/bundle_error_rms_mm";
/// Depth at which the camera frustums are drawn, mm.
const FRUSTUM_DEPTH_MM: f32 = 40.0;

fn describe_target(target: &RerunTarget) -> String {
    match target {
        RerunTarget::File(p) => format!("file {}", p.display()),
        RerunTarget::Spawn => "spawned viewer".into(),
        RerunTarget::Connect(a) => format!("viewer at {}", RerunTarget::connect_url(a)),
    }
}

/// Marker index as a class id; callers checked it fits.
fn class_id(marker: usize) -> u16 {
    u16::try_from(marker).unwrap_or(u16::MAX)
}

fn transform_of(pose: &Isometry3<f64>) -> rr::Transform3D {
    let t = pose.translation.vector;
    let q = pose.rotation.coords; // (i, j, k, w)
    rr::Transform3D::from_translation_rotation(
        [t.x as f32, t.y as f32, t.z as f32],
        rr::Quaternion::from_xyzw([q.x as f32, q.y as f32, q.z as f32, q.w as f32]),
    )
}

fn bundle_points(bundles: &[BundlePoint], radius_mm: f32) -> rr::Points3D {
    rr::Points3D::new(bundles.iter().map(|b| {
        let p = b.position_mm;
        [p.x as f32, p.y as f32, p.z as f32]
    }))
    .with_class_ids(bundles.iter().map(|b| class_id(b.marker)))
    .with_radii([rr::Radius::new_scene_units(radius_mm)])
}

/// Logs `data` at `entity`, or clears the entity when there is none now but was before.
fn log_or_clear<A: rr::AsComponents>(
    rec: &RecordingStream,
    entity: &str,
    present: &mut bool,
    data: Option<A>,
) -> Result<(), rr::RecordingStreamError> {
    match data {
        Some(data) => {
            *present = true;
            rec.log(entity, &data)
        }
        None if std::mem::take(present) => rec.log(entity, &rr::Clear::flat()),
        None => Ok(()),
    }
}

/// Area-weighted vertex normals (unit length; zero for unused vertices) of
/// [`crate::mesh::vertex_normals_of_triangles`], as f32 triples.
///
/// # Panics
/// If a triangle index is outside `positions` (the sink keeps only the triangles inside the
/// session's topology, whose vertex count every frame's mesh is checked against).
fn vertex_normals(positions: &[Point3<f64>], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    crate::mesh::vertex_normals_of_triangles(triangles, positions)
        .iter()
        .map(|n| [n.x as f32, n.y as f32, n.z as f32])
        .collect()
}

/// Mean and maximum of the finite values (NaN, NaN when there are none).
fn mean_and_max(values: &[f32]) -> (f64, f64) {
    let (mut sum, mut max, mut n) = (0.0, f64::NEG_INFINITY, 0usize);
    for v in values
        .iter()
        .map(|&v| f64::from(v))
        .filter(|v| v.is_finite())
    {
        sum += v;
        max = max.max(v);
        n += 1;
    }
    if n == 0 {
        (f64::NAN, f64::NAN)
    } else {
        (sum / n as f64, max)
    }
}

/// Colour of a confidence in 0..1: red (0), yellow (0.5), green (1).
pub fn confidence_colour(confidence: f64) -> rr::Color {
    let c = if confidence.is_finite() {
        confidence.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let r = (2.0 * (1.0 - c)).min(1.0);
    let g = (2.0 * c).min(1.0);
    rr::Color::from_rgb((r * 255.0).round() as u8, (g * 255.0).round() as u8, 0)
}

/// Heat-map colour of `t` in 0..1 (clamped): blue, cyan, green, yellow, red, the "jet"
/// ramp. NaN (no ground truth for the vertex) is grey.
pub fn heat_colour(t: f64) -> rr::Color {
    if t.is_nan() {
        return rr::Color::from_rgb(128, 128, 128);
    }
    let t = t.clamp(0.0, 1.0);
    let channel =
        |centre: f64| ((1.5 - (4.0 * t - centre).abs()).clamp(0.0, 1.0) * 255.0).round() as u8;
    rr::Color::from_rgb(channel(3.0), channel(2.0), channel(1.0))
}

#[cfg(test)]
mod tests {
    use std::collections::{BTreeMap, BTreeSet};
    use std::io::BufReader;

    use nalgebra::{IsometryMatrix3, Rotation3, Translation3, Vector3};
    use re_log_encoding::DecoderApp;
    use rr::log::{Chunk, LogMsg};

    use nalgebra::Point2;

    use super::*;
    use crate::camera::{Camera, Distortion, StereoRig};
    use crate::capture::GrayImage;
    use crate::sink::rerun::DEFAULT_VIEWER_URL;
    use crate::timecode::Timecode;
    use crate::timecode::TimecodeRate;

    /// What a decoded `.rrd` holds: rows per entity (temporal), static entities, timelines.
    #[derive(Debug, Default)]
    struct Decoded {
        rows: BTreeMap<String, usize>,
        static_entities: BTreeSet<String>,
        timelines: BTreeSet<String>,
    }

    fn decode(path: &Path) -> Decoded {
        let file = std::fs::File::open(path).expect("open rrd");
        let mut out = Decoded::default();
        for msg in DecoderApp::decode_lazy(BufReader::new(file)) {
            let LogMsg::ArrowMsg(_, arrow) = msg.expect("decode message") else {
                continue;
            };
            let chunk = Chunk::from_arrow_msg(&arrow).expect("chunk");
            let entity = chunk.entity_path().to_string();
            if chunk.is_static() {
                out.static_entities.insert(entity);
            } else {
                *out.rows.entry(entity).or_default() += chunk.num_rows();
                out.timelines
                    .extend(chunk.timelines().keys().map(|t| t.to_string()));
            }
        }
        out
    }

    fn rig() -> StereoRig {
        let cam = Camera::new(
            64,
            48,
            [60.0, 60.0, 31.5, 23.5],
            Distortion::Pinhole {
                k: [0.0; 3],
                p: [0.0; 2],
            },
        );
        StereoRig {
            cam0: cam.clone(),
            cam1: cam,
            cam1_from_cam0: IsometryMatrix3::from_parts(
                Translation3::new(-60.0, 0.0, 0.0),
                Rotation3::from_scaled_axis(Vector3::new(0.0, 0.1, 0.0)),
            ),
            rms_px: 0.2,
        }
    }

    /// A 3 × 3 grid of vertices (mm), two triangles per cell.
    fn grid_topology() -> MeshTopology {
        let mut triangles = Vec::new();
        for y in 0..2u32 {
            for x in 0..2u32 {
                let v = y * 3 + x;
                triangles.push([v, v + 1, v + 3]);
                triangles.push([v + 1, v + 4, v + 3]);
            }
        }
        let uvs = (0..9)
            .map(|i| Point2::new(f64::from(i % 3) / 2.0, f64::from(i / 3) / 2.0))
            .collect();
        MeshTopology {
            vertex_count: 9,
            triangles,
            vertex_uvs: Some(uvs),
        }
    }

    fn session() -> RerunSession {
        RerunSession {
            name: "test session".into(),
            marker_names: vec!["nose".into(), "chin".into(), "brow_L".into()],
            rig: Some(rig()),
            mesh: Some(grid_topology()),
        }
    }

    /// Owned data of one synthetic frame.
    struct FrameData {
        index: usize,
        timecode: Timecode,
        images: [GrayImage; 2],
        markers: [Vec<MarkerPixel>; 2],
        bundles: Vec<BundlePoint>,
        mesh: Vec<Point3<f64>>,
        errors: Vec<f32>,
    }

    fn frame_data(index: usize) -> FrameData {
        let image = |seed: u8| GrayImage {
            width: 64,
            height: 48,
            data: (0..64 * 48).map(|i| (i as u8).wrapping_mul(seed)).collect(),
        };
        let shift = index as f64;
        let markers: Vec<MarkerPixel> = (0..3)
            .map(|m| MarkerPixel {
                marker: m,
                pixel: Point2::new(10.0 + 10.0 * m as f64 + shift, 20.0),
            })
            .collect();
        let bundles = (0..3)
            .map(|m| BundlePoint {
                marker: m,
                position_mm: Point3::new(m as f64 * 10.0, shift, 300.0),
                confidence: m as f64 / 2.0,
            })
            .collect();
        let mesh: Vec<Point3<f64>> = (0..9)
            .map(|i| Point3::new(f64::from(i % 3) * 10.0, f64::from(i / 3) * 10.0, shift))
            .collect();
        FrameData {
            index,
            timecode: Timecode::from_frame_count(TimecodeRate::FPS_30, 108_000 + index as u64),
            images: [image(3), image(5)],
            markers: [markers.clone(), markers],
            bundles,
            errors: (0..9).map(|i| i as f32 * 0.3).collect(),
            mesh,
        }
    }

    fn log(sink: &mut RerunSink, d: &FrameData) {
        let timings = [("detect", 1.5), ("solve", 2.25)];
        let frame = RerunFrame {
            frame: d.index.into(),
            timestamp_ns: d.index as u64 * 16_666_667,
            timecode: Some(&d.timecode),
            images: [Some(&d.images[0]), Some(&d.images[1])],
            markers: [&d.markers[0], &d.markers[1]],
            bundles_in_cam0: &d.bundles,
            bundles_in_head: &d.bundles,
            cam0_from_head: Some(Isometry3::translation(0.0, 0.0, 100.0)),
            mesh_in_head: Some(&d.mesh),
            vertex_error_mm: Some(&d.errors),
            bundle_error_rms_mm: Some(0.1),
            stage_ms: &timings,
        };
        sink.log_frame(&frame).expect("log frame");
    }

    fn write_rrd(path: &Path, frames: usize, params: RerunParams) -> RerunStats {
        let mut sink = RerunSink::new(RerunTarget::File(path.to_path_buf()), params).expect("sink");
        sink.begin_session(&session()).expect("begin");
        for i in 0..frames {
            log(&mut sink, &frame_data(i));
        }
        sink.finish().expect("finish")
    }

    #[test]
    fn rrd_file_decodes_with_every_entity_on_all_timelines() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("run.rrd");
        let stats = write_rrd(&path, 3, RerunParams::default());
        assert_eq!(stats.frames, 3);
        assert!(
            !partial_path(&path).exists(),
            "the partial file was renamed"
        );
        let d = decode(&path);
        for entity in [
            "/cam0/image",
            "/cam1/image",
            "/cam0/markers",
            "/cam1/markers",
            "/world/bundles_in_cam0",
            "/world/head",
            "/world/head/bundles",
            "/world/head/mesh",
            "/timecode",
            "/timings/detect",
            "/timings/solve",
            "/accuracy/vertex_error_mean_mm",
            "/accuracy/vertex_error_max_mm",
        ] {
            assert_eq!(d.rows.get(entity), Some(&3), "{entity}: {:?}", d.rows);
        }
        for entity in [
            "/",
            "/world",
            "/world/cam0",
            "/world/cam1",
            "/world/head/mesh",
        ] {
            assert!(
                d.static_entities.contains(entity),
                "static {entity}: {:?}",
                d.static_entities
            );
        }
        for timeline in [TIMELINE_FRAME, TIMELINE_TIMECODE, TIMELINE_CAPTURE] {
            assert!(
                d.timelines.contains(timeline),
                "{timeline}: {:?}",
                d.timelines
            );
        }
    }

    /// The pipeline's view: a [`FrameResult`] through the [`Sink`] trait.
    #[test]
    fn sink_trait_logs_pipeline_frames() {
        use std::sync::Arc;

        use crate::dataset::{Marker, MarkerLayout};
        use crate::mesh::Mesh;
        use crate::pipeline::MarkerResult;

        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("sub").join("take.rrd");
        let mut sink =
            RerunSink::new(RerunTarget::File(path.clone()), RerunParams::default()).expect("sink");
        let layout = MarkerLayout {
            markers: ["nose", "chin", "brow_L"]
                .iter()
                .enumerate()
                .map(|(i, name)| Marker {
                    name: (*name).into(),
                    vertex: i as u32,
                    stabilize_weight: 0.0,
                })
                .collect(),
        };
        let topo = grid_topology();
        let polygons: Vec<Vec<u32>> = topo.triangles.iter().map(|t| t.to_vec()).collect();
        let neutral = Mesh::new(frame_data(0).mesh, &polygons, Vec::new(), None).expect("mesh");
        let meta = SessionMeta {
            name: "take".into(),
            fps: 60.0,
            timecode_rate: Some(TimecodeRate::FPS_30),
            first_frame: crate::frame_index::FrameIndex::new(0),
            frame_count: Some(2),
            layout: Arc::new(layout),
            neutral_markers_head: Arc::new(vec![Point3::origin(); 3]),
            neutral: Some(Arc::new(neutral)),
            face_vertices: None,
            rig: Some(rig()),
            image_size: Some((64, 48)),
        };
        assert!(sink.name().contains("take.rrd"), "{}", sink.name());
        Sink::begin(&mut sink, &meta).expect("begin");
        for i in 0..2 {
            let d = frame_data(i);
            let mut fr = FrameResult::new(i.into(), 0, Some(d.timecode), d.images.clone(), 3);
            fr.markers[0] = MarkerResult {
                status: BundleStatus::Observed,
                point_in_cam0: Some(Point3::new(0.0, 0.0, 300.0)),
                point_in_head: Some(Point3::new(0.0, 0.0, 200.0)),
                pixels: Some([Point2::new(10.0, 10.0), Point2::new(20.0, 10.0)]),
                confidence: 0.9,
                reprojection_px: 0.2,
                reacquired: false,
            };
            fr.markers[1] = MarkerResult {
                status: BundleStatus::GapFilled,
                point_in_head: Some(Point3::new(0.0, 30.0, 200.0)),
                confidence: 0.5,
                ..MarkerResult::MISSING
            };
            fr.cam0_from_head = Some(Isometry3::translation(0.0, 0.0, 100.0));
            fr.mesh = Some(Arc::new(d.mesh.clone()));
            fr.mesh_error_mm = Some(Arc::new(d.errors.clone()));
            fr.timings.set(Stage::Track, 4.0);
            fr.timings.set(Stage::Solve, 2.0);
            Sink::write(&mut sink, &fr).expect("write");
        }
        Sink::finish(&mut sink, &Metrics::default()).expect("finish");
        let d = decode(&path);
        for entity in [
            "/cam0/image",
            "/cam1/markers",
            "/world/bundles_in_cam0",
            "/world/head/bundles",
            "/world/head/mesh",
            "/timings/track",
            "/timings/solve",
            "/timings/end_to_end",
        ] {
            assert_eq!(d.rows.get(entity), Some(&2), "{entity}: {:?}", d.rows);
        }
        assert_eq!(
            d.rows.get("/timings/stabilize"),
            None,
            "stages that did not run"
        );
    }

    #[test]
    fn rrd_file_grows_with_frames() {
        let dir = tempfile::tempdir().expect("tempdir");
        let short = dir.path().join("short.rrd");
        let long = dir.path().join("long.rrd");
        write_rrd(&short, 2, RerunParams::default());
        write_rrd(&long, 6, RerunParams::default());
        let size = |p: &Path| std::fs::metadata(p).expect("metadata").len();
        let mut magic = [0u8; 4];
        std::io::Read::read_exact(&mut std::fs::File::open(&short).expect("open"), &mut magic)
            .expect("read");
        assert_eq!(magic, re_log_encoding::RRD_FOURCC, "rrd header magic");
        assert!(
            size(&long) > size(&short),
            "{} vs {}",
            size(&long),
            size(&short)
        );
        assert_eq!(decode(&long).rows.get("/world/head/mesh"), Some(&6));
    }

    #[test]
    fn images_every_nth_frame() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("sparse.rrd");
        let params = RerunParams {
            image_every: 2,
            image_downscale: 2,
            ..Default::default()
        };
        let stats = write_rrd(&path, 5, params);
        assert_eq!(stats.image_frames, 3, "frames 0, 2, 4");
        let d = decode(&path);
        assert_eq!(d.rows.get("/cam0/image"), Some(&3));
        assert_eq!(d.rows.get("/cam0/markers"), Some(&5));
    }

    #[test]
    fn missing_data_is_cleared_not_left_stale() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("gaps.rrd");
        let mut sink =
            RerunSink::new(RerunTarget::File(path.clone()), RerunParams::default()).expect("sink");
        sink.begin_session(&session()).expect("begin");
        log(&mut sink, &frame_data(0));
        // A frame with nothing but its index: every per-frame entity gets one clear row.
        sink.log_frame(&RerunFrame {
            frame: FrameIndex::new(1),
            ..Default::default()
        })
        .expect("empty frame");
        // A second empty frame logs nothing more.
        sink.log_frame(&RerunFrame {
            frame: FrameIndex::new(2),
            ..Default::default()
        })
        .expect("empty frame");
        sink.finish().expect("finish");
        let d = decode(&path);
        for entity in [
            "/cam0/markers",
            "/world/head",
            "/world/head/bundles",
            "/world/head/mesh",
            "/timecode",
        ] {
            assert_eq!(d.rows.get(entity), Some(&2), "{entity}: {:?}", d.rows);
        }
        assert_eq!(
            d.rows.get("/cam0/image"),
            Some(&1),
            "images are not cleared"
        );
    }

    #[test]
    fn frame_that_does_not_fit_the_session_is_an_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut sink = RerunSink::new(
            RerunTarget::File(dir.path().join("bad.rrd")),
            RerunParams::default(),
        )
        .expect("sink");
        sink.begin_session(&session()).expect("begin");
        let short = vec![Point3::origin(); 5];
        let err = sink
            .log_frame(&RerunFrame {
                frame: FrameIndex::new(7),
                mesh_in_head: Some(&short),
                ..Default::default()
            })
            .expect_err("wrong vertex count");
        assert!(err.to_string().contains("frame 7"), "{err}");
        assert!(err.to_string().contains("5 vertices"), "{err}");
        let mesh = frame_data(0).mesh;
        let errors = vec![0.0f32; 4];
        let err = sink
            .log_frame(&RerunFrame {
                frame: FrameIndex::new(8),
                mesh_in_head: Some(&mesh),
                vertex_error_mm: Some(&errors),
                ..Default::default()
            })
            .expect_err("wrong error count");
        assert!(err.to_string().contains("4 vertex errors"), "{err}");
        let bad = RerunParams {
            image_downscale: 0,
            ..Default::default()
        };
        let err = RerunSink::new(RerunTarget::File(dir.path().join("x.rrd")), bad)
            .expect_err("bad params");
        assert!(err.to_string().contains("image_downscale"), "{err}");
    }

    #[test]
    fn dropped_sink_leaves_a_readable_recording() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("stopped.rrd");
        {
            let mut sink = RerunSink::new(RerunTarget::File(path.clone()), RerunParams::default())
                .expect("sink");
            sink.begin_session(&session()).expect("begin");
            log(&mut sink, &frame_data(0));
            log(&mut sink, &frame_data(1));
        }
        assert_eq!(decode(&path).rows.get("/world/head/mesh"), Some(&2));
    }

    #[test]
    fn unreachable_directory_is_a_start_error() {
        // The parent "folder" is a regular file: no folder can be made there, not even by
        // root.
        let dir = tempfile::tempdir().expect("tempdir");
        let blocker = dir.path().join("not-a-folder");
        std::fs::write(&blocker, b"x").expect("write");
        let err = RerunSink::new(
            RerunTarget::File(blocker.join("x.rrd")),
            RerunParams::default(),
        )
        .expect_err("no such folder");
        assert!(matches!(err, RerunSinkError::Start { .. }), "{err}");
        assert!(err.to_string().contains("not-a-folder"), "{err}");
    }

    #[test]
    fn downscale_averages_blocks() {
        let image = GrayImage {
            width: 5,
            height: 4,
            data: vec![
                0, 10, 20, 30, 99, //
                10, 20, 30, 40, 99, //
                100, 100, 0, 0, 99, //
                100, 101, 0, 1, 99,
            ],
        };
        let (w, h, px) = downscale(&image, 2);
        assert_eq!((w, h), (2, 2));
        // Means 10, 30, 100.25, 0.25, rounded half up.
        assert_eq!(px, vec![10, 30, 100, 0]);
        assert_eq!(downscale(&image, 1).2, image.data);
    }

    #[test]
    fn colour_ramps_hit_their_ends() {
        assert_eq!(confidence_colour(0.0), rr::Color::from_rgb(255, 0, 0));
        assert_eq!(confidence_colour(0.5), rr::Color::from_rgb(255, 255, 0));
        assert_eq!(confidence_colour(1.0), rr::Color::from_rgb(0, 255, 0));
        assert_eq!(confidence_colour(f64::NAN), rr::Color::from_rgb(255, 0, 0));
        assert_eq!(heat_colour(0.5), rr::Color::from_rgb(128, 255, 128));
        // Blue end, red end; beyond the range is clamped.
        assert_eq!(heat_colour(0.0), rr::Color::from_rgb(0, 0, 128));
        assert_eq!(heat_colour(1.0), rr::Color::from_rgb(128, 0, 0));
        assert_eq!(heat_colour(7.0), heat_colour(1.0));
    }

    #[test]
    fn vertex_normals_of_a_flat_grid_point_along_z() {
        let topo = grid_topology();
        let positions = frame_data(0).mesh;
        for n in vertex_normals(&positions, &topo.triangles) {
            assert!(
                (n[2].abs() - 1.0).abs() < 1e-6 && n[0].abs() < 1e-6,
                "{n:?}"
            );
        }
    }

    #[test]
    fn connect_address_becomes_a_proxy_url() {
        assert_eq!(
            RerunTarget::connect_url("127.0.0.1:9877"),
            "rerun+http://127.0.0.1:9877/proxy"
        );
        assert_eq!(
            RerunTarget::connect_url(DEFAULT_VIEWER_URL),
            DEFAULT_VIEWER_URL
        );
        // The constant (kept for builds without the SDK) is the SDK's own default.
        assert_eq!(DEFAULT_VIEWER_URL, rr::DEFAULT_CONNECT_URL);
    }

    /// `rerun rrd verify` (the viewer's own loader) accepts the file, when the `rerun`
    /// command is installed (`pip install rerun-sdk==0.36.3`).
    #[test]
    fn rerun_cli_verifies_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("verify.rrd");
        write_rrd(&path, 3, RerunParams::default());
        let out = match std::process::Command::new("rerun")
            .args(["rrd", "verify"])
            .arg(&path)
            .output()
        {
            Ok(out) => out,
            Err(e) => {
                eprintln!("skipped: the `rerun` command is not available ({e})");
                return;
            }
        };
        assert!(
            out.status.success(),
            "rerun rrd verify failed:\n{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}
