//! Synthetic helmet footage: renders a recording session (DESIGN.md §4) of an actor with
//! painted face markers, seen by a calibrated stereo rig, with ground truth under `gt/`;
//! and images of calibration targets for a rig.
//!
//! Depends on [`crate::camera`], [`crate::dataset`] and [`crate::mesh`].
//!
//! # Image model
//! Per camera and frame: the face mesh (head frame → cam0 → camera) is rasterized with a
//! depth buffer ([`raster::Fragments`]), so markers are hidden by the nose, the lips and
//! closing eyelids exactly as the geometry says. Markers are discs of ink of radius
//! [`SynthParams::marker_radius_mm`] on the skin around their vertex: a pixel is inked by its
//! surface point's 3D distance to the marker centre (antialiased over one pixel footprint),
//! so dots are foreshortened on slanted skin. Radiance is
//! `albedo · (ambient + (1 − ambient)·max(0, n·l)) · (d₀/d)²` plus a Blinn-Phong highlight,
//! for a light at each camera (a helmet LED ring), then a vignette, optional Gaussian and
//! motion blur, Gaussian sensor noise and 8-bit quantization.

pub mod animation;
pub mod preset;
pub mod raster;
pub mod rig;
mod session;
pub mod skin;
pub mod target;

pub use animation::AnimationParams;
pub use preset::{PRESET_NAMES, Preset, preset, presets};
pub use rig::{LensModel, RigParams};
pub use session::{
    DETECTABLE_BORDER_PX, DotAppearance, SessionSummary, dot_appearance, render_session,
};
pub use skin::SkinParams;

use std::path::PathBuf;

use nalgebra::{
    IsometryMatrix3, Matrix3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};
use rand::RngCore;

use crate::camera::{Camera, StereoRig};
use crate::dataset::MarkerLayout;
use crate::dataset::actor::Actor;
use crate::mesh::Mesh;
use crate::numeric::{SplitMix64, standard_normal};
use crate::timecode::{Timecode, TimecodeRate};
pub use crate::track::profile::Polarity;

/// Errors of the synthesizer.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// A parameter is out of range.
    #[error("invalid synth parameter: {0}")]
    Params(String),
    /// The weights CSV is invalid.
    #[error("{path}:{line}: {message}")]
    Weights {
        /// The file.
        path: PathBuf,
        /// 1-based line (0: the whole file).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// Writing an output failed.
    #[error("writing {path}: {message}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The marker layout does not fit the performer's mesh.
    #[error("marker layout: {0}")]
    Layout(String),
}

/// Rendering and session parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthParams {
    /// Frames per second of the session. Default 60.
    pub fps: f64,
    /// Distance from the midpoint of the two camera centres to the face centre (the
    /// centroid of the markers), mm. Default 225.
    pub face_distance_mm: f64,
    /// Radius of a painted marker dot, mm. Default 1.2.
    pub marker_radius_mm: f64,
    /// Skin albedo (0..1). Default 0.62.
    pub skin_albedo: f64,
    /// Marker ink albedo (0..1). Default 0.08.
    pub ink_albedo: f64,
    /// Ambient share of the lighting (0..1). Default 0.25.
    pub ambient: f64,
    /// Exposure: 8-bit value of a lit white surface facing the camera at the face
    /// distance. Default 250.
    pub exposure_dn: f64,
    /// Strength of the specular highlight (0: none). Default 0.25.
    pub specular: f64,
    /// Sensor noise standard deviation, 8-bit levels. Default 1.5.
    pub noise_dn: f64,
    /// Gaussian blur (defocus) sigma, pixels (0: none). Default 0.
    pub blur_px: f64,
    /// Motion blur: sub-frame renders averaged over the shutter (1: none). Default 1.
    pub motion_blur_samples: usize,
    /// Shutter open time as a fraction of the frame interval. Default 0.5.
    pub shutter_fraction: f64,
    /// Helmet slip: amplitude of the slow rigid drift of the head relative to the
    /// cameras, translation mm (0: no slip). Default 0.
    pub slip_mm: f64,
    /// Helmet slip: rotation amplitude, degrees. Default 0.
    pub slip_deg: f64,
    /// Period scale of the slip, seconds. Default 4.
    pub slip_period_secs: f64,
    /// Seed of noise and slip. Default 7.
    pub seed: u64,
    /// Timecode of frame 0 (`HH:MM:SS:FF`, `;` before the frames for drop-frame rates),
    /// written in `frames.csv` and `session.toml`. Default `01:00:00:00`.
    pub timecode_start: String,
    /// Timecode rate. Default 30 (60 fps cameras on 30 fps code: two sub-frames).
    pub timecode_rate: TimecodeRate,
    /// Ground truth: smallest projected minor axis (full width) of a dot that counts as
    /// detectable, pixels. Default 2: by the sampling theorem a feature narrower than two
    /// pixels is not resolved as a shape, so a tracker cannot measure its width, tell it
    /// from a crease or noise by area and roundness, or place its centre across the thin
    /// axis better than the antialiasing of one pixel row. For the default 2.4 mm dots at
    /// 225 mm (7.5 px across) this is a dot about 75° from facing the camera.
    pub detectable_min_minor_axis_px: f64,
    /// Dark ink dots, or bright ones (retroreflective under the helmet's ring light).
    /// Default dark.
    pub polarity: Polarity,
    /// Bright dots: radiance of a retroreflective dot facing the camera relative to a
    /// white diffuse surface (it falls off with the square root of the cosine of the
    /// entrance angle). Default 3 (saturates the sensor).
    pub bright_dot_gain: f64,
    /// Colour images (RGB PNG) with these colours; `None`: monochrome. Default none.
    pub color: Option<ColorParams>,
    /// Bits per sample of the written images. Default 8.
    pub bit_depth: BitDepth,
    /// Freckles, moles, hair, pores, sheen, flicker, boom shadow, worn dots. Default all
    /// off.
    pub skin: SkinParams,
    /// Whether the session gets a capture profile (`profile.toml`, named in
    /// `session.toml`). Default none.
    pub profile: ProfileOutput,
}

