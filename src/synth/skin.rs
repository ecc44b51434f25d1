//! Real skin for synthetic footage: the distractors a marker detector meets on a real
//! face, all fixed on the skin so they move with it.
//!
//! - Spots and strokes ([`SkinFeature`]): freckles (many small, low-contrast brown
//!   spots), moles (a few spots as dark as the ink, some right beside a dot) and hair
//!   strokes (thin dark eyebrow-like strokes, some lying across a dot). Each is anchored
//!   by barycentric positions on triangles of the performer's mesh
//!   ([`SurfacePoint`]), drawn by the 3D distance of a pixel's surface point to it, like
//!   the ink.
//! - Worn dots ([`DotWear`]): a few dots partly wiped (lighter, smeared into an ellipse
//!   along the skin) and a few wiped away completely.
//! - A skin texture ([`SkinTexture`]): pores and fine albedo grain, broad blotches, and a
//!   wetness mask for the specular sheen, looked up through a cylindrical chart of the
//!   rest (neutral) position of each pixel's surface point, so it too moves with the skin.
//! - Lighting that is not the skin's: the shadow of the helmet boom ([`ShadowBand`]) and
//!   the flicker of the lights ([`flicker_gain`]).
//!
//! Everything is seeded from [`super::SynthParams::seed`], so a session renders the same
//! way every time.

