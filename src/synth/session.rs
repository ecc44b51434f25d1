//! Writing a rendered session: images, `session.toml`, `frames.csv` and ground truth.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::{IsometryMatrix3, Point3, Vector3};
use rayon::prelude::*;

use super::skin::{self, DotWear, ShadowBand, SkinLayout, SkinSurface};
use super::{
    BitDepth, Performer, Polarity, ProfileOutput, Samples, Scene, SynthError, SynthParams,
    neutral_head_pose, quaternion_wxyz, raster, shade, slip, to_gray8, to_u16, write_png,
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
    distractors: String,
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
    let skin_layout = place_skin(performer, layout, params, &material)?;
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
        // Each marker's wear in this frame (a dot wiped off mid-take is intact before).
        let wear: Vec<DotWear> = skin_layout.wear.iter().map(|w| w.at_frame(f)).collect();
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
            let t_sub = t + offset / params.fps;
            let cam0_from_head: IsometryMatrix3<f64> = head0 * slip(params, t_sub, &pivot);
            let shadow = ShadowBand::at(&params.skin, t_sub, &(head0 * pivot), params.seed);
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
                    rest_positions: &neutral.positions,
                    skin: &skin_layout,
                    wear: &wear,
                    cam0_from_cam: if c == 0 {
                        IsometryMatrix3::identity()
                    } else {
                        rig.cam1_from_cam0.inverse()
                    },
                    shadow,
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
        let gain = skin::flicker_gain(
            &params.skin,
            f,
            params.fps,
            params.shutter_fraction / params.fps,
            params.seed,
        ) as f32;
        let ch = params.channels();
        for (c, cam) in cams.iter().enumerate() {
            let (w, h) = (cam.width_px as usize, cam.height_px as usize);
            let img = &mut radiance[c];
            if samples > 1 {
                let k = 1.0 / samples as f32;
                img.iter_mut().for_each(|v| *v *= k);
            }
            if gain != 1.0 {
                img.iter_mut().for_each(|v| *v *= gain);
            }
            blur_channels(img, w, h, ch, params.blur_px);
            let seed = params
                .seed
                .wrapping_mul(1_000_003)
                .wrapping_add((f as u64) * 2 + c as u64);
            let path = out.join(format!("cam{c}/{f:06}.png"));
            if params.bit_depth == BitDepth::Eight {
                let samples8 = to_gray8(img, params.noise_dn, seed);
                write_png(
                    &path,
                    cam.width_px,
                    cam.height_px,
                    ch,
                    Samples::Eight(&samples8),
                )?;
            } else {
                let samples16 = to_u16(img, params.noise_dn, seed, params.bit_depth);
                write_png(
                    &path,
                    cam.width_px,
                    cam.height_px,
                    ch,
                    Samples::Sixteen(&samples16),
                )?;
            }
        }
        // Ground truth.
        let mut bundles = String::new();
        let mut projections = String::new();
        let mut visible = [0usize; 4];
        for (k, m) in layout.markers.iter().enumerate() {
            let wiped = matches!(wear.get(k), Some(DotWear::Wiped { .. }));
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
                // A wiped dot is not there to detect.
                let det = !wiped
                    && look
                        .is_some_and(|a| seen && a.detectable(params.detectable_min_minor_axis_px));
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
        let distractors = distractor_rows(
            f,
            &cams,
            rig,
            &cam0_from_head,
            &positions,
            &normals,
            neutral,
            layout,
            &skin_layout,
            &wear,
            centre_views.as_slice(),
            params.marker_radius_mm,
        );
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
            distractors,
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
    let profile_text = match &params.profile {
        ProfileOutput::None => None,
        ProfileOutput::Generated => Some(generated_profile(params, rig, &head0, neutral, layout)),
        ProfileOutput::Text(t) => Some(t.clone()),
    };
    let profile_line = if let Some(text) = &profile_text {
        write_text(&out.join("profile.toml"), text)?;
        "profile = \"profile.toml\"\n"
    } else {
        ""
    };
    let session = format!(
        "# Synthetic helmet session rendered by helmcap synth.\nfps = {:?}\ncameras = [\"cam0\", \"cam1\"]\ncalibration = \"calibration.yaml\"\n{profile_line}\n[timecode]\nrate = \"{}\"\nstart = \"{}\"\n",
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
    let mut distractors = String::from("frame,camera,kind,u,v,diameter_px,marker\n");
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
        distractors.push_str(&t.distractors);
        summary.visible_cam0 += t.visible[0];
        summary.visible_cam1 += t.visible[1];
        summary.visible_both += t.visible[2];
        summary.detectable_both += t.visible[3];
    }
    write_text(&out.join("gt/bundles.csv"), &bundles)?;
    write_text(&out.join("gt/head_pose.csv"), &poses)?;
    write_text(&out.join("gt/projections.csv"), &projections)?;
    if params.skin.any() {
        write_text(&out.join("gt/distractors.csv"), &distractors)?;
    }
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

/// Gaussian blur of each channel of an interleaved image.
fn blur_channels(img: &mut [f32], w: usize, h: usize, channels: usize, sigma_px: f64) {
    if sigma_px <= 0.0 {
        return;
    }
    if channels == 1 {
        raster::gaussian_blur(img, w, h, sigma_px);
        return;
    }
    let mut plane = vec![0.0f32; w * h];
    for c in 0..channels {
        for (p, v) in plane.iter_mut().zip(img.iter().skip(c).step_by(channels)) {
            *p = *v;
        }
        raster::gaussian_blur(&mut plane, w, h, sigma_px);
        for (v, p) in img.iter_mut().skip(c).step_by(channels).zip(&plane) {
            *v = *p;
        }
    }
}

/// Places the skin's features on the performer: face skin is every triangle whose
/// corners are all face vertices (not eyeball); eyebrow hair goes in the built-in
/// actor's brow regions.
fn place_skin(
    performer: &Performer,
    layout: &MarkerLayout,
    params: &SynthParams,
    material: &[u8],
) -> Result<SkinLayout, SynthError> {
    if !params.skin.any() {
        return Ok(SkinLayout {
            wear: vec![DotWear::Intact; layout.len()],
            ..SkinLayout::default()
        });
    }
    let neutral = performer.neutral();
    let face_vertex: Vec<bool> = match performer {
        Performer::Actor(a) => a.regions().iter().map(|r| r.is_face()).collect(),
        Performer::Dataset(d) => (0..neutral.vertex_count() as u32)
            .map(|v| d.is_face_vertex(v))
            .collect(),
    };
    let skin_triangle: Vec<bool> = neutral
        .triangles
        .iter()
        .zip(material)
        .map(|(t, &m)| {
            m == 0
                && t.iter()
                    .all(|&v| face_vertex.get(v as usize).copied().unwrap_or(false))
        })
        .collect();
    let brow_vertices: Vec<u32> = match performer {
        Performer::Actor(a) => a
            .regions()
            .iter()
            .enumerate()
            .filter(|(_, r)| {
                matches!(
                    r,
                    crate::dataset::actor::Region::BrowL | crate::dataset::actor::Region::BrowR
                )
            })
            .map(|(v, _)| v as u32)
            .collect(),
        Performer::Dataset(_) => Vec::new(),
    };
    let marker_vertices: Vec<u32> = layout.markers.iter().map(|m| m.vertex).collect();
    skin::place(
        &params.skin,
        &SkinSurface {
            mesh: neutral,
            skin_triangle: &skin_triangle,
            brow_vertices: &brow_vertices,
            marker_vertices: &marker_vertices,
            dot_radius_mm: params.marker_radius_mm,
            skin_color: params.skin_rgb(),
        },
        params.seed,
    )
}

/// Rows of `gt/distractors.csv` for one frame: every freckle, mole and hair stroke
/// (centre; `diameter_px` the projected major axis of a spot, or a stroke's length) and
/// every dot smudged or wiped in this frame (`wear`, with its marker name) whose centre is
/// visible and whose extent is mostly unoccluded and inside the image.
#[allow(clippy::too_many_arguments)]
fn distractor_rows(
    f: usize,
    cams: &[&crate::camera::Camera; 2],
    rig: &StereoRig,
    cam0_from_head: &IsometryMatrix3<f64>,
    positions: &[Point3<f64>],
    normals: &[Vector3<f64>],
    neutral: &crate::mesh::Mesh,
    layout: &MarkerLayout,
    skin_layout: &SkinLayout,
    wear: &[DotWear],
    views: &[Option<raster::Fragments>],
    dot_radius_mm: f64,
) -> String {
    let mut rows = String::new();
    if skin_layout.features.is_empty() && wear.iter().all(|w| *w == DotWear::Intact) {
        return rows;
    }
    for (c, cam) in cams.iter().enumerate() {
        let Some(frags) = views.get(c).and_then(|v| v.as_ref()) else {
            continue;
        };
        let cam_from_head = if c == 0 {
            *cam0_from_head
        } else {
            rig.cam1_from_cam0 * cam0_from_head
        };
        let mut row = |kind: &str,
                       centre: Point3<f64>,
                       normal: Vector3<f64>,
                       radius: f64,
                       length: Option<f64>,
                       marker: &str| {
            let pc = cam_from_head * centre;
            let nc = cam_from_head.rotation * normal;
            let Some(look) = dot_appearance(cam, frags, &pc, &nc, radius) else {
                return;
            };
            if look.view_angle_deg >= 90.0 || look.unoccluded_fraction < 0.5 || !look.inside_image {
                return;
            }
            let Some(px) = cam.project(&pc.coords) else {
                return;
            };
            let diameter = length.map_or(look.major_axis_px, |l| l * cam.fx() / pc.coords.norm());
            let _ = writeln!(
                rows,
                "{f},cam{c},{kind},{:.4},{:.4},{diameter:.3},{marker}",
                px.x, px.y
            );
        };
        for feat in &skin_layout.features {
            let mid = &feat.anchors[feat.anchors.len() / 2];
            let centre = mid.locate(&neutral.triangles, positions);
            let normal = mid.normal(&neutral.triangles, normals);
            let length = (feat.kind == skin::FeatureKind::Hair).then(|| {
                feat.anchors
                    .windows(2)
                    .map(|w| {
                        (w[1].locate(&neutral.triangles, positions)
                            - w[0].locate(&neutral.triangles, positions))
                        .norm()
                    })
                    .sum::<f64>()
            });
            row(feat.kind.name(), centre, normal, feat.radius_mm, length, "");
        }
        for (m, wear) in layout.markers.iter().zip(wear) {
            if let Some(kind) = wear.name() {
                let v = m.vertex as usize;
                row(kind, positions[v], normals[v], dot_radius_mm, None, &m.name);
            }
        }
    }
    rows
}

/// The capture profile a rig operator would write for this session: dot diameter,
/// polarity, colour (8-bit levels of the paint's albedo), and the nearest and farthest
/// distance from either camera to any dot in the neutral pose, widened by 15 % and
/// rounded outward to 5 mm.
fn generated_profile(
    params: &SynthParams,
    rig: &StereoRig,
    head0: &IsometryMatrix3<f64>,
    neutral: &crate::mesh::Mesh,
    layout: &MarkerLayout,
) -> String {
    let c1 = rig.cam1_centre_in_cam0();
    let (mut near, mut far) = (f64::MAX, 0.0f64);
    for m in &layout.markers {
        if let Some(p) = neutral.positions.get(m.vertex as usize) {
            let q = head0 * p;
            for d in [q.coords.norm(), (q - c1).norm()] {
                near = near.min(d);
                far = far.max(d);
            }
        }
    }
    let near = ((near / 1.15) / 5.0).floor().max(1.0) * 5.0;
    let far = ((far * 1.15) / 5.0).ceil().max(near / 5.0 + 1.0) * 5.0;
    let mut text = format!(
        "# Capture profile of a synthetic helmet session (helmcap synth).\n\
         dot_diameter_mm = {:?}\npolarity = \"{}\"\n",
        params.dot_diameter_mm(),
        match params.polarity {
            Polarity::Dark => "dark",
            Polarity::Bright => "bright",
        }
    );
    if let (Some(c), Polarity::Dark) = (params.color, params.polarity) {
        let [r, g, b] = c.dot_rgb.map(|x| (x * 255.0).round());
        let _ = writeln!(text, "color = [{r:?}, {g:?}, {b:?}]");
    }
    let _ = writeln!(text, "camera_distance_mm = [{near:?}, {far:?}]");
    text
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;
    use std::path::PathBuf;
    use std::sync::OnceLock;

    use super::*;
    use crate::dataset::actor::{Actor, ActorParams};
    use crate::synth::{ColorParams, RigParams, SkinParams, animation};

    /// The built-in actor and its layout, built once for all tests.
    fn actor() -> &'static (Performer, MarkerLayout) {
        static A: OnceLock<(Performer, MarkerLayout)> = OnceLock::new();
        A.get_or_init(|| {
            let actor = Actor::new(&ActorParams::default()).unwrap();
            let layout = MarkerLayout::parse_csv(
                include_str!("../../configs/markers/builtin-actor.csv"),
                "builtin-actor.csv",
            )
            .unwrap();
            (Performer::Actor(Box::new(actor)), layout)
        })
    }

    /// A small near rig: 640×512 fisheye at 85°, 120 mm from the face (about 3.5 px/mm).
    fn small_rig() -> StereoRig {
        RigParams {
            width_px: 640,
            height_px: 512,
            fov_deg: 85.0,
            baseline_mm: 50.0,
            convergence_mm: 120.0,
            ..RigParams::default()
        }
        .build()
        .unwrap()
    }

    /// Noise-free parameters for the small rig.
    fn base() -> SynthParams {
        SynthParams {
            face_distance_mm: 120.0,
            marker_radius_mm: 1.3,
            noise_dn: 0.0,
            ..SynthParams::default()
        }
    }

    struct Image {
        width: usize,
        channels: usize,
        depth16: bool,
        samples: Vec<u16>,
    }

    impl Image {
        fn at(&self, x: usize, y: usize, c: usize) -> f64 {
            f64::from(self.samples[(y * self.width + x) * self.channels + c])
        }
        /// Grey value (channel mean) at a rounded pixel.
        fn grey(&self, u: f64, v: f64) -> f64 {
            let (x, y) = (u.round() as usize, v.round() as usize);
            (0..self.channels).map(|c| self.at(x, y, c)).sum::<f64>() / self.channels as f64
        }
    }

    fn read_png(path: &Path) -> Image {
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0u8; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        buf.truncate(info.buffer_size());
        let channels = info.color_type.samples();
        let depth16 = info.bit_depth == png::BitDepth::Sixteen;
        let samples = if depth16 {
            buf.chunks_exact(2)
                .map(|b| u16::from_be_bytes([b[0], b[1]]))
                .collect()
        } else {
            buf.iter().map(|&b| u16::from(b)).collect()
        };
        Image {
            width: info.width as usize,
            channels,
            depth16,
            samples,
        }
    }

    /// Renders `frames` frames into a fresh temporary folder.
    fn render(params: &SynthParams, frames: usize) -> tempfile::TempDir {
        let (performer, layout) = actor();
        let names = performer.expression_names();
        let weights = animation::random_curves(&names, frames, params.fps, &Default::default());
        let dir = tempfile::tempdir().unwrap();
        render_session(
            performer,
            layout,
            &small_rig(),
            &weights,
            params,
            dir.path(),
            false,
            &|| {},
        )
        .unwrap();
        dir
    }

    fn image(dir: &Path, cam: usize, frame: usize) -> Image {
        read_png(&dir.join(format!("cam{cam}/{frame:06}.png")))
    }

    /// Rows of a CSV file as maps from the header's names.
    fn rows(path: PathBuf) -> Vec<HashMap<String, String>> {
        let text = std::fs::read_to_string(path).unwrap();
        let mut lines = text.lines();
        let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
        lines
            .map(|l| {
                header
                    .iter()
                    .cloned()
                    .zip(l.split(',').map(String::from))
                    .collect()
            })
            .collect()
    }

    fn num(row: &HashMap<String, String>, key: &str) -> f64 {
        row[key].parse().unwrap()
    }

    #[test]
    fn moles_freckles_and_hair_are_dark_spots_fixed_on_the_skin() {
        let skin = SkinParams {
            freckles: 200,
            moles: 10,
            hair_strokes: 30,
            ..SkinParams::default()
        };
        // Helmet slip moves the face across the image between frames.
        let clean_params = SynthParams {
            slip_mm: 2.0,
            slip_deg: 1.5,
            slip_period_secs: 0.5,
            ..base()
        };
        let frames = 3;
        let clean = render(&clean_params, frames);
        let dirty = render(
            &SynthParams {
                skin,
                ..clean_params.clone()
            },
            frames,
        );
        assert!(!clean.path().join("gt/distractors.csv").exists());
        let distractors = rows(dirty.path().join("gt/distractors.csv"));
        let mut checked: HashMap<&str, (usize, usize)> = HashMap::new();
        let mut mole_positions = Vec::new();
        for r in &distractors {
            let (f, c) = (num(r, "frame") as usize, r["camera"] == "cam1");
            let (u, v) = (num(r, "u"), num(r, "v"));
            let kind = r["kind"].as_str();
            let a = image(clean.path(), usize::from(c), f).grey(u, v);
            let b = image(dirty.path(), usize::from(c), f).grey(u, v);
            if a < 30.0 {
                continue; // shadowed grazing skin: nothing to compare
            }
            let entry = checked.entry(kind).or_default();
            entry.0 += 1;
            let dark = match kind {
                // Moles are as dark as the ink (albedo 0.09 vs skin 0.62).
                "mole" => b < 0.45 * a,
                // Freckles darken their centre by 10-30 % (less where small and soft).
                "freckle" => b < 0.97 * a,
                // A hair 0.12 mm wide covers about a third of a 0.3 mm pixel; the
                // stroke's middle anchor may sit between pixel centres.
                "hair" => b < a - 3.0,
                _ => true,
            };
            entry.1 += usize::from(dark);
            if kind == "mole" && f == 0 && !c {
                mole_positions.push((u, v));
            }
            if kind == "mole" && f == 2 && !c {
                mole_positions.push((u, v));
            }
        }
        // A few moles sit on skin seen nearly edge-on, where a 1.5 mm spot is a sliver.
        for (kind, min_share) in [("mole", 0.9), ("freckle", 0.8), ("hair", 0.6)] {
            let (n, dark) = checked.get(kind).copied().unwrap_or((0, 0));
            assert!(n >= 3, "{kind}: only {n} visible");
            assert!(
                dark as f64 >= min_share * n as f64,
                "{kind}: {dark} of {n} dark"
            );
        }
        // Moles never appear in the marker ground truth: a mole's centre lies outside every
        // dot on the skin (at least the dot's radius away), so its projection lies
        // outside the dot's projected minor half-axis (the skin foreshortens both alike;
        // a fixed pixel distance fails beside dots seen at a slant).
        let projections = rows(dirty.path().join("gt/projections.csv"));
        for r in distractors.iter().filter(|r| r["kind"] == "mole") {
            for p in projections
                .iter()
                .filter(|p| p["frame"] == r["frame"] && p["camera"] == r["camera"])
            {
                let d = (num(p, "u") - num(r, "u")).hypot(num(p, "v") - num(r, "v"));
                assert!(
                    d > 0.5 * num(p, "minor_axis_px"),
                    "mole at a marker: {r:?} {p:?}"
                );
            }
        }
        // The slip moved the moles between frame 0 and 2 (they are on the skin, not on
        // the image).
        assert!(mole_positions.len() >= 4);
    }

    #[test]
    fn wiped_dots_leave_no_blob_and_smudged_dots_are_fainter_but_detectable() {
        let skin = SkinParams {
            smudged_dots: 10,
            wiped_dots: 10,
            ..SkinParams::default()
        };
        let clean = render(&base(), 1);
        let worn = render(&SynthParams { skin, ..base() }, 1);
        let rows = rows(worn.path().join("gt/distractors.csv"));
        let proj = rows_by_marker(worn.path());
        let clean_img = image(clean.path(), 0, 0);
        let worn_img = image(worn.path(), 0, 0);
        let (mut wiped, mut smudged) = (0, 0);
        for r in rows.iter().filter(|r| r["camera"] == "cam0") {
            let (u, v) = (num(r, "u"), num(r, "v"));
            let p = &proj[&(r["marker"].clone(), "cam0".to_string())];
            let before = clean_img.grey(u, v);
            let after = worn_img.grey(u, v);
            // Skin level: the darkest ring pixel 2 radii out in the clean image is not
            // inked; take the median of the ring in the worn image.
            let radius = 0.5 * num(r, "diameter_px");
            let ring = ring_median(&worn_img, u, v, 2.0 * radius + 2.0);
            match r["kind"].as_str() {
                "wiped_dot" => {
                    wiped += 1;
                    assert_eq!(p["detectable"], "0", "{r:?}");
                    // At the face's silhouette or in deep shadow the ring holds the black
                    // background: no skin level to compare with.
                    if ring < 60.0 {
                        continue;
                    }
                    // No ink left: every pixel of the disc is far lighter than ink (ink is
                    // about 13 % of the skin's level; the skin's own shading, pores and
                    // sensor noise vary by up to a fifth across a disc).
                    let disc_min = disc_min(&worn_img, u, v, radius);
                    assert!(disc_min > 0.5 * ring, "{r:?}: {disc_min} vs skin {ring}");
                    assert!(after > 2.0 * before, "{r:?}: {after} vs inked {before}");
                }
                "smudged_dot" => {
                    smudged += 1;
                    // Lighter than the intact dot, darker than the skin.
                    assert!(after > before + 5.0, "{r:?}: {after} vs {before}");
                    assert!(after < 0.85 * ring, "{r:?}: {after} vs skin {ring}");
                    if p["visible"] == "1" && num(p, "minor_axis_px") > 4.0 {
                        assert_eq!(p["detectable"], "1", "{p:?}");
                    }
                }
                _ => {}
            }
        }
        assert!(wiped >= 3 && smudged >= 3, "{wiped} {smudged}");
    }

    #[test]
    fn a_dot_wiped_mid_take_is_inked_before_its_frame_and_gone_after() {
        let wiped_at = |frames: (usize, usize)| SynthParams {
            skin: SkinParams {
                wiped_dots: 10,
                wipe_frames: frames,
                ..SkinParams::default()
            },
            ..base()
        };
        let clean = render(&base(), 2);
        let from_start = render(&wiped_at((0, 0)), 2);
        let mid_take = render(&wiped_at((1, 1)), 2);
        // Frame 0: the dots wiped off on frame 1 are still there, as in the clean take.
        assert_eq!(
            image(mid_take.path(), 0, 0).samples,
            image(clean.path(), 0, 0).samples
        );
        assert_ne!(
            image(from_start.path(), 0, 0).samples,
            image(clean.path(), 0, 0).samples
        );
        // Frame 1: gone, as if wiped from the start.
        assert_eq!(
            image(mid_take.path(), 0, 1).samples,
            image(from_start.path(), 0, 1).samples
        );
        // The ground truth follows: no wiped dot on frame 0, and each wiped dot of frame 1
        // not detectable.
        let gone: Vec<HashMap<String, String>> = rows(mid_take.path().join("gt/distractors.csv"))
            .into_iter()
            .filter(|r| r["kind"] == "wiped_dot")
            .collect();
        assert!(gone.iter().all(|r| r["frame"] == "1"));
        assert!(gone.len() >= 3, "{} wiped dots seen", gone.len());
        let projections = rows(mid_take.path().join("gt/projections.csv"));
        for r in &gone {
            let p = projections
                .iter()
                .find(|p| {
                    p["frame"] == "1" && p["marker"] == r["marker"] && p["camera"] == r["camera"]
                })
                .unwrap();
            assert_eq!(p["detectable"], "0", "{p:?}");
        }
        let markers: Vec<&String> = gone.iter().map(|r| &r["marker"]).collect();
        let detectable_before = projections
            .iter()
            .filter(|p| p["frame"] == "0" && markers.contains(&&p["marker"]))
            .filter(|p| p["detectable"] == "1")
            .count();
        assert!(detectable_before >= 3, "{detectable_before}");
    }

    fn rows_by_marker(dir: &Path) -> HashMap<(String, String), HashMap<String, String>> {
        rows(dir.join("gt/projections.csv"))
            .into_iter()
            .map(|r| ((r["marker"].clone(), r["camera"].clone()), r))
            .collect()
    }

    fn ring_median(img: &Image, u: f64, v: f64, r: f64) -> f64 {
        let mut vals: Vec<f64> = (0..32)
            .map(|k| {
                let a = std::f64::consts::TAU * f64::from(k) / 32.0;
                img.grey(u + r * a.cos(), v + r * a.sin())
            })
            .collect();
        vals.sort_by(f64::total_cmp);
        vals[16]
    }

    fn disc_min(img: &Image, u: f64, v: f64, r: f64) -> f64 {
        let mut m = f64::MAX;
        let r = r.max(1.0);
        let ri = r.ceil() as i64;
        for dy in -ri..=ri {
            for dx in -ri..=ri {
                if ((dx * dx + dy * dy) as f64) <= r * r {
                    m = m.min(img.grey(u + dx as f64, v + dy as f64));
                }
            }
        }
        m
    }

    #[test]
    fn flicker_scales_each_frame_as_configured() {
        let skin = SkinParams {
            flicker_amplitude: 0.4,
            flicker_hz: 100.0,
            ..SkinParams::default()
        };
        let p = SynthParams {
            skin: skin.clone(),
            ..base()
        };
        let frames = 4;
        let steady = render(&base(), frames);
        let flick = render(&p, frames);
        let mut gains = Vec::new();
        for f in 0..frames {
            let a = image(steady.path(), 0, f);
            let b = image(flick.path(), 0, f);
            let (mut sa, mut sb) = (0.0, 0.0);
            for (x, y) in a.samples.iter().zip(&b.samples) {
                // Unclipped, well-lit pixels.
                if (40..200).contains(x) && *y < 250 {
                    sa += f64::from(*x);
                    sb += f64::from(*y);
                }
            }
            let expected = skin::flicker_gain(&skin, f, 60.0, 0.5 / 60.0, p.seed);
            let measured = sb / sa;
            assert!(
                (measured - expected).abs() < 0.01,
                "frame {f}: {measured} vs {expected}"
            );
            gains.push(expected);
        }
        // The frames really differ (100 Hz on 60 fps beats at 20 Hz).
        let spread = gains.iter().copied().fold(f64::MIN, f64::max)
            - gains.iter().copied().fold(f64::MAX, f64::min);
        assert!(spread > 0.05, "{gains:?}");
    }

    #[test]
    fn shadow_sheen_and_pores_change_the_skin_as_configured() {
        let clean = image(render(&base(), 1).path(), 0, 0);
        let with =
            |skin: SkinParams| image(render(&SynthParams { skin, ..base() }, 1).path(), 0, 0);
        let ratios = |img: &Image| -> Vec<f64> {
            clean
                .samples
                .iter()
                .zip(&img.samples)
                .filter(|(a, _)| (40..230).contains(*a))
                .map(|(a, b)| f64::from(*b) / f64::from(*a))
                .collect()
        };
        // Boom shadow: a band of the face loses up to 60 % of the direct light; nothing
        // gets brighter.
        let shadow = ratios(&with(SkinParams {
            boom_shadow: 0.6,
            ..SkinParams::default()
        }));
        let dark = shadow.iter().filter(|r| **r < 0.8).count() as f64 / shadow.len() as f64;
        assert!((0.03..0.7).contains(&dark), "{dark}");
        assert!(shadow.iter().all(|r| *r < 1.02));
        assert!(shadow.iter().copied().fold(1.0, f64::min) < 0.6);
        // Pores: albedo varies pixel to pixel with about the configured spread.
        let pores = ratios(&with(SkinParams {
            pores: 0.1,
            ..SkinParams::default()
        }));
        let m = pores.iter().sum::<f64>() / pores.len() as f64;
        let sd = (pores.iter().map(|r| (r - m).powi(2)).sum::<f64>() / pores.len() as f64).sqrt();
        assert!((0.03..0.2).contains(&sd), "{sd}");
        // Sheen: wet highlights saturate more pixels than the dry skin's.
        let sheen = with(SkinParams {
            sheen: 1.5,
            pores: 0.02,
            ..SkinParams::default()
        });
        let bright = |img: &Image| img.samples.iter().filter(|v| **v >= 250).count();
        assert!(
            bright(&sheen) > bright(&clean) + 50,
            "{} {}",
            bright(&sheen),
            bright(&clean)
        );
    }

    #[test]
    fn colour_dots_have_their_hue_and_bright_dots_shine() {
        let green = render(
            &SynthParams {
                color: Some(ColorParams::default()),
                ..base()
            },
            1,
        );
        let img = image(green.path(), 0, 0);
        assert_eq!(img.channels, 3);
        let proj = rows(green.path().join("gt/projections.csv"));
        let mut n = 0;
        for r in proj
            .iter()
            .filter(|r| r["camera"] == "cam0" && r["detectable"] == "1")
        {
            if num(r, "minor_axis_px") < 5.0 {
                continue;
            }
            let (x, y) = (num(r, "u").round() as usize, num(r, "v").round() as usize);
            let [red, g, b] = [0, 1, 2].map(|c| img.at(x, y, c));
            if g < 20.0 {
                continue;
            }
            n += 1;
            let hue = hue_deg(red, g, b);
            assert!(
                (100.0..160.0).contains(&hue),
                "{r:?}: rgb {red} {g} {b} hue {hue}"
            );
        }
        assert!(n > 20, "{n}");
        // The skin is skin-coloured: red over green over blue.
        let (sx, sy) = (320, 256);
        let skin = [0, 1, 2].map(|c| img.at(sx, sy, c));
        assert!(skin[0] > skin[1] && skin[1] > skin[2], "{skin:?}");

        let bright = render(
            &SynthParams {
                polarity: Polarity::Bright,
                exposure_dn: 150.0,
                ..base()
            },
            1,
        );
        let img = image(bright.path(), 0, 0);
        let mut n = 0;
        for r in rows(bright.path().join("gt/projections.csv"))
            .iter()
            .filter(|r| r["camera"] == "cam0" && r["detectable"] == "1")
        {
            let (u, v) = (num(r, "u"), num(r, "v"));
            let ring = ring_median(&img, u, v, 0.5 * num(r, "minor_axis_px") + 6.0);
            if num(r, "minor_axis_px") > 5.0 {
                n += 1;
                assert!(img.grey(u, v) > ring + 40.0, "{r:?}");
            }
        }
        assert!(n > 20);
    }

    fn hue_deg(r: f64, g: f64, b: f64) -> f64 {
        let max = r.max(g).max(b);
        let min = r.min(g).min(b);
        let d = (max - min).max(1e-9);
        let h = if max == r {
            ((g - b) / d).rem_euclid(6.0)
        } else if max == g {
            (b - r) / d + 2.0
        } else {
            (r - g) / d + 4.0
        };
        60.0 * h
    }

    #[test]
    fn twelve_bit_data_in_sixteen_bit_png() {
        let dir = render(
            &SynthParams {
                bit_depth: BitDepth::Twelve,
                noise_dn: 1.5,
                ..base()
            },
            1,
        );
        let img = image(dir.path(), 1, 0);
        assert!(img.depth16);
        assert!(img.samples.iter().all(|v| v % 16 == 0));
        let max = img.samples.iter().copied().max().unwrap();
        assert!(max >> 4 > 3000, "{max}");
        let distinct: std::collections::HashSet<u16> = img.samples.iter().copied().collect();
        assert!(distinct.len() > 1000, "{}", distinct.len());
    }

    #[test]
    fn generated_profile_is_a_valid_capture_profile() {
        let dir = render(
            &SynthParams {
                profile: ProfileOutput::Generated,
                color: Some(ColorParams::default()),
                ..base()
            },
            1,
        );
        let session = std::fs::read_to_string(dir.path().join("session.toml")).unwrap();
        assert!(session.contains("profile = \"profile.toml\""), "{session}");
        let profile =
            crate::track::profile::CaptureProfile::load(&dir.path().join("profile.toml")).unwrap();
        assert_eq!(profile.dot_diameter_mm, 2.6);
        assert_eq!(profile.color, Some([20.0, 115.0, 41.0]));
        let (near, far) = profile.camera_distance_mm;
        // The face is about 120 mm from the cameras: nose tip nearer, cheeks farther.
        assert!(
            (50.0..110.0).contains(&near) && (130.0..250.0).contains(&far),
            "{near} {far}"
        );
        let replay = crate::capture::Replay::open(dir.path(), Default::default());
        assert!(replay.is_ok(), "{replay:?}");
    }
}