/// Colours of a colour camera's view (linear RGB albedo, 0..1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColorParams {
    /// Skin albedo. Default `[0.74, 0.58, 0.49]` (a light skin tone; luma about the grey
    /// default's 0.62).
    pub skin_rgb: [f64; 3],
    /// Dot paint albedo (dark dots; bright dots are white under the ring light). Default
    /// green `[0.08, 0.45, 0.16]`.
    pub dot_rgb: [f64; 3],
}

impl Default for ColorParams {
    fn default() -> Self {
        Self {
            skin_rgb: [0.74, 0.58, 0.49],
            dot_rgb: [0.08, 0.45, 0.16],
        }
    }
}

/// Bits per sample of the written PNG images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BitDepth {
    /// 8-bit samples.
    #[default]
    Eight,
    /// 12-bit sensor data in 16-bit words, shifted up by 4 bits (the low 4 bits zero), as
    /// machine-vision cameras deliver it.
    Twelve,
    /// Full 16-bit samples.
    Sixteen,
}

impl BitDepth {
    /// Largest sample value of the sensor data (before any shift into 16-bit words).
    pub fn max_value(self) -> u32 {
        match self {
            BitDepth::Eight => 255,
            BitDepth::Twelve => 4095,
            BitDepth::Sixteen => 65_535,
        }
    }
}

/// Whether and how a session's capture profile is written.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum ProfileOutput {
    /// No profile.
    #[default]
    None,
    /// A profile stating what a rig operator knows: dot diameter, polarity, colour, and
    /// the range of distances from the cameras to the dots (from the neutral pose, with a
    /// margin, rounded to 5 mm).
    Generated,
    /// This TOML text, as given (`synth --profile FILE`).
    Text(String),
}

impl Default for SynthParams {
    fn default() -> Self {
        Self {
            fps: 60.0,
            face_distance_mm: 225.0,
            marker_radius_mm: 1.2,
            skin_albedo: 0.62,
            ink_albedo: 0.08,
            ambient: 0.25,
            exposure_dn: 250.0,
            specular: 0.25,
            noise_dn: 1.5,
            blur_px: 0.0,
            motion_blur_samples: 1,
            shutter_fraction: 0.5,
            slip_mm: 0.0,
            slip_deg: 0.0,
            slip_period_secs: 4.0,
            seed: 7,
            timecode_start: "01:00:00:00".into(),
            timecode_rate: TimecodeRate::FPS_30,
            detectable_min_minor_axis_px: 2.0,
            polarity: Polarity::Dark,
            bright_dot_gain: 3.0,
            color: None,
            bit_depth: BitDepth::Eight,
            skin: SkinParams::default(),
            profile: ProfileOutput::None,
        }
    }
}

