//! The neutral skin surface of one identity: a star-shaped radial function.
//!
//! The skin is `P(u, v) = C + r(u, v)·d(u, v)`, where `C` is a fixed centre inside the
//! head, `d` the unit direction of azimuth `θ = u/R0` (0 = straight ahead, +x side
//! positive) and elevation `φ = v/R0`, and `r` the distance to the skin along that ray.
//! `(u, v)` are "parameter millimetres": arc length on a sphere of radius `R0 = 100 mm`,
//! close to true millimetres on the face.
//!
//! `r` is built in three layers:
//! 1. a base head: the smooth union (polynomial smooth maximum of the ray exit distances)
//!    of four convex superellipsoids (cranium, mid face, lower face with the jaw, neck);
//! 2. facial features added along the ray as compactly supported bumps and grooves in
//!    `(u, v)`: nose, brow ridge, eye sockets, cheekbones, lips, labiomental fold, chin,
//!    temples, a shallow nasolabial fold;
//! 3. the eyelids: a sphere 1.2 mm outside each eyeball, smoothly united with the face,
//!    so the lids lie on (and blink over) the eyeball.
//!
//! Identity parameters place features in `(u, v)`; a smooth monotone map from the
//! canonical (default identity) parameters to the identity's parameters
//! ([`IdentityWarp`]) makes every identity share one topology with its features (eye and
//! mouth openings, nose tip, chin) on the same vertices.

use std::f64::consts::{FRAC_PI_2, PI};

use nalgebra::{Point3, Vector3};

use super::ActorError;
use super::params::ActorParams;

/// Parameter millimetres per radian.
pub(crate) const R0: f64 = 100.0;
/// Lowest parameter row: the neck opening (elevation about −70°).
pub(crate) const V_MIN: f64 = -1.22 * R0;
/// Parameter height of the crown pole (elevation +90°).
pub(crate) const V_POLE: f64 = FRAC_PI_2 * R0;
/// Parameter half-circumference: the back seam is at `u = ±U_SEAM`.
pub(crate) const U_SEAM: f64 = PI * R0;
/// Radius of each eyeball sphere, mm.
pub(crate) const EYEBALL_RADIUS_MM: f64 = 12.0;
/// Radius of the sphere the eyelids lie on (eyeball plus lid clearance), mm.
const LID_RADIUS_MM: f64 = 13.2;
/// Blend width of the base head's smooth union, mm.
const BLEND_MM: f64 = 12.0;
/// Blend width between the face and the eyelid spheres, mm.
const LID_BLEND_MM: f64 = 2.5;

/// Centre of the rays, mm, head frame.
pub(crate) fn ray_centre() -> Vector3<f64> {
    Vector3::new(0.0, -40.0, -15.0)
}

/// Unit ray direction of parameter point `(u, v)`.
pub(crate) fn direction(u: f64, v: f64) -> Vector3<f64> {
    let (t, p) = (u / R0, v / R0);
    Vector3::new(p.cos() * t.sin(), p.sin(), p.cos() * t.cos())
}

/// Hermite smoothstep: 0 below `e0`, 1 above `e1`, C1 in between.
pub(crate) fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A soft elliptic disc: 1 at the centre, 0 at and beyond the ellipse of radii
/// `(ru, rv)`, C1 everywhere.
pub(crate) fn disc(du: f64, dv: f64, ru: f64, rv: f64) -> f64 {
    let d = ((du / ru).powi(2) + (dv / rv).powi(2)).sqrt();
    1.0 - smoothstep(0.0, 1.0, d)
}

/// Like [`disc`] but C2 (quintic smootherstep falloff), for expression masks whose
/// curvature should stay smooth.
pub(crate) fn disc2(du: f64, dv: f64, ru: f64, rv: f64) -> f64 {
    let d = ((du / ru).powi(2) + (dv / rv).powi(2)).sqrt();
    if d >= 1.0 {
        return 0.0;
    }
    1.0 - d * d * d * (d * (d * 6.0 - 15.0) + 10.0)
}