use nalgebra::{Point3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::SynthError;
use crate::mesh::Mesh;

/// The distractors of real skin and lighting. Every effect is off by default.
#[derive(Debug, Clone, PartialEq)]
pub struct SkinParams {
    /// Number of freckles (small low-contrast brown spots) on the face (0: none). Default 0.
    pub freckles: usize,
    /// Freckle diameters, mm (uniform in the range). Default 0.6 to 2.2.
    pub freckle_diameter_mm: (f64, f64),
    /// How much darker a freckle is than the skin around it (share of the albedo, uniform
    /// in the range). Default 0.1 to 0.3.
    pub freckle_contrast: (f64, f64),
    /// Number of moles (spots as dark as the ink) (0: none). Default 0.
    pub moles: usize,
    /// Mole diameters, mm (uniform in the range). Default 1.5 to 4.
    pub mole_diameter_mm: (f64, f64),
    /// Share of the moles placed right beside a dot (0.2 to 1.5 mm from its rim). Default 0.5.
    pub moles_beside_dots: f64,
    /// Albedo of a mole (grey; brown in colour images). Default 0.09 (the ink is 0.08).
    pub mole_albedo: f64,
    /// Number of hair strokes (eyebrow hairs, stray hairs) (0: none). Default 0.
    pub hair_strokes: usize,
    /// Stroke lengths, mm (uniform in the range). Default 5 to 12.
    pub hair_length_mm: (f64, f64),
    /// Width of a hair, mm. Default 0.12.
    pub hair_width_mm: f64,
    /// Share of the strokes that lie across a dot. Default 0.3.
    pub hair_across_dots: f64,
    /// Albedo of hair. Default 0.05.
    pub hair_albedo: f64,
    /// Strength of the skin texture: standard deviation of the pore and grain albedo
    /// factor (0: smooth skin). Default 0.
    pub pores: f64,
    /// Strength of wet specular highlights on oily, sweaty patches of skin, relative to
    /// a white diffuse surface (0: none). They come on top of
    /// [`super::SynthParams::specular`]. Default 0.
    pub sheen: f64,
    /// Blinn-Phong exponent of the sheen (sharper for higher). Default 300.
    pub sheen_exponent: f64,
    /// Light flicker: modulation depth of the light (0: steady). Default 0.
    pub flicker_amplitude: f64,
    /// Light flicker frequency, Hz (100: a mains light on 50 Hz, seen by 60 fps cameras
    /// as a 20 Hz beat). Default 100.
    pub flicker_hz: f64,
    /// Helmet-boom shadow: share of the direct light blocked in the band (0: none).
    /// Default 0.
    pub boom_shadow: f64,
    /// Width of the boom's shadow band, mm. Default 18.
    pub boom_width_mm: f64,
    /// Penumbra (soft edge) of the shadow, mm. Default 10.
    pub boom_softness_mm: f64,
    /// Period of the shadow's slow sweep over the face, seconds. Default 5.
    pub boom_period_secs: f64,
    /// Number of dots partly wiped off (lighter, smeared into an ellipse). Default 0.
    pub smudged_dots: usize,
    /// Number of dots wiped off completely. Default 0.
    pub wiped_dots: usize,
    /// Put a mole beside every wiped dot (0.2 to 1.5 mm from where its rim was, diameter
    /// in [`SkinParams::mole_diameter_mm`]): the spot a labeler must not take for the
    /// missing marker. Default false.
    pub moles_beside_wiped_dots: bool,
    /// Frames `(first, last)` over which the wiped dots are wiped off, evenly spread: the
    /// first wiped dot is gone from frame `first`, the last from frame `last`. Before its
    /// frame a dot is intact (an actor wiping sweat off mid-take), so a labeler has tracked
    /// the marker beside its mole before it vanishes. Default `(0, 0)`: all wiped from the
    /// first frame.
    pub wipe_frames: (usize, usize),
}

impl Default for SkinParams {
    fn default() -> Self {
        Self {
            freckles: 0,
            freckle_diameter_mm: (0.6, 2.2),
            freckle_contrast: (0.1, 0.3),
            moles: 0,
            mole_diameter_mm: (1.5, 4.0),
            moles_beside_dots: 0.5,
            mole_albedo: 0.09,
            hair_strokes: 0,
            hair_length_mm: (5.0, 12.0),
            hair_width_mm: 0.12,
            hair_across_dots: 0.3,
            hair_albedo: 0.05,
            pores: 0.0,
            sheen: 0.0,
            sheen_exponent: 300.0,
            flicker_amplitude: 0.0,
            flicker_hz: 100.0,
            boom_shadow: 0.0,
            boom_width_mm: 18.0,
            boom_softness_mm: 10.0,
            boom_period_secs: 5.0,
            smudged_dots: 0,
            wiped_dots: 0,
            moles_beside_wiped_dots: false,
            wipe_frames: (0, 0),
        }
    }
}

impl SkinParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`SynthError::Params`] naming the field.
    pub fn validate(&self) -> Result<(), SynthError> {
        let check = |ok: bool, field: &str| {
            if ok {
                Ok(())
            } else {
                Err(SynthError::Params(format!("skin.{field} out of range")))
            }
        };
        let range = |(a, b): (f64, f64), lo: f64, hi: f64| {
            a.is_finite() && b.is_finite() && lo <= a && a <= b && b <= hi
        };
        check(self.freckles <= 100_000, "freckles")?;
        check(
            range(self.freckle_diameter_mm, 0.05, 10.0),
            "freckle_diameter_mm",
        )?;
        check(range(self.freckle_contrast, 0.0, 1.0), "freckle_contrast")?;
        check(self.moles <= 1000, "moles")?;
        check(range(self.mole_diameter_mm, 0.1, 20.0), "mole_diameter_mm")?;
        check(
            (0.0..=1.0).contains(&self.moles_beside_dots),
            "moles_beside_dots",
        )?;
        check((0.0..=1.0).contains(&self.mole_albedo), "mole_albedo")?;
        check(self.hair_strokes <= 100_000, "hair_strokes")?;
        check(range(self.hair_length_mm, 0.5, 50.0), "hair_length_mm")?;
        check(
            self.hair_width_mm > 0.0 && self.hair_width_mm <= 2.0,
            "hair_width_mm",
        )?;
        check(
            (0.0..=1.0).contains(&self.hair_across_dots),
            "hair_across_dots",
        )?;
        check((0.0..=1.0).contains(&self.hair_albedo), "hair_albedo")?;
        check((0.0..=0.5).contains(&self.pores), "pores")?;
        check((0.0..=20.0).contains(&self.sheen), "sheen")?;
        check(
            (1.0..=10_000.0).contains(&self.sheen_exponent),
            "sheen_exponent",
        )?;
        check(
            (0.0..=1.0).contains(&self.flicker_amplitude),
            "flicker_amplitude",
        )?;
        check(
            self.flicker_hz.is_finite() && self.flicker_hz >= 0.0,
            "flicker_hz",
        )?;
        check((0.0..=1.0).contains(&self.boom_shadow), "boom_shadow")?;
        check(self.wipe_frames.0 <= self.wipe_frames.1, "wipe_frames")?;
        check(
            self.boom_width_mm > 0.0 && self.boom_width_mm < 500.0,
            "boom_width_mm",
        )?;
        check(
            self.boom_softness_mm > 0.0 && self.boom_softness_mm < 500.0,
            "boom_softness_mm",
        )?;
        check(
            self.boom_period_secs > 0.0 && self.boom_period_secs.is_finite(),
            "boom_period_secs",
        )?;
        Ok(())
    }

    /// Whether any effect is on.
    pub fn any(&self) -> bool {
        self != &Self {
            freckle_diameter_mm: self.freckle_diameter_mm,
            freckle_contrast: self.freckle_contrast,
            mole_diameter_mm: self.mole_diameter_mm,
            moles_beside_dots: self.moles_beside_dots,
            mole_albedo: self.mole_albedo,
            hair_length_mm: self.hair_length_mm,
            hair_width_mm: self.hair_width_mm,
            hair_across_dots: self.hair_across_dots,
            hair_albedo: self.hair_albedo,
            sheen_exponent: self.sheen_exponent,
            flicker_hz: self.flicker_hz,
            boom_width_mm: self.boom_width_mm,
            boom_softness_mm: self.boom_softness_mm,
            boom_period_secs: self.boom_period_secs,
            ..Self::default()
        }
    }
}

/// A point fixed on the skin: barycentric weights on one triangle of the mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// Triangle index into [`Mesh::triangles`].
    pub triangle: u32,
    /// Barycentric weights of the triangle's corners (sum 1).
    pub bary: [f64; 3],
}

impl SurfacePoint {
    /// The point for vertex positions `positions` (any frame: head or camera).
    pub fn locate(&self, triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Point3<f64> {
        let Some(tri) = triangles.get(self.triangle as usize) else {
            return Point3::origin();
        };
        let mut p = Vector3::zeros();
        for (k, &v) in tri.iter().enumerate() {
            if let Some(q) = positions.get(v as usize) {
                p += q.coords * self.bary[k];
            }
        }
        Point3::from(p)
    }

    /// The interpolated vertex normal (normalized) for `normals`.
    pub fn normal(&self, triangles: &[[u32; 3]], normals: &[Vector3<f64>]) -> Vector3<f64> {
        let Some(tri) = triangles.get(self.triangle as usize) else {
            return Vector3::z();
        };
        let mut n = Vector3::zeros();
        for (k, &v) in tri.iter().enumerate() {
            if let Some(q) = normals.get(v as usize) {
                n += q * self.bary[k];
            }
        }
        n.try_normalize(1e-12).unwrap_or_else(Vector3::z)
    }
}

/// What a skin feature is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeatureKind {
    /// A freckle.
    Freckle,
    /// A mole.
    Mole,
    /// A hair stroke.
    Hair,
}