impl SynthParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`SynthError::Params`] naming the field.
    pub fn validate(&self) -> Result<(), SynthError> {
        let check = |ok: bool, field: &str| {
            if ok {
                Ok(())
            } else {
                Err(SynthError::Params(format!("{field} out of range")))
            }
        };
        check(self.fps > 0.0 && self.fps <= 1000.0, "fps")?;
        check(self.face_distance_mm > 20.0, "face_distance_mm")?;
        check(
            self.marker_radius_mm > 0.0 && self.marker_radius_mm < 10.0,
            "marker_radius_mm",
        )?;
        check((0.0..=1.0).contains(&self.skin_albedo), "skin_albedo")?;
        check((0.0..=1.0).contains(&self.ink_albedo), "ink_albedo")?;
        check((0.0..=1.0).contains(&self.ambient), "ambient")?;
        check(self.exposure_dn > 0.0, "exposure_dn")?;
        check(self.specular >= 0.0, "specular")?;
        check(self.noise_dn >= 0.0 && self.noise_dn < 100.0, "noise_dn")?;
        check(self.blur_px >= 0.0 && self.blur_px < 20.0, "blur_px")?;
        check(
            (1..=16).contains(&self.motion_blur_samples),
            "motion_blur_samples",
        )?;
        check(
            self.shutter_fraction > 0.0 && self.shutter_fraction <= 1.0,
            "shutter_fraction",
        )?;
        check(self.slip_mm >= 0.0 && self.slip_mm < 50.0, "slip_mm")?;
        check(self.slip_deg >= 0.0 && self.slip_deg < 30.0, "slip_deg")?;
        check(self.slip_period_secs > 0.0, "slip_period_secs")?;
        check(
            self.detectable_min_minor_axis_px.is_finite()
                && self.detectable_min_minor_axis_px >= 0.0,
            "detectable_min_minor_axis_px",
        )?;
        check(
            self.bright_dot_gain.is_finite() && self.bright_dot_gain > 0.0,
            "bright_dot_gain",
        )?;
        if let Some(c) = &self.color {
            let ok = |v: &[f64; 3]| v.iter().all(|x| (0.0..=1.0).contains(x));
            check(ok(&c.skin_rgb), "color.skin_rgb")?;
            check(ok(&c.dot_rgb), "color.dot_rgb")?;
        }
        self.skin.validate()?;
        self.start_timecode().map(|_| ())
    }

    /// Colour channels of the images: 3 for colour, 1 for grey.
    pub fn channels(&self) -> usize {
        if self.color.is_some() { 3 } else { 1 }
    }

    /// Skin albedo as linear RGB (grey: the same value thrice).
    pub fn skin_rgb(&self) -> [f64; 3] {
        self.color.map_or([self.skin_albedo; 3], |c| c.skin_rgb)
    }

    /// Painted dot diameter, mm.
    pub fn dot_diameter_mm(&self) -> f64 {
        2.0 * self.marker_radius_mm
    }

    /// The timecode of frame 0.
    ///
    /// # Errors
    /// [`SynthError::Params`] when `timecode_start` is not a label at `timecode_rate`.
    pub fn start_timecode(&self) -> Result<Timecode, SynthError> {
        Timecode::parse_at(&self.timecode_start, self.timecode_rate)
            .map_err(|e| SynthError::Params(format!("timecode_start: {e}")))
    }
}

/// The default helmet rig the footage is rendered with
/// ([`crate::camera::default_helmet_rig`]).
///
/// # Errors
/// Only if the shipped file were broken (a bug).
pub fn default_rig() -> Result<StereoRig, crate::camera::CalibFileError> {
    crate::camera::default_helmet_rig()
}

/// What is rendered: a mesh whose positions change per frame, with markers on vertices.
pub enum Performer {
    /// The built-in actor with its nonlinear expression model.
    Actor(Box<Actor>),
    /// A dataset's neutral plus linear combinations of its shapes.
    Dataset(Box<crate::dataset::Dataset>),
}

impl Performer {
    /// The neutral mesh.
    pub fn neutral(&self) -> &Mesh {
        match self {
            Performer::Actor(a) => a.neutral(),
            Performer::Dataset(d) => &d.neutral,
        }
    }

    /// Names of the expression weights.
    pub fn expression_names(&self) -> Vec<&str> {
        match self {
            Performer::Actor(a) => a.expression_names().to_vec(),
            Performer::Dataset(d) => d.shapes.iter().map(|s| s.name.as_str()).collect(),
        }
    }

    /// Vertex positions (head frame, mm) for weights.
    pub fn evaluate(&self, weights: &[f64]) -> Vec<Point3<f64>> {
        match self {
            Performer::Actor(a) => a.evaluate(weights).positions,
            Performer::Dataset(d) => {
                let mut pos = d.neutral.positions.clone();
                for (s, &w) in d.shapes.iter().zip(weights) {
                    if w != 0.0 {
                        for ((p, q), n) in
                            pos.iter_mut().zip(&s.positions).zip(&d.neutral.positions)
                        {
                            *p += (q - n) * w;
                        }
                    }
                }
                pos
            }
        }
    }

    /// Vertices whose surface is an eye (rendered as eyeball, never inked).
    fn eyeball_ranges(&self) -> Vec<std::ops::Range<usize>> {
        match self {
            Performer::Actor(a) => a.eyeball_vertices().to_vec(),
            Performer::Dataset(_) => Vec::new(),
        }
    }
}