/// `(1 − t²)³` on |t| < 1, else 0 (C2 compact bump).
pub(crate) fn bump3(t: f64) -> f64 {
    if t.abs() >= 1.0 {
        0.0
    } else {
        let s = 1.0 - t * t;
        s * s * s
    }
}

/// Polynomial smooth maximum (C1) with blend width `k`.
fn smax(a: f64, b: f64, k: f64) -> f64 {
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.max(b) + h * h * k * 0.25
}

/// A convex superellipsoid `Σ_k |(x_k − c_k)/s_k|^(n_k) = 1`, with its own semi-axis on
/// each side of the centre along each axis.
#[derive(Debug, Clone)]
struct Blob {
    centre: Vector3<f64>,
    semi_pos: Vector3<f64>,
    semi_neg: Vector3<f64>,
    /// Exponent per axis (each ≥ 1 keeps the blob convex).
    exponent: Vector3<f64>,
}

impl Blob {
    /// Value and derivative of the implicit function along `o + t·d` (o relative to
    /// the centre).
    fn implicit(&self, o: &Vector3<f64>, d: &Vector3<f64>, t: f64) -> (f64, f64) {
        let (mut f, mut df) = (-1.0, 0.0);
        for k in 0..3 {
            let n = self.exponent[k];
            let q = o[k] + t * d[k];
            let s = if q >= 0.0 {
                self.semi_pos[k]
            } else {
                self.semi_neg[k]
            };
            let a = q.abs() / s;
            // One power per axis: `aⁿ = aⁿ⁻¹·a` (n ≥ 1).
            let below = a.powf(n - 1.0);
            f += below * a;
            df += n * below * q.signum() * d[k] / s;
        }
        (f, df)
    }

    /// Distance from `origin` along unit `dir` to where the ray leaves the blob; 0 when
    /// the origin is not inside. The implicit function is convex along the ray, so
    /// Newton's method from a point beyond the surface converges monotonically.
    fn exit_distance(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> f64 {
        let o = origin - self.centre;
        if self.implicit(&o, dir, 0.0).0 >= 0.0 {
            return 0.0;
        }
        let reach = self.semi_pos.sup(&self.semi_neg).norm();
        let mut t = o.norm() + reach;
        for _ in 0..60 {
            let (f, df) = self.implicit(&o, dir, t);
            if df <= 1e-12 {
                break;
            }
            let step = f / df;
            t -= step;
            if step.abs() < 1e-10 {
                break;
            }
        }
        t.max(0.0)
    }
}

/// Far intersection distance of a ray from `origin` with a sphere, if it hits.
fn sphere_exit(origin: &Vector3<f64>, dir: &Vector3<f64>, c: &Vector3<f64>, r: f64) -> Option<f64> {
    let o = origin - c;
    let b = o.dot(dir);
    let disc = b * b - (o.norm_squared() - r * r);
    (disc >= 0.0).then(|| -b + disc.sqrt())
}

/// Feature positions of one identity in parameter millimetres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Layout {
    /// Chin bottom (menton).
    pub v_chin: f64,
    /// Most forward point of the chin (pogonion).
    pub v_pog: f64,
    /// Labiomental fold (the crease between lower lip and chin).
    pub v_labiomental: f64,
    /// Lip line (stomion).
    pub v_mouth: f64,
    /// Base of the nose (subnasale).
    pub v_sub: f64,
    /// Nose tip.
    pub v_tip: f64,
    /// Nose bridge root (nasion).
    pub v_nasion: f64,
    /// Eye centres.
    pub v_eye: f64,
    /// Brow line.
    pub v_brow: f64,
    /// Hairline (top of the forehead).
    pub v_hair: f64,
    /// Eye centre, |u|.
    pub u_eye: f64,
    /// Half width of the eye opening.
    pub a_eye: f64,
    /// Mouth corner, |u|.
    pub u_corner: f64,
    /// Nostril wing, |u|.
    pub u_ala: f64,
}

