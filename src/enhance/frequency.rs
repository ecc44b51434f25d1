//! Frequency separation by one implicit curvature-flow step and one uniform Laplacian
//! smoothing step (Bermano et al. 2014 §4.2, Eq. 1; Desbrun et al. 1999).

use nalgebra::{Point3, Vector3};
use nalgebra_sparse::{CooMatrix, CsrMatrix};

use super::EnhanceError;
use crate::mesh::{Mesh, cotangent_laplacian_of, uniform_laplacian};
use crate::numeric::SpdFactor;

/// Tuning of the low-pass filter [`LowPass`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LowPassParams {
    /// λdt of Eq. (1), mm². Default 125 mm², the paper's value, which we keep because our
    /// shapes are in millimetres like the paper's captures: with the paper's K (≈ Δ/6 on a
    /// regular mesh, see [`LowPass`]) a sinusoid of wavelength ℓ is scaled by
    /// 1 / (1 + λdt (2π/ℓ)² / 6), so ℓ = 29 mm keeps half its amplitude, expression-scale
    /// bulges (40-80 mm) keep 65-95 % and wrinkles and furrows (2-10 mm) keep under 5 %:
    /// exactly the split between what a rig or marker solve captures and what it misses.
    /// Scale it with the square of the unit if shapes are not in millimetres.
    pub lambda_dt_mm2: f64,
    /// Step μ of the uniform Laplacian smoothing that follows (x ← x + μ L_u x; 1 moves every
    /// vertex to its neighbours' mean). The paper does "one iteration" without a step; we
    /// default to 0.5, enough to regularize the sliver triangles the implicit step leaves
    /// while shrinking the face (and its boundary) less than a full step.
    pub uniform_step: f64,
}

impl Default for LowPassParams {
    fn default() -> Self {
        Self {
            lambda_dt_mm2: 125.0,
            uniform_step: 0.5,
        }
    }
}

impl LowPassParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`EnhanceError::InvalidParam`] naming the first bad field.
    pub fn validate(&self) -> Result<(), EnhanceError> {
        if !(self.lambda_dt_mm2.is_finite() && self.lambda_dt_mm2 >= 0.0) {
            return Err(EnhanceError::invalid(
                "low_pass.lambda_dt_mm2",
                self.lambda_dt_mm2,
            ));
        }
        if !(self.uniform_step.is_finite() && (0.0..=1.0).contains(&self.uniform_step)) {
            return Err(EnhanceError::invalid(
                "low_pass.uniform_step",
                self.uniform_step,
            ));
        }
        Ok(())
    }
}

/// The low-pass filter f(·) of Bermano et al. 2014 §4.2: one implicit curvature-flow step
/// `(I − λdt K) Xⁿ⁺¹ = Xⁿ` (Eq. 1) with `K_ij = (cot α_j + cot β_j) / (4 A_i)` for
/// neighbours, `K_ii = −Σ K_ik`, `A_i` the summed area of the triangles around vertex i,
/// followed by one uniform Laplacian smoothing step.
///
/// Solved in the symmetric form `(D − λdt L) Xⁿ⁺¹ = D Xⁿ`, `D = diag(2 A_i)`, `L` the
/// cotangent Laplacian (negative semi-definite, `L_ij = ½(cot α + cot β)`), so that
/// `D⁻¹L = K` and the matrix is symmetric positive definite: factored once by sparse
/// Cholesky in [`LowPass::new`], back-substituted in [`LowPass::apply`].
///
/// # Deviations
/// K is built once at the neutral pose rather than at every shape's own positions (the
/// paper's §5.5 makes the same assumption for its reconstruction Laplacian). This makes
/// f linear and identical for every database shape and input frame, so that f commutes
/// with the blending of §5.3-5.4, and costs one back-substitution per frame instead of a
/// factorization (tens of milliseconds at 27k vertices), which the 30 frames/s goal needs.
pub struct LowPass {
    factor: SpdFactor,
    diag: Vec<f64>,
    uniform: CsrMatrix<f64>,
    uniform_step: f64,
}

impl std::fmt::Debug for LowPass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LowPass")
            .field("vertices", &self.diag.len())
            .field("uniform_step", &self.uniform_step)
            .finish_non_exhaustive()
    }
}