/// Places the head: `cam0_from_head` for the neutral so that the marker centroid sits
/// `face_distance_mm` along the mean optical axis from the midpoint of the camera centres,
/// the face (head +z) looks back along that axis and head +y points to image up.
pub fn neutral_head_pose(
    rig: &StereoRig,
    neutral: &Mesh,
    layout: &MarkerLayout,
    face_distance_mm: f64,
) -> IsometryMatrix3<f64> {
    let c1 = rig.cam1_centre_in_cam0();
    let mid = Point3::from(c1.coords * 0.5);
    let axis1 = rig.cam1_from_cam0.rotation.inverse() * Vector3::z();
    let axis = (Vector3::z() + axis1).normalize();
    let target = mid + axis * face_distance_mm;
    // Head axes in cam0: z_head = −axis, y_head ≈ −y_cam0, x_head = y × z.
    let z_h = -axis;
    let y_h = (-Vector3::y() - z_h * z_h.dot(&-Vector3::y())).normalize();
    let x_h = y_h.cross(&z_h);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x_h, y_h, z_h]));
    let centroid = layout
        .markers
        .iter()
        .filter_map(|m| neutral.positions.get(m.vertex as usize))
        .fold(Vector3::zeros(), |a, p| a + p.coords)
        / layout.markers.len().max(1) as f64;
    let t = target.coords - rotation * centroid;
    IsometryMatrix3::from_parts(Translation3::from(t), rotation)
}

/// Helmet slip at time `t`: a small slow rigid motion of the head in its own frame
/// (sums of incommensurate sines with seeded phases), composed as
/// `cam0_from_head(t) = cam0_from_head_neutral · slip(t)`.
pub fn slip(
    params: &SynthParams,
    t_secs: f64,
    pivot_in_head: &Point3<f64>,
) -> IsometryMatrix3<f64> {
    if params.slip_mm == 0.0 && params.slip_deg == 0.0 {
        return IsometryMatrix3::identity();
    }
    let phase = |k: u64| {
        // A fixed hash of the seed gives phases in [0, 2π).
        let h = (params.seed ^ 0x5eed)
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .wrapping_add(k.wrapping_mul(0x632b_e59b_d9b4_e019));
        (h >> 11) as f64 / (1u64 << 53) as f64 * std::f64::consts::TAU
    };
    let w = std::f64::consts::TAU / params.slip_period_secs;
    let wave = |k: u64| {
        0.7 * (w * t_secs + phase(k)).sin() + 0.3 * (w * 2.37 * t_secs + phase(k + 10)).sin()
    };
    // Slip starts from zero so the first frames are at the calibrated neutral placement.
    let ramp = (t_secs / params.slip_period_secs).clamp(0.0, 1.0);
    let trans = Vector3::new(wave(0), wave(1), 0.5 * wave(2)) * params.slip_mm * ramp;
    let rot = Vector3::new(wave(3), wave(4), wave(5)) * params.slip_deg.to_radians() * ramp;
    let r = Rotation3::from_scaled_axis(rot);
    // Rotate about the pivot, then translate.
    let t = pivot_in_head.coords - r * pivot_in_head.coords + trans;
    IsometryMatrix3::from_parts(Translation3::from(t), r)
}

/// Quaternion (w, x, y, z) of a rotation.
pub fn quaternion_wxyz(r: &Rotation3<f64>) -> [f64; 4] {
    let q = UnitQuaternion::from_rotation_matrix(r);
    [q.w, q.i, q.j, q.k]
}

/// Everything needed to shade one camera's view of one frame.
pub(crate) struct Scene<'a> {
    pub camera: &'a Camera,
    /// Vertex positions in this camera's frame, mm.
    pub points_in_cam: Vec<Point3<f64>>,
    pub normals_in_cam: Vec<Vector3<f64>>,
    pub triangles: &'a [[u32; 3]],
    /// Per triangle: 0 skin, 1 eyeball.
    pub triangle_material: &'a [u8],
    /// Marker centres and normals in this camera's frame.
    pub markers: Vec<(Point3<f64>, Vector3<f64>)>,
    /// Eye centres in this camera's frame with the iris direction.
    pub eyes: Vec<(Point3<f64>, Vector3<f64>)>,
    /// Rest (neutral) vertex positions, head frame: where the skin texture is looked up.
    pub rest_positions: &'a [Point3<f64>],
    /// Features, dot wear and texture on the skin.
    pub skin: &'a skin::SkinLayout,
    /// Per marker, its wear in this frame ([`skin::DotWear::at_frame`] of the layout's).
    pub wear: &'a [skin::DotWear],
    /// cam0 from this camera: the boom shadow is fixed to the helmet (cam0).
    pub cam0_from_cam: IsometryMatrix3<f64>,
    /// The boom shadow at this instant, if any.
    pub shadow: Option<skin::ShadowBand>,
}