/// Monotone cubic Hermite interpolation (Fritsch and Carlson 1980) through increasing
/// knots, extrapolated linearly.
#[derive(Debug, Clone)]
struct MonotoneCubic {
    x: Vec<f64>,
    y: Vec<f64>,
    m: Vec<f64>,
}

impl MonotoneCubic {
    fn new(x: Vec<f64>, y: Vec<f64>) -> Self {
        let n = x.len();
        let delta: Vec<f64> = (0..n - 1)
            .map(|i| (y[i + 1] - y[i]) / (x[i + 1] - x[i]))
            .collect();
        let mut m = vec![0.0; n];
        m[0] = delta[0];
        m[n - 1] = delta[n - 2];
        for i in 1..n - 1 {
            m[i] = if delta[i - 1] * delta[i] <= 0.0 {
                0.0
            } else {
                // Harmonic mean keeps the interpolant monotone.
                2.0 / (1.0 / delta[i - 1] + 1.0 / delta[i])
            };
        }
        Self { x, y, m }
    }

    fn eval(&self, t: f64) -> f64 {
        let n = self.x.len();
        if t <= self.x[0] {
            return self.y[0] + self.m[0] * (t - self.x[0]);
        }
        if t >= self.x[n - 1] {
            return self.y[n - 1] + self.m[n - 1] * (t - self.x[n - 1]);
        }
        let i = self.x.partition_point(|&xi| xi <= t).clamp(1, n - 1) - 1;
        let h = self.x[i + 1] - self.x[i];
        let s = (t - self.x[i]) / h;
        let (s2, s3) = (s * s, s * s * s);
        (2.0 * s3 - 3.0 * s2 + 1.0) * self.y[i]
            + (s3 - 2.0 * s2 + s) * h * self.m[i]
            + (-2.0 * s3 + 3.0 * s2) * self.y[i + 1]
            + (s3 - s2) * h * self.m[i + 1]
    }
}

/// Smooth monotone map from canonical to identity parameter coordinates:
/// `v' = f(v)` (monotone cubic through the feature heights) and
/// `u' = u·(1 + (k(v) − 1)·Λ(u))`, a horizontal scale `k` that matches the eyes at eye
/// height and the mouth corners at mouth height, faded out toward the back seam.
#[derive(Debug, Clone)]
pub(crate) struct IdentityWarp {
    fv: Option<MonotoneCubic>,
    k_eye: f64,
    k_mouth: f64,
    v_eye: f64,
    v_mouth: f64,
}

impl IdentityWarp {
    fn identity() -> Self {
        Self {
            fv: None,
            k_eye: 1.0,
            k_mouth: 1.0,
            v_eye: 0.0,
            v_mouth: 0.0,
        }
    }

    fn new(canon: &Layout, id: &Layout) -> Self {
        let knots = |l: &Layout| {
            vec![
                V_MIN, l.v_chin, l.v_mouth, l.v_tip, l.v_eye, l.v_hair, V_POLE,
            ]
        };
        Self {
            fv: Some(MonotoneCubic::new(knots(canon), knots(id))),
            k_eye: id.u_eye / canon.u_eye,
            k_mouth: id.u_corner / canon.u_corner,
            v_eye: canon.v_eye,
            v_mouth: canon.v_mouth,
        }
    }

    /// Identity parameter coordinates of canonical `(u, v)`.
    pub(crate) fn apply(&self, u: f64, v: f64) -> (f64, f64) {
        let Some(fv) = &self.fv else {
            return (u, v);
        };
        let k = 1.0
            + (self.k_eye - 1.0) * disc(0.0, v - self.v_eye, 1.0, 30.0)
            + (self.k_mouth - 1.0) * disc(0.0, v - self.v_mouth, 1.0, 26.0);
        let fade = 1.0 - smoothstep(70.0, 200.0, u.abs());
        (u * (1.0 + (k - 1.0) * fade), fv.eval(v))
    }
}

