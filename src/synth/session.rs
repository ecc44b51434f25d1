//! Writing a rendered session: images, `session.toml`, `frames.csv` and ground truth.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::{IsometryMatrix3, Point3, Vector3};
use rayon::prelude::*;

use super::{
    Performer, Scene, SynthError, SynthParams, neutral_head_pose, quaternion_wxyz, raster, shade,
    slip, to_gray8, write_png_gray,
};
use crate::camera::StereoRig;
use crate::dataset::MarkerLayout;
use crate::mesh::vertex_normals_of;

/// What a rendered session holds, for reports.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionSummary {
    /// Frames rendered.
    pub frames: usize,
    /// Markers in the layout.
    pub markers: usize,
    /// Marker observations visible in cam0 over all frames.
    pub visible_cam0: usize,
    /// Marker observations visible in cam1 over all frames.
    pub visible_cam1: usize,
    /// Marker observations visible in both cameras.
    pub visible_both: usize,
    /// Marker observations detectable in both cameras (see [`DotAppearance::detectable`]).
    pub detectable_both: usize,
}

/// Ground truth of one frame (rows of the gt CSV files, without headers).
struct FrameTruth {
    bundles: String,
    head_pose: String,
    projections: String,
    visible: [usize; 4],
}

fn write_text(path: &Path, text: &str) -> Result<(), SynthError> {
    crate::atomic_file::write_atomically(path, |w| w.write_all(text.as_bytes())).map_err(|e| {
        SynthError::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        }
    })
}

