//! The expression model: soft-tissue displacement fields, eyelid states, wrinkles,
//! corrective pairs and the jaw pose, and how [`evaluate`](super::Actor::evaluate)
//! combines them.
//!
//! All fields are defined on the canonical parameters `(u, v)` with compactly supported
//! masks, so an expression moves exactly the vertices of its region and leaves the rest
//! bit-for-bit unchanged.

use std::f64::consts::TAU;

use nalgebra::Vector3;

use crate::dataset::JawPose;

use super::openings::LidState;
use super::surface::{Layout, disc2 as disc, nasolabial_coords, smoothstep};
use crate::numeric::SplitMix64;

/// Names of the expressions in their fixed order (ARKit / FACS style; `_L` is the
/// actor's left, +x).
pub(crate) const NAMES: [&str; 36] = [
    "jawOpen",
    "jawLeft",
    "jawRight",
    "jawForward",
    "mouthSmile_L",
    "mouthSmile_R",
    "mouthFrown_L",
    "mouthFrown_R",
    "mouthFunnel",
    "mouthPucker",
    "mouthPress_L",
    "mouthPress_R",
    "mouthStretch_L",
    "mouthStretch_R",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthLeft",
    "mouthRight",
    "browInnerUp",
    "browOuterUp_L",
    "browOuterUp_R",
    "browDown_L",
    "browDown_R",
    "eyeBlink_L",
    "eyeBlink_R",
    "eyeSquint_L",
    "eyeSquint_R",
    "eyeWide_L",
    "eyeWide_R",
    "noseSneer_L",
    "noseSneer_R",
    "cheekPuff",
    "cheekSquint_L",
    "cheekSquint_R",
];

/// Indices into [`NAMES`]. For a `_L` / `_R` pair, `_R` is `_L + 1`.
pub(crate) mod ix {
    pub const JAW_OPEN: usize = 0;
    pub const JAW_LEFT: usize = 1;
    pub const JAW_RIGHT: usize = 2;
    pub const JAW_FORWARD: usize = 3;
    pub const SMILE: usize = 4;
    pub const FROWN: usize = 6;
    pub const FUNNEL: usize = 8;
    pub const PUCKER: usize = 9;
    pub const PRESS: usize = 10;
    pub const STRETCH: usize = 12;
    pub const ROLL_LOWER: usize = 14;
    pub const ROLL_UPPER: usize = 15;
    pub const SHRUG_LOWER: usize = 16;
    pub const SHRUG_UPPER: usize = 17;
    pub const MOUTH_LEFT: usize = 18;
    pub const MOUTH_RIGHT: usize = 19;
    pub const BROW_INNER_UP: usize = 20;
    pub const BROW_OUTER_UP: usize = 21;
    pub const BROW_DOWN: usize = 23;
    pub const BLINK: usize = 25;
    pub const SQUINT: usize = 27;
    pub const WIDE: usize = 29;
    pub const SNEER: usize = 31;
    pub const CHEEK_PUFF: usize = 33;
    pub const CHEEK_SQUINT: usize = 34;
}

/// Jaw opening of `jawOpen` at weight 1, radians (about 17°).
pub(crate) const JAW_OPEN_RAD: f64 = 0.30;
/// Sideways jaw rotation of `jawLeft` / `jawRight` at weight 1, radians (about 4.3°).
pub(crate) const JAW_LATERAL_RAD: f64 = 0.075;
/// Jaw protrusion of `jawForward` at weight 1, mm.
pub(crate) const JAW_FORWARD_MM: f64 = 6.0;

/// Local frame and parameters of one skin vertex, for building fields.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Frame {
    /// Canonical `u`.
    pub u: f64,
    /// Canonical `v` (neutral openings).
    pub v: f64,
    /// Unit outward normal of the neutral.
    pub n: Vector3<f64>,
    /// Unit tangent toward +u (toward the actor's left on the face).
    pub tu: Vector3<f64>,
    /// Unit tangent pointing up the surface (`n × tu`).
    pub tv: Vector3<f64>,
    /// Share of the jaw side of the lip line (0 upper, 1 lower).
    pub lower: f64,
}

