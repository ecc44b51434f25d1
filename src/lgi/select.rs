//! Choosing one marker's local geometry for a frame (Cong et al. 2019 §4 and §5.1).
//!
//! 1. **Inside**: every tetrahedron containing the bundle gives a candidate with the
//!    bundle's convex barycentric weights, Eq. (1).
//! 2. **Outside every tetrahedron**: the bundle is projected onto the convex hull of the
//!    point cloud (the union of all four-point tetrahedra), and the candidates are the
//!    tetrahedra at the projected point ("one could consider not only the distance from
//!    the bundle under consideration to the resulting surface, but also the distances that
//!    neighboring bundles would be from the resulting surface"). When pruning left the
//!    hull point in no tetrahedron, the closest point over the kept tetrahedra is searched
//!    through the grid.
//! 3. **Scoring**: a candidate's cost is the root-mean-square distance from the present
//!    neighbouring bundles to the candidate's surface at their markers (plus, outside, the
//!    bundle's own projection distance), plus `temporal_weight_mm` times the fraction of its
//!    corners not shared with the previous frame's choice ("higher priority to tetrahedra
//!    which share more points ... with the tetrahedron used on the previous frame").
//!    Exact ties go to the least-deforming shapes (a `1e-6` weight on the candidate's
//!    deformation, far below any neighbour distance that matters).

use nalgebra::{Point3, Vector3};

use super::barycentric::{
    TripleTable, closest_on_simplex, combine, corners_from_faces, tet_barycentric,
};
use super::index::MarkerIndex;

/// Weight of the deformation tie-break, per millimetre of patch deformation.
const TIE_BREAK: f64 = 1e-6;
/// Smallest barycentric weight still counted as inside in `f64`.
const INSIDE_SLACK: f64 = -1e-9;
/// Containment slack for a point on the hull (it lies on a face: one weight is ~0).
const HULL_SLACK: f64 = -1e-7;
/// Projections this close to the closest one tie, and the neighbour criterion decides, mm.
const PROJECTION_TIE_MM: f64 = 1e-6;

/// The local geometry chosen for a marker in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Choice {
    /// Point indices of the simplex corners (corners past the simplex's dimension repeat
    /// corner 0 with weight 0).
    pub corners: [u16; 4],
    /// Variant chosen at each corner (index into the marker's variants).
    pub variants: [u32; 4],
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
    /// Neighbour errors of each point's representative: `points × present neighbours`.
    err: Vec<Vector3<f64>>,
    /// Gram matrix of `err` over the present neighbours, `points × points`.
    gram: Vec<f64>,
    /// Variant representing each point in this frame.
    rep: Vec<u32>,
    /// Deformation of each point's representative.
    deform: Vec<f64>,
    /// Whether each point is a corner of the previous frame's choice.
    in_previous: Vec<bool>,
    /// Orientations of the query against every triple of points.
    table: TripleTable,
}

/// Selection settings (from [`super::LgiParams`]).
#[derive(Debug, Clone, Copy)]
pub struct SelectParams {
    /// Temporal preference per unshared corner fraction, mm.
    pub temporal_weight_mm: f64,
    /// Tetrahedra within this distance of the bundle compete too, mm (noisy bundles).
    pub bundle_tolerance_mm: f64,
}

