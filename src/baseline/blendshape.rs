//! Blendshape fit: the weights of the dataset's shapes that best reproduce the bundles,
//! bounded to [0, 1] (Cong et al. 2019 §7, "Comparison to Other Approaches"; Lewis et al.
//! 2014; Kazlauskaite 2015 §3):
//!
//! min_w ‖B w − (y − x₀)‖² + μ ‖w‖²  subject to 0 ≤ w_n ≤ 1,
//!
//! with `B` the shapes' displacements at the present markers (3 rows per marker), `y` the
//! bundles and `x₀` the neutral marker positions. The result is `x₀ + Σ w_n b_n` over every
//! vertex.
//!
//! # Solver
//! A primal active-set method on the normal equations (Nocedal and Wright 2006 §16.5),
//! specialised to box constraints: the free weights solve the equality-constrained
//! problem by Cholesky; a step that leaves the box stops at the first bound and fixes that
//! weight; a bound weight whose gradient points into the box is released. It is exact (a
//! finite number of steps), warm-starts from the previous frame, and for the ~50 shapes of
//! a face rig costs well under a millisecond. The paper's soft penalty toward [0, 1] is
//! replaced by hard bounds, the stronger (and usual) form.
//!
//! # Tuning
//! `μ` (relative to the mean diagonal of `BᵀB`) is tiny by default, so a performance in
//! the rig's linear span is reproduced exactly; raise it for noisy bundles.

use nalgebra::{DMatrix, DVector, Point3};

use super::BaselineError;
use crate::bundles::FrameBundles;
use crate::dataset::{Dataset, MarkerLayout};
use crate::numeric::box_qp;

/// Blendshape fit parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BlendshapeParams {
    /// Ridge μ relative to the mean diagonal of `BᵀB`. Default 1e-6.
    pub regularization: f64,
    /// Most active-set iterations per frame. Default 500.
    pub max_iterations: usize,
}

impl Default for BlendshapeParams {
    fn default() -> Self {
        Self {
            regularization: 1e-6,
            max_iterations: 500,
        }
    }
}

/// Bounded blendshape fit over a dataset.
#[derive(Debug)]
pub struct BlendshapeSolver {
    params: BlendshapeParams,
    neutral: Vec<Point3<f64>>,
    /// Per shape, the displacement of every vertex (flattened xyz, #V·3).
    shapes: Vec<Vec<f64>>,
    /// `3·markers × shapes` displacement matrix at the markers.
    basis: DMatrix<f64>,
    /// Neutral marker positions.
    rest: Vec<Point3<f64>>,
    /// Weights of the previous frame (warm start).
    previous: DVector<f64>,
}

impl BlendshapeSolver {
    /// Precomputes the marker basis.
    ///
    /// # Errors
    /// [`BaselineError`] when the layout does not fit the dataset, the dataset has no
    /// shapes, or the parameters are invalid.
    pub fn new(
        dataset: &Dataset,
        layout: &MarkerLayout,
        params: &BlendshapeParams,
    ) -> Result<Self, BaselineError> {
        layout
            .validate_for(dataset)
            .map_err(|e| BaselineError::Layout(e.to_string()))?;
        if dataset.shapes.is_empty() {
            return Err(BaselineError::Param(
                "the dataset has no shapes to fit".into(),
            ));
        }
        if !(params.regularization >= 0.0 && params.regularization.is_finite()) {
            return Err(BaselineError::Param(format!(
                "regularization = {} must be ≥ 0",
                params.regularization
            )));
        }
        let x0 = &dataset.neutral.positions;
        let ns = dataset.shapes.len();
        let nm = layout.len();
        let basis = DMatrix::from_fn(3 * nm, ns, |r, s| {
            let v = layout.markers[r / 3].vertex as usize;
            (dataset.shapes[s].positions[v] - x0[v])[r % 3]
        });
        let shapes = dataset
            .shapes
            .iter()
            .map(|s| {
                s.positions
                    .iter()
                    .zip(x0)
                    .flat_map(|(p, q)| {
                        let d = p - q;
                        [d.x, d.y, d.z]
                    })
                    .collect()
            })
            .collect();
        Ok(Self {
            params: *params,
            neutral: x0.clone(),
            shapes,
            basis,
            rest: layout
                .markers
                .iter()
                .map(|m| x0[m.vertex as usize])
                .collect(),
            previous: DVector::zeros(ns),
        })
    }

    /// The weights of the last solved frame.
    pub fn weights(&self) -> &DVector<f64> {
        &self.previous
    }

    /// Fits the present bundles and returns every vertex.
    ///
    /// # Errors
    /// [`BaselineError::Frame`] when the frame does not fit the layout or has no bundle.
    pub fn solve(&mut self, bundles: &FrameBundles) -> Result<Vec<Point3<f64>>, BaselineError> {
        let present = super::present_mask(bundles, self.rest.len())?;
        let rows: Vec<usize> = (0..present.len())
            .filter(|&m| present[m])
            .flat_map(|m| [3 * m, 3 * m + 1, 3 * m + 2])
            .collect();
        let ns = self.shapes.len();
        let b = self.basis.select_rows(&rows);
        let mut rhs = DVector::zeros(rows.len());
        for (i, &r) in rows.iter().enumerate() {
            let m = r / 3;
            if let Some(p) = bundles.positions[m] {
                rhs[i] = (p - self.rest[m])[r % 3];
            }
        }
        let mut h = b.transpose() * &b;
        let g = b.transpose() * rhs;
        let mean_diag = (0..ns).map(|i| h[(i, i)]).sum::<f64>() / ns as f64;
        for i in 0..ns {
            h[(i, i)] += self.params.regularization * mean_diag.max(1e-12);
        }
        let w = box_qp(&h, &g, &self.previous, self.params.max_iterations);
        self.previous = w.clone();
        let mut out = self.neutral.clone();
        for (s, shape) in self.shapes.iter().enumerate() {
            let ws = w[s];
            if ws == 0.0 {
                continue;
            }
            for (p, d) in out.iter_mut().zip(shape.chunks_exact(3)) {
                p.x += ws * d[0];
                p.y += ws * d[1];
                p.z += ws * d[2];
            }
        }
        Ok(out)
    }
}
