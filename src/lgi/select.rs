//! Choosing one marker's local geometry for a frame (Cong et al. 2019 §4 and §5.1).
//!
//! 1. **Inside**: every tetrahedron containing the bundle gives a candidate with the
//!    bundle's convex barycentric weights, Eq. (1).
//! 2. **Outside every tetrahedron**: the candidates are the closest points of the tetrahedra
//!    within `projection_slack_mm` of the closest one ("one could consider not only the
//!    distance from the bundle under consideration to the resulting surface, but also the
//!    distances that neighboring bundles would be from the resulting surface").
//! 3. **Scoring**: a candidate's cost is the root-mean-square distance from the present
//!    neighbouring bundles to the candidate's surface at their markers (plus, outside, the
//!    bundle's own projection distance), plus `temporal_weight_mm` times the fraction of its
//!    corners not shared with the previous frame's choice ("higher priority to tetrahedra
//!    which share more points ... with the tetrahedron used on the previous frame").
//!    Exact ties go to the least-deforming shapes (a `1e-6` weight on the candidate's
//!    deformation, far below any neighbour distance that matters).

use nalgebra::{Point3, Vector3};

use super::barycentric::{closest_on_simplex, combine, tet_barycentric};
use super::index::MarkerIndex;

/// Weight of the deformation tie-break, per millimetre of patch deformation.
const TIE_BREAK: f64 = 1e-6;
/// Slack of the `f32` containment pre-test, in barycentric units.
const PRETEST_SLACK: f32 = 1e-4;
/// Smallest barycentric weight still counted as inside in `f64`.
const INSIDE_SLACK: f64 = -1e-9;

/// The local geometry chosen for a marker in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Choice {
    /// Point indices of the simplex corners (corners past the simplex's dimension repeat
    /// corner 0 with weight 0).
    pub corners: [u16; 4],
    /// Convex weights of the corners.
    pub weights: [f64; 4],
    /// Whether the bundle lies in the chosen tetrahedron (else it was projected).
    pub inside: bool,
    /// The bundle minus the candidate's marker position (zero inside), mm.
    pub residual: Vector3<f64>,
    /// The candidate's cost (see the module docs), mm.
    pub cost_mm: f64,
}

/// Per-frame scratch memory for [`choose`], reused across markers and frames.
#[derive(Debug, Default)]
pub struct Scratch {
    stamp: Vec<u32>,
    epoch: u32,
    found: Vec<(u32, [f64; 4], f64)>,
}

/// Selection settings (from [`super::LgiParams`]).
#[derive(Debug, Clone, Copy)]
pub struct SelectParams {
    /// Outside: candidates within this distance of the closest projection, mm.
    pub projection_slack_mm: f64,
    /// Temporal preference per unshared corner fraction, mm.
    pub temporal_weight_mm: f64,
}