/// Chooses the local geometry of marker `mi` for the (unskinned) bundle `x`.
///
/// `neighbors[k]` is the bundle of `mi.neighbors[k]` in this frame (`None` when missing);
/// `previous` the corners chosen for this marker in the previous frame.
///
/// The neighbour cost of convex weights `w` over points is the quadratic form
/// `wᵀ G w`, `G_ab = mean_k (q_ak − y_k)·(q_bk − y_k)` with `q_ak` neighbour `k`'s position
/// in point `a`'s shape and `y_k` its bundle, so `G` is formed once per marker and frame and
/// each candidate costs a handful of operations.
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
    let np = mi.points.len();
    // Neighbour errors of each point's representative variant, then their Gram matrix.
    let present: Vec<usize> = (0..nk).filter(|&k| neighbors[k].is_some()).collect();
    let npk = present.len();
    // Each point is represented by its variant that best predicts the neighbours alone.
    scratch.rep.clear();
    for j in 0..np {
        let (lo, hi) = (mi.point_variants[j], mi.point_variants[j + 1]);
        let mut best = (f64::INFINITY, lo);
        if hi - lo > 1 && npk > 0 {
            for u in lo..hi {
                let e: f64 = present
                    .iter()
                    .filter_map(|&k| {
                        neighbors[k].map(|y| {
                            (mi.neighbor_positions[u as usize * nk + k] - y).norm_squared()
                        })
                    })
                    .sum::<f64>()
                    .sqrt()
                    + TIE_BREAK * mi.deformation_mm[u as usize];
                if e < best.0 {
                    best = (e, u);
                }
            }
        }
        scratch.rep.push(best.1);
    }
    scratch.err.clear();
    for j in 0..np {
        let rep = scratch.rep[j] as usize;
        for &k in &present {
            if let Some(y) = neighbors[k] {
                scratch.err.push(mi.neighbor_positions[rep * nk + k] - y);
            }
        }
    }
    // Every entry is written below when a neighbour is present (no clearing: with large
    // clouds that would be most of the work).
    scratch.gram.resize(np * np, 0.0);
    if npk == 0 {
        scratch.gram.iter_mut().for_each(|g| *g = 0.0);
    } else {
        let inv = 1.0 / npk as f64;
        for a in 0..np {
            let ea = &scratch.err[a * npk..(a + 1) * npk];
            for b in a..np {
                let eb = &scratch.err[b * npk..(b + 1) * npk];
                let g = ea.iter().zip(eb).map(|(u, v)| u.dot(v)).sum::<f64>() * inv;
                scratch.gram[a * np + b] = g;
                scratch.gram[b * np + a] = g;
            }
        }
    }
    // Per point: its representative's deformation (the tie-break) and whether the previous
    // frame's choice used it (the temporal preference).
    scratch.deform.clear();
    scratch
        .deform
        .extend(scratch.rep.iter().map(|&r| mi.deformation_mm[r as usize]));
    scratch.in_previous.clear();
    scratch.in_previous.resize(np, false);
    if let Some(prev) = previous {
        for &c in &prev[..=dim] {
            if let Some(f) = scratch.in_previous.get_mut(c as usize) {
                *f = true;
            }
        }
    }
    let gram = &scratch.gram;
    let deform_of = &scratch.deform;
    let in_previous = &scratch.in_previous;
    // A candidate's cost is `sqrt(q + self_d2) + extra`, `q = wᵀ G w` over its corners
    // and `extra` the temporal preference and the tie-break, both non-negative.
    let quadratic = |c: &[usize; 4], w: &[f64; 4]| -> f64 {
        if dim == 3 {
            // The common case, by symmetry: the diagonal and each pair once.
            let g = |a: usize, b: usize| gram[c[a] * np + c[b]];
            let diag = w[0] * w[0] * g(0, 0)
                + w[1] * w[1] * g(1, 1)
                + w[2] * w[2] * g(2, 2)
                + w[3] * w[3] * g(3, 3);
            let off = w[0] * (w[1] * g(0, 1) + w[2] * g(0, 2) + w[3] * g(0, 3))
                + w[1] * (w[2] * g(1, 2) + w[3] * g(1, 3))
                + w[2] * w[3] * g(2, 3);
            diag + 2.0 * off
        } else {
            let mut q = 0.0;
            for a in 0..=dim {
                for b in 0..=dim {
                    q += w[a] * w[b] * gram[c[a] * np + c[b]];
                }
            }
            q
        }
    };
    let temporal_per_corner = if previous.is_some() {
        params.temporal_weight_mm / (dim + 1) as f64
    } else {
        0.0
    };
    let extra = |c: &[usize; 4], w: &[f64; 4]| -> f64 {
        let mut deform = 0.0;
        let mut shared = 0usize;
        for a in 0..=dim {
            deform += w[a] * deform_of[c[a]];
            shared += usize::from(in_previous[c[a]]);
        }
        temporal_per_corner * (dim + 1 - shared) as f64 + TIE_BREAK * deform
    };

    let mut best: Option<([u16; 4], [f64; 4], bool, f64)> = None;
    let consider = |best: &mut Option<([u16; 4], [f64; 4], bool, f64)>,
                    corners: [u16; 4],
                    w: [f64; 4],
                    inside: bool,
                    self_d2: f64| {
        let c = corners.map(usize::from);
        let base = quadratic(&c, &w).max(0.0) + self_d2;
        let extra = extra(&c, &w);
        if let Some(b) = best.as_ref() {
            // Without the square root when the candidate clearly loses: most do.
            let room = b.3 - extra;
            if room <= 0.0 || base > room * room * (1.0 + 1e-12) {
                return;
            }
        }
        let cost = base.sqrt() + extra;
        if best.as_ref().is_none_or(|b| cost < b.3) {
            *best = Some((corners, w, inside, cost));
        }
    };

    if let Some(grid) = &mi.grid {
        // 1. Tetrahedra containing the bundle (or near it, with a tolerance). Candidate
        //    list: the grid cell's when it is short, else every tetrahedron (the
        //    all-combination tetrahedra overlap so much that a cell often lists most of
        //    them). The winner's weights are recomputed exactly below.
        // Fills the table at `y`: sign codes for containment, or with a tolerance for
        // nearness (`TripleTable::fill_used_coded_near`).
        let fill = |table: &mut TripleTable, y: &Point3<f64>, tol: f64| {
            if tol > 0.0 {
                table.fill_used_coded_near(
                    &mi.points,
                    y,
                    &mi.used_triples,
                    &mi.triple_inv_area2,
                    tol,
                );
            } else {
                table.fill_used_coded(&mi.points, y, &mi.used_triples, mi.scan.tolerance);
            }
        };
        // Considers the tetrahedra containing (or near) `y`, with the table filled there.
        let scan = |best: &mut Option<([u16; 4], [f64; 4], bool, f64)>,
                    table: &TripleTable,
                    y: &Point3<f64>,
                    inside: bool,
                    self_d2: f64,
                    tol: f64| {
            for_each_containing(mi, grid, table, y, inside, tol, |t, faces, mut w, d| {
                let self_d2 = self_d2 + d * d;
                // A near candidate farther than the best one's whole cost loses.
                if best
                    .as_ref()
                    .is_some_and(|b| self_d2 > b.3 * b.3 * (1.0 + 1e-9))
                {
                    return;
                }
                if tol > 0.0 {
                    // Near, not inside: the closest point's weights, roughly.
                    clamp_convex(&mut w);
                }
                // The corners from the faces (a small shared table) rather than from the
                // marker's corner list, which would be one more stream of memory.
                let corners =
                    corners_from_faces(&faces).unwrap_or_else(|| mi.simplices.corners[t as usize]);
                consider(best, corners, w, inside, self_d2);
            });
        };
        let mut table = std::mem::take(&mut scratch.table);
        let tol = params.bundle_tolerance_mm;
        fill(&mut table, x, tol);
        scan(&mut best, &table, x, true, 0.0, tol);
        if best.is_none() {
            // 2. Outside: project onto the cloud's convex hull (the union of all
            //    four-point tetrahedra) and choose among the tetrahedra at that point.
            if let Some((q, h)) = super::hull::closest_on_hull(&mi.points, &mi.hull, x) {
                let d2 = (q - x).norm_squared();
                // First the tetrahedra on that hull triangle, then (pruned there) any.
                fill(&mut table, &q, 0.0);
                for &t in &mi.hull_tets[h] {
                    let t = t as usize;
                    if let Some(mut w) = table.inside(&mi.faces[t], mi.inv_volume[t], HULL_SLACK) {
                        clamp_convex(&mut w);
                        consider(&mut best, mi.simplices.corners[t], w, false, d2);
                    }
                }
                if best.is_none() {
                    scan(&mut best, &table, &q, false, d2, 0.0);
                }
            }
        }
        scratch.table = table;
        // The winner's exact weights: its barycentric coordinates of the bundle when it
        // contains it, else the closest point of the tetrahedron (a pre-test false
        // positive, or a projection).
        if let Some(b) = &mut best {
            let p = mi.corners_of(&b.0);
            match tet_barycentric(&p, x) {
                Some(mut w) if w.iter().all(|&v| v >= INSIDE_SLACK) => {
                    clamp_convex(&mut w);
                    b.1 = w;
                    b.2 = true;
                }
                _ => {
                    b.1 = closest_on_simplex(&p, x);
                    b.2 = false;
                }
            }
        }
        if best.is_none() {
            // 3. The hull point lies in no kept tetrahedron (thin ones were pruned at the
            //    hull): the closest point over the tetrahedra, via the grid's shells.
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
            let stamp = &mut scratch.stamp;
            let found = &mut scratch.found;
            // A lower bound of each tetrahedron's distance from the table (the farthest
            // face plane the bundle is outside of) skips the exact closest point for
            // those that cannot be the closest: the same result, far fewer of them.
            let table = &mut scratch.table;
            table.fill_used(&mi.points, x, &mi.used_triples);
            grid.visit_shells(x, |_, list| {
                for &t in list {
                    if stamp[t as usize] == epoch {
                        continue;
                    }
                    stamp[t as usize] = epoch;
                    let faces = mi.scan.faces(t as usize);
                    let w = table.weights(&faces);
                    if w.iter().all(|v| v.is_finite())
                        && table.outside_distance(&faces, &w, &mi.triple_inv_area2)
                            > dmin + PROJECTION_TIE_MM
                    {
                        continue;
                    }
                    let p = mi.corners(t as usize);
                    let w = closest_on_simplex(&p, x);
                    let d = (combine(&p, &w) - x).norm();
                    if d <= dmin + PROJECTION_TIE_MM {
                        found.push((t, w, d));
                        dmin = dmin.min(d);
                    }
                }
                let b = dmin + PROJECTION_TIE_MM;
                b * b
            });
            for &(t, w, d) in scratch.found.iter() {
                if d <= dmin + PROJECTION_TIE_MM {
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
            if d <= dmin + PROJECTION_TIE_MM {
                consider(&mut best, c, w, false, d * d);
            }
        }
    }
    let (corners, weights, inside, cost_mm) =
        best.unwrap_or(([0; 4], [1.0, 0.0, 0.0, 0.0], false, f64::INFINITY));
    let variants = refine_variants(mi, &corners, &weights, dim, neighbors, &scratch.rep);
    let mut at = Vector3::zeros();
    for c in 0..=dim {
        at += mi.variant_position[variants[c] as usize].coords * weights[c];
    }
    Choice {
        corners,
        variants,
        weights,
        inside,
        residual: x.coords - at,
        cost_mm,
    }
}

/// Picks, corner by corner, the variant of each point whose shape best predicts the
/// present neighbours given the other corners (one pass of coordinate descent on the
/// neighbour cost; ties to the least deforming variant).
fn refine_variants(
    mi: &MarkerIndex,
    corners: &[u16; 4],
    weights: &[f64; 4],
    dim: usize,
    neighbors: &[Option<Point3<f64>>],
    rep: &[u32],
) -> [u32; 4] {
    let nk = mi.neighbors.len();
    let mut var = [0u32; 4];
    for c in 0..4 {
        var[c] = rep[corners[c] as usize];
    }
    let has_choice = (0..=dim).any(|c| {
        let j = corners[c] as usize;
        mi.point_variants[j + 1] - mi.point_variants[j] > 1 && weights[c] > 0.0
    });
    if !has_choice || neighbors.iter().all(Option::is_none) {
        return var;
    }
    for c in 0..=dim {
        let j = corners[c] as usize;
        let (lo, hi) = (mi.point_variants[j], mi.point_variants[j + 1]);
        if hi - lo <= 1 || weights[c] <= 0.0 {
            continue;
        }
        let mut best = (f64::INFINITY, var[c]);
        for u in lo..hi {
            let mut cost = 0.0;
            for (k, y) in neighbors.iter().enumerate() {
                let Some(y) = y else { continue };
                let mut pred = Vector3::zeros();
                for c2 in 0..=dim {
                    let v = if c2 == c { u } else { var[c2] } as usize;
                    pred += mi.neighbor_positions[v * nk + k].coords * weights[c2];
                }
                cost += (pred - y.coords).norm_squared();
            }
            let cost = cost.sqrt() + TIE_BREAK * mi.deformation_mm[u as usize];
            if cost < best.0 {
                best = (cost, u);
            }
        }
        var[c] = best.1;
    }
    var
}

/// Calls `hit(t, faces, w, d)` for the tetrahedra `t` of `mi` containing the point `y`
/// whose orientations and codes `table` holds, with its face triples, its barycentric
/// coordinates `w` and distance `d` (0); with `tol_mm > 0` (and `table` coded for it, see
/// [`TripleTable::fill_used_coded_near`]) for those within about `tol_mm` of it instead
/// (distance bound from the face planes). Scans the grid cell of `y` when it lists less
/// than half the tetrahedra, else every tetrahedron; nothing when `y` is outside the grid
/// box, `strict` and `tol_mm == 0`. Tetrahedra come in ascending order.
fn for_each_containing(
    mi: &MarkerIndex,
    grid: &super::grid::TetGrid,
    table: &TripleTable,
    y: &Point3<f64>,
    strict: bool,
    tol_mm: f64,
    mut hit: impl FnMut(u32, [u32; 4], [f64; 4], f64),
) {
    let all = mi.scan.len();
    let codes = table.codes();
    if tol_mm > 0.0 {
        // The near codes make the pre-test exact: every tetrahedron passing it is within
        // the tolerance (`TripleTable::near`).
        mi.scan.for_each_candidate(codes, |t, faces| {
            let w = table.weights(&faces);
            let d = table.outside_distance(&faces, &w, &mi.triple_inv_area2);
            if w.iter().all(|v| v.is_finite()) {
                hit(t as u32, faces, w, d);
            }
        });
        return;
    }
    // The sign pre-test (see `TetScan`) passes every tetrahedron the exact test accepts.
    let mut exact = |t: usize, faces: [u32; 4]| {
        let w = table.weights(&faces);
        if w[0].min(w[1]).min(w[2].min(w[3])) >= INSIDE_SLACK {
            hit(t as u32, faces, w, 0.0);
        }
    };
    let cell = grid.candidates(y);
    if cell.len() * 2 < all {
        for &t in cell {
            let t = t as usize;
            if mi.scan.may_contain(codes, t) {
                exact(t, mi.scan.faces(t));
            }
        }
    } else if grid.contains(y) || !strict {
        mi.scan.for_each_candidate(codes, exact);
    }
}

/// Clamps negative weights to zero and renormalizes to sum 1.
fn clamp_convex(w: &mut [f64; 4]) {
    for v in w.iter_mut() {
        *v = v.max(0.0);
    }
    let s = (w[0] + w[1]) + (w[2] + w[3]);
    if s > 0.0 {
        let inv = 1.0 / s;
        for v in w.iter_mut() {
            *v *= inv;
        }
    }
}