/// A rendered view: radiance per pixel and channel (8-bit scale, float; channels
/// interleaved), plus the fragments.
pub(crate) struct View {
    pub radiance: Vec<f32>,
    pub fragments: raster::Fragments,
}

/// A colour as stored in the albedo buffer: RGB, or its luma for grey images.
fn albedo_of(rgb: [f64; 3], channels: usize) -> [f32; 3] {
    if channels == 3 {
        rgb.map(|x| x as f32)
    } else {
        [skin::luma(rgb) as f32; 3]
    }
}

/// Calls `paint(i, p, n)` for every pixel `i` within `extent_mm` of the surface point
/// `centre` (camera frame) whose surface is skin facing like `normal`, with its surface
/// point `p`, normal `n` and pixel footprint in mm.
fn for_skin_pixels(
    scene: &Scene<'_>,
    frags: &raster::Fragments,
    centre: &Point3<f64>,
    normal: &Vector3<f64>,
    extent_mm: f64,
    mut paint: impl FnMut(usize, &Point3<f64>, &Vector3<f64>, f64),
) {
    let cam = scene.camera;
    let (w, h) = (frags.width, frags.height);
    let Some(centre_px) = cam.project(&centre.coords) else {
        return;
    };
    // Bounding box of the projected disc: rim points every 45° (the true extent is at
    // most 1/cos 22.5° beyond them), plus 2 px for the antialiased edge.
    let helper = if normal.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let t1 = normal.cross(&helper).normalize();
    let t2 = normal.cross(&t1);
    let reach = extent_mm / (std::f64::consts::FRAC_PI_8).cos();
    let (mut lo, mut hi) = (centre_px, centre_px);
    for k in 0..8 {
        let phi = std::f64::consts::FRAC_PI_4 * f64::from(k);
        let q = centre + (t1 * phi.cos() + t2 * phi.sin()) * reach;
        match cam.project(&q.coords) {
            Some(px) => {
                lo = lo.inf(&px);
                hi = hi.sup(&px);
            }
            None => {
                // Behind the camera: fall back to a generous square.
                let half = extent_mm / (centre.coords.norm() / cam.fx()) * 2.0;
                lo = lo.inf(&(centre_px - nalgebra::Vector2::repeat(half)));
                hi = hi.sup(&(centre_px + nalgebra::Vector2::repeat(half)));
            }
        }
    }
    let x0 = (lo.x - 2.0).floor().max(0.0) as usize;
    let x1 = (hi.x + 2.0).ceil().min(w as f64 - 1.0);
    let y0 = (lo.y - 2.0).floor().max(0.0) as usize;
    let y1 = (hi.y + 2.0).ceil().min(h as f64 - 1.0);
    if x1 < 0.0 || y1 < 0.0 {
        return;
    }
    for y in y0..=y1 as usize {
        for x in x0..=x1 as usize {
            let i = y * w + x;
            let Some((t, p, pn)) = frags.surface(
                i,
                scene.triangles,
                &scene.points_in_cam,
                &scene.normals_in_cam,
            ) else {
                continue;
            };
            if scene.triangle_material.get(t as usize) != Some(&0) || pn.dot(normal) < 0.5 {
                continue;
            }
            let footprint = (p.coords.norm() / cam.fx()).max(1e-6);
            paint(i, &p, &pn, footprint);
        }
    }
}

