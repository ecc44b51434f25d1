//! Gradient-domain (Poisson) mesh reconstruction with a prefactored Laplacian
//! (Bermano et al. 2014 §5.5, after Botsch et al. 2006).

use nalgebra::{Matrix3, Point3, Vector3};
use nalgebra_sparse::CsrMatrix;

use super::EnhanceError;
use crate::mesh::{Mesh, boundary_loops, cotangent_laplacian_of};
use crate::numeric::SpdFactor;

/// Tuning of [`PoissonSolver`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PoissonParams {
    /// Weight `w` of the 1D Laplacian regularization along the mesh boundaries (§5.5),
    /// relative to the (dimensionless) cotangent Laplacian. Default 0.05, the paper's value.
    pub boundary_weight: f64,
    /// Weight of a soft pull toward the anchor positions, relative to the mean lumped vertex
    /// area; only there to remove the translation null space of the Laplacian (and to place
    /// disconnected pieces such as eyeballs). Default 1e-6 (its effect on the shape is far
    /// below a micron).
    pub anchor_weight: f64,
}

impl Default for PoissonParams {
    fn default() -> Self {
        Self {
            boundary_weight: 0.05,
            anchor_weight: 1e-6,
        }
    }
}

impl PoissonParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`EnhanceError::InvalidParam`] naming the first bad field.
    pub fn validate(&self) -> Result<(), EnhanceError> {
        if !(self.boundary_weight.is_finite() && self.boundary_weight >= 0.0) {
            return Err(EnhanceError::invalid(
                "poisson.boundary_weight",
                self.boundary_weight,
            ));
        }
        if !(self.anchor_weight.is_finite() && self.anchor_weight > 0.0) {
            return Err(EnhanceError::invalid(
                "poisson.anchor_weight",
                self.anchor_weight,
            ));
        }
        Ok(())
    }
}

/// Rebuilds vertex positions whose per-triangle gradients best match target deformation
/// gradients (Bermano et al. 2014 §5.5, after Botsch et al. 2006):
///
/// min_x Σ_t A_t ‖∇_t x − F_t‖²_F + w Σ_{i∈∂} ‖δ¹ᵢ(x) − δ¹ᵢ(y)‖² + ε Σ_i mᵢ ‖xᵢ − yᵢ‖²,
///
/// where ∇_t is the gradient on rest triangle t (area A_t), F_t the target gradient
/// (restricted to the rest triangle's plane), δ¹ᵢ the 1D Laplacian along the boundary loop
/// (`xᵢ − ½(x_prev + x_next)`), y the anchor positions and mᵢ the lumped vertex area over
/// its mean. The normal equations `(−L + w BᵀB + ε M) x = div F + w BᵀB y + ε M y`
/// (L the cotangent Laplacian of the rest mesh, negative semi-definite) are factored ONCE
/// in [`PoissonSolver::new`]; [`PoissonSolver::solve`] only back-substitutes.
///
/// # Deviations
/// - The paper "minimizes the 1D Laplacian term along the mesh boundaries" (target 0). We
///   match the anchor's boundary 1D Laplacian instead: a target of 0 straightens and
///   shrinks a curved boundary (a face mask's edge is curved), while matching the
///   low-frequency input keeps its outline and still suppresses boundary artifacts.
/// - The tiny anchor term ε is ours: it fixes the translation (the paper leaves the system
///   singular and re-aligns afterwards, which we also do).
pub struct PoissonSolver {
    triangles: Vec<[u32; 3]>,
    /// Per triangle: A_t ∇φ for its three corners (rest), mm.
    weighted_hat_gradients: Vec<[Vector3<f64>; 3]>,
    /// Boundary loops (vertex indices, cyclic).
    loops: Vec<Vec<u32>>,
    /// Lumped vertex weight ε mᵢ/m̄.
    anchor: Vec<f64>,
    boundary_weight: f64,
    factor: SpdFactor,
}

impl std::fmt::Debug for PoissonSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoissonSolver")
            .field("vertices", &self.anchor.len())
            .field("triangles", &self.triangles.len())
            .finish_non_exhaustive()
    }
}

impl PoissonSolver {
    /// Precomputes and factors the system for `mesh`'s triangles at `rest` (#V, mm).
    ///
    /// # Errors
    /// [`EnhanceError::InvalidParam`] for bad params, [`EnhanceError::Shape`] when `rest`
    /// does not match the mesh, [`EnhanceError::Factorization`] if Cholesky fails.
    pub fn new(
        mesh: &Mesh,
        rest: &[Point3<f64>],
        params: &PoissonParams,
    ) -> Result<Self, EnhanceError> {
        params.validate()?;
        let n = mesh.vertex_count();
        let areas = super::rest_triangle_areas(mesh, rest)?;
        let weighted_hat_gradients = mesh
            .triangles
            .iter()
            .zip(&areas)
            .map(|(t, &area)| hat_gradients(t, rest).map(|g| g * area))
            .collect();
        let mut lumped = vec![0.0; n];
        for (t, &area) in mesh.triangles.iter().zip(&areas) {
            for &v in t {
                lumped[v as usize] += area / 3.0;
            }
        }
        let mean = lumped.iter().sum::<f64>() / n.max(1) as f64;
        let mean = if mean > 0.0 { mean } else { 1.0 };
        // Vertices in no triangle still need a positive diagonal.
        let anchor: Vec<f64> = lumped
            .iter()
            .map(|&m| params.anchor_weight * (m / mean).max(1.0e-3))
            .collect();
        let loops = boundary_loops(mesh);
        let l = cotangent_laplacian_of(mesh, rest);
        let mut coo = nalgebra_sparse::CooMatrix::new(n, n);
        for (i, j, &v) in l.triplet_iter() {
            coo.push(i, j, -v);
        }
        for (i, &a) in anchor.iter().enumerate() {
            coo.push(i, i, a);
        }
        let w = params.boundary_weight;
        if w > 0.0 {
            for lp in &loops {
                for (row, coeffs) in boundary_rows(lp) {
                    let _ = row;
                    for &(a, ca) in &coeffs {
                        for &(b, cb) in &coeffs {
                            coo.push(a as usize, b as usize, w * ca * cb);
                        }
                    }
                }
            }
        }
        let a = CsrMatrix::from(&coo);
        let factor = SpdFactor::new(&a, "Poisson system")?;
        Ok(Self {
            triangles: mesh.triangles.clone(),
            weighted_hat_gradients,
            loops,
            anchor,
            boundary_weight: w,
            factor,
        })
    }