/// A sparse per-vertex vector field, mm.
#[derive(Debug, Clone, Default)]
pub(crate) struct SparseField {
    /// Vertex indices.
    pub idx: Vec<u32>,
    /// Vectors.
    pub vec: Vec<Vector3<f64>>,
}

impl SparseField {
    /// Samples `f` on every skin vertex, keeping the nonzero vectors.
    fn sample(frames: &[Frame], f: impl Fn(&Frame) -> Vector3<f64>) -> Self {
        let mut out = Self::default();
        for (k, fr) in frames.iter().enumerate() {
            let d = f(fr);
            if d.norm_squared() > 1e-18 {
                out.idx.push(k as u32);
                out.vec.push(d);
            }
        }
        out
    }

    /// Adds `scale ×` the field to `pos`.
    pub(crate) fn add_to(&self, pos: &mut [nalgebra::Point3<f64>], scale: f64) {
        for (&i, d) in self.idx.iter().zip(&self.vec) {
            pos[i as usize] += d * scale;
        }
    }
}

/// A wrinkle pattern: a height field along the neutral normal (mm at full depth) and
/// the expressions that drive it.
#[derive(Debug, Clone)]
pub(crate) struct Wrinkle {
    /// Name, for docs and debugging.
    pub name: &'static str,
    /// Displacement at full depth (height × neutral normal), mm.
    pub field: SparseField,
    /// Activation `a = Σ coefficient·weight`; the depth is `smoothstep(0, 1, a)`.
    pub drivers: Vec<(usize, f64)>,
}

/// A corrective term: a field scaled by the product of two weights.
#[derive(Debug, Clone)]
pub(crate) struct Corrective {
    /// First expression.
    pub a: usize,
    /// Second expression.
    pub b: usize,
    /// Field at `w_a = w_b = 1`, mm.
    pub field: SparseField,
}

/// The complete expression model of one identity.
#[derive(Debug, Clone)]
pub(crate) struct Model {
    /// Soft-tissue field of each expression (applied before jaw skinning), mm.
    pub soft: Vec<SparseField>,
    /// Corrective pairs.
    pub correctives: Vec<Corrective>,
    /// Wrinkle patterns.
    pub wrinkles: Vec<Wrinkle>,
}

/// Weight of expression `i`, sanitized: missing or non-finite weights are 0, others
/// clamped to [0, 1].
pub(crate) fn weight(w: &[f64], i: usize) -> f64 {
    match w.get(i) {
        Some(x) if x.is_finite() => x.clamp(0.0, 1.0),
        _ => 0.0,
    }
}

/// Eyelid states (left, right) of a weight vector. Blink closes the upper lid; squint
/// and cheek squint raise the lower lid and lower the upper lid a little; wide raises
/// the upper lid. Closure saturates at 1 and a closed upper lid meets the lower lid
/// wherever that is, so blink + squint is not the sum of the two.
pub(crate) fn lid_states(w: &[f64]) -> [LidState; 2] {
    let mut out = [LidState::default(); 2];
    for (s, lid) in out.iter_mut().enumerate() {
        let blink = weight(w, ix::BLINK + s);
        let squint = weight(w, ix::SQUINT + s);
        let cheek = weight(w, ix::CHEEK_SQUINT + s);
        let smile = weight(w, ix::SMILE + s);
        let wide = weight(w, ix::WIDE + s);
        lid.close = (blink + 0.22 * squint + 0.08 * cheek).min(1.0);
        lid.raise = (0.12 * blink + 0.45 * squint + 0.2 * cheek + 0.08 * smile - 0.15 * wide)
            .clamp(-0.2, 0.7);
        lid.wide = wide;
    }
    out
}

/// Jaw pose of a weight vector.
pub(crate) fn jaw_pose(w: &[f64]) -> JawPose {
    JawPose {
        open_rad: JAW_OPEN_RAD * weight(w, ix::JAW_OPEN),
        lateral_rad: JAW_LATERAL_RAD * (weight(w, ix::JAW_LEFT) - weight(w, ix::JAW_RIGHT)),
        forward_mm: JAW_FORWARD_MM * weight(w, ix::JAW_FORWARD),
    }
}

