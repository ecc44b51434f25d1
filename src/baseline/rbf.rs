//! Thin-plate radial-basis-function interpolation of the bundle displacements over the
//! neutral mesh: the "interpolating the bundle displacements across the mesh" baseline of
//! Cong et al. 2019 Figure 4 (after Bhat et al. 2013) and the thin-plate-spline warp of
//! Kazlauskaite 2015.
//!
//! d(x) = Σ_m α_m φ(r_m(x)) + a + B x, with `[Φ P; Pᵀ 0] [α; (a, B)] = [D; 0]`, where `D`
//! holds the present bundles' displacements from their neutral positions, `Φ_mn =
//! φ(r_m(c_n))`, and `P` the affine basis at the marker positions. The interpolant passes
//! through every bundle and is the smoothest such warp (bending energy).
//!
//! # Tuning (defaults chosen on the ICT benchmark)
//! - **Kernel**: `r` (the biharmonic spline of 3D space, the thin-plate spline's 3D form)
//!   by default: on ICT it is within 5 % of `r² log r` on exact bundles and 10–20 % better
//!   with noise. `r² log r` is available.
//! - **Distance**: Euclidean on the neutral. Distances along the mesh (edge-graph
//!   geodesics) were tried to keep the lips apart, but they do not give a conditionally
//!   positive definite kernel and the ICT system diverged (errors of tens of mm).
//!   The lips separate anyway in this benchmark because every lip marker sits ≥ 5 mm
//!   from the lip line.
//!
//! The system depends only on which markers are present, so it is factored once per set of
//! present markers (cached) and each frame costs a back-substitution and one product.

use nalgebra::{DMatrix, DVector, Point3, Vector3};

use super::BaselineError;
use crate::bundles::FrameBundles;
use crate::dataset::{Dataset, MarkerLayout};

/// Radial function φ(r).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RbfKernel {
    /// `r² log r`, the thin-plate spline of a 2D domain.
    ThinPlate,
    /// `r`, the biharmonic spline of 3D space.
    Biharmonic,
}

/// RBF baseline parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RbfParams {
    /// Radial function. Default biharmonic.
    pub kernel: RbfKernel,
    /// Ridge added to the kernel matrix's diagonal, relative to its mean absolute entry
    /// (0 interpolates exactly). Default 0.
    pub smoothing: f64,
}

impl Default for RbfParams {
    fn default() -> Self {
        Self {
            kernel: RbfKernel::Biharmonic,
            smoothing: 0.0,
        }
    }
}

fn phi(kernel: RbfKernel, r: f64) -> f64 {
    match kernel {
        RbfKernel::ThinPlate => {
            if r <= 0.0 {
                0.0
            } else {
                r * r * r.ln()
            }
        }
        RbfKernel::Biharmonic => r,
    }
}

/// Thin-plate RBF solver over a dataset's neutral.
#[derive(Debug)]
pub struct RbfSolver {
    params: RbfParams,
    neutral: Vec<Point3<f64>>,
    /// Neutral marker positions.
    rest: Vec<Point3<f64>>,
    /// Marker vertices.
    vertices: Vec<u32>,
    /// `#V × markers` kernel values φ(r_m(v)), row-major (reached vertices; others copy).
    kernel: Vec<f64>,
    /// Vertex whose displacement each vertex takes (itself, with Euclidean distances).
    source: Vec<u32>,
    /// Last present set and its factored system.
    cache: Option<(
        Vec<bool>,
        nalgebra::linalg::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
    )>,
}