/// Feature amplitudes of one identity, mm.
#[derive(Debug, Clone, Copy)]
struct Amplitudes {
    nose: f64,
    brow: f64,
    cheek: f64,
    chin: f64,
    lips: f64,
}

/// The neutral skin surface of one identity.
#[derive(Debug, Clone)]
pub(crate) struct Surface {
    blobs: Vec<Blob>,
    /// Feature positions in this identity's parameter coordinates.
    pub layout: Layout,
    amp: Amplitudes,
    /// Eyeball centres (left = +x first), mm, head frame.
    pub eye_centres: [Vector3<f64>; 2],
    /// Pivot of the jaw (midpoint of the jaw joints), mm, head frame.
    pub jaw_pivot: Point3<f64>,
    warp: IdentityWarp,
}

/// Physical heights (head frame y, mm) of the features of an identity.
struct Heights {
    nasion: f64,
    eye: f64,
    brow: f64,
    hair: f64,
    chin: f64,
    crown: f64,
    tip: f64,
    sub: f64,
    mouth: f64,
}

impl Heights {
    fn of(p: &ActorParams) -> Self {
        let nasion = 12.0;
        let eye = nasion - 7.0;
        let chin = nasion - p.face_length_mm;
        let tip = nasion - p.nose_length_mm;
        let sub = tip - 9.0 * p.nose_length_mm / 44.0;
        Self {
            nasion,
            eye,
            brow: eye + 19.0,
            hair: nasion + 62.0 * p.face_length_mm / 120.0,
            chin,
            crown: chin + p.head_height_mm,
            tip,
            sub,
            mouth: sub - (sub - chin) / 3.0,
        }
    }
}