impl FeatureKind {
    /// The name used in `gt/distractors.csv`.
    pub fn name(self) -> &'static str {
        match self {
            FeatureKind::Freckle => "freckle",
            FeatureKind::Mole => "mole",
            FeatureKind::Hair => "hair",
        }
    }
}

/// One spot or stroke on the skin.
#[derive(Debug, Clone, PartialEq)]
pub struct SkinFeature {
    /// What it is.
    pub kind: FeatureKind,
    /// Anchors: a spot's centre (once), or a stroke's start, middle and end (the stroke is
    /// the polyline through them, so it bends with the skin).
    pub anchors: Vec<SurfacePoint>,
    /// A spot's radius, or half the width of a stroke, mm.
    pub radius_mm: f64,
    /// Width of the soft edge, mm (0: as sharp as the pixel footprint).
    pub softness_mm: f64,
    /// The colour the skin takes under the feature (albedo, linear RGB).
    pub color: [f64; 3],
    /// Opacity at the centre (0..1).
    pub opacity: f64,
}

/// How worn a painted dot is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DotWear {
    /// As painted.
    Intact,
    /// Partly wiped: the ink smeared into an ellipse along the skin toward `toward`,
    /// `stretch` times longer than the dot and `1/√stretch` as wide, and only `opacity`
    /// as dense. Still a dot: its centre stays at the marker.
    Smudged {
        /// A point on the skin giving the smear's direction from the marker.
        toward: SurfacePoint,
        /// Length of the smear over the dot's diameter (≥ 1).
        stretch: f64,
        /// Remaining ink density (0..1).
        opacity: f64,
    },
    /// Wiped off from frame `from_frame` on: no ink left, not detectable (an intact dot
    /// before it).
    Wiped {
        /// The first frame without the dot.
        from_frame: usize,
    },
}

impl DotWear {
    /// The name used in `gt/distractors.csv`, or `None` for an intact dot.
    pub fn name(&self) -> Option<&'static str> {
        match self {
            DotWear::Intact => None,
            DotWear::Smudged { .. } => Some("smudged_dot"),
            DotWear::Wiped { .. } => Some("wiped_dot"),
        }
    }

    /// The wear in frame `frame`: a dot wiped off later is intact until then.
    pub fn at_frame(self, frame: usize) -> DotWear {
        match self {
            DotWear::Wiped { from_frame } if frame < from_frame => DotWear::Intact,
            wear => wear,
        }
    }
}

/// Where the skin is, for placing features: the mesh with a per-triangle flag and
/// optional eyebrow vertices.
pub struct SkinSurface<'a> {
    /// The performer's neutral mesh (head frame, mm).
    pub mesh: &'a Mesh,
    /// Per triangle: whether it is face skin (features may go there).
    pub skin_triangle: &'a [bool],
    /// Vertices of the eyebrows (hair strokes cluster there), may be empty.
    pub brow_vertices: &'a [u32],
    /// The marker vertices, in layout order.
    pub marker_vertices: &'a [u32],
    /// Dot radius, mm.
    pub dot_radius_mm: f64,
    /// Skin albedo (linear RGB; grey images use its luma).
    pub skin_color: [f64; 3],
}

/// Everything placed on one performer's skin.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SkinLayout {
    /// Spots and strokes.
    pub features: Vec<SkinFeature>,
    /// Per marker (layout order): its wear.
    pub wear: Vec<DotWear>,
    /// Pores, grain and wetness; `None` when both pores and sheen are off.
    pub texture: Option<SkinTexture>,
}

/// Nearest-vertex and incident-triangle lookups on the neutral, for pinning 3D points to
/// the skin.
struct Pinner<'a> {
    mesh: &'a Mesh,
    /// The skin triangles' indices, ascending.
    skin_list: Vec<u32>,
    incident: Vec<Vec<u32>>,
    normals: Vec<Vector3<f64>>,
}

impl<'a> Pinner<'a> {
    fn new(mesh: &'a Mesh, skin_triangle: &'a [bool]) -> Self {
        let mut incident = vec![Vec::new(); mesh.positions.len()];
        for (t, tri) in mesh.triangles.iter().enumerate() {
            if skin_triangle.get(t) == Some(&true) {
                for &v in tri {
                    if let Some(list) = incident.get_mut(v as usize) {
                        list.push(t as u32);
                    }
                }
            }
        }
        let normals = crate::mesh::vertex_normals_of(mesh, &mesh.positions);
        let skin_list = (0..mesh.triangles.len() as u32)
            .filter(|&t| skin_triangle.get(t as usize) == Some(&true))
            .collect();
        Self {
            mesh,
            skin_list,
            incident,
            normals,
        }
    }

    /// The skin point nearest to `p` among the triangles around the nearest skin vertex.
    fn pin(&self, p: &Point3<f64>) -> Option<SurfacePoint> {
        let v = self
            .incident
            .iter()
            .enumerate()
            .filter(|(_, ts)| !ts.is_empty())
            .map(|(v, _)| (v, (self.mesh.positions[v] - p).norm_squared()))
            .min_by(|a, b| a.1.total_cmp(&b.1))?
            .0;
        let mut best: Option<(f64, SurfacePoint)> = None;
        for &t in &self.incident[v] {
            let tri = self.mesh.triangles[t as usize];
            let [a, b, c] = tri.map(|i| self.mesh.positions[i as usize]);
            let bary = closest_barycentric(p, &a, &b, &c);
            let q = a.coords * bary[0] + b.coords * bary[1] + c.coords * bary[2];
            let d = (q - p.coords).norm_squared();
            if best.as_ref().is_none_or(|(bd, _)| d < *bd) {
                best = Some((d, SurfacePoint { triangle: t, bary }));
            }
        }
        best.map(|(_, s)| s)
    }

