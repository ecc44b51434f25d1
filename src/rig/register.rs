//! Scan registration by optimal-step non-rigid ICP (Amberg, Romdhani & Vetter 2007,
//! "Optimal Step Nonrigid ICP Algorithms for Surface Registration"; summarized in
//! Kazlauskaite 2015 §3.3.2): deforms a template mesh onto a scan of any topology, so
//! that the scan's shape gets the template's topology.
//!
//! # The method (Amberg et al. §3)
//! Every template vertex `vᵢ` gets its own affine transform `Xᵢ` (3 × 4, unknowns
//! `X = [X₁ … X_N]ᵀ`, 4N × 3). For a stiffness `α`, the cost (Eq. 1-6)
//!
//! `E(X) = ‖W (D X − U)‖²  +  α ‖(M ⊗ G) X‖²  +  β ‖D_L X − U_L‖²`
//!
//! - data term (Eq. 2): `D` holds `[vᵢᵀ 1]` in block row i, `U` the closest scan points,
//!   `W` the correspondence weights (0 for rejected pairs);
//! - stiffness term (Eq. 3): `M` the edge-vertex incidence matrix of the template,
//!   `G = diag(1, 1, 1, γ)` weighs the rotation/skew part against the translation;
//! - landmark term (Eq. 5): template vertices with known scan positions;
//!
//! is quadratic in `X`; its minimizer solves the sparse normal equations (Eq. 12). For
//! each `α` of a decreasing schedule, the algorithm alternates closest points and solves
//! until `X` changes by less than a tolerance (Algorithm 1).
//!
//! # Choices
//! - Correspondences: the closest point on the scan surface (among the triangles around
//!   the nearest scan vertices, found with a `kiddo` k-d tree), dropped when farther than
//!   [`RegistrationParams::max_distance`], when the normals differ by more than
//!   [`RegistrationParams::max_normal_angle_deg`], or when the closest scan vertex lies
//!   on the scan's boundary (Amberg §3.1: "robustness").
//! - The problem is solved in normalized coordinates (template centred, RMS radius 1), so
//!   that α and γ do not depend on the mesh's unit; γ = 1 as in the paper.
//! - Initialization: the rigid transform (Horn 1987) mapping the landmarks when at least 3
//!   are given, else the one aligning the centroids.

use std::num::NonZero;

use kiddo::SquaredEuclidean;
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use nalgebra::{Point3, Vector3};
use nalgebra_sparse::{CooMatrix, CsrMatrix};
use rayon::prelude::*;

use super::RigError;
use crate::align::horn::horn_alignment;
use crate::mesh::{Mesh, Topology, edges, vertex_normals_of};
use crate::numeric::SpdFactor;

/// Tuning of [`register`]. Lengths are relative to the template's RMS radius (the
/// registration runs in normalized coordinates).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RegistrationParams {
    /// Stiffness schedule α, decreasing (Amberg §4: from stiff, near-affine, to flexible).
    /// Default 100, 50, 20, 10, 5, 2, 1, 0.5.
    pub stiffness: Vec<f64>,
    /// γ of `G = diag(1, 1, 1, γ)`. Default 1.
    pub gamma: f64,
    /// Weight β of each landmark relative to one data correspondence. Default 10.
    pub landmark_weight: f64,
    /// Most closest-point iterations per stiffness. Default 10.
    pub max_iterations: usize,
    /// An iteration converged when no vertex moved more than this (relative). Default 1e-4.
    pub tolerance: f64,
    /// Correspondences farther than this (relative to the RMS radius) are dropped.
    /// Default 0.1 (1 cm on a 10 cm head radius).
    pub max_distance: f64,
    /// Correspondences whose normals differ by more than this are dropped, degrees.
    /// Default 60.
    pub max_normal_angle_deg: f64,
}