/// The two sides: (index offset, sign of u).
const SIDES: [(usize, f64); 2] = [(0, 1.0), (1, -1.0)];

/// Soft-tissue field of expression `e` (mm, before jaw skinning).
fn soft_field(e: usize, frames: &[Frame], l: &Layout) -> SparseField {
    let (um, vm, uc) = (0.0, l.v_mouth, l.u_corner);
    let (ue, ve) = (l.u_eye, l.v_eye);
    let vb = l.v_brow;
    // Side of a sided expression (+1 left, −1 right).
    let side = |base: usize| if e == base { 1.0 } else { -1.0 };
    SparseField::sample(frames, |f| {
        let (u, v) = (f.u, f.v);
        let out = |s: f64| s * f.tu;
        let upper = 1.0 - f.lower;
        // The chin curves sharply under the jaw, so the mentalis pull is a fixed
        // head-frame direction (up and forward) rather than along the local tangent.
        let chin_up = |up: f64, fwd: f64| Vector3::new(0.0, up, fwd);
        let corners_in = |ru: f64, rv: f64, amount: f64| {
            SIDES
                .iter()
                .map(|&(_, s)| disc(u - s * uc, v - vm, ru, rv) * (-amount) * out(s))
                .sum::<Vector3<f64>>()
        };
        match e {
            ix::JAW_OPEN => {
                let lips = disc(u - um, v - vm, uc + 6.0, 9.0);
                let cheeks: Vector3<f64> = SIDES
                    .iter()
                    .map(|&(_, s)| {
                        disc(u - s * (uc + 18.0), v - (vm + 5.0), 14.0, 18.0) * -1.5 * f.n
                    })
                    .sum();
                lips * -1.2 * f.n + corners_in(14.0, 14.0, 2.5)
                    - upper * disc(u, v - vm, uc + 5.0, 10.0) * f.tv
                    + cheeks
            }
            ix::JAW_LEFT | ix::JAW_RIGHT => {
                // The lips lag a little behind the jaw.
                let s = if e == ix::JAW_LEFT { 1.0 } else { -1.0 };
                f.lower * disc(u, v - vm, uc + 4.0, 8.0) * -1.2 * s * f.tu
            }
            ix::JAW_FORWARD => f.lower * disc(u, v - (vm - 4.0), uc + 4.0, 10.0) * 1.0 * f.n,
            e if e == ix::SMILE || e == ix::SMILE + 1 => {
                let s = side(ix::SMILE);
                disc(u - s * uc, v - vm, 22.0, 18.0) * (6.0 * out(s) + 7.0 * f.tv - 2.5 * f.n)
                    + upper * disc(u - s * (uc - 8.0), v - (vm + 6.0), 14.0, 10.0) * 2.0 * f.tv
                    + disc(u - s * (uc + 14.0), v - (vm + 28.0), 22.0, 20.0)
                        * (3.0 * f.tv + 2.5 * f.n)
                    + disc(u - s * ue, v - (ve - 9.0), 14.0, 6.0) * (1.0 * f.tv + 0.5 * f.n)
            }
            e if e == ix::FROWN || e == ix::FROWN + 1 => {
                let s = side(ix::FROWN);
                disc(u - s * uc, v - vm, 18.0, 16.0) * (-5.0 * f.tv + 1.0 * out(s) - 0.5 * f.n)
                    + f.lower * disc(u - s * (uc - 8.0), v - (vm - 6.0), 14.0, 10.0) * -2.0 * f.tv
                    + disc(u - s * (uc + 4.0), v - (vm - 20.0), 16.0, 14.0) * -1.5 * f.tv
            }
            ix::FUNNEL => {
                let lips = disc(u, v - vm, uc + 6.0, 12.0);
                let part = disc(u, v - vm, uc - 2.0, 10.0);
                lips * 5.0 * f.n
                    + corners_in(14.0, 12.0, 4.0)
                    + part * (upper - f.lower) * 2.2 * f.tv
            }
            ix::PUCKER => {
                let lips = disc(u, v - vm, uc + 8.0, 14.0);
                lips * 6.0 * f.n
                    + corners_in(18.0, 14.0, 8.0)
                    + lips * (f.lower - upper) * 0.5 * f.tv
            }
            e if e == ix::PRESS || e == ix::PRESS + 1 => {
                let s = side(ix::PRESS);
                let lips = disc(u - s * 0.5 * uc, v - vm, 0.9 * uc, 8.0);
                lips * (upper * (-1.5 * f.tv - 1.2 * f.n) + f.lower * (1.5 * f.tv - 1.2 * f.n))
                    + disc(u - s * 6.0, v - l.v_pog, 18.0, 14.0) * chin_up(2.0, 0.5)
            }
            e if e == ix::STRETCH || e == ix::STRETCH + 1 => {
                let s = side(ix::STRETCH);
                disc(u - s * uc, v - vm, 20.0, 16.0) * (6.0 * out(s) - 3.0 * f.tv - 1.0 * f.n)
                    + f.lower * disc(u - s * (uc - 6.0), v - (vm - 5.0), 16.0, 12.0) * -3.0 * f.tv
                    + disc(u - s * (uc + 12.0), v - (vm - 35.0), 20.0, 25.0)
                        * (-1.0 * f.tv + 1.0 * out(s))
            }
            ix::ROLL_LOWER => {
                f.lower * disc(u, v - (vm - 3.0), uc, 7.0) * (-4.0 * f.n + 2.0 * f.tv)
            }
            ix::ROLL_UPPER => upper * disc(u, v - (vm + 3.0), uc, 7.0) * (-4.0 * f.n - 2.0 * f.tv),
            ix::SHRUG_LOWER => {
                f.lower * disc(u, v - (vm - 4.0), uc + 4.0, 10.0) * (3.0 * f.tv + 2.0 * f.n)
                    + disc(u, v - l.v_pog, 22.0, 16.0) * chin_up(3.0, 1.0)
            }
            ix::SHRUG_UPPER => {
                upper * disc(u, v - (vm + 4.0), uc + 4.0, 10.0) * (3.0 * f.tv + 1.0 * f.n)
            }
            ix::MOUTH_LEFT | ix::MOUTH_RIGHT => {
                let s = if e == ix::MOUTH_LEFT { 1.0 } else { -1.0 };
                disc(u, v - vm, uc + 14.0, 18.0) * 6.0 * s * f.tu
            }
            ix::BROW_INNER_UP => {
                let inner: Vector3<f64> = SIDES
                    .iter()
                    .map(|&(_, s)| {
                        disc(u - s * 14.0, v - vb, 16.0, 14.0) * 8.0 * f.tv
                            + disc(u - s * (ue - 6.0), v - (ve + 9.0), 10.0, 6.0) * 1.5 * f.tv
                    })
                    .sum();
                inner + disc(u, v - (vb + 22.0), 40.0, 30.0) * 4.0 * f.tv
            }
            e if e == ix::BROW_OUTER_UP || e == ix::BROW_OUTER_UP + 1 => {
                let s = side(ix::BROW_OUTER_UP);
                disc(u - s * 40.0, v - vb, 18.0, 14.0) * 8.0 * f.tv
                    + disc(u - s * 35.0, v - (vb + 22.0), 28.0, 28.0) * 3.0 * f.tv
            }
            e if e == ix::BROW_DOWN || e == ix::BROW_DOWN + 1 => {
                let s = side(ix::BROW_DOWN);
                disc(u - s * 22.0, v - vb, 22.0, 14.0) * (-5.0 * f.tv - 3.0 * out(s) + 1.0 * f.n)
                    + disc(u - s * 6.0, v - (vb - 2.0), 14.0, 16.0) * (1.2 * f.n - 1.5 * out(s))
                    + disc(u - s * ue, v - (ve + 10.0), 14.0, 6.0) * -1.5 * f.tv
            }
            e if e == ix::BLINK || e == ix::BLINK + 1 => {
                // The lid itself moves by the eyelid warp; the lower lid bulges a little.
                let s = side(ix::BLINK);
                disc(u - s * ue, v - (ve - 6.0), 12.0, 4.0) * 0.3 * f.n
            }
            e if e == ix::SQUINT || e == ix::SQUINT + 1 => {
                let s = side(ix::SQUINT);
                disc(u - s * ue, v - (ve - 10.0), 16.0, 7.0) * (1.5 * f.tv + 1.2 * f.n)
            }
            e if e == ix::WIDE || e == ix::WIDE + 1 => {
                let s = side(ix::WIDE);
                disc(u - s * ue, v - (vb - 2.0), 18.0, 8.0) * 1.5 * f.tv
            }
            e if e == ix::SNEER || e == ix::SNEER + 1 => {
                let s = side(ix::SNEER);
                disc(u - s * 0.7 * l.u_ala, v - (l.v_tip - 3.0), 10.0, 10.0)
                    * (4.0 * f.tv + 1.5 * out(s))
                    + disc(u - s * 8.0, v - (l.v_tip + 12.0), 8.0, 14.0) * 3.0 * f.tv
                    + upper * disc(u - s * 14.0, v - (vm + 9.0), 10.0, 8.0) * 1.5 * f.tv
                    + disc(u - s * 10.0, v - vb, 12.0, 10.0) * -1.5 * f.tv
            }
            ix::CHEEK_PUFF => {
                let cheeks: Vector3<f64> = SIDES
                    .iter()
                    .map(|&(_, s)| {
                        disc(u - s * (uc + 16.0), v - (vm + 6.0), 22.0, 24.0) * 7.0 * f.n
                    })
                    .sum();
                cheeks + disc(u, v - vm, uc, 10.0) * 1.5 * f.n + corners_in(10.0, 8.0, 1.0)
            }
            e if e == ix::CHEEK_SQUINT || e == ix::CHEEK_SQUINT + 1 => {
                let s = side(ix::CHEEK_SQUINT);
                disc(u - s * (ue + 8.0), v - (ve - 22.0), 22.0, 16.0) * (3.5 * f.tv + 2.0 * f.n)
                    + disc(u - s * ue, v - (ve - 8.0), 14.0, 6.0) * 1.2 * f.tv
            }
            _ => Vector3::zeros(),
        }
    })
}