/// Chooses the local geometry of marker `mi` for the (unskinned) bundle `x`.
///
/// `neighbors[k]` is the bundle of `mi.neighbors[k]` in this frame (`None` when missing);
/// `previous` the corners chosen for this marker in the previous frame.
pub fn choose(
    mi: &MarkerIndex,
    x: &Point3<f64>,
    neighbors: &[Option<Point3<f64>>],
    previous: Option<&[u16; 4]>,
    params: &SelectParams,
    scratch: &mut Scratch,
) -> Choice {
    let dim = mi.simplices.dim as usize;
    let nk = mi.neighbors.len();
    let score = |corners: &[u16; 4], w: &[f64; 4], self_d2: f64| -> f64 {
        let mut sum = 0.0;
        let mut count = 0usize;
        for (k, y) in neighbors.iter().enumerate() {
            let Some(y) = y else { continue };
            let mut pred = Vector3::zeros();
            for c in 0..=dim {
                pred += mi.neighbor_positions[corners[c] as usize * nk + k].coords * w[c];
            }
            sum += (pred - y.coords).norm_squared();
            count += 1;
        }
        let nbr = if count > 0 { sum / count as f64 } else { 0.0 };
        let mut cost = (nbr + self_d2).sqrt();
        if let Some(prev) = previous {
            let shared = corners[..=dim]
                .iter()
                .filter(|c| prev[..=dim].contains(c))
                .count();
            cost += params.temporal_weight_mm * (dim + 1 - shared) as f64 / (dim + 1) as f64;
        }
        let deform: f64 = (0..=dim)
            .map(|c| w[c] * mi.deformation_mm[corners[c] as usize])
            .sum();
        cost + TIE_BREAK * deform
    };

    let mut best: Option<Choice> = None;
    let consider =
        |best: &mut Option<Choice>, corners: [u16; 4], w: [f64; 4], inside: bool, self_d2: f64| {
            let cost = score(&corners, &w, self_d2);
            if best.as_ref().is_none_or(|b| cost < b.cost_mm) {
                *best = Some(Choice {
                    corners,
                    weights: w,
                    inside,
                    residual: Vector3::zeros(),
                    cost_mm: cost,
                });
            }
        };

    if let Some(grid) = &mi.grid {
        // 1. Tetrahedra containing the bundle.
        for &t in grid.candidates(x) {
            let t = t as usize;
            let c = mi.simplices.corners[t];
            let p0 = mi.points[c[0] as usize];
            let d = x - p0;
            let d = [d.x as f32, d.y as f32, d.z as f32];
            let inv = &mi.inverses[t];
            let mut wsum = 0f32;
            let mut ok = true;
            for row in inv {
                let wi = row[0] * d[0] + row[1] * d[1] + row[2] * d[2];
                ok &= wi >= -PRETEST_SLACK;
                wsum += wi;
            }
            if !ok || 1.0 - wsum < -PRETEST_SLACK {
                continue;
            }
            let Some(mut w) = tet_barycentric(&mi.corners(t), x) else {
                continue;
            };
            if w.iter().any(|&v| v < INSIDE_SLACK) {
                continue;
            }
            clamp_convex(&mut w);
            consider(&mut best, c, w, true, 0.0);
        }
        if best.is_none() {
            // 2. Projection onto the tetrahedral volume, via the grid's shells.
            let n = mi.simplices.corners.len();
            if scratch.stamp.len() < n {
                scratch.stamp.resize(n, 0);
            }
            scratch.epoch = scratch.epoch.wrapping_add(1);
            if scratch.epoch == 0 {
                scratch.stamp.iter_mut().for_each(|s| *s = 0);
                scratch.epoch = 1;
            }
            let epoch = scratch.epoch;
            scratch.found.clear();
            let mut dmin = f64::INFINITY;
            let slack = params.projection_slack_mm;
            let stamp = &mut scratch.stamp;
            let found = &mut scratch.found;
            grid.visit_shells(x, |_, list| {
                for &t in list {
                    if stamp[t as usize] == epoch {
                        continue;
                    }
                    stamp[t as usize] = epoch;
                    let p = mi.corners(t as usize);
                    let w = closest_on_simplex(&p, x);
                    let d = (combine(&p, &w) - x).norm();
                    if d <= dmin + slack {
                        found.push((t, w, d));
                        dmin = dmin.min(d);
                    }
                }
                let b = dmin + slack;
                b * b
            });
            for &(t, w, d) in scratch.found.iter() {
                if d <= dmin + slack {
                    consider(&mut best, mi.simplices.corners[t as usize], w, false, d * d);
                }
            }
        }
    } else {
        // Lower-dimensional marker: always a projection, over every simplex.
        let mut cands: Vec<([u16; 4], [f64; 4], f64)> = Vec::new();
        let mut dmin = f64::INFINITY;
        for c in &mi.simplices.corners {
            let p: Vec<Point3<f64>> = c[..=dim].iter().map(|&k| mi.points[k as usize]).collect();
            let w = closest_on_simplex(&p, x);
            let d = (combine(&p, &w) - x).norm();
            dmin = dmin.min(d);
            cands.push((*c, w, d));
        }
        for (c, w, d) in cands {
            if d <= dmin + params.projection_slack_mm {
                consider(&mut best, c, w, false, d * d);
            }
        }
    }
    let mut choice = best.unwrap_or(Choice {
        corners: [0; 4],
        weights: [1.0, 0.0, 0.0, 0.0],
        inside: false,
        residual: Vector3::zeros(),
        cost_mm: f64::INFINITY,
    });
    let mut at = Vector3::zeros();
    for c in 0..=dim.min(3) {
        at += mi.points[choice.corners[c] as usize].coords * choice.weights[c];
    }
    choice.residual = x.coords - at;
    choice
}

/// Clamps tiny negative weights to zero and renormalizes to sum 1.
fn clamp_convex(w: &mut [f64; 4]) {
    for v in w.iter_mut() {
        *v = v.max(0.0);
    }
    let s: f64 = w.iter().sum();
    if s > 0.0 {
        for v in w.iter_mut() {
            *v /= s;
        }
    }
}