impl Default for RegistrationParams {
    fn default() -> Self {
        Self {
            stiffness: vec![100.0, 50.0, 20.0, 10.0, 5.0, 2.0, 1.0, 0.5],
            gamma: 1.0,
            landmark_weight: 10.0,
            max_iterations: 10,
            tolerance: 1e-4,
            max_distance: 0.1,
            max_normal_angle_deg: 60.0,
        }
    }
}

impl RegistrationParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`RigError::InvalidParam`] naming the first bad field.
    pub fn validate(&self) -> Result<(), RigError> {
        if self.stiffness.is_empty() {
            return Err(RigError::invalid(
                "stiffness",
                0.0,
                "needs at least one value",
            ));
        }
        for &a in &self.stiffness {
            if !(a.is_finite() && a > 0.0) {
                return Err(RigError::invalid("stiffness", a, "must be finite and > 0"));
            }
        }
        for (field, v) in [
            ("gamma", self.gamma),
            ("landmark_weight", self.landmark_weight),
            ("tolerance", self.tolerance),
            ("max_distance", self.max_distance),
            ("max_normal_angle_deg", self.max_normal_angle_deg),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(RigError::invalid(field, v, "must be finite and > 0"));
            }
        }
        if self.max_iterations == 0 {
            return Err(RigError::invalid(
                "max_iterations",
                0.0,
                "must be at least 1",
            ));
        }
        Ok(())
    }
}

/// The result of [`register`].
#[derive(Debug, Clone, PartialEq)]
pub struct Registration {
    /// The template's vertices on the scan (#V, the scan's unit and frame).
    pub positions: Vec<Point3<f64>>,
    /// RMS distance of the accepted correspondences in the last iteration (scan unit).
    pub rms_distance: f64,
    /// Fraction of template vertices with an accepted correspondence in the last iteration.
    pub matched_fraction: f64,
    /// Closest-point iterations run in total.
    pub iterations: usize,
}