/// Distance from `p` to the polyline through `points`.
fn polyline_distance(p: &Point3<f64>, points: &[Point3<f64>]) -> f64 {
    points
        .windows(2)
        .map(|s| {
            let ab = s[1] - s[0];
            let len2 = ab.norm_squared();
            let t = if len2 > 0.0 {
                ((p - s[0]).dot(&ab) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (p - (s[0] + ab * t)).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Renders one view without noise (see the module docs for the model).
pub(crate) fn shade(scene: &Scene<'_>, params: &SynthParams) -> View {
    let cam = scene.camera;
    let pixels: Vec<Option<Point2<f64>>> = scene
        .points_in_cam
        .iter()
        .map(|p| cam.project(&p.coords))
        .collect();
    let frags = raster::Fragments::rasterize(cam, &scene.points_in_cam, &pixels, scene.triangles);
    let (w, h) = (frags.width, frags.height);
    let ch = params.channels();
    let mut albedo = if ch == 1 {
        vec![params.skin_albedo as f32; w * h]
    } else {
        let s = albedo_of(params.skin_rgb(), 3);
        (0..w * h).flat_map(|_| s).collect()
    };
    let mix = |albedo: &mut [f32], i: usize, target: &[f32; 3], amount: f32| {
        for (k, a) in albedo[i * ch..(i + 1) * ch].iter_mut().enumerate() {
            *a += (target[k] - *a) * amount;
        }
    };
    let bright = params.polarity == Polarity::Bright;
    let mut retro = if bright {
        vec![0.0f32; w * h]
    } else {
        Vec::new()
    };
    // Freckles and moles lie under the paint.
    for f in &scene.skin.features {
        if f.kind == skin::FeatureKind::Hair {
            continue;
        }
        let Some(at) = f.anchors.first() else {
            continue;
        };
        let c = at.locate(scene.triangles, &scene.points_in_cam);
        let n = at.normal(scene.triangles, &scene.normals_in_cam);
        let target = albedo_of(f.color, ch);
        let extent = f.radius_mm + f.softness_mm;
        for_skin_pixels(scene, &frags, &c, &n, extent, |i, p, _, footprint| {
            let cov = skin::coverage((p - c).norm(), f.radius_mm, footprint, f.softness_mm);
            if cov > 0.0 {
                mix(&mut albedo, i, &target, (cov * f.opacity) as f32);
            }
        });
    }
    // Ink: each marker inks the skin pixels whose surface point is within its radius
    // (within the smear's ellipse for a smudged dot).
    let r = params.marker_radius_mm;
    let ink = match params.color {
        Some(c) => albedo_of(c.dot_rgb, 3),
        None => [params.ink_albedo as f32; 3],
    };
    for (k, (c, n)) in scene.markers.iter().enumerate() {
        let wear = scene.wear.get(k).copied().unwrap_or(skin::DotWear::Intact);
        // Smear axes: e1 along the smear (semi-axis r·stretch), e2 across (r/√stretch).
        let smear = match wear {
            skin::DotWear::Wiped { .. } => continue,
            skin::DotWear::Intact => None,
            skin::DotWear::Smudged {
                toward,
                stretch,
                opacity,
            } => {
                let q = toward.locate(scene.triangles, &scene.points_in_cam);
                let d = q - c;
                let e1 = (d - n * n.dot(&d)).try_normalize(1e-9);
                e1.map(|e1| (e1, n.cross(&e1), r * stretch, r / stretch.sqrt(), opacity))
            }
        };
        let extent = smear.map_or(r, |s| s.2);
        for_skin_pixels(scene, &frags, c, n, extent, |i, p, _, footprint| {
            let (coverage, density) = match smear {
                None => {
                    let d = (p - c).norm();
                    (((r - d) / footprint + 0.5).clamp(0.0, 1.0), 1.0)
                }
                Some((e1, e2, a, b, opacity)) => {
                    let dp = p - c;
                    let rho = ((dp.dot(&e1) / a).powi(2)
                        + (dp.dot(&e2) / b).powi(2)
                        + (dp.dot(n) / b).powi(2))
                    .sqrt();
                    (((1.0 - rho) * b / footprint + 0.5).clamp(0.0, 1.0), opacity)
                }
            };
            if coverage > 0.0 {
                if bright {
                    retro[i] = retro[i].max((coverage * density) as f32);
                } else if smear.is_none() && ch == 1 {
                    let a = albedo[i];
                    albedo[i] = a + (ink[0] - a) * coverage as f32;
                } else {
                    mix(&mut albedo, i, &ink, (coverage * density) as f32);
                }
            }
        });
    }
    // Hair lies on top of the paint.
    for f in &scene.skin.features {
        if f.kind != skin::FeatureKind::Hair || f.anchors.len() < 2 {
            continue;
        }
        let pts: Vec<Point3<f64>> = f
            .anchors
            .iter()
            .map(|a| a.locate(scene.triangles, &scene.points_in_cam))
            .collect();
        let mid = pts[pts.len() / 2];
        let n = f.anchors[f.anchors.len() / 2].normal(scene.triangles, &scene.normals_in_cam);
        let extent = pts.iter().map(|q| (q - mid).norm()).fold(0.0, f64::max) + f.radius_mm;
        let target = albedo_of(f.color, ch);
        for_skin_pixels(scene, &frags, &mid, &n, extent, |i, p, _, footprint| {
            let d = polyline_distance(p, &pts);
            let cov = skin::coverage(d, f.radius_mm, footprint, 0.0) * f.opacity;
            if cov > 0.0 {
                mix(&mut albedo, i, &target, cov as f32);
                if bright {
                    retro[i] *= 1.0 - cov as f32;
                }
            }
        });
    }
    let mut radiance = vec![0.0f32; w * h * ch];
    let cx = cam.k[(0, 2)];
    let cy = cam.k[(1, 2)];
    let diag = (cx * cx + cy * cy).sqrt();
    let texture = scene.skin.texture.as_ref();
    let sheen = params.skin.sheen;
    for (i, out) in radiance.chunks_exact_mut(ch).enumerate() {
        let Some((t, p, n)) = frags.surface(
            i,
            scene.triangles,
            &scene.points_in_cam,
            &scene.normals_in_cam,
        ) else {
            continue;
        };
        let dist = p.coords.norm();
        let l = -p.coords / dist;
        let ndl = n.dot(&l);
        let mut a = [0.0f64; 3];
        for (k, v) in a.iter_mut().take(ch).enumerate() {
            *v = f64::from(albedo[i * ch + k]);
        }
        let eyeball = scene.triangle_material.get(t as usize) == Some(&1);
        if eyeball {
            // Eyeball: white sclera, dark iris toward the front.
            let mut e = 0.8;
            for (ec, dir) in &scene.eyes {
                let v = (p - ec).normalize();
                let cos = v.dot(dir);
                if cos > 0.95 {
                    e = 0.03;
                } else if cos > 0.85 {
                    e = 0.25;
                }
            }
            a = [e; 3];
        }
        // Skin texture, and wet highlights where the skin is wet.
        let mut wet_spec = 0.0;
        if let (Some(tex), false) = (texture, eyeball) {
            let rest = frags.rest_point(i, scene.triangles, scene.rest_positions);
            let factor = f64::from(tex.albedo_factor(&rest));
            a.iter_mut().for_each(|v| *v *= factor);
            if sheen > 0.0 && ndl > 0.0 {
                wet_spec =
                    sheen * f64::from(tex.wetness(&rest)) * ndl.powf(params.skin.sheen_exponent);
            }
        }
        let vignette_at = || {
            let x = (i % w) as f64 - cx;
            let y = (i / w) as f64 - cy;
            1.0 - 0.35 * ((x * x + y * y) / (diag * diag))
        };
        if ndl <= 0.0 {
            // The inside of the head seen through the mouth, or a grazing back face.
            let value = 0.02 * vignette_at() * params.exposure_dn;
            out.iter_mut().for_each(|o| *o = value as f32);
            continue;
        }
        let d0 = params.face_distance_mm;
        let falloff = (d0 / dist).powi(2);
        let direct = match &scene.shadow {
            Some(s) => (1.0 - params.ambient) * ndl * s.direct_light(&(scene.cam0_from_cam * p)),
            None => (1.0 - params.ambient) * ndl,
        };
        // Blinn-Phong with the light at the camera: half vector = view vector.
        let spec = params.specular * ndl.powi(60) + wet_spec;
        // cos⁴-like vignette of a wide lens, by distance from the principal point.
        let vignette = vignette_at();
        let cover = if bright { f64::from(retro[i]) } else { 0.0 };
        for (k, o) in out.iter_mut().enumerate() {
            let diffuse = a[k] * (params.ambient + direct);
            let mut value = (diffuse + spec) * falloff;
            if cover > 0.0 {
                // A retroreflective dot returns the ring light to the camera.
                let r = params.bright_dot_gain * ndl.sqrt() * falloff;
                value = value * (1.0 - cover) + r * cover;
            }
            *o = (value * vignette * params.exposure_dn) as f32;
        }
    }
    View {
        radiance,
        fragments: frags,
    }
}

/// The shared table of 65 536 standard normal samples (Box-Muller, fixed seed).
fn normal_table() -> &'static [f32] {
    static TABLE: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut rng = SplitMix64::new(0x006e_6f69_7365);
        (0..1 << 16)
            .map(|_| standard_normal(&mut rng) as f32)
            .collect()
    })
}

/// Standard normal samples, one per index, from [`normal_table`] indexed by a seeded
/// [`SplitMix64`] (16 bits per sample, four per draw).
struct NoiseStream {
    rng: SplitMix64,
    bits: u64,
    table: &'static [f32],
}

impl NoiseStream {
    fn new(seed: u64) -> Self {
        Self {
            rng: SplitMix64::new(seed),
            bits: 0,
            table: normal_table(),
        }
    }

    /// The sample for index `i` (indices must come in order from 0).
    fn sample(&mut self, i: usize) -> f32 {
        if i.is_multiple_of(4) {
            self.bits = self.rng.next_u64();
        }
        self.table[((self.bits >> (16 * (i % 4))) & 0xffff) as usize]
    }
}

/// Adds Gaussian sensor noise (seeded) and quantizes to 8 bits. Samples come from a
/// table of 65 536 standard normal values (Box-Muller) indexed by a seeded generator,
/// which is ~20× faster than drawing each sample and statistically the same for pixel
/// noise.
pub(crate) fn to_gray8(radiance: &[f32], noise_dn: f64, seed: u64) -> Vec<u8> {
    let mut noise = NoiseStream::new(seed);
    radiance
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let n = noise.sample(i);
            (v + noise_dn as f32 * n).round().clamp(0.0, 255.0) as u8
        })
        .collect()
}