    /// A point on the skin at `from` moved `distance` mm along the tangent direction
    /// closest to `dir`, pinned back onto the skin.
    fn step(&self, from: &SurfacePoint, dir: &Vector3<f64>, distance: f64) -> Option<SurfacePoint> {
        let p = from.locate(&self.mesh.triangles, &self.mesh.positions);
        let n = from.normal(&self.mesh.triangles, &self.normals);
        let t = (dir - n * n.dot(dir)).try_normalize(1e-9)?;
        self.pin(&(p + t * distance))
    }

    fn skin_vertex_normal(&self, v: u32) -> Vector3<f64> {
        self.normals
            .get(v as usize)
            .copied()
            .unwrap_or_else(Vector3::z)
    }

    fn at_vertex(&self, v: u32) -> Option<SurfacePoint> {
        let t = *self.incident.get(v as usize)?.first()?;
        let tri = self.mesh.triangles[t as usize];
        let mut bary = [0.0; 3];
        let k = tri.iter().position(|&x| x == v)?;
        bary[k] = 1.0;
        Some(SurfacePoint { triangle: t, bary })
    }

    /// Area-weighted random skin point.
    fn random_point(&self, cumulative: &[f64], rng: &mut StdRng) -> Option<SurfacePoint> {
        let total = *cumulative.last()?;
        if total <= 0.0 {
            return None;
        }
        let x = rng.random_range(0.0..total);
        let k = cumulative
            .partition_point(|&c| c <= x)
            .min(cumulative.len() - 1);
        let t = *self.skin_list.get(k)?;
        let (mut r1, mut r2): (f64, f64) = (rng.random(), rng.random());
        if r1 + r2 > 1.0 {
            r1 = 1.0 - r1;
            r2 = 1.0 - r2;
        }
        Some(SurfacePoint {
            triangle: t,
            bary: [1.0 - r1 - r2, r1, r2],
        })
    }
}