    /// Number of triangles the solver expects gradients for.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The positions (#V, mm) whose gradients best match `gradients` (#T), with the
    /// boundary and translation taken from `anchor` (#V, mm).
    ///
    /// # Errors
    /// [`EnhanceError::Shape`] when a length is wrong.
    pub fn solve(
        &self,
        gradients: &[Matrix3<f64>],
        anchor: &[Point3<f64>],
    ) -> Result<Vec<Point3<f64>>, EnhanceError> {
        if gradients.len() != self.triangles.len() {
            return Err(EnhanceError::Shape {
                what: "gradients",
                expected: self.triangles.len(),
                got: gradients.len(),
            });
        }
        if anchor.len() != self.anchor.len() {
            return Err(EnhanceError::Shape {
                what: "anchor positions",
                expected: self.anchor.len(),
                got: anchor.len(),
            });
        }
        let mut rhs: Vec<Vector3<f64>> = anchor
            .iter()
            .zip(&self.anchor)
            .map(|(p, &e)| p.coords * e)
            .collect();
        for ((t, g), f) in self
            .triangles
            .iter()
            .zip(&self.weighted_hat_gradients)
            .zip(gradients)
        {
            for k in 0..3 {
                rhs[t[k] as usize] += f * g[k];
            }
        }
        if self.boundary_weight > 0.0 {
            for lp in &self.loops {
                for (_, coeffs) in boundary_rows(lp) {
                    let target: Vector3<f64> = coeffs
                        .iter()
                        .map(|&(v, c)| anchor[v as usize].coords * c)
                        .sum();
                    for &(v, c) in &coeffs {
                        rhs[v as usize] += target * (self.boundary_weight * c);
                    }
                }
            }
        }
        self.factor.solve3(&mut rhs);
        Ok(rhs.into_iter().map(Point3::from).collect())
    }
}

/// Gradients of the three hat functions of triangle `t` at `positions` (1/mm); zero for a
/// degenerate triangle.
fn hat_gradients(t: &[u32; 3], positions: &[Point3<f64>]) -> [Vector3<f64>; 3] {
    let [a, b, c] = t.map(|v| positions[v as usize]);
    let n = (b - a).cross(&(c - a));
    let twice_area_sq = n.norm_squared();
    if twice_area_sq <= 0.0 {
        return [Vector3::zeros(); 3];
    }
    // ∇φ_i = n × e_i / (2A)·(1/|n|)… written as (n × e_i) / |n|², e_i the edge opposite i.
    [c - b, a - c, b - a].map(|e| n.cross(&e) / twice_area_sq)
}

/// The 1D Laplacian rows of one boundary loop: for each vertex, its coefficients
/// (self 1, loop neighbours −½). Loops shorter than 3 yield nothing.
fn boundary_rows(lp: &[u32]) -> Vec<(u32, [(u32, f64); 3])> {
    let k = lp.len();
    if k < 3 {
        return Vec::new();
    }
    (0..k)
        .map(|i| {
            let prev = lp[(i + k - 1) % k];
            let next = lp[(i + 1) % k];
            (lp[i], [(lp[i], 1.0), (prev, -0.5), (next, -0.5)])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::enhance::deformation_gradient::{deformation_gradients, rest_frame_inverses};

    fn bumpy_grid() -> Mesh {
        let mut m = crate::mesh::test_meshes::grid(12, 2.0);
        for p in &mut m.positions {
            p.z = (p.x * 0.4).sin() * 1.5 + (p.y * 0.3).cos();
        }
        m
    }

    #[test]
    fn own_gradients_give_the_mesh_back_up_to_translation() {
        let rest = bumpy_grid();
        let solver = PoissonSolver::new(&rest, &rest.positions, &PoissonParams::default()).unwrap();
        // Deform nonrigidly, then ask for that pose's gradients relative to the rest.
        let target: Vec<Point3<f64>> = rest
            .positions
            .iter()
            .map(|p| Point3::new(p.x * 1.1, p.y + 0.05 * p.x * p.x, p.z + (p.y * 0.5).sin()))
            .collect();
        let inv = rest_frame_inverses(&rest.triangles, &rest.positions);
        let grads = deformation_gradients(&rest.triangles, &inv, &target);
        // Anchor: the target shifted by a constant, so only translation is left open.
        let shift = Vector3::new(3.0, -1.0, 2.0);
        let anchor: Vec<_> = target.iter().map(|p| p + shift).collect();
        let x = solver.solve(&grads, &anchor).unwrap();
        let mean: Vector3<f64> = x
            .iter()
            .zip(&target)
            .map(|(a, b)| a - b)
            .sum::<Vector3<f64>>()
            / x.len() as f64;
        let worst = x
            .iter()
            .zip(&target)
            .map(|(a, b)| (a - b - mean).norm())
            .fold(0.0, f64::max);
        assert!(worst < 1e-6, "worst deviation {worst} mm");
        assert!(solver.solve(&grads[1..], &anchor).is_err());
    }
}