impl LowPass {
    /// Builds and factors the filter for `mesh`'s connectivity at `rest` (#V, mm).
    ///
    /// # Errors
    /// [`EnhanceError::InvalidParam`], [`EnhanceError::Shape`] for a wrong length,
    /// [`EnhanceError::Factorization`] if Cholesky fails.
    pub fn new(
        mesh: &Mesh,
        rest: &[Point3<f64>],
        params: &LowPassParams,
    ) -> Result<Self, EnhanceError> {
        params.validate()?;
        let n = mesh.vertex_count();
        let areas = super::rest_triangle_areas(mesh, rest)?;
        let mut diag = vec![0.0; n];
        for (t, &a) in mesh.triangles.iter().zip(&areas) {
            for &v in t {
                diag[v as usize] += 2.0 * a;
            }
        }
        // A vertex in no triangle keeps its position: give it a unit diagonal.
        let mean = diag.iter().sum::<f64>() / n.max(1) as f64;
        for d in &mut diag {
            if *d <= 0.0 {
                *d = if mean > 0.0 { mean } else { 1.0 };
            }
        }
        let l = cotangent_laplacian_of(mesh, rest);
        let mut coo = CooMatrix::new(n, n);
        for (i, j, &v) in l.triplet_iter() {
            coo.push(i, j, -params.lambda_dt_mm2 * v);
        }
        for (i, &d) in diag.iter().enumerate() {
            coo.push(i, i, d);
        }
        let factor = SpdFactor::new(&CsrMatrix::from(&coo), "curvature-flow system")?;
        Ok(Self {
            factor,
            diag,
            uniform: uniform_laplacian(mesh),
            uniform_step: params.uniform_step,
        })
    }

    /// f(X): the low-frequency version of `positions` (#V, mm).
    ///
    /// # Errors
    /// [`EnhanceError::Shape`] when `positions` has the wrong length.
    pub fn apply(&self, positions: &[Point3<f64>]) -> Result<Vec<Point3<f64>>, EnhanceError> {
        if positions.len() != self.diag.len() {
            return Err(EnhanceError::Shape {
                what: "positions",
                expected: self.diag.len(),
                got: positions.len(),
            });
        }
        let mut x: Vec<Vector3<f64>> = positions
            .iter()
            .zip(&self.diag)
            .map(|(p, &d)| p.coords * d)
            .collect();
        self.factor.solve3(&mut x);
        let mut out = x.clone();
        if self.uniform_step > 0.0 {
            for (i, row) in self.uniform.row_iter().enumerate() {
                let mut lx = Vector3::zeros();
                for (&j, &v) in row.col_indices().iter().zip(row.values()) {
                    lx += x[j] * v;
                }
                out[i] += lx * self.uniform_step;
            }
        }
        Ok(out.into_iter().map(Point3::from).collect())
    }

    /// The high band X − f(X) of `positions` (Eq. 1's split: what the low-pass removes),
    /// as offsets per vertex, mm.
    ///
    /// # Errors
    /// As [`LowPass::apply`].
    pub fn high_band(&self, positions: &[Point3<f64>]) -> Result<Vec<Vector3<f64>>, EnhanceError> {
        let low = self.apply(positions)?;
        Ok(positions.iter().zip(&low).map(|(p, l)| p - l).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn attenuates_fine_ripples_and_keeps_broad_shape() {
        let mut mesh = crate::mesh::test_meshes::grid(60, 1.0);
        let len = mesh.positions.iter().map(|p| p.x).fold(0.0, f64::max);
        let flat = mesh.positions.clone();
        for p in &mut mesh.positions {
            // A broad 60 mm bump plus 4 mm ripples.
            p.z = 5.0 * (std::f64::consts::PI * p.x / len).sin()
                + 0.5 * (std::f64::consts::TAU * p.y / 4.0).sin();
        }
        let lp = LowPass::new(&mesh, &flat, &LowPassParams::default()).unwrap();
        let out = lp.apply(&mesh.positions).unwrap();
        // Interior column at the bump's crest: ripples gone, bump mostly kept.
        let mut ripple = 0.0_f64;
        let mut crest = 0.0_f64;
        for (p, q) in mesh.positions.iter().zip(&out) {
            if (p.x - len / 2.0).abs() < 0.5 && p.y > 0.25 * len && p.y < 0.75 * len {
                ripple = ripple.max((q.z - out_mean_z(&out, p.x)).abs());
                crest = crest.max(q.z);
            }
        }
        assert!(ripple < 0.05, "ripple left {ripple} mm");
        assert!(crest > 2.5, "bump crest {crest} mm");
        assert!(lp.apply(&mesh.positions[1..]).is_err());
        // The high band is what the low-pass removed.
        let high = lp.high_band(&mesh.positions).unwrap();
        for ((h, p), q) in high.iter().zip(&mesh.positions).zip(&out) {
            assert!((h - (p - q)).norm() < 1e-12);
        }
        assert!(lp.high_band(&mesh.positions[1..]).is_err());
    }

    fn out_mean_z(out: &[Point3<f64>], x: f64) -> f64 {
        let col: Vec<f64> = out
            .iter()
            .filter(|q| (q.x - x).abs() < 0.6)
            .map(|q| q.z)
            .collect();
        col.iter().sum::<f64>() / col.len() as f64
    }
}