/// Barycentric weights of the point of triangle `abc` nearest to `p` (Ericson, Real-Time
/// Collision Detection, 5.1.5).
fn closest_barycentric(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> [f64; 3] {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    [1.0 - v - w, v, w]
}

/// A random unit vector perpendicular to `n`.
fn random_tangent(n: &Vector3<f64>, rng: &mut StdRng) -> Vector3<f64> {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let t1 = n.cross(&helper).normalize();
    let t2 = n.cross(&t1);
    let phi = rng.random_range(0.0..std::f64::consts::TAU);
    t1 * phi.cos() + t2 * phi.sin()
}

fn uniform(rng: &mut StdRng, (a, b): (f64, f64)) -> f64 {
    if b > a { rng.random_range(a..=b) } else { a }
}

/// Places every feature of `params` on `surface`, seeded with `seed`.
///
/// # Errors
/// [`SynthError::Params`] for invalid parameters, or when features are asked for but the
/// mesh has no skin to put them on.
pub fn place(
    params: &SkinParams,
    surface: &SkinSurface<'_>,
    seed: u64,
) -> Result<SkinLayout, SynthError> {
    params.validate()?;
    let mesh = surface.mesh;
    let markers = surface.marker_vertices;
    let mut layout = SkinLayout {
        features: Vec::new(),
        wear: vec![DotWear::Intact; markers.len()],
        texture: (params.pores > 0.0 || params.sheen > 0.0)
            .then(|| SkinTexture::new(mesh, params.pores, seed)),
    };
    let wants_features = params.freckles + params.moles + params.hair_strokes > 0;
    let wants_wear = params.smudged_dots + params.wiped_dots > 0;
    if !wants_features && !wants_wear {
        return Ok(layout);
    }
    if params.smudged_dots + params.wiped_dots > markers.len() {
        return Err(SynthError::Params(format!(
            "skin: {} smudged and {} wiped dots, but only {} markers",
            params.smudged_dots,
            params.wiped_dots,
            markers.len()
        )));
    }
    let pinner = Pinner::new(mesh, surface.skin_triangle);
    let mut cumulative = Vec::new();
    let mut total = 0.0;
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if surface.skin_triangle.get(t) == Some(&true) {
            let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
            total += 0.5 * (b - a).cross(&(c - a)).norm();
            cumulative.push(total);
        }
    }
    if cumulative.is_empty() || total <= 0.0 {
        return Err(SynthError::Params(
            "skin: the mesh has no face skin to place features on".into(),
        ));
    }
    let no_skin = || SynthError::Params("skin: could not pin a feature to the skin".into());
    let mut rng = StdRng::seed_from_u64(seed ^ 0x736b_696e);
    let skin = surface.skin_color;
    // Freckles: brown, darker in blue than in red.
    for _ in 0..params.freckles {
        let at = pinner
            .random_point(&cumulative, &mut rng)
            .ok_or_else(no_skin)?;
        let c = uniform(&mut rng, params.freckle_contrast);
        let radius = 0.5 * uniform(&mut rng, params.freckle_diameter_mm);
        layout.features.push(SkinFeature {
            kind: FeatureKind::Freckle,
            anchors: vec![at],
            radius_mm: radius,
            softness_mm: 0.4 * radius,
            color: [
                skin[0] * (1.0 - 0.8 * c),
                skin[1] * (1.0 - c),
                skin[2] * (1.0 - 1.25 * c).max(0.0),
            ],
            opacity: 1.0,
        });
    }
    // Moles: dark brown, as dark as the ink in grey.
    let mole_color = {
        let brown = [1.25, 0.95, 0.8];
        let l = luma(brown);
        brown.map(|x| (x / l * params.mole_albedo).min(1.0))
    };
    let mole = |at, radius: f64| SkinFeature {
        kind: FeatureKind::Mole,
        anchors: vec![at],
        radius_mm: radius,
        softness_mm: 0.15 * radius,
        color: mole_color,
        opacity: 1.0,
    };
    for k in 0..params.moles {
        let radius = 0.5 * uniform(&mut rng, params.mole_diameter_mm);
        let beside = !markers.is_empty()
            && (k as f64) < params.moles_beside_dots * params.moles as f64 - 1e-9;
        let at = if beside {
            let v = markers[rng.random_range(0..markers.len())];
            let gap = rng.random_range(0.2..=1.5);
            let from = pinner.at_vertex(v).ok_or_else(no_skin)?;
            let dir = random_tangent(&pinner.skin_vertex_normal(v), &mut rng);
            pinner
                .step(&from, &dir, surface.dot_radius_mm + gap + radius)
                .ok_or_else(no_skin)?
        } else {
            pinner
                .random_point(&cumulative, &mut rng)
                .ok_or_else(no_skin)?
        };
        layout.features.push(mole(at, radius));
    }
    // Hair: across dots, in the brows, or stray.
    let hair_color = {
        let brown = [1.2, 1.0, 0.85];
        let l = luma(brown);
        brown.map(|x| (x / l * params.hair_albedo).min(1.0))
    };
    for k in 0..params.hair_strokes {
        let length = uniform(&mut rng, params.hair_length_mm);
        let across = !markers.is_empty()
            && (k as f64) < params.hair_across_dots * params.hair_strokes as f64 - 1e-9;
        let (mid, dir) = if across {
            let v = markers[rng.random_range(0..markers.len())];
            let mid = pinner.at_vertex(v).ok_or_else(no_skin)?;
            // Offset a little so the hair crosses the dot off its centre.
            let n = pinner.skin_vertex_normal(v);
            let side = random_tangent(&n, &mut rng);
            let dir = side.cross(&n);
            let off = rng.random_range(-0.6..=0.6) * surface.dot_radius_mm;
            let mid = if off.abs() > 1e-3 {
                pinner.step(&mid, &(side * off.signum()), off.abs())
            } else {
                Some(mid)
            }
            .ok_or_else(no_skin)?;
            (mid, dir)
        } else if !surface.brow_vertices.is_empty() {
            let v = surface.brow_vertices[rng.random_range(0..surface.brow_vertices.len())];
            let mid = pinner.at_vertex(v).ok_or_else(no_skin)?;
            let p = mesh.positions[v as usize];
            // Brow hair grows outward (away from the midline) and slightly up.
            let lateral = if p.x >= 0.0 { 1.0 } else { -1.0 };
            let angle = rng.random_range(0.1..0.6);
            (
                mid,
                Vector3::new(lateral * f64::cos(angle), f64::sin(angle), 0.0),
            )
        } else {
            let mid = pinner
                .random_point(&cumulative, &mut rng)
                .ok_or_else(no_skin)?;
            let n = mid.normal(&mesh.triangles, &pinner.normals);
            (mid, random_tangent(&n, &mut rng))
        };
        let start = pinner
            .step(&mid, &(-dir), 0.5 * length)
            .ok_or_else(no_skin)?;
        let end = pinner.step(&mid, &dir, 0.5 * length).ok_or_else(no_skin)?;
        layout.features.push(SkinFeature {
            kind: FeatureKind::Hair,
            anchors: vec![start, mid, end],
            radius_mm: 0.5 * params.hair_width_mm,
            softness_mm: 0.0,
            color: hair_color,
            opacity: rng.random_range(0.7..=1.0),
        });
    }
    // Worn dots: distinct markers, chosen at random.
    let mut order: Vec<usize> = (0..markers.len()).collect();
    for i in (1..order.len()).rev() {
        order.swap(i, rng.random_range(0..=i));
    }
    for (j, &m) in order
        .iter()
        .take(params.smudged_dots + params.wiped_dots)
        .enumerate()
    {
        layout.wear[m] = if j < params.smudged_dots {
            let v = markers[m];
            let from = pinner.at_vertex(v).ok_or_else(no_skin)?;
            let dir = random_tangent(&pinner.skin_vertex_normal(v), &mut rng);
            let toward = pinner.step(&from, &dir, 3.0).ok_or_else(no_skin)?;
            DotWear::Smudged {
                toward,
                stretch: rng.random_range(1.4..=2.2),
                opacity: rng.random_range(0.45..=0.75),
            }
        } else {
            DotWear::Wiped { from_frame: 0 }
        };
    }
    if params.moles_beside_wiped_dots {
        for (m, wear) in layout.wear.iter().enumerate() {
            if !matches!(wear, DotWear::Wiped { .. }) {
                continue;
            }
            let radius = 0.5 * uniform(&mut rng, params.mole_diameter_mm);
            let gap = rng.random_range(0.2..=1.5);
            let v = markers[m];
            let from = pinner.at_vertex(v).ok_or_else(no_skin)?;
            let dir = random_tangent(&pinner.skin_vertex_normal(v), &mut rng);
            let at = pinner
                .step(&from, &dir, surface.dot_radius_mm + gap + radius)
                .ok_or_else(no_skin)?;
            layout.features.push(mole(at, radius));
        }
    }
    // The frames the dots are wiped at, in the order they were chosen (no random draw:
    // wiping mid-take moves nothing else on the skin).
    let (first, last) = params.wipe_frames;
    let wiped: Vec<usize> = order
        .iter()
        .skip(params.smudged_dots)
        .take(params.wiped_dots)
        .copied()
        .collect();
    let spread = (last - first) as f64 / wiped.len().saturating_sub(1).max(1) as f64;
    for (j, &m) in wiped.iter().enumerate() {
        layout.wear[m] = DotWear::Wiped {
            from_frame: first + (j as f64 * spread).round() as usize,
        };
    }
    Ok(layout)
}