impl RbfSolver {
    /// Precomputes the distances from every marker to every vertex.
    ///
    /// # Errors
    /// [`BaselineError`] when the layout does not fit the dataset or the parameters are
    /// invalid.
    pub fn new(
        dataset: &Dataset,
        layout: &MarkerLayout,
        params: &RbfParams,
    ) -> Result<Self, BaselineError> {
        layout
            .validate_for(dataset)
            .map_err(|e| BaselineError::Layout(e.to_string()))?;
        if !(params.smoothing >= 0.0 && params.smoothing.is_finite()) {
            return Err(BaselineError::Param(format!(
                "smoothing = {} must be ≥ 0",
                params.smoothing
            )));
        }
        let mesh = &dataset.neutral;
        let n = mesh.vertex_count();
        let nm = layout.len();
        let rest: Vec<Point3<f64>> = layout
            .markers
            .iter()
            .map(|m| mesh.positions[m.vertex as usize])
            .collect();
        let dist_cols: Vec<Vec<f64>> = rest
            .iter()
            .map(|c| mesh.positions.iter().map(|p| (p - c).norm()).collect())
            .collect();
        let source: Vec<u32> = (0..n as u32).collect();
        let mut kernel = vec![0.0; n * nm];
        for (m, col) in dist_cols.iter().enumerate() {
            for (v, &d) in col.iter().enumerate() {
                if d.is_finite() {
                    kernel[v * nm + m] = phi(params.kernel, d);
                }
            }
        }
        Ok(Self {
            params: *params,
            neutral: mesh.positions.clone(),
            rest,
            vertices: layout.markers.iter().map(|m| m.vertex).collect(),
            kernel,
            source,
            cache: None,
        })
    }

    /// Interpolates the present bundles' displacements over every vertex.
    ///
    /// # Errors
    /// [`BaselineError::Frame`] when the frame does not fit the layout, has no bundle, or
    /// the present markers make the system singular (fewer than four, or all coplanar).
    pub fn solve(&mut self, bundles: &FrameBundles) -> Result<Vec<Point3<f64>>, BaselineError> {
        let present = super::present_mask(bundles, self.rest.len())?;
        let idx: Vec<usize> = (0..present.len()).filter(|&m| present[m]).collect();
        let k = idx.len();
        let fresh = !matches!(&self.cache, Some((p, _)) if *p == present);
        if fresh {
            let size = k + 4;
            let mut a = DMatrix::zeros(size, size);
            let mut mean_abs = 0.0;
            let nm = self.rest.len();
            for (i, &mi) in idx.iter().enumerate() {
                let vi = self.vertices[mi] as usize;
                for (j, &mj) in idx.iter().enumerate() {
                    a[(i, j)] = self.kernel[vi * nm + mj];
                    mean_abs += a[(i, j)].abs();
                }
                let c = self.rest[mi];
                for (q, val) in [1.0, c.x, c.y, c.z].into_iter().enumerate() {
                    a[(i, k + q)] = val;
                    a[(k + q, i)] = val;
                }
            }
            mean_abs /= (k * k).max(1) as f64;
            for i in 0..k {
                a[(i, i)] += self.params.smoothing * mean_abs;
            }
            self.cache = Some((present.clone(), a.lu()));
        }
        let Some((_, lu)) = &self.cache else {
            return Err(BaselineError::Frame {
                frame: bundles.frame,
                message: "RBF system not factored".into(),
            });
        };
        let mut coef = Vec::with_capacity(3);
        for axis in 0..3 {
            let mut rhs = DVector::zeros(k + 4);
            for (i, &mi) in idx.iter().enumerate() {
                if let Some(p) = bundles.positions[mi] {
                    rhs[i] = (p - self.rest[mi])[axis];
                }
            }
            let sol = lu.solve(&rhs).ok_or_else(|| BaselineError::Frame {
                frame: bundles.frame,
                message: format!(
                    "the {k} present markers do not determine a thin-plate spline (need 4 not \
                     coplanar)"
                ),
            })?;
            coef.push(sol);
        }
        // Per reached vertex: Σ α φ + affine.
        let n = self.neutral.len();
        let nm = self.rest.len();
        let alpha: Vec<Vector3<f64>> = (0..k)
            .map(|i| Vector3::new(coef[0][i], coef[1][i], coef[2][i]))
            .collect();
        let affine: Vec<Vector3<f64>> = (0..4)
            .map(|q| Vector3::new(coef[0][k + q], coef[1][k + q], coef[2][k + q]))
            .collect();
        let mut disp = vec![Vector3::zeros(); n];
        for (v, d) in disp.iter_mut().enumerate() {
            if self.source[v] as usize != v {
                continue;
            }
            let p = self.neutral[v];
            let row = &self.kernel[v * nm..(v + 1) * nm];
            let mut s = affine[0] + affine[1] * p.x + affine[2] * p.y + affine[3] * p.z;
            for (a, &mi) in alpha.iter().zip(&idx) {
                s += a * row[mi];
            }
            *d = s;
        }
        Ok((0..n)
            .map(|v| self.neutral[v] + disp[self.source[v] as usize])
            .collect())
    }
}