/// Adds sensor noise (`noise_dn` in 8-bit levels, scaled with the signal) and quantizes
/// radiance on the 8-bit scale to `depth`'s range, as 16-bit words: 12-bit data shifted
/// up by 4 bits, or full 16-bit samples.
pub(crate) fn to_u16(radiance: &[f32], noise_dn: f64, seed: u64, depth: BitDepth) -> Vec<u16> {
    let max = depth.max_value() as f32;
    let scale = max / 255.0;
    let shift = if depth == BitDepth::Twelve { 4 } else { 0 };
    let sigma = noise_dn as f32 * scale;
    let mut noise = NoiseStream::new(seed);
    radiance
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let n = noise.sample(i);
            let q = (v * scale + sigma * n).round().clamp(0.0, max) as u16;
            q << shift
        })
        .collect()
}

/// Samples of an image to write.
pub enum Samples<'a> {
    /// 8-bit samples.
    Eight(&'a [u8]),
    /// 16-bit samples.
    Sixteen(&'a [u16]),
}

/// Writes an 8-bit grayscale PNG.
///
/// # Errors
/// [`SynthError::Write`] naming the file.
pub fn write_png_gray(
    path: &std::path::Path,
    width: u32,
    height: u32,
    pixels: &[u8],
) -> Result<(), SynthError> {
    write_png(path, width, height, 1, Samples::Eight(pixels))
}

/// Writes a grey (`channels` 1) or RGB (3, interleaved) PNG of 8 or 16 bits per sample.
///
/// # Errors
/// [`SynthError::Write`] naming the file, also when the sample count does not match.
pub fn write_png(
    path: &std::path::Path,
    width: u32,
    height: u32,
    channels: usize,
    samples: Samples<'_>,
) -> Result<(), SynthError> {
    let err = |message: String| SynthError::Write {
        path: path.to_path_buf(),
        message,
    };
    let expected = width as usize * height as usize * channels;
    let (len, depth) = match samples {
        Samples::Eight(s) => (s.len(), png::BitDepth::Eight),
        Samples::Sixteen(s) => (s.len(), png::BitDepth::Sixteen),
    };
    if len != expected {
        return Err(err(format!(
            "{len} samples for a {width}x{height}x{channels} image"
        )));
    }
    let color = match channels {
        1 => png::ColorType::Grayscale,
        3 => png::ColorType::Rgb,
        _ => return Err(err(format!("{channels} channels (1 or 3 supported)"))),
    };
    let file = std::fs::File::create(path).map_err(|e| err(e.to_string()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    enc.set_color(color);
    enc.set_depth(depth);
    enc.set_compression(png::Compression::Fast);
    // The "up" filter for every row: replay decodes it several times faster than the
    // adaptive choice (mostly Paeth on camera noise), for files a few percent larger.
    enc.set_filter(png::Filter::Up);
    let mut writer = enc.write_header().map_err(|e| err(e.to_string()))?;
    match samples {
        Samples::Eight(s) => writer.write_image_data(s),
        Samples::Sixteen(s) => {
            // PNG stores 16-bit samples big-endian.
            let bytes: Vec<u8> = s.iter().flat_map(|v| v.to_be_bytes()).collect();
            writer.write_image_data(&bytes)
        }
    }
    .map_err(|e| err(e.to_string()))?;
    writer.finish().map_err(|e| err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_rig_is_a_helmet() {
        let rig = default_rig().unwrap();
        rig.validate().unwrap();
        assert_eq!((rig.cam0.width_px, rig.cam0.height_px), (1280, 1024));
        let b = rig.baseline_mm();
        assert!((60.0..=80.0).contains(&b), "{b}");
        // Stacked vertically: cam1 below cam0 (image y down).
        let c1 = rig.cam1_centre_in_cam0();
        assert!(c1.y > 0.9 * b, "{c1}");
    }

    #[test]
    fn slip_is_small_and_starts_at_identity() {
        let p = SynthParams {
            slip_mm: 1.5,
            slip_deg: 1.0,
            ..Default::default()
        };
        let pivot = Point3::new(0.0, 0.0, 0.0);
        assert_eq!(slip(&p, 0.0, &pivot), IsometryMatrix3::identity());
        for k in 0..100 {
            let s = slip(&p, f64::from(k) * 0.1, &pivot);
            assert!(s.translation.vector.norm() < 1.5 * 1.5 * 1.01);
            assert!(s.rotation.angle() < 1.8f64.to_radians());
        }
    }
}