/// Corrective fields for common pairs (scaled by `w_a·w_b`).
fn correctives(frames: &[Frame], l: &Layout) -> Vec<Corrective> {
    let (vm, uc, vb) = (l.v_mouth, l.u_corner, l.v_brow);
    let mut out = Vec::new();
    for (k, s) in SIDES {
        // Smile with an open jaw: corners stay up and wide.
        out.push(Corrective {
            a: ix::SMILE + k,
            b: ix::JAW_OPEN,
            field: SparseField::sample(frames, |f| {
                disc(f.u - s * uc, f.v - vm, 18.0, 14.0) * (3.0 * f.tv + 2.0 * s * f.tu - 1.5 * f.n)
            }),
        });
        // Inner brow raised while pulled down: the oblique "grief" brow, pinched inward.
        out.push(Corrective {
            a: ix::BROW_DOWN + k,
            b: ix::BROW_INNER_UP,
            field: SparseField::sample(frames, |f| {
                disc(f.u - s * 12.0, f.v - vb, 12.0, 12.0) * (2.0 * f.tv - 2.5 * s * f.tu)
            }),
        });
        // Blink and squint: the lower lid bunches.
        out.push(Corrective {
            a: ix::BLINK + k,
            b: ix::SQUINT + k,
            field: SparseField::sample(frames, |f| {
                disc(f.u - s * l.u_eye, f.v - (l.v_eye - 8.0), 14.0, 6.0) * (1.0 * f.tv + 1.0 * f.n)
            }),
        });
    }
    // Funnel with an open jaw: less protrusion, a taller O.
    out.push(Corrective {
        a: ix::FUNNEL,
        b: ix::JAW_OPEN,
        field: SparseField::sample(frames, |f| {
            let lips = disc(f.u, f.v - vm, uc + 4.0, 12.0);
            lips * (-2.5 * f.n + (1.0 - f.lower) * 1.5 * f.tv - f.lower * 1.5 * f.tv)
        }),
    });
    // Symmetric smile lifts the middle of the upper lip.
    out.push(Corrective {
        a: ix::SMILE,
        b: ix::SMILE + 1,
        field: SparseField::sample(frames, |f| {
            disc(f.u, f.v - (vm + 4.0), 16.0, 8.0) * 1.2 * f.tv
        }),
    });
    out
}