fn mkdir(path: &Path) -> Result<(), SynthError> {
    std::fs::create_dir_all(path).map_err(|e| SynthError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// A point counts as visible in a camera when it projects inside the image, its normal
/// faces the camera (angle below 80°), and the rendered surface at its pixel lies within
/// this distance of it (mm).
const VISIBILITY_TOLERANCE_MM: f64 = 0.6;

/// Points sampled on a dot's rim for its detectability (every 22.5°).
const RIM_SAMPLES: usize = 16;

/// How a painted dot appears in one camera: the measurements behind the `detectable`
/// column of `gt/projections.csv`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DotAppearance {
    /// Angle between the skin normal at the dot and the direction to the camera, degrees.
    pub view_angle_deg: f64,
    /// Full minor axis of the dot's projected ellipse, pixels: `2·√(2·λ_min)` of the
    /// covariance of its projected rim (a rim sampled uniformly in angle has variance
    /// `a²/2` along a semi-axis `a`), through the full lens model.
    pub minor_axis_px: f64,
    /// Full major axis, pixels (same construction).
    pub major_axis_px: f64,
    /// Share of the dot's samples (centre and rim) that pass the depth test: 1 when no
    /// eyelid, lip or nose covers any part of it.
    pub unoccluded_fraction: f64,
    /// Every sample projects at least [`DETECTABLE_BORDER_PX`] inside the image.
    pub inside_image: bool,
}

/// A dot whose rim comes closer than this to the image border is not detectable: the
/// detector measures its background on a ring 3 px outside the blob.
pub const DETECTABLE_BORDER_PX: f64 = 3.0;

impl DotAppearance {
    /// Whether a dot tracker can be expected to find this dot: unoccluded over its whole
    /// disc, inside the image, and with a projected minor axis of at least
    /// `min_minor_axis_px` (see [`SynthParams::detectable_min_minor_axis_px`]).
    pub fn detectable(&self, min_minor_axis_px: f64) -> bool {
        self.unoccluded_fraction >= 1.0
            && self.inside_image
            && self.view_angle_deg < 90.0
            && self.minor_axis_px >= min_minor_axis_px
    }
}

/// Depth test of a surface point `pc` (camera frame, mm) against the rendered depth at its
/// nearest pixel: the drawn surface lies within [`VISIBILITY_TOLERANCE_MM`] plus the skin's
/// depth change over 1.5 pixel footprints at the slant `tan_slant` (at least 1).
fn passes_depth_test(
    frags: &raster::Fragments,
    pc: &Point3<f64>,
    px: &nalgebra::Point2<f64>,
    footprint_mm: f64,
    tan_slant: f64,
) -> bool {
    if !(px.x > -0.5 && px.y > -0.5) {
        return false;
    }
    let x = px.x.round() as usize;
    let y = px.y.round() as usize;
    if x >= frags.width || y >= frags.height {
        return false;
    }
    let i = y * frags.width + x;
    if frags.triangle[i] == raster::NO_TRIANGLE {
        return false;
    }
    (f64::from(frags.depth[i]) - pc.z).abs()
        < VISIBILITY_TOLERANCE_MM + 1.5 * footprint_mm * tan_slant.max(1.0)
}

/// Measures how the dot of radius `radius_mm` at `centre` (camera frame) with skin normal
/// `normal` appears through `cam`, with occlusion from the rendered `frags`. `None` when
/// the centre does not project.
pub fn dot_appearance(
    cam: &crate::camera::Camera,
    frags: &raster::Fragments,
    centre: &Point3<f64>,
    normal: &Vector3<f64>,
    radius_mm: f64,
) -> Option<DotAppearance> {
    let n = normal.try_normalize(1e-12)?;
    let to_cam = -centre.coords.try_normalize(1e-12)?;
    let cos = n.dot(&to_cam).clamp(-1.0, 1.0);
    let view_angle_deg = cos.acos().to_degrees();
    let tan_slant = (1.0 - cos * cos).max(0.0).sqrt() / cos.abs().max(1e-3);
    let footprint_mm = centre.coords.norm() / cam.fx();
    // A tangent basis of the disc.
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let t1 = n.cross(&helper).normalize();
    let t2 = n.cross(&t1);
    let (w, h) = (f64::from(cam.width_px), f64::from(cam.height_px));
    let b = DETECTABLE_BORDER_PX;
    let inside = |p: &nalgebra::Point2<f64>| {
        p.x >= b - 0.5 && p.y >= b - 0.5 && p.x <= w - 0.5 - b && p.y <= h - 0.5 - b
    };
    let centre_px = cam.project(&centre.coords)?;
    let mut inside_image = inside(&centre_px);
    let mut passed = usize::from(passes_depth_test(
        frags,
        centre,
        &centre_px,
        footprint_mm,
        tan_slant,
    ));
    let mut samples = 1usize;
    let mut rim = Vec::with_capacity(RIM_SAMPLES);
    for k in 0..RIM_SAMPLES {
        let phi = std::f64::consts::TAU * k as f64 / RIM_SAMPLES as f64;
        let p = centre + radius_mm * (phi.cos() * t1 + phi.sin() * t2);
        samples += 1;
        let Some(px) = cam.project(&p.coords) else {
            inside_image = false;
            continue;
        };
        inside_image &= inside(&px);
        passed += usize::from(passes_depth_test(frags, &p, &px, footprint_mm, tan_slant));
        rim.push(px);
    }
    let (minor_axis_px, major_axis_px) = if rim.len() == RIM_SAMPLES {
        let m = rim.len() as f64;
        let (mx, my) = (
            rim.iter().map(|p| p.x).sum::<f64>() / m,
            rim.iter().map(|p| p.y).sum::<f64>() / m,
        );
        let (mut a, mut bb, mut c) = (0.0, 0.0, 0.0);
        for p in &rim {
            a += (p.x - mx).powi(2) / m;
            bb += (p.y - my).powi(2) / m;
            c += (p.x - mx) * (p.y - my) / m;
        }
        let disc = ((a - bb).powi(2) / 4.0 + c * c).sqrt();
        let (l1, l2) = ((a + bb) / 2.0 + disc, ((a + bb) / 2.0 - disc).max(0.0));
        (2.0 * (2.0 * l2).sqrt(), 2.0 * (2.0 * l1).sqrt())
    } else {
        (0.0, 0.0)
    };
    Some(DotAppearance {
        view_angle_deg,
        minor_axis_px,
        major_axis_px,
        unoccluded_fraction: passed as f64 / samples as f64,
        inside_image,
    })
}

/// Renders `weights.len()` frames of `performer` wearing `layout`, seen by `rig`, into the
/// session folder `out` (created; existing files are overwritten):
/// `session.toml`, `calibration.yaml` (the rig), `frames.csv`, `cam0/`, `cam1/` PNGs and
/// `gt/` with `bundles.csv` (`frame,marker,x,y,z`, head frame, mm, every marker every frame,
/// plus `visible0,visible1`), `head_pose.csv` (`frame,qw,qx,qy,qz,tx,ty,tz`: head → cam0,
/// mm), `projections.csv` (`frame,camera,marker,u,v,visible`, pixels, then
/// `view_angle_deg,minor_axis_px,unoccluded,detectable` from [`dot_appearance`]: a dot is
/// detectable when visible and [`DotAppearance::detectable`]), `weights.csv`, and
/// with `write_meshes` one OBJ per frame under `gt/mesh/`. Frames render in parallel;
/// `progress` is called once per finished frame.
///
/// # Errors
/// [`SynthError`] for invalid parameters, a layout that does not fit the mesh, or a file
/// that cannot be written.
#[allow(clippy::too_many_arguments)]
pub fn render_session(
    performer: &Performer,
    layout: &MarkerLayout,
    rig: &StereoRig,
    weights: &[Vec<f64>],
    params: &SynthParams,
    out: &Path,
    write_meshes: bool,
    progress: &(dyn Fn() + Sync),
) -> Result<SessionSummary, SynthError> {
    params.validate()?;
    rig.validate()
        .map_err(|e| SynthError::Params(format!("rig: {e}")))?;
    let neutral = performer.neutral();
    if layout.is_empty() {
        return Err(SynthError::Layout("no markers".into()));
    }
    if let Some(m) = layout
        .markers
        .iter()
        .find(|m| m.vertex as usize >= neutral.vertex_count())
    {
        return Err(SynthError::Layout(format!(
            "marker {} is on vertex {}, the mesh has {}",
            m.name,
            m.vertex,
            neutral.vertex_count()
        )));
    }
    if weights.is_empty() {
        return Err(SynthError::Params("no frames to render".into()));
    }
    for d in ["cam0", "cam1", "gt"] {
        mkdir(&out.join(d))?;
    }
    if write_meshes {
        mkdir(&out.join("gt/mesh"))?;
    }
    let eyeballs = performer.eyeball_ranges();
    let is_eye = |v: u32| eyeballs.iter().any(|r| r.contains(&(v as usize)));
    let material: Vec<u8> = neutral
        .triangles
        .iter()
        .map(|t| u8::from(is_eye(t[0])))
        .collect();
    let eye_centres: Vec<Point3<f64>> = match performer {
        Performer::Actor(a) => a.eyeball_centres().to_vec(),
        Performer::Dataset(_) => Vec::new(),
    };
    let head0 = neutral_head_pose(rig, neutral, layout, params.face_distance_mm);
    let pivot = layout
        .markers
        .iter()
        .map(|m| neutral.positions[m.vertex as usize].coords)
        .sum::<Vector3<f64>>()
        / layout.len() as f64;
    let pivot = Point3::from(pivot);
    let clock = crate::timecode::TimecodeClock::new(params.start_timecode()?, params.fps);
    let cams = [&rig.cam0, &rig.cam1];
    let done = AtomicUsize::new(0);

    let render_frame = |f: usize| -> Result<FrameTruth, SynthError> {
        let t = f as f64 / params.fps;
        let samples = params.motion_blur_samples;
        let mut radiance: [Vec<f32>; 2] = [Vec::new(), Vec::new()];
        let mut centre_views: Vec<Option<raster::Fragments>> = vec![None, None];
        let mut centre_state = None;
        for s in 0..samples {
            // Sub-frame time within the shutter, centred on the frame time.
            let offset = if samples == 1 {
                0.0
            } else {
                (s as f64 / (samples - 1) as f64 - 0.5) * params.shutter_fraction
            };
            let w: Vec<f64> = if offset == 0.0 {
                weights[f].clone()
            } else {
                let g = if offset > 0.0 {
                    (f + 1).min(weights.len() - 1)
                } else {
                    f.saturating_sub(1)
                };
                let a = offset.abs();
                weights[f]
                    .iter()
                    .zip(&weights[g])
                    .map(|(x, y)| x + (y - x) * a)
                    .collect()
            };
            let positions = performer.evaluate(&w);
            let normals = vertex_normals_of(neutral, &positions);
            let cam0_from_head: IsometryMatrix3<f64> =
                head0 * slip(params, t + offset / params.fps, &pivot);
            let is_centre = s == samples / 2;
            for (c, cam) in cams.iter().enumerate() {
                let cam_from_head = if c == 0 {
                    cam0_from_head
                } else {
                    rig.cam1_from_cam0 * cam0_from_head
                };
                let scene = Scene {
                    camera: cam,
                    points_in_cam: positions.iter().map(|p| cam_from_head * p).collect(),
                    normals_in_cam: normals.iter().map(|n| cam_from_head.rotation * n).collect(),
                    triangles: &neutral.triangles,
                    triangle_material: &material,
                    markers: layout
                        .markers
                        .iter()
                        .map(|m| {
                            let v = m.vertex as usize;
                            (
                                cam_from_head * positions[v],
                                cam_from_head.rotation * normals[v],
                            )
                        })
                        .collect(),
                    eyes: eye_centres
                        .iter()
                        .map(|e| (cam_from_head * e, cam_from_head.rotation * Vector3::z()))
                        .collect(),
                };
                let view = shade(&scene, params);
                if radiance[c].is_empty() {
                    radiance[c] = view.radiance;
                } else {
                    radiance[c]
                        .iter_mut()
                        .zip(&view.radiance)
                        .for_each(|(a, b)| *a += b);
                }
                if is_centre {
                    centre_views[c] = Some(view.fragments);
                }
            }
            if is_centre {
                centre_state = Some((positions, normals, cam0_from_head));
            }
        }
        let (positions, normals, cam0_from_head) = centre_state
            .ok_or_else(|| SynthError::Params("motion_blur_samples must be at least 1".into()))?;
        for (c, cam) in cams.iter().enumerate() {
            let (w, h) = (cam.width_px as usize, cam.height_px as usize);
            let img = &mut radiance[c];
            if samples > 1 {
                let k = 1.0 / samples as f32;
                img.iter_mut().for_each(|v| *v *= k);
            }
            raster::gaussian_blur(img, w, h, params.blur_px);
            let seed = params
                .seed
                .wrapping_mul(1_000_003)
                .wrapping_add((f as u64) * 2 + c as u64);
            let gray = to_gray8(img, params.noise_dn, seed);
            write_png_gray(
                &out.join(format!("cam{c}/{f:06}.png")),
                cam.width_px,
                cam.height_px,
                &gray,
            )?;
        }
        // Ground truth.
        let mut bundles = String::new();
        let mut projections = String::new();
        let mut visible = [0usize; 4];
        for m in &layout.markers {
            let v = m.vertex as usize;
            let p = positions[v];
            let mut vis = [false; 2];
            let mut detectable = [false; 2];
            for (c, cam) in cams.iter().enumerate() {
                let cam_from_head = if c == 0 {
                    cam0_from_head
                } else {
                    rig.cam1_from_cam0 * cam0_from_head
                };
                let pc = cam_from_head * p;
                let nc = cam_from_head.rotation * normals[v];
                let Some(px) = cam.project(&pc.coords) else {
                    continue;
                };
                let facing = nc.dot(&(-pc.coords.normalize())) > 10f64.to_radians().sin();
                let mut seen = false;
                if facing
                    && cam.contains(&px)
                    && let Some(frags) = &centre_views[c]
                {
                    let x = px.x.round() as usize;
                    let y = px.y.round() as usize;
                    let i = y.min(frags.height - 1) * frags.width + x.min(frags.width - 1);
                    if frags.triangle[i] != raster::NO_TRIANGLE {
                        // Depth of the drawn surface at the nearest pixel centre vs. the
                        // marker's, allowing for the skin's slope over half a pixel.
                        let footprint_mm = pc.coords.norm() / cam.fx();
                        seen = (f64::from(frags.depth[i]) - pc.z).abs()
                            < VISIBILITY_TOLERANCE_MM + 1.5 * footprint_mm;
                    }
                }
                vis[c] = seen;
                let look = centre_views[c].as_ref().and_then(|frags| {
                    dot_appearance(cam, frags, &pc, &nc, params.marker_radius_mm)
                });
                let det =
                    look.is_some_and(|a| seen && a.detectable(params.detectable_min_minor_axis_px));
                detectable[c] = det;
                let (angle, minor, unocc) = look.map_or((90.0, 0.0, 0.0), |a| {
                    (a.view_angle_deg, a.minor_axis_px, a.unoccluded_fraction)
                });
                let _ = writeln!(
                    projections,
                    "{f},cam{c},{},{:.4},{:.4},{},{angle:.2},{minor:.3},{unocc:.3},{}",
                    m.name,
                    px.x,
                    px.y,
                    u8::from(seen),
                    u8::from(det)
                );
            }
            visible[0] += usize::from(vis[0]);
            visible[1] += usize::from(vis[1]);
            visible[2] += usize::from(vis[0] && vis[1]);
            visible[3] += usize::from(detectable[0] && detectable[1]);
            let _ = writeln!(
                bundles,
                "{f},{},{:.5},{:.5},{:.5},{},{}",
                m.name,
                p.x,
                p.y,
                p.z,
                u8::from(vis[0]),
                u8::from(vis[1])
            );
        }
        let q = quaternion_wxyz(&cam0_from_head.rotation);
        let tr = cam0_from_head.translation.vector;
        let head_pose = format!(
            "{f},{:.10},{:.10},{:.10},{:.10},{:.5},{:.5},{:.5}\n",
            q[0], q[1], q[2], q[3], tr.x, tr.y, tr.z
        );
        if write_meshes {
            crate::mesh::obj::write_obj_positions(
                &out.join(format!("gt/mesh/frame_{f:06}.obj")),
                neutral,
                &positions,
            )
            .map_err(|e| SynthError::Write {
                path: out.join(format!("gt/mesh/frame_{f:06}.obj")),
                message: e.to_string(),
            })?;
        }
        done.fetch_add(1, Ordering::Relaxed);
        progress();
        Ok(FrameTruth {
            bundles,
            head_pose,
            projections,
            visible,
        })
    };
    let truths: Vec<FrameTruth> = (0..weights.len())
        .into_par_iter()
        .map(render_frame)
        .collect::<Result<_, _>>()?;

    // Session files.
    let calib_path = out.join("calibration.yaml");
    crate::camera::write_rig(&calib_path, rig).map_err(|e| SynthError::Write {
        path: calib_path.clone(),
        message: e.to_string(),
    })?;
    let session = format!(
        "# Synthetic helmet session rendered by helmcap synth.\nfps = {:?}\ncameras = [\"cam0\", \"cam1\"]\ncalibration = \"calibration.yaml\"\n\n[timecode]\nrate = \"{}\"\nstart = \"{}\"\n",
        params.fps, params.timecode_rate, params.timecode_start
    );
    write_text(&out.join("session.toml"), &session)?;
    let mut frames = String::from("frame,timestamp_ns,timecode\n");
    for f in 0..weights.len() {
        let t_ns = (f as f64 * 1e9 / params.fps).round() as u64;
        let _ = writeln!(frames, "{f},{t_ns},{}", clock.stamp(f as u64));
    }
    write_text(&out.join("frames.csv"), &frames)?;
    let mut bundles = String::from("frame,marker,x,y,z,visible0,visible1\n");
    let mut poses = String::from("frame,qw,qx,qy,qz,tx,ty,tz\n");
    let mut projections = String::from(
        "frame,camera,marker,u,v,visible,view_angle_deg,minor_axis_px,unoccluded,detectable\n",
    );
    let mut summary = SessionSummary {
        frames: weights.len(),
        markers: layout.len(),
        visible_cam0: 0,
        visible_cam1: 0,
        visible_both: 0,
        detectable_both: 0,
    };
    for t in &truths {
        bundles.push_str(&t.bundles);
        poses.push_str(&t.head_pose);
        projections.push_str(&t.projections);
        summary.visible_cam0 += t.visible[0];
        summary.visible_cam1 += t.visible[1];
        summary.visible_both += t.visible[2];
        summary.detectable_both += t.visible[3];
    }
    write_text(&out.join("gt/bundles.csv"), &bundles)?;
    write_text(&out.join("gt/head_pose.csv"), &poses)?;
    write_text(&out.join("gt/projections.csv"), &projections)?;
    let names = performer.expression_names();
    let mut wcsv = format!("frame,{}\n", names.join(","));
    for (f, w) in weights.iter().enumerate() {
        let _ = write!(wcsv, "{f}");
        for x in w {
            let _ = write!(wcsv, ",{x:.6}");
        }
        wcsv.push('\n');
    }
    write_text(&out.join("gt/weights.csv"), &wcsv)?;
    layout
        .write_csv(&out.join("gt/markers.csv"))
        .map_err(|e| SynthError::Write {
            path: out.join("gt/markers.csv"),
            message: e.to_string(),
        })?;
    Ok(summary)
}