/// Closest point on triangle `abc` to `p` (Ericson, Real-Time Collision Detection §5.1.5).
fn closest_on_triangle(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> Point3<f64> {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// The scan prepared for closest-point queries.
struct Scan {
    positions: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
    /// Triangles around each vertex.
    vertex_triangles: Vec<Vec<u32>>,
    boundary: Vec<bool>,
    tree: ImmutableKdTree<f64, u64, 3, 32>,
}

impl Scan {
    fn new(mesh: &Mesh, positions: Vec<Point3<f64>>) -> Self {
        let mut vertex_triangles = vec![Vec::new(); positions.len()];
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for &v in tri {
                vertex_triangles[v as usize].push(t as u32);
            }
        }
        let boundary = Topology::new(mesh).boundary_vertex_mask();
        let pts: Vec<[f64; 3]> = positions.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = ImmutableKdTree::new_from_slice(&pts);
        Self {
            positions,
            triangles: mesh.triangles.clone(),
            vertex_triangles,
            boundary,
            tree,
        }
    }

    /// Closest surface point to `p`, its triangle's unit normal, and whether the nearest
    /// scan vertex is on the boundary.
    fn closest(&self, p: &Point3<f64>) -> Option<(Point3<f64>, Vector3<f64>, bool)> {
        let k = NonZero::new(6)?;
        let near = self.tree.nearest_n::<SquaredEuclidean>(&[p.x, p.y, p.z], k);
        let first = near.first()?.item as usize;
        let mut best: Option<(f64, Point3<f64>, u32)> = None;
        for nb in &near {
            for &t in &self.vertex_triangles[nb.item as usize] {
                let [a, b, c] = self.triangles[t as usize].map(|v| self.positions[v as usize]);
                let q = closest_on_triangle(p, &a, &b, &c);
                let d = (q - p).norm_squared();
                if best.is_none_or(|(bd, _, _)| d < bd) {
                    best = Some((d, q, t));
                }
            }
        }
        let (_, q, t) = best?;
        let [a, b, c] = self.triangles[t as usize].map(|v| self.positions[v as usize]);
        let n = (b - a).cross(&(c - a)).try_normalize(0.0)?;
        Some((q, n, self.boundary[first]))
    }
}

/// Registers `template` onto `scan` (optimal-step NICP, see the module docs).
/// `landmarks` pairs template vertices with their positions on the scan (scan unit and
/// frame). `on_step` sees (stiffness index, iteration, RMS distance) after each solve.
///
/// # Errors
/// [`RigError::InvalidParam`] for bad params, [`RigError::Input`] for a landmark vertex
/// out of range or a degenerate template, [`RigError::Factor`] when a system cannot be
/// factored.
pub fn register(
    template: &Mesh,
    scan: &Mesh,
    landmarks: &[(u32, Point3<f64>)],
    params: &RegistrationParams,
    on_step: &mut dyn FnMut(usize, usize, f64),
) -> Result<Registration, RigError> {
    params.validate()?;
    let nv = template.vertex_count();
    if let Some((v, _)) = landmarks.iter().find(|(v, _)| *v as usize >= nv) {
        return Err(RigError::Input(format!(
            "landmark vertex {v} is out of range (the template has {nv} vertices)"
        )));
    }
    // Normalization: template centred at its centroid, RMS radius 1.
    let centroid = template
        .positions
        .iter()
        .fold(Vector3::zeros(), |s, p| s + p.coords)
        / nv.max(1) as f64;
    let radius = (template
        .positions
        .iter()
        .map(|p| (p.coords - centroid).norm_squared())
        .sum::<f64>()
        / nv.max(1) as f64)
        .sqrt();
    if !(radius.is_finite() && radius > 0.0) {
        return Err(RigError::Input(
            "the template is degenerate (zero size)".into(),
        ));
    }
    let norm = |p: &Point3<f64>| Point3::from((p.coords - centroid) / radius);
    let v: Vec<Point3<f64>> = template.positions.iter().map(norm).collect();
    let scan_pts: Vec<Point3<f64>> = scan.positions.iter().map(norm).collect();
    let lm: Vec<(usize, Point3<f64>)> = landmarks
        .iter()
        .map(|(i, p)| (*i as usize, norm(p)))
        .collect();
    let scan = Scan::new(scan, scan_pts);
    // Initial rigid alignment.
    let init = if lm.len() >= 3 {
        let src: Vec<Point3<f64>> = lm.iter().map(|(i, _)| v[*i]).collect();
        let dst: Vec<Point3<f64>> = lm.iter().map(|(_, p)| *p).collect();
        horn_alignment(&src, &dst, &[])
            .map_err(|e| RigError::Input(format!("landmark alignment: {e}")))?
    } else {
        let c = scan
            .positions
            .iter()
            .fold(Vector3::zeros(), |s, p| s + p.coords)
            / scan.positions.len().max(1) as f64;
        nalgebra::Isometry3::translation(c.x, c.y, c.z)
    };
    // X: per vertex the 4×3 block [A; t]ᵀ such that y = Xᵀ [v; 1].
    let r = init.rotation.to_rotation_matrix().into_inner();
    let t = init.translation.vector;
    let mut x: Vec<Vector3<f64>> = Vec::with_capacity(4 * nv);
    for _ in 0..nv {
        for k in 0..3 {
            x.push(r.column(k).into_owned());
        }
        x.push(t);
    }
    let deform = |x: &[Vector3<f64>]| -> Vec<Point3<f64>> {
        v.iter()
            .enumerate()
            .map(|(i, p)| {
                Point3::from(
                    x[4 * i] * p.x + x[4 * i + 1] * p.y + x[4 * i + 2] * p.z + x[4 * i + 3],
                )
            })
            .collect()
    };
    let edge_list = edges(template);
    let cos_max = params.max_normal_angle_deg.to_radians().cos();
    let ext = |p: &Point3<f64>| [p.x, p.y, p.z, 1.0];
    let mut y = deform(&x);
    let mut rms = 0.0;
    let mut matched = 0.0;
    let mut iterations = 0;
    for (si, &alpha) in params.stiffness.iter().enumerate() {
        for it in 0..params.max_iterations {
            iterations += 1;
            let normals = vertex_normals_of(template, &y);
            let corr: Vec<Option<Point3<f64>>> = y
                .par_iter()
                .zip(&normals)
                .map(|(p, n)| {
                    let (q, qn, on_boundary) = scan.closest(p)?;
                    let ok = !on_boundary
                        && (q - p).norm() <= params.max_distance
                        && n.dot(&qn) >= cos_max;
                    ok.then_some(q)
                })
                .collect();
            let mut coo = CooMatrix::new(4 * nv, 4 * nv);
            let mut rhs = vec![Vector3::zeros(); 4 * nv];
            // Stiffness: α ‖G (X_i − X_j)‖² per edge.
            let g2 = [1.0, 1.0, 1.0, params.gamma * params.gamma];
            for e in &edge_list {
                let (i, j) = (e[0] as usize, e[1] as usize);
                for (k, g) in g2.iter().enumerate() {
                    let w = alpha * g;
                    coo.push(4 * i + k, 4 * i + k, w);
                    coo.push(4 * j + k, 4 * j + k, w);
                    coo.push(4 * i + k, 4 * j + k, -w);
                    coo.push(4 * j + k, 4 * i + k, -w);
                }
            }
            // Data and landmarks: w ‖X_iᵀ ṽ_i − u‖².
            let mut add = |i: usize, u: &Point3<f64>, w: f64| {
                let vt = ext(&v[i]);
                for a in 0..4 {
                    for b in 0..4 {
                        coo.push(4 * i + a, 4 * i + b, w * vt[a] * vt[b]);
                    }
                    rhs[4 * i + a] += u.coords * (w * vt[a]);
                }
            };
            let mut sq = 0.0;
            let mut count = 0usize;
            for (i, c) in corr.iter().enumerate() {
                if let Some(u) = c {
                    add(i, u, 1.0);
                    sq += (u - y[i]).norm_squared();
                    count += 1;
                }
            }
            for (i, u) in &lm {
                add(*i, u, params.landmark_weight);
            }
            rms = if count > 0 {
                (sq / count as f64).sqrt()
            } else {
                0.0
            };
            matched = count as f64 / nv.max(1) as f64;
            // A vertex without data keeps a tiny pull toward its current transform, so that
            // a component with no correspondence stays where it is.
            for i in 0..nv {
                for k in 0..4 {
                    let w = 1e-8;
                    coo.push(4 * i + k, 4 * i + k, w);
                    rhs[4 * i + k] += x[4 * i + k] * w;
                }
            }
            let factor = SpdFactor::new(&CsrMatrix::from(&coo), "non-rigid ICP")?;
            factor.solve3(&mut rhs);
            x = rhs;
            let next = deform(&x);
            let moved = next
                .iter()
                .zip(&y)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
            y = next;
            on_step(si, it, rms * radius);
            if moved < params.tolerance {
                break;
            }
        }
    }
    Ok(Registration {
        positions: y
            .iter()
            .map(|p| Point3::from(p.coords * radius + centroid))
            .collect(),
        rms_distance: rms * radius,
        matched_fraction: matched,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Translation3};

    /// A bumpy height field over [0, size]², sampled on an `n × n` grid, as triangles;
    /// `jitter` shifts the interior samples in the plane (a different remeshing).
    fn surface(n: usize, size: f64, jitter: f64, seed: u64) -> Mesh {
        let mut rng = crate::numeric::SplitMix64::new(seed);
        let mut rnd = || rng.uniform(-1.0, 1.0);
        let h = |x: f64, y: f64| 8.0 * (x * 0.08).sin() * (y * 0.06).cos() + 0.002 * x * y;
        let step = size / n as f64;
        let mut positions = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let interior = i > 0 && j > 0 && i < n && j < n;
                let (dx, dy) = if interior {
                    (rnd() * jitter * step, rnd() * jitter * step)
                } else {
                    (0.0, 0.0)
                };
                let (x, y) = (i as f64 * step + dx, j as f64 * step + dy);
                positions.push(Point3::new(x, y, h(x, y)));
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let mut tris = Vec::new();
        for j in 0..n {
            for i in 0..n {
                tris.push(vec![id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                tris.push(vec![id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        Mesh::new(positions, &tris, Vec::new(), None).unwrap()
    }

    #[test]
    fn a_remeshed_moved_noisy_copy_is_recovered() {
        // Known mesh: 40×40 samples of the surface over 100 mm. Template: the same mesh
        // squashed (bumps 30 % lower) and stretched 4 % — what NICP must undo. Scan: the
        // surface resampled on a jittered 57×57 grid (re-indexed by a permutation),
        // rotated 25° and moved 40 mm, with ±0.1 mm noise.
        let known = surface(40, 100.0, 0.0, 1);
        let template = known
            .with_positions(
                known
                    .positions
                    .iter()
                    .map(|p| Point3::new(p.x * 1.04, p.y, p.z * 0.7))
                    .collect(),
            )
            .unwrap();
        let resampled = surface(57, 100.0, 0.3, 2);
        let nv = resampled.vertex_count();
        let perm: Vec<usize> = (0..nv).map(|i| (i * 7919) % nv).collect();
        let mut inverse = vec![0u32; nv];
        for (new, &old) in perm.iter().enumerate() {
            inverse[old] = new as u32;
        }
        let motion = Translation3::new(40.0, -15.0, 20.0)
            * Rotation3::from_axis_angle(&Vector3::y_axis(), 25f64.to_radians());
        let mut rng = crate::numeric::SplitMix64::new(9);
        let mut noise = || rng.uniform(-0.1, 0.1);
        let positions: Vec<Point3<f64>> = perm
            .iter()
            .map(|&old| motion * resampled.positions[old] + Vector3::new(noise(), noise(), noise()))
            .collect();
        let polys: Vec<Vec<u32>> = resampled
            .triangles
            .iter()
            .map(|t| t.iter().map(|&v| inverse[v as usize]).collect())
            .collect();
        let scan = Mesh::new(positions, &polys, Vec::new(), None).unwrap();
        // Landmarks: the four corners and the centre, at their true (moved) positions.
        let landmarks: Vec<(u32, Point3<f64>)> = [0usize, 40, 40 * 41, 41 * 41 - 1, 20 * 41 + 20]
            .iter()
            .map(|&v| (v as u32, motion * known.positions[v]))
            .collect();
        let reg = register(
            &template,
            &scan,
            &landmarks,
            &RegistrationParams::default(),
            &mut |_, _, _| {},
        )
        .unwrap();
        let truth: Vec<Point3<f64>> = known.positions.iter().map(|p| motion * p).collect();
        let errors: Vec<f64> = reg
            .positions
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).norm())
            .collect();
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let worst = errors.iter().copied().fold(0.0, f64::max);
        println!(
            "registration: vertex error RMS {rms:.3} mm, worst {worst:.3} mm; surface RMS \
             {:.3} mm, {:.0} % matched, {} iterations",
            reg.rms_distance,
            reg.matched_fraction * 100.0,
            reg.iterations
        );
        // Before registration the template is off by several millimetres.
        let before = (template
            .positions
            .iter()
            .zip(&known.positions)
            .map(|(a, b)| (a - b).norm_squared())
            .sum::<f64>()
            / errors.len() as f64)
            .sqrt();
        assert!(before > 3.0, "{before}");
        assert!(rms < 0.5, "vertex RMS {rms} mm");
        assert!(
            reg.rms_distance < 0.2,
            "surface RMS {} mm",
            reg.rms_distance
        );
    }
}