/// Identity-specific wrinkle layout drawn from the seed.
struct WrinkleLayout {
    wavelength: f64,
    phase: f64,
    arch: f64,
    amp_phase: [f64; 2],
    glabella: f64,
    crow_step: f64,
    crow_phase: [f64; 2],
    bunny_phase: [f64; 2],
    chin_phase: [f64; 2],
}

impl WrinkleLayout {
    fn new(seed: u64) -> Self {
        let mut r = SplitMix64::new(seed ^ 0x7772_696e_6b6c_6573);
        Self {
            wavelength: r.uniform(6.8, 9.2),
            phase: r.next_f64(),
            arch: r.uniform(1.5, 5.0),
            amp_phase: [r.uniform(0.0, TAU), r.uniform(0.0, TAU)],
            glabella: r.uniform(-0.8, 1.2),
            crow_step: r.uniform(0.27, 0.34),
            crow_phase: [r.next_f64(), r.next_f64()],
            bunny_phase: [r.next_f64(), r.next_f64()],
            chin_phase: [r.uniform(0.0, TAU), r.uniform(0.0, TAU)],
        }
    }
}

/// Periodic furrow profile with zero mean: −0.625 in the furrow (ξ integer), +0.375 on
/// the ridges.
fn furrow(xi: f64) -> f64 {
    let c = 0.5 * (1.0 + (TAU * xi).cos());
    -(c * c - 0.375)
}