impl Surface {
    /// The surface of identity `p`. `canon` is the canonical (default identity) layout
    /// the topology was laid out on; `None` builds the canonical surface itself.
    pub(crate) fn new(p: &ActorParams, canon: Option<&Layout>) -> Result<Self, ActorError> {
        let h = Heights::of(p);
        let glabella_z = 92.0;
        let cranium_y = h.eye + 10.0;
        let cranium_z = glabella_z - 0.5 * p.head_depth_mm;
        let lower_y = h.mouth - 5.0;
        let blobs = vec![
            Blob {
                centre: Vector3::new(0.0, cranium_y, cranium_z),
                semi_pos: Vector3::new(
                    0.5 * p.head_width_mm,
                    h.crown - cranium_y,
                    0.5 * p.head_depth_mm,
                ),
                semi_neg: Vector3::new(0.5 * p.head_width_mm, 95.0, 0.5 * p.head_depth_mm),
                exponent: Vector3::new(2.15, 2.15, 2.15),
            },
            Blob {
                centre: Vector3::new(0.0, h.eye - 24.0, -4.0),
                semi_pos: Vector3::new(0.44 * p.head_width_mm, 40.0, 86.0),
                semi_neg: Vector3::new(0.44 * p.head_width_mm, 42.0, 60.0),
                exponent: Vector3::new(2.4, 2.4, 2.4),
            },
            Blob {
                centre: Vector3::new(0.0, lower_y, 0.0),
                semi_pos: Vector3::new(0.5 * p.jaw_width_mm, 60.0, 86.0),
                semi_neg: Vector3::new(0.5 * p.jaw_width_mm, lower_y - h.chin - 2.0, 26.0),
                exponent: Vector3::new(2.6, 4.0, 2.6),
            },
            Blob {
                centre: Vector3::new(0.0, h.chin - 100.0, -22.0),
                semi_pos: Vector3::new(54.0 * p.head_width_mm / 152.0, 230.0, 57.0),
                semi_neg: Vector3::new(54.0 * p.head_width_mm / 152.0, 230.0, 57.0),
                exponent: Vector3::new(2.2, 2.2, 2.2),
            },
        ];
        let c = ray_centre();
        for (i, b) in blobs.iter().enumerate() {
            if b.implicit(&(c - b.centre), &Vector3::x(), 0.0).0 >= 0.0 {
                return Err(ActorError::Geometry(format!(
                    "base head part {i} does not contain the ray centre"
                )));
            }
        }
        let mut s = Self {
            blobs,
            layout: Layout {
                v_chin: 0.0,
                v_pog: 0.0,
                v_labiomental: 0.0,
                v_mouth: 0.0,
                v_sub: 0.0,
                v_tip: 0.0,
                v_nasion: 0.0,
                v_eye: 0.0,
                v_brow: 0.0,
                v_hair: 0.0,
                u_eye: 0.0,
                a_eye: 0.0,
                u_corner: 0.0,
                u_ala: 0.0,
            },
            amp: Amplitudes {
                nose: p.nose_protrusion_mm,
                brow: p.brow_prominence_mm,
                cheek: p.cheek_fullness_mm,
                chin: p.chin_prominence_mm,
                lips: p.lip_fullness_mm,
            },
            eye_centres: [Vector3::zeros(); 2],
            jaw_pivot: Point3::new(0.0, h.eye - 22.0, glabella_z - 0.52 * p.head_depth_mm),
            warp: IdentityWarp::identity(),
        };
        let v_eye = s.v_for_y(h.eye);
        let v_mouth = s.v_for_y(h.mouth);
        let v_tip = s.v_for_y(h.tip);
        let u_eye = s.u_for_x(0.5 * p.eye_spacing_mm, v_eye);
        s.layout = Layout {
            v_chin: s.v_for_y(h.chin),
            v_pog: s.v_for_y(h.chin + 13.0),
            v_labiomental: s.v_for_y(h.mouth - 17.0),
            v_mouth,
            v_sub: s.v_for_y(h.sub),
            v_tip,
            v_nasion: s.v_for_y(h.nasion),
            v_eye,
            v_brow: s.v_for_y(h.brow),
            v_hair: s.v_for_y(h.hair),
            u_eye,
            a_eye: s.u_for_x(0.5 * p.eye_spacing_mm + 13.5, v_eye) - u_eye,
            u_corner: s.u_for_x(0.5 * p.lip_width_mm, v_mouth),
            u_ala: s.u_for_x(0.5 * p.nose_width_mm, v_tip - 4.0),
        };
        let l = s.layout;
        let ordered = [
            V_MIN,
            l.v_chin,
            l.v_mouth,
            l.v_sub,
            l.v_tip,
            l.v_eye,
            l.v_hair,
            V_POLE - 20.0,
        ];
        if ordered.windows(2).any(|w| w[1] - w[0] < 4.0) || !ordered.iter().all(|x| x.is_finite()) {
            return Err(ActorError::Geometry(
                "feature heights are out of order for these proportions".into(),
            ));
        }
        for (side, sign) in [1.0, -1.0].into_iter().enumerate() {
            let d = direction(sign * l.u_eye, l.v_eye);
            let r = s.base_radius(&d) + s.features(sign * l.u_eye, l.v_eye);
            s.eye_centres[side] = c + (r + 3.0 - LID_RADIUS_MM) * d;
        }
        if let Some(canon) = canon {
            s.warp = IdentityWarp::new(canon, &s.layout);
        }
        Ok(s)
    }

    /// Distance along `d` to the base head (smooth union of the blobs).
    fn base_radius(&self, d: &Vector3<f64>) -> f64 {
        let c = ray_centre();
        self.blobs
            .iter()
            .map(|b| b.exit_distance(&c, d))
            .fold(0.0, |acc, r| smax(acc, r, BLEND_MM))
    }

    /// Head-frame height of the base profile at `(0, v)`.
    fn base_y(&self, v: f64) -> f64 {
        let d = direction(0.0, v);
        ray_centre().y + self.base_radius(&d) * d.y
    }