/// Rec. 709 luma of a linear RGB albedo: what a monochrome sensor sees.
pub fn luma(rgb: [f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// Side of a fine texture tile, texels.
const FINE_SIZE: usize = 1024;
/// Fine texel size, mm (a 205 mm tile).
const FINE_MM: f64 = 0.2;
/// Side of a coarse texture tile, texels.
const COARSE_SIZE: usize = 128;
/// Coarse texel size, mm (a 256 mm tile).
const COARSE_MM: f64 = 2.0;

/// Pores, grain, blotches and wetness on a cylindrical chart of the neutral head:
/// `s = R·atan2(x − cx, z − cz)`, `t = y` (mm), around the vertical axis through the
/// middle of the head, so one chart millimetre is about one millimetre of the face's
/// front and sides. Textures are tiles (periodic), precomputed once.
#[derive(Debug, Clone, PartialEq)]
pub struct SkinTexture {
    centre_x: f64,
    centre_z: f64,
    radius: f64,
    /// Albedo factor (mean 1) of pores and grain, fine tile.
    fine: Vec<f32>,
    /// Albedo factor of broad blotches (mean 1), coarse tile.
    blotch: Vec<f32>,
    /// Wetness 0..1, coarse tile.
    wet: Vec<f32>,
}

impl SkinTexture {
    /// Builds the textures for the neutral `mesh` with albedo variation `strength`
    /// (standard deviation of the fine factor).
    pub fn new(mesh: &Mesh, strength: f64, seed: u64) -> Self {
        let (mut lo, mut hi) = (Vector3::repeat(f64::MAX), Vector3::repeat(f64::MIN));
        for p in &mesh.positions {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        let radius = (0.5 * (hi.x - lo.x)).max(1.0);
        let centre_x = 0.5 * (hi.x + lo.x);
        // About as deep as wide: the axis sits a half-width behind the face's front.
        let centre_z = hi.z - radius;
        let mut rng = StdRng::seed_from_u64(seed ^ 0x706f_7265);
        // Fine: grain (white noise blurred over ~0.2 mm) plus pores (dark pits, ~1 per mm²).
        let n = FINE_SIZE;
        let mut grain: Vec<f32> = (0..n * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        blur_periodic(&mut grain, n, 1.0);
        normalize(&mut grain);
        let mut pits = vec![0.0f32; n * n];
        let area_mm2 = (n as f64 * FINE_MM).powi(2);
        for _ in 0..area_mm2 as usize {
            let (x, y) = (rng.random_range(0..n), rng.random_range(0..n));
            let depth: f32 = rng.random_range(0.5..1.0);
            for (dx, dy, w) in [
                (0, 0, 1.0f32),
                (1, 0, 0.4),
                (n - 1, 0, 0.4),
                (0, 1, 0.4),
                (0, n - 1, 0.4),
            ] {
                pits[((y + dy) % n) * n + (x + dx) % n] -= depth * w;
            }
        }
        normalize(&mut pits);
        let s = strength as f32;
        let fine = grain
            .iter()
            .zip(&pits)
            .map(|(g, p)| (1.0 + s * (0.6 * g + 0.8 * p)).clamp(0.3, 1.7))
            .collect();
        // Coarse: blotches (uneven tone over ~1 cm) and wet patches (~1-2 cm).
        let m = COARSE_SIZE;
        let mut blotch: Vec<f32> = (0..m * m).map(|_| rng.random_range(-1.0..1.0)).collect();
        blur_periodic(&mut blotch, m, 2.5);
        normalize(&mut blotch);
        let blotch = blotch
            .iter()
            .map(|b| (1.0 + 0.5 * s * b).clamp(0.5, 1.5))
            .collect();
        let mut wet: Vec<f32> = (0..m * m).map(|_| rng.random_range(-1.0..1.0)).collect();
        blur_periodic(&mut wet, m, 4.0);
        normalize(&mut wet);
        // About a third of the skin is wet: a smooth step around the 65th percentile.
        let wet = wet
            .iter()
            .map(|w| {
                let x = ((w - 0.1) / 0.8).clamp(0.0, 1.0);
                x * x * (3.0 - 2.0 * x)
            })
            .collect();
        Self {
            centre_x,
            centre_z,
            radius,
            fine,
            blotch,
            wet,
        }
    }

    /// Chart coordinates (mm) of a rest-pose point (head frame).
    pub fn chart(&self, rest: &Point3<f64>) -> (f64, f64) {
        let s = self.radius * (rest.x - self.centre_x).atan2(rest.z - self.centre_z);
        (s, rest.y)
    }

    /// Albedo factor (pores, grain, blotches) at a rest-pose point.
    pub fn albedo_factor(&self, rest: &Point3<f64>) -> f32 {
        let (s, t) = self.chart(rest);
        bilinear(&self.fine, FINE_SIZE, s / FINE_MM, t / FINE_MM)
            * bilinear(&self.blotch, COARSE_SIZE, s / COARSE_MM, t / COARSE_MM)
    }

    /// Wetness (0..1) at a rest-pose point.
    pub fn wetness(&self, rest: &Point3<f64>) -> f32 {
        let (s, t) = self.chart(rest);
        bilinear(&self.wet, COARSE_SIZE, s / COARSE_MM, t / COARSE_MM)
    }
}

/// Bilinear lookup in a periodic `n × n` tile at texel coordinates `(x, y)`.
fn bilinear(tile: &[f32], n: usize, x: f64, y: f64) -> f32 {
    let nf = n as f64;
    let x = x.rem_euclid(nf);
    let y = y.rem_euclid(nf);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let (x0, y0) = ((x0 as usize) % n, (y0 as usize) % n);
    let (x1, y1) = ((x0 + 1) % n, (y0 + 1) % n);
    let at = |x: usize, y: usize| tile.get(y * n + x).copied().unwrap_or(1.0);
    let top = at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx;
    let bottom = at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// Separable Gaussian blur of a periodic `n × n` tile.
fn blur_periodic(tile: &mut [f32], n: usize, sigma: f64) {
    let radius = (3.0 * sigma).ceil() as usize;
    let kernel: Vec<f32> = (0..=2 * radius)
        .map(|i| {
            let d = i as f64 - radius as f64;
            (-(d * d) / (2.0 * sigma * sigma)).exp() as f32
        })
        .collect();
    let sum: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / sum).collect();
    let mut tmp = vec![0.0f32; tile.len()];
    for y in 0..n {
        for x in 0..n {
            tmp[y * n + x] = kernel
                .iter()
                .enumerate()
                .map(|(k, w)| w * tile[y * n + (x + n * 4 + k - radius) % n])
                .sum();
        }
    }
    for y in 0..n {
        for x in 0..n {
            tile[y * n + x] = kernel
                .iter()
                .enumerate()
                .map(|(k, w)| w * tmp[((y + n * 4 + k - radius) % n) * n + x])
                .sum();
        }
    }
}

/// Shifts and scales to mean 0, standard deviation 1.
fn normalize(values: &mut [f32]) {
    let n = values.len().max(1) as f64;
    let mean = values.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let var = values
        .iter()
        .map(|&v| (f64::from(v) - mean).powi(2))
        .sum::<f64>()
        / n;
    let sd = var.sqrt().max(1e-12);
    for v in values {
        *v = ((f64::from(*v) - mean) / sd) as f32;
    }
}

/// The shadow of the helmet boom from the room's key light: a soft band between two
/// parallel planes fixed to the helmet (the cam0 frame), sweeping slowly across the face.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadowBand {
    /// Unit normal of the band's mid-plane, cam0 frame.
    pub normal: Vector3<f64>,
    /// Signed distance of the mid-plane from the cam0 origin, mm.
    pub offset_mm: f64,
    /// Half the band's full-shadow width, mm.
    pub half_width_mm: f64,
    /// Penumbra width on each side, mm.
    pub softness_mm: f64,
    /// Share of the direct light blocked in full shadow.
    pub depth: f64,
}

impl ShadowBand {
    /// The band at time `t_secs` for a face centred at `face_centre` (cam0 frame), or
    /// `None` when the shadow is off. The band runs diagonally across the face (the boom
    /// comes in from the side) and its mid-plane sweeps ±0.35 face widths (taken as 150
    /// mm) around the face centre with period `boom_period_secs`.
    pub fn at(
        params: &SkinParams,
        t_secs: f64,
        face_centre: &Point3<f64>,
        seed: u64,
    ) -> Option<Self> {
        if params.boom_shadow <= 0.0 {
            return None;
        }
        let h = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 11;
        let phase = (h as f64 / (1u64 << 53) as f64) * std::f64::consts::TAU;
        let angle = 0.35 + 0.5 * (h % 1000) as f64 / 1000.0;
        let normal = Vector3::new(angle.cos(), angle.sin(), 0.0);
        let sweep =
            0.35 * 150.0 * (std::f64::consts::TAU * t_secs / params.boom_period_secs + phase).sin();
        Some(Self {
            normal,
            offset_mm: normal.dot(&face_centre.coords) + sweep,
            half_width_mm: 0.5 * params.boom_width_mm,
            softness_mm: params.boom_softness_mm,
            depth: params.boom_shadow,
        })
    }

    /// Factor on the direct light at a point (cam0 frame): `1 − depth` in full shadow,
    /// 1 outside, a smoothstep across the penumbra.
    pub fn direct_light(&self, p_in_cam0: &Point3<f64>) -> f64 {
        let d = (self.normal.dot(&p_in_cam0.coords) - self.offset_mm).abs();
        let x = ((self.half_width_mm + self.softness_mm - d) / self.softness_mm).clamp(0.0, 1.0);
        1.0 - self.depth * x * x * (3.0 - 2.0 * x)
    }
}

/// Gain of the light on frame `frame` at `fps` with shutter open `shutter_secs`: the
/// light `1 + A·sin(2π·F·t + φ)` (A [`SkinParams::flicker_amplitude`], F
/// [`SkinParams::flicker_hz`], φ from the seed) averaged over the exposure centred on the
/// frame time, `1 + A·sin(2π·F·t + φ)·sinc(π·F·T)`: a short shutter sees the flicker's
/// full depth, one as long as its period sees none.
pub fn flicker_gain(
    params: &SkinParams,
    frame: usize,
    fps: f64,
    shutter_secs: f64,
    seed: u64,
) -> f64 {
    if params.flicker_amplitude == 0.0 || params.flicker_hz == 0.0 {
        return 1.0;
    }
    let h = (seed ^ 0xf11c).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 11;
    let phase = (h as f64 / (1u64 << 53) as f64) * std::f64::consts::TAU;
    let t = frame as f64 / fps;
    let x = std::f64::consts::PI * params.flicker_hz * shutter_secs;
    let sinc = if x.abs() < 1e-9 { 1.0 } else { x.sin() / x };
    1.0 + params.flicker_amplitude
        * (std::f64::consts::TAU * params.flicker_hz * t + phase).sin()
        * sinc
}

/// Coverage of a pixel of footprint `footprint` (mm) by a band of half width `half` at
/// distance `d` from its centre line, with a soft edge `soft` (box-filtered, 1D): the
/// exact area fraction for a straight edge, so a hair thinner than a pixel darkens it by
/// its share of the pixel.
pub fn coverage(d: f64, half: f64, footprint: f64, soft: f64) -> f64 {
    let w = footprint.max(soft).max(1e-9);
    let lo = (d - 0.5 * w).max(-half);
    let hi = (d + 0.5 * w).min(half);
    ((hi - lo) / w).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_is_the_area_fraction() {
        // Far inside and far outside.
        assert_eq!(coverage(0.0, 5.0, 1.0, 0.0), 1.0);
        assert_eq!(coverage(7.0, 5.0, 1.0, 0.0), 0.0);
        // On the edge: half.
        assert!((coverage(5.0, 5.0, 1.0, 0.0) - 0.5).abs() < 1e-12);
        // A hair a tenth of a pixel wide covers a tenth of the pixel it crosses.
        assert!((coverage(0.0, 0.05, 1.0, 0.0) - 0.1).abs() < 1e-12);
    }

    #[test]
    fn closest_point_is_on_the_triangle() {
        let a = Point3::new(0.0, 0.0, 0.0);
        let b = Point3::new(1.0, 0.0, 0.0);
        let c = Point3::new(0.0, 1.0, 0.0);
        let w = closest_barycentric(&Point3::new(0.25, 0.25, 3.0), &a, &b, &c);
        assert!((w[1] - 0.25).abs() < 1e-12 && (w[2] - 0.25).abs() < 1e-12);
        let w = closest_barycentric(&Point3::new(2.0, 2.0, 0.0), &a, &b, &c);
        assert!((w[1] - 0.5).abs() < 1e-12 && (w[2] - 0.5).abs() < 1e-12);
        assert_eq!(
            closest_barycentric(&Point3::new(-1.0, -1.0, 0.0), &a, &b, &c),
            [1.0, 0.0, 0.0]
        );
    }

    #[test]
    fn flicker_follows_the_light_and_the_shutter() {
        let p = SkinParams {
            flicker_amplitude: 0.2,
            flicker_hz: 100.0,
            ..SkinParams::default()
        };
        let gains: Vec<f64> = (0..600)
            .map(|f| flicker_gain(&p, f, 61.0, 1e-6, 3))
            .collect();
        let max = gains.iter().copied().fold(f64::MIN, f64::max);
        let min = gains.iter().copied().fold(f64::MAX, f64::min);
        // A very short shutter samples the full ±20 % (at 61 fps the phases spread out).
        assert!(max > 1.19 && max <= 1.2 + 1e-12, "{max}");
        assert!((0.8 - 1e-12..0.81).contains(&min), "{min}");
        // A shutter of exactly one flicker period averages it away.
        assert!((flicker_gain(&p, 17, 60.0, 0.01, 3) - 1.0).abs() < 1e-12);
        assert_eq!(flicker_gain(&SkinParams::default(), 17, 60.0, 0.01, 3), 1.0);
    }

    #[test]
    fn shadow_band_is_dark_inside_and_soft_at_the_edge() {
        let p = SkinParams {
            boom_shadow: 0.6,
            boom_width_mm: 20.0,
            boom_softness_mm: 10.0,
            ..SkinParams::default()
        };
        let band = ShadowBand::at(&p, 1.0, &Point3::new(0.0, 0.0, 200.0), 5).unwrap();
        let on = Point3::from(band.normal * band.offset_mm);
        assert!((band.direct_light(&on) - 0.4).abs() < 1e-12);
        let edge = Point3::from(band.normal * (band.offset_mm + 15.0));
        assert!((band.direct_light(&edge) - 0.7).abs() < 1e-12);
        let out = Point3::from(band.normal * (band.offset_mm + 25.0));
        assert_eq!(band.direct_light(&out), 1.0);
        assert!(ShadowBand::at(&SkinParams::default(), 1.0, &on, 5).is_none());
    }

    #[test]
    fn default_is_off_and_any_sees_each_effect() {
        assert!(!SkinParams::default().any());
        SkinParams::default().validate().unwrap();
        for p in [
            SkinParams {
                freckles: 3,
                ..Default::default()
            },
            SkinParams {
                pores: 0.1,
                ..Default::default()
            },
            SkinParams {
                flicker_amplitude: 0.1,
                ..Default::default()
            },
            SkinParams {
                wiped_dots: 1,
                ..Default::default()
            },
        ] {
            assert!(p.any());
        }
        let bad = SkinParams {
            mole_albedo: f64::NAN,
            ..Default::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("mole_albedo")
        );
    }
}