/// The wrinkle patterns of an identity.
fn wrinkles(frames: &[Frame], l: &Layout, seed: u64, scale: f64) -> Vec<Wrinkle> {
    let w = WrinkleLayout::new(seed);
    let along_n = |depth: f64, h: &dyn Fn(f64, f64) -> f64| {
        SparseField::sample(frames, |f| depth * scale * h(f.u, f.v) * f.n)
    };
    let forehead = |u: f64, v: f64| {
        let mv = smoothstep(l.v_brow + 6.0, l.v_brow + 12.0, v)
            * (1.0 - smoothstep(l.v_hair - 10.0, l.v_hair - 2.0, v));
        let mu = 1.0 - smoothstep(42.0, 58.0, u.abs());
        if mv * mu == 0.0 {
            return 0.0;
        }
        let xi = (v - l.v_brow - w.arch * (u / 45.0).powi(2)) / w.wavelength + w.phase;
        let amp = 0.7
            + 0.3
                * (TAU * u / 43.0 + w.amp_phase[0]).sin()
                * (TAU * v / 29.0 + w.amp_phase[1]).sin();
        furrow(xi) * amp * mu * mv
    };
    let centre_share = |u: f64| 1.0 - smoothstep(12.0, 32.0, u.abs());
    let mut out = vec![Wrinkle {
        name: "forehead_centre",
        field: along_n(1.2, &|u, v| forehead(u, v) * centre_share(u)),
        drivers: vec![
            (ix::BROW_INNER_UP, 1.0),
            (ix::BROW_OUTER_UP, 0.3),
            (ix::BROW_OUTER_UP + 1, 0.3),
        ],
    }];
    for (k, s) in SIDES {
        let on_side = move |u: f64| if u * s > 0.0 { 1.0 } else { 0.0 };
        out.push(Wrinkle {
            name: if k == 0 { "forehead_L" } else { "forehead_R" },
            field: along_n(1.2, &|u, v| {
                forehead(u, v) * (1.0 - centre_share(u)) * on_side(u)
            }),
            drivers: vec![(ix::BROW_OUTER_UP + k, 1.0), (ix::BROW_INNER_UP, 0.45)],
        });
        out.push(Wrinkle {
            name: if k == 0 { "glabella_L" } else { "glabella_R" },
            field: along_n(1.0, &|u, v| {
                let vertical = 1.0 - smoothstep(0.5, 1.0, (v - (l.v_brow - 1.0)).abs() / 13.0);
                let g = s * (5.5 + w.glabella);
                let lines = (-((u - g) / 2.0).powi(2)).exp()
                    + 0.5 * (-((u - g - 5.0 * s) / 2.0).powi(2)).exp();
                -lines * vertical
            }),
            drivers: vec![(ix::BROW_DOWN + k, 1.0), (ix::SNEER + k, 0.3)],
        });
        out.push(Wrinkle {
            name: if k == 0 {
                "crows_feet_L"
            } else {
                "crows_feet_R"
            },
            field: along_n(0.6, &|u, v| {
                let du = s * (u - s * (l.u_eye + l.a_eye + 2.0));
                let dv = v - (l.v_eye + 0.5);
                let rho = du.hypot(dv);
                let mask = smoothstep(3.0, 8.0, rho)
                    * (1.0 - smoothstep(16.0, 24.0, rho))
                    * (1.0 - smoothstep(0.9, 1.3, (dv.atan2(du) + 0.1).abs()));
                if mask == 0.0 {
                    return 0.0;
                }
                furrow(dv.atan2(du) / w.crow_step + w.crow_phase[k]) * mask
            }),
            drivers: vec![
                (ix::SQUINT + k, 1.0),
                (ix::SMILE + k, 0.6),
                (ix::CHEEK_SQUINT + k, 0.8),
            ],
        });
        out.push(Wrinkle {
            name: if k == 0 {
                "nasolabial_L"
            } else {
                "nasolabial_R"
            },
            field: along_n(1.3, &|u, v| {
                if u * s <= 0.0 {
                    return 0.0;
                }
                let (d, along) = nasolabial_coords(l, u, v);
                let profile =
                    -(-(d / 2.4).powi(2)).exp() + 0.55 * (-((d - 4.5) / 2.8).powi(2)).exp();
                profile * along * (1.0 - smoothstep(10.0, 14.0, d.abs()))
            }),
            drivers: vec![
                (ix::SMILE + k, 1.0),
                (ix::SNEER + k, 0.7),
                (ix::CHEEK_SQUINT + k, 0.3),
            ],
        });
        out.push(Wrinkle {
            name: if k == 0 { "bunny_L" } else { "bunny_R" },
            field: along_n(0.5, &|u, v| {
                let du = s * (u - s * 7.5);
                let dv = v - (l.v_nasion - 13.0);
                let mask = disc(du, dv, 9.0, 8.0);
                if mask == 0.0 {
                    return 0.0;
                }
                furrow((0.64 * du + 0.77 * dv) / 4.2 + w.bunny_phase[k]) * mask
            }),
            drivers: vec![(ix::SNEER + k, 1.0), (ix::BROW_DOWN + k, 0.25)],
        });
    }
    out.push(Wrinkle {
        name: "chin_dimpling",
        field: along_n(0.8, &|u, v| {
            let y = v - l.v_pog;
            let mask = disc(u, y, 17.0, 10.0);
            if mask == 0.0 {
                return 0.0;
            }
            let cells = ((TAU * u / 5.5 + w.chin_phase[0]).sin()
                * (TAU * y / 5.0 + w.chin_phase[1]).sin())
            .max(0.0);
            -(cells.powf(1.5) - 0.13) * mask
        }),
        drivers: vec![
            (ix::PRESS, 0.6),
            (ix::PRESS + 1, 0.6),
            (ix::SHRUG_LOWER, 1.0),
        ],
    });
    out
}

impl Model {
    /// Builds the model of one identity on its skin frames.
    pub(crate) fn new(frames: &[Frame], canon: &Layout, seed: u64, wrinkle_scale: f64) -> Self {
        Self {
            soft: (0..NAMES.len())
                .map(|e| soft_field(e, frames, canon))
                .collect(),
            correctives: correctives(frames, canon),
            wrinkles: wrinkles(frames, canon, seed, wrinkle_scale),
        }
    }
}

/// Wrinkle depth ramp: `smoothstep(0, 1, a)`, saturating at 1.
pub(crate) fn wrinkle_ramp(activation: f64) -> f64 {
    smoothstep(0.0, 1.0, activation)
}