    /// Parameter height `v` where the midline base profile reaches height `y` (bisection).
    fn v_for_y(&self, y: f64) -> f64 {
        let (mut lo, mut hi) = (V_MIN, 0.45 * PI * R0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.base_y(mid) < y {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// Parameter `u ≥ 0` where the base surface at height `v` reaches lateral `x`.
    fn u_for_x(&self, x: f64, v: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, 0.5 * PI * R0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            let d = direction(mid, v);
            if self.base_radius(&d) * d.x < x {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// Facial feature offsets along the ray at identity parameters `(u, v)`, mm.
    fn features(&self, u: f64, v: f64) -> f64 {
        let l = &self.layout;
        let a = &self.amp;
        let au = u.abs();
        let mut r = 0.0;

        // Nose: a ridge from the nasion to the tip, rounded under the tip down to the
        // subnasale, plus the nostril wings.
        let bridge = l.v_nasion - l.v_tip;
        if v <= l.v_nasion + 10.0 && v >= l.v_sub - 1.0 {
            let (height, half_width) = if v >= l.v_nasion {
                let t = (v - l.v_nasion) / 10.0;
                (1.5 * bump3(t), 10.0)
            } else if v >= l.v_tip {
                let t = (l.v_nasion - v) / bridge;
                (1.5 + (a.nose - 1.5) * t.powf(1.6), 8.5 + 5.0 * t * t)
            } else {
                let t = ((l.v_tip - v) / (l.v_tip - l.v_sub)).min(1.0);
                (a.nose * (1.0 - t * t).powf(1.5), 13.5 + 3.0 * t)
            };
            let x = u / half_width;
            if x.abs() < 1.0 {
                r += height * (1.0 - x * x).powi(2);
            }
        }
        let ala_u = (l.u_ala - 5.5).max(6.0);
        r += 0.3 * a.nose * disc(au - ala_u, v - (l.v_tip - 5.0), 8.0, 7.5);

        // Brow ridge: two lobes above the eyes and a milder glabella.
        r += a.brow * disc(au - 0.75 * l.u_eye, v - (l.v_brow - 1.0), 26.0, 11.0);
        r += 0.5 * a.brow * disc(u, v - (l.v_brow - 4.0), 14.0, 10.0);

        // Eye sockets (the lids are added as spheres in `radius`).
        r -= 9.0 * disc(au - l.u_eye, v - (l.v_eye + 1.0), 21.0, 15.0);

        // Cheekbones and cheeks.
        r += a.cheek * disc(au - (l.u_eye + 14.0), v - (l.v_eye - 22.0), 26.0, 19.0);
        r += 0.5 * a.cheek * disc(au - (l.u_corner + 14.0), v - (l.v_mouth + 10.0), 18.0, 20.0);

        // Temples.
        r -= 3.0 * disc(au - (l.u_eye + 36.0), v - (l.v_brow + 6.0), 16.0, 22.0);

        // Mouth: the lips' vermilion, the crease where they meet, the philtrum.
        let lip_profile = if au < l.u_corner {
            (1.0 - (au / l.u_corner).powi(2)).powf(0.7)
        } else {
            0.0
        };
        r += a.lips * lip_profile * bump3((v - (l.v_mouth + 4.0)) / 5.5);
        r += 1.2 * a.lips * lip_profile * bump3((v - (l.v_mouth - 5.0)) / 6.5);
        r -= 2.0 * lip_profile.sqrt() * bump3((v - l.v_mouth) / 2.8);
        r += 2.5 * disc(u, v - l.v_mouth, l.u_corner + 10.0, 18.0);
        r -= 0.8 * bump3(u / 4.0) * disc(0.0, v - 0.5 * (l.v_sub + l.v_mouth + 4.0), 1.0, 6.0);
        r -= 1.0 * disc(au - (l.u_corner + 2.0), v - l.v_mouth, 4.0, 4.0);

        // Labiomental fold and chin boss.
        r -= 2.2 * disc(u, v - l.v_labiomental, 20.0, 4.5);
        r += a.chin * disc(u, v - l.v_pog, 18.0, 13.0);

        // Shallow neutral nasolabial fold.
        r -= 0.7 * nasolabial_groove(l, u, v);
        r
    }

    /// Distance along the ray to the skin at identity parameters `(u, v)`, mm.
    pub(crate) fn radius(&self, u: f64, v: f64) -> f64 {
        let d = direction(u, v);
        let c = ray_centre();
        let mut r = self.base_radius(&d) + self.features(u, v);
        for e in &self.eye_centres {
            if let Some(t) = sphere_exit(&c, &d, e, LID_RADIUS_MM) {
                r = smax(r, t, LID_BLEND_MM);
            }
        }
        r
    }

    /// Skin point at canonical parameters `(u, v)` (after the identity warp).
    pub(crate) fn point(&self, u: f64, v: f64) -> Point3<f64> {
        let (ui, vi) = self.warp.apply(u, v);
        self.point_identity(ui, vi)
    }

    /// Skin point at this identity's own parameters.
    pub(crate) fn point_identity(&self, u: f64, v: f64) -> Point3<f64> {
        Point3::from(ray_centre() + self.radius(u, v) * direction(u, v))
    }
}

/// A groove profile along the nasolabial fold (the line from the nostril wing to beyond
/// the mouth corner): 1 on the line, 0 a few millimetres away, on both sides of the face.
pub(crate) fn nasolabial_groove(l: &Layout, u: f64, v: f64) -> f64 {
    let au = u.abs();
    if au < l.u_ala - 8.0 || au > l.u_corner + 30.0 || v > l.v_tip + 8.0 || v < l.v_mouth - 25.0 {
        return 0.0;
    }
    let (d, along) = nasolabial_coords(l, u, v);
    (-(d / 2.6).powi(2)).exp() * along
}

/// Signed distance from the nasolabial line (positive laterally), and a 0..1 mask that
/// fades the fold out at both ends.
pub(crate) fn nasolabial_coords(l: &Layout, u: f64, v: f64) -> (f64, f64) {
    let au = u.abs();
    // Quadratic Bézier from beside the nostril wing, bowing outward, to below the
    // mouth corner.
    let p0 = (l.u_ala + 3.0, l.v_tip - 2.0);
    let p1 = (l.u_corner + 9.0, 0.5 * (l.v_tip + l.v_mouth) - 2.0);
    let p2 = (l.u_corner + 6.0, l.v_mouth - 12.0);
    let at = |t: f64| {
        let s = 1.0 - t;
        (
            s * s * p0.0 + 2.0 * s * t * p1.0 + t * t * p2.0,
            s * s * p0.1 + 2.0 * s * t * p1.1 + t * t * p2.1,
        )
    };
    let dist2 = |t: f64| {
        let (x, y) = at(t);
        (au - x).powi(2) + (v - y).powi(2)
    };
    // Coarse search, then a ternary refinement around the best sample.
    let n = 16;
    let mut t_best = 0.0;
    let mut d_best = f64::INFINITY;
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let d = dist2(t);
        if d < d_best {
            (t_best, d_best) = (t, d);
        }
    }
    let (mut lo, mut hi) = (
        (t_best - 1.0 / n as f64).max(0.0),
        (t_best + 1.0 / n as f64).min(1.0),
    );
    for _ in 0..30 {
        let m1 = lo + (hi - lo) / 3.0;
        let m2 = hi - (hi - lo) / 3.0;
        if dist2(m1) < dist2(m2) {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    let t = 0.5 * (lo + hi);
    let best = (dist2(t), t, au - at(t).0);
    let dist = best.0.sqrt() * best.2.signum();
    let along = smoothstep(0.0, 0.15, best.1) * (1.0 - smoothstep(0.8, 1.0, best.1));
    (dist, along)
}
